"""One trajectory, many steps: the cost per step of filtering a single path, side by side with
peers (issue 13, goal 3; issue 28, item 7: every side on one core with one thread, :mod:`_pin`).

Two models, one path each (``--steps``, default 20000):

* (a) the scalar cubic sensor of ``bench_ekf.py``: ``x[k+1] = 0.99 x[k] + w``, ``y = x³ + v``,
  Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1;
* (b) the n = 4 sin-coupled chain of ``bench_dimensions.py`` (``chain(4)``, m = 2 measurements,
  m0 = 0, P0 = I).

Sides, in one run, µs per step (best of ``--repeat``, 3, calls; the first apart):

* nlfilter ``EKF``, ``UKF`` and ``SecondOrderFilter`` (form ``"truncated"``) in the columns
  ``default`` (``run`` with no ``backend=``; what it resolves to is recorded), ``numpy`` and
  ``numba`` (compile apart and included). A column that runs the NumPy loop runs the first
  ``--numpy-steps`` steps (2000: its cost per step does not depend on the length); its
  "compile included" time is its first call with the run part scaled to all the steps;
* filterpy ``ExtendedKalmanFilter`` / ``UnscentedKalmanFilter`` (a Python loop over steps);
* dynamax ``extended_kalman_filter`` / ``unscented_kalman_filter`` in float64 under ``jit``, no
  ``vmap`` (one trajectory; compile apart and included);
* the second-order filter has no peer: nlfilter only.

The largest |difference| of filtered means is reported between the columns and for each peer,
with the same start: filterpy predicts first (nlfilter ``start="predict"``), dynamax updates first
(nlfilter's default). Writes the run ``--label`` of ``benchmarks/results/bench_single_path.json``:
the sides, and the rows naming both (``peer_over_ours`` > 1: nlfilter faster). No timing is
asserted anywhere.

Run: ``taskset -c 1 python benchmarks/bench_single_path.py [--steps 20000] [--repeat 3] [--quick]``
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread for every side)

import argparse  # noqa: E402
import pathlib  # noqa: E402

import numpy as np  # noqa: E402
from _peers import (dynamax_filters, filterpy_pair, maxdiff, nlfilter_sides, per_step, rows_against,  # noqa: E402
                    scaled)
from _models import CUBIC_Q, CUBIC_R, Q, R, chain, chain_jax, chain_np, cubic, cubic_jax, cubic_np  # noqa: E402

from nlfilter.filters import EKF, UKF, SecondOrderFilter  # noqa: E402
from nlfilter.simulate import simulate  # noqa: E402

OUT = pathlib.Path(__file__).parent / "results" / "bench_single_path.json"
FILTERS = {"ekf": EKF, "ukf": UKF, "second-order": lambda md: SecondOrderFilter(md, form="truncated")}


def problems():
    """name -> (model, m0, P0, filterpy functions, dynamax spec, Q, R)."""
    return {"cubic sensor (n=1)": (cubic(), np.array([0.5]), np.array([[0.1]]), cubic_np(), cubic_jax,
                                   np.array([[CUBIC_Q]]), np.array([[CUBIC_R]])),
            "chain (n=4)": (chain(4), np.zeros(4), np.eye(4), chain_np(4), lambda jnp: chain_jax(4, jnp),
                            Q * np.eye(4), R * np.eye(2))}


def measure(name, md, m0, P0, fns, spec, Qm, Rm, a):
    sim = simulate(md, a.steps, paths=1, rng=13, m0=m0, P0=P0)
    ys = np.ascontiguousarray(sim.ys)  # (1, T, m)
    T, Tn = a.steps, min(a.numpy_steps, a.steps)
    n = len(m0)
    row = {"problem": name, "n": int(n), "m": int(ys.shape[-1]), "steps": T, "numpy_steps": Tn,
           "nlfilter": {}, "notes": [], "max_abs_difference_of_means": {}}
    diff = row["max_abs_difference_of_means"]
    on_numpy = [c for c in a.columns if c == "numpy" or (c == "default" and _pin.default_backend() == "numpy")]
    ours, est = {}, {}
    for k in FILTERS:
        ours[k], est[k] = {}, {}
        for cols, steps in ((on_numpy, Tn), ([c for c in a.columns if c not in on_numpy], T)):
            if not cols:
                continue
            t, e, notes = nlfilter_sides(lambda: FILTERS[k](md), ys[:, :steps], m0, P0, a.repeat, cols)
            row["notes"] += [f"{k}: {x}" for x in notes if f"{k}: {x}" not in row["notes"]]
            done = {}  # the numpy column may be the default call's own measurement: one object, kept one
            for col in t:
                ours[k][col] = done.setdefault(id(t[col]), scaled(t[col], T / steps))
                row["nlfilter"].setdefault(k, {})[col] = {**per_step(t[col], steps), "steps": steps}
            est[k].update(e)
        base = est[k].get("numpy")
        for col, e in est[k].items():
            if base is not None and e is not base:  # not the default call's own (same) measurement
                diff[f"{k}: {col} vs numpy"] = maxdiff(e.means[0, :Tn], base.means[0, :Tn])
    full = {k: next((e for c, e in est[k].items() if e.means.shape[1] == T), None) for k in est}
    rows = []
    try:
        t_fp, fp_means = filterpy_pair(fns, ys, m0, P0, Qm, Rm, a.repeat)
        row["filterpy"] = {k: {"us_per_step": v * 1e6} for k, v in t_fp.items()}
        rows += rows_against(ours, "filterpy (a Python loop)", {k: {"best": v * T} for k, v in t_fp.items()}, T)
        for k in t_fp:  # filterpy predicts first
            pred = (EKF if k == "ekf" else UKF)(md, start="predict").run(ys[:, :Tn], m0, P0, backend="numpy").means
            diff[f"{k}: filterpy vs numpy"] = maxdiff(fp_means[k][0, :Tn], pred[0])
    except ImportError as exc:
        row["notes"].append(f"filterpy not installed: {exc}")
    try:
        t_dm, dm_means = dynamax_filters(spec, ys[0], a.repeat, vmap=False, kinds=("ekf", "ukf"))
        row["dynamax"] = {k: per_step(v, T) for k, v in t_dm.items()}
        rows += rows_against(ours, "dynamax jit float64", t_dm, T)
        for k in t_dm:
            if full.get(k) is not None:
                diff[f"{k}: dynamax vs nlfilter (all steps)"] = maxdiff(dm_means[k], full[k].means[0])
    except ImportError as exc:
        row["notes"].append(f"dynamax/jax not installed: {exc}")
    row["rows"] = rows
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--numpy-steps", type=int, default=2000, help="steps of the NumPy loop (per step reported)")
    ap.add_argument("--repeat", type=int, default=3, help="calls per side, the first (compile) apart")
    ap.add_argument("--columns", nargs="+", choices=["default", "numpy", "numba"],
                    default=["default", "numpy", "numba"], help="nlfilter's calls: default (no backend=), numpy, numba")
    ap.add_argument("--quick", action="store_true", help="smoke size: 300 steps, 100 NumPy steps, 2 calls")
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    if a.quick:
        a.steps, a.numpy_steps, a.repeat = 300, 100, 2
    rows = []
    for name, problem in problems().items():
        rows.append(measure(name, *problem, a))
        for r in rows[-1]["rows"]:
            print(f"{name}: {r['ours']} vs {r['peer']} ({r['compile']}): {r['peer_over_ours']:.2f}x", flush=True)
    _pin.write(a.out, a.label, {
        "quick": a.quick, "repeat": a.repeat, "columns": a.columns,
        "problems": {"cubic sensor (n=1)": "x' = 0.99 x + w, y = x^3 + v, Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1",
                     "chain (n=4)": "_models.chain(4): x_i' = 0.9 x_i + 0.1 sin(x_{i+1}) + w, "
                                    "y_j = x_j + 0.1 x_{j+2}^2 + v, Q = 0.01 I, R = 0.1 I, m0 = 0, P0 = I"},
        "units": "µs per step of one trajectory; compile apart and included", "second_order_form": "truncated (no peer)",
        "rows": rows}, benchmark="single path")


if __name__ == "__main__":
    main()
