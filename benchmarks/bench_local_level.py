"""The local-level maximum-likelihood fit, side by side with statsmodels (issue 28, items 3, 5 and 7).

The 100-step scalar local level ``x[k+1] = x[k] + w`` (variance q), ``y[k] = x[k] + v`` (variance
r); both variances estimated by maximum likelihood from one record:

* ``--data nile`` (default): the Nile's annual flow 1871–1970 (statsmodels' ``nile`` data set, 100
  values; the textbook local-level example of Durbin & Koopman);
* ``--data simulated``: 100 steps simulated with q = 0.5, r = 1 (seed 0).

Sides, each on one core with one thread (:mod:`_pin`, imported first):

* statsmodels ``UnobservedComponents(y, "llevel", loglikelihood_burn=0).fit(disp=False)``: its
  default fit (L-BFGS, standard errors from the outer product of gradients), with its default
  approximate diffuse prior N(0, 10⁶) and, through ``loglikelihood_burn=0``, the first
  observation's term in the likelihood (statsmodels' default burns it; nlfilter has no burn);
* ``nlfilter.fit(model, ys, params0, filter="kf", m0=0, P0=1e6)``: the same prior and likelihood,
  from statsmodels' own starting values; the default call (no ``backend=``: what ``fit``'s default
  is here is recorded) and the columns of ``--columns`` (``numpy``, ``numba``: a backend that
  refuses the Kalman filter is a note).

Each side is timed ``--rounds`` (7) times in alternation (statsmodels, then each nlfilter column,
then again): the first round apart (a compile, a cache load, first-call imports), the best and
the median of the per-round ratios of the others (paired: the load is the same within a round).
Reported: wall seconds, the estimates of both and their relative difference, and the
log-likelihood of each side's optimum (statsmodels' ``loglike``: the same function). Writes the
run ``--label`` of ``benchmarks/results/bench_local_level.json``.

Run: ``taskset -c 1 python benchmarks/bench_local_level.py [--rounds 7] [--data nile|simulated]``
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread for every side)

import argparse  # noqa: E402
import inspect  # noqa: E402
import pathlib  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402

from nlfilter import DiscreteModel, fit, simulate  # noqa: E402

OUT = pathlib.Path(__file__).parent / "results" / "bench_local_level.json"
P0 = 1e6  # statsmodels' approximate diffuse variance (``ssm.initial_variance``)


def local_level(q=1.0, r=1.0) -> DiscreteModel:
    x = sp.Symbol("x")
    qs, rs = sp.symbols("q r", positive=True)
    return DiscreteModel([x], f=[x], h=[x], Q=[[qs]], R=[[rs]], params={qs: q, rs: r}, name="local level")


def data(which: str) -> np.ndarray:
    if which == "nile":
        import statsmodels.api as sm

        return sm.datasets.nile.load_pandas().data["volume"].to_numpy(float)
    md = local_level(0.5, 1.0)
    return simulate(md, 100, paths=1, rng=0, m0=0.0, P0=1.0).ys[0, :, 0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", choices=["nile", "simulated"], default="nile")
    ap.add_argument("--rounds", type=int, default=7, help="alternating rounds, the first apart")
    ap.add_argument("--columns", nargs="*", choices=["numpy", "numba"], default=["numpy", "numba"],
                    help="explicit backends timed beside the default call")
    ap.add_argument("--quick", action="store_true", help="smoke: 2 rounds")
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    if a.quick:
        a.rounds = 2
    from statsmodels.tsa.statespace.structural import UnobservedComponents

    y = data(a.data)
    mod = UnobservedComponents(y, "llevel", loglikelihood_burn=0)
    start = dict(zip(mod.param_names, mod.start_params))
    params0 = {"q": float(start["sigma2.level"]), "r": float(start["sigma2.irregular"])}
    md, ys = local_level(**params0), y[None, :, None]
    fit_default = inspect.signature(fit).parameters["backend"].default
    notes = [f"fit's default backend here: {fit_default!r}"]
    sides = {"statsmodels": lambda: mod.fit(disp=False),
             f"nlfilter default call (fit's backend={fit_default!r})":
                 lambda: fit(md, ys, params0, filter="kf", m0=0.0, P0=P0)}
    for col in a.columns:
        if col == fit_default:
            notes.append(f"backend={col!r} is the default call here: one column")
            continue
        try:
            fit(md, ys[:, :5], {"q": params0["q"]}, filter="kf", m0=0.0, P0=P0, backend=col, se=False)
        except TypeError as exc:
            notes.append(f"backend={col!r}: {exc}")
            continue
        sides[f"nlfilter backend={col!r}"] = lambda col=col: fit(md, ys, params0, filter="kf", m0=0.0, P0=P0,
                                                                  backend=col)
    times = {k: [] for k in sides}
    results = {}
    for _ in range(a.rounds):
        for k, fn in sides.items():
            t = time.perf_counter()
            results[k] = fn()
            times[k].append(time.perf_counter() - t)
    sm_res = results["statsmodels"]
    sm_q, sm_r = float(sm_res.params[1]), float(sm_res.params[0])
    out = {"data": a.data, "steps": len(y), "rounds": a.rounds, "params0": params0, "notes": notes, "sides": {}}
    for k, ts in times.items():
        later = ts[1:] or ts
        side = {"first_seconds": ts[0], "best_seconds": min(later), "median_seconds": statistics.median(later)}
        if k == "statsmodels":
            side.update(q=sm_q, r=sm_r, loglik=float(sm_res.llf), converged=bool(sm_res.mle_retvals["converged"]))
        else:
            res = results[k]
            q, r = float(res.params["q"]), float(res.params["r"])
            side.update(q=q, r=r, loglik=float(res.loglik), converged=bool(res.converged),
                        statsmodels_loglike_at_this_optimum=float(mod.loglike(np.array([r, q]))),
                        max_rel_difference_from_statsmodels=max(abs(q - sm_q) / sm_q, abs(r - sm_r) / sm_r),
                        loglik_minus_statsmodels=float(mod.loglike(np.array([r, q]))) - float(sm_res.llf),
                        evaluations=int(res.nfev))
        out["sides"][k] = side
    rows = []
    for k in sides:
        if k == "statsmodels":
            continue
        ratios = [s / o for s, o in zip(times["statsmodels"][1:], times[k][1:])]
        rows.append(_pin.side_by_side(k, "statsmodels UnobservedComponents('llevel').fit", out["sides"][k]["best_seconds"],
                                      out["sides"]["statsmodels"]["best_seconds"], "wall seconds per fit (best)",
                                      paired_median_peer_over_ours=statistics.median(ratios) if ratios else None,
                                      first_call_peer_over_ours=times["statsmodels"][0] / times[k][0]))
    out["rows"] = rows
    for r in rows:
        print(f"{r['ours']}: {r['ours_value']:.3f} s, statsmodels {r['peer_value']:.3f} s: "
              f"statsmodels/ours {r['peer_over_ours']:.3f} (paired median {r['paired_median_peer_over_ours']})")
    _pin.write(a.out, a.label, out, benchmark="local level")


if __name__ == "__main__":
    main()
