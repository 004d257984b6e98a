"""The Gaussian filters' cost per path-step at every state dimension, side by side with peers
(issue 13, goals 1 and 6: the dimension sweep).

Model (n states, m = ⌈n/2⌉ measurements; a nonlinear coupled chain)::

    x_i[k+1] = 0.9 x_i[k] + 0.1 sin(x_{i+1}[k]) + w_i      (x_{n+1} := x_1; n = 1: 0.9 x + 0.1 sin x)
    y_j[k]   = x_j[k] + 0.1 x_{j+m}[k]² + v_j             (x_{j+m} := x_j past n)

with Q = 0.01 I, R = 0.1 I, m0 = 0, P0 = I, 1000 paths × 200 steps (``--paths``, ``--steps``):

* nlfilter EKF, UKF, CKF, GHKF (order 2 up to n = 8: 2ⁿ nodes), SecondOrderFilter (default form),
  batched over paths;
* filterpy ``ExtendedKalmanFilter`` and ``UnscentedKalmanFilter`` (a Python loop per path and
  step) on a subset of paths (``--filterpy-paths``), per path-step;
* with ``--backend numba`` or ``both``: the same nlfilter filters through ``run(..., backend="numba")``
  (the compiled loop; compile time, the first run on 10 steps, reported apart) and the largest
  difference of its means from the NumPy loop's;
* dynamax ``extended_kalman_filter`` / ``unscented_kalman_filter`` in float64 under ``jit`` +
  ``vmap`` (compile time excluded, reported apart), where jax and dynamax install.

Every time is the best of ``--repeat`` (3) runs, in µs per path-step. The largest difference of
filtered means against each peer is reported (same start: filterpy predicts first, so nlfilter
runs with ``start="predict"`` against it; dynamax updates first, as nlfilter's default). ``--label`` names the run (``before`` /
``after``): the JSON keeps one entry per label, so the timings of the code before a change stay
beside those after it. No timing is asserted anywhere.

Run: ``PYTHONPATH=src python benchmarks/bench_dimensions.py [--label after] [--dims 1 2 4 8 16]
[--backend numpy|numba|both]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import platform
import time

import numpy as np
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import CKF, EKF, GHKF, UKF, SecondOrderFilter
from nlfilter.simulate import simulate

Q, R = 0.01, 0.1
OUT = pathlib.Path(__file__).parent / "results" / "bench_dimensions.json"


def chain(n: int) -> DiscreteModel:
    x = sp.symbols(f"x1:{n + 1}")
    m = math.ceil(n / 2)
    f = [0.9 * x[i] + 0.1 * sp.sin(x[(i + 1) % n]) for i in range(n)]
    h = [x[j] + 0.1 * x[(j + m) % n] ** 2 for j in range(m)]
    return DiscreteModel(list(x), f, h, Q=Q * np.eye(n), R=R * np.eye(m), name=f"chain n={n}")


def best_of(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def compiled(flt, ys, m0, P0, repeat, **kw):
    """``flt.run(ys, m0, P0, backend="numba")``: compile seconds (its first run, on 10 steps), best
    seconds of ``repeat`` runs on all of ``ys``, and the estimates."""
    t0 = time.perf_counter()
    flt.run(ys[..., :10, :], m0, P0, backend="numba", **kw)
    first = time.perf_counter() - t0
    t, est = best_of(lambda: flt.run(ys, m0, P0, backend="numba", **kw), repeat)
    return first, t, est


def _np_fns(n):
    m = math.ceil(n / 2)
    nxt = [(i + 1) % n for i in range(n)]
    sq = [(j + m) % n for j in range(m)]

    def fx(x, dt=None):
        return 0.9 * x + 0.1 * np.sin(x[nxt])

    def hx(x):
        return x[:m] + 0.1 * x[sq] ** 2

    def F(x):
        J = 0.9 * np.eye(n)
        for i in range(n):
            J[i, nxt[i]] += 0.1 * np.cos(x[nxt[i]])
        return J

    def H(x):
        J = np.zeros((m, n))
        for j in range(m):
            J[j, j] += 1.0
            J[j, sq[j]] += 0.2 * x[sq[j]]
        return J

    return fx, hx, F, H


def filterpy_runs(n, ys, npth, repeat):
    """µs per path-step of filterpy's EKF and UKF and their means ``(npth, T, n)``."""
    return filterpy_pair(_np_fns(n), ys[:npth], np.zeros(n), np.eye(n), Q * np.eye(n),
                         R * np.eye(ys.shape[-1]), repeat)


def filterpy_pair(fns, ys, m0, P0, Qm, Rm, repeat):
    """filterpy's EKF and UKF over every path of ``ys (paths, T, m)`` with the NumPy functions
    ``fns = (fx, hx, F, H)`` of one state ``(n,)``: µs per path-step and the means ``(paths, T, n)``."""
    from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

    fx, hx, F, H = fns
    n, m = len(m0), ys.shape[-1]
    npth, T = ys.shape[:2]

    class FP(ExtendedKalmanFilter):
        def predict(self, u=0):
            self.F = F(self.x[:, 0])
            self.x = fx(self.x[:, 0])[:, None]
            self.P = self.F @ self.P @ self.F.T + self.Q

    def ekf():
        out = np.empty((npth, T, n))
        for p in range(npth):
            f = FP(n, m)
            f.x, f.P, f.Q, f.R = np.array(m0, float)[:, None], np.array(P0, float), Qm, Rm
            for k in range(T):
                f.predict()
                f.update(ys[p, k][:, None], lambda x: H(x[:, 0]), lambda x: hx(x[:, 0])[:, None])
                out[p, k] = f.x[:, 0]
        return out

    def ukf():
        out = np.empty((npth, T, n))
        for p in range(npth):
            pts = MerweScaledSigmaPoints(n, alpha=1.0, beta=2.0, kappa=0.0)
            f = UnscentedKalmanFilter(n, m, 1.0, hx, fx, pts)
            f.x, f.P, f.Q, f.R = np.array(m0, float), np.array(P0, float), Qm, Rm
            for k in range(T):
                f.predict()
                f.update(ys[p, k])
                out[p, k] = f.x
        return out

    te, me = best_of(ekf, repeat)
    tu, mu = best_of(ukf, repeat)
    return {"ekf": te / (npth * T) * 1e6, "ukf": tu / (npth * T) * 1e6}, {"ekf": me, "ukf": mu}


def dynamax_runs(n, ys, repeat):
    """µs per path-step of dynamax's EKF and UKF (jit + vmap, float64), compile seconds, means."""
    return dynamax_pair(lambda jnp: dynamax_chain(n, ys.shape[-1], jnp), ys, repeat, vmap=True)


def dynamax_chain(n, m, jnp):
    """The chain's ``(m0, P0, f, Q, h, R)`` in jax."""
    nxt = jnp.array([(i + 1) % n for i in range(n)])
    sq = jnp.array([(j + m) % n for j in range(m)])
    return (jnp.zeros(n), jnp.eye(n), lambda x: 0.9 * x + 0.1 * jnp.sin(x[nxt]), Q * jnp.eye(n),
            lambda x: x[:m] + 0.1 * x[sq] ** 2, R * jnp.eye(m))


def dynamax_pair(spec, ys, repeat, vmap=True):
    """dynamax's EKF and UKF (float64, ``jit``, over the paths of ``ys (paths, T, m)`` with ``vmap``,
    or over one trajectory ``ys (T, m)`` without): µs per (path-)step, compile seconds, means, jax's
    version. ``spec(jnp)`` gives the model ``(m0, P0, f, Q, h, R)``."""
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from dynamax.nonlinear_gaussian_ssm import (ParamsNLGSSM, UKFHyperParams, extended_kalman_filter,
                                                unscented_kalman_filter)

    m0, P0, f, Qm, h, Rm = spec(jnp)
    params = ParamsNLGSSM(initial_mean=m0, initial_covariance=P0, dynamics_function=f, dynamics_covariance=Qm,
                          emission_function=h, emission_covariance=Rm)
    hyper = UKFHyperParams(alpha=1.0, beta=2.0, kappa=0.0)
    over = jax.vmap if vmap else (lambda fn: fn)
    runs = {"ekf": jax.jit(over(lambda y: extended_kalman_filter(params, y).filtered_means)),
            "ukf": jax.jit(over(lambda y: unscented_kalman_filter(params, y, hyper).filtered_means))}
    yj = jnp.asarray(ys)
    us, compile_s, means = {}, {}, {}
    for name, run in runs.items():
        t0 = time.perf_counter()
        run(yj).block_until_ready()
        first = time.perf_counter() - t0
        t, out = best_of(lambda: run(yj).block_until_ready(), repeat)
        us[name] = t / math.prod(ys.shape[:-1]) * 1e6
        compile_s[name] = first - t
        means[name] = np.asarray(out)
    return us, compile_s, means, jax.__version__


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dims", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    ap.add_argument("--paths", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--filterpy-paths", type=int, default=5)
    ap.add_argument("--backend", choices=["numpy", "numba", "both"], default="numpy",
                    help="nlfilter's run loop: numpy (the reference, default), numba (compiled; compile time "
                         "apart) or both columns")
    ap.add_argument("--no-peers", action="store_true", help="nlfilter only")
    ap.add_argument("--peers-from", default=None, metavar="LABEL",
                    help="with --no-peers: copy the peers' timings from that run of the JSON (same machine)")
    ap.add_argument("--label", default="after", help="the entry of the JSON to write (e.g. before/after)")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    if a.backend != "numpy":
        import nlfilter.filters.compiled  # noqa: F401  (numba imported outside the compile times)
    rows = []
    notes = []
    jax_version = None
    for n in a.dims:
        md = chain(n)
        sim = simulate(md, a.steps, paths=a.paths, rng=n, m0=np.zeros(n), P0=np.eye(n))
        ys = np.ascontiguousarray(sim.ys)
        ps = a.paths * a.steps
        m0, P0 = np.zeros(n), np.eye(n)
        filters = {"ekf": EKF(md), "ukf": UKF(md), "ckf": CKF(md), "second-order": SecondOrderFilter(md)}
        if n <= 8:
            filters["ghkf-2"] = GHKF(md, order=2)
        row = {"n": n, "m": ys.shape[-1], "paths": a.paths, "steps": a.steps, "us_per_path_step": {}}
        for name, flt in filters.items():
            if a.backend != "numba":
                t, _ = best_of(lambda: flt.run(ys, m0, P0), a.repeat)
                row["us_per_path_step"][name] = t / ps * 1e6
            if a.backend != "numpy":
                first, t, est = compiled(flt, ys, m0, P0, a.repeat)
                row.setdefault("numba_us_per_path_step", {})[name] = t / ps * 1e6
                row.setdefault("numba_compile_seconds", {})[name] = first
                row.setdefault("numba_vs_numpy_max_abs_difference_of_means", {})[name] = float(
                    np.max(np.abs(est.means - flt.run(ys, m0, P0).means)))
        if not row["us_per_path_step"]:
            del row["us_per_path_step"]
        if not a.no_peers:
            # filterpy predicts first; dynamax, as nlfilter's default, updates first
            first = {k: cls(md, start="predict").run(ys, m0, P0).means for k, cls in (("ekf", EKF), ("ukf", UKF))}
            ours = {k: cls(md).run(ys, m0, P0).means for k, cls in (("ekf", EKF), ("ukf", UKF))}
            diffs = {}
            try:
                npth = min(a.filterpy_paths, a.paths)
                us, means = filterpy_runs(n, ys, npth, a.repeat)
                row["filterpy_us_per_path_step"] = us
                row["filterpy_paths_timed"] = npth
                for k in us:
                    diffs[f"{k}_vs_filterpy"] = float(np.max(np.abs(first[k][:npth] - means[k])))
            except ImportError as exc:
                notes.append(f"filterpy not installed: {exc}") if n == a.dims[0] else None
            try:
                us, comp, means, jax_version = dynamax_runs(n, ys, a.repeat)
                row["dynamax_us_per_path_step"] = us
                row["dynamax_compile_seconds"] = comp
                for k in us:
                    diffs[f"{k}_vs_dynamax"] = float(np.max(np.abs(ours[k] - means[k])))
                for col, key in (("us_per_path_step", "dynamax_over_nlfilter"),
                                 ("numba_us_per_path_step", "dynamax_over_nlfilter_numba")):
                    if col in row:
                        row[key] = {k: us[k] / row[col][k] for k in us}
            except ImportError as exc:
                notes.append(f"dynamax/jax not installed: {exc}") if n == a.dims[0] else None
            row["max_abs_difference_of_means"] = diffs
        rows.append(row)
        print(json.dumps(row), flush=True)
    out = pathlib.Path(a.out)
    res = json.loads(out.read_text()) if out.exists() else {}
    if a.peers_from:
        peers = {r["n"]: r for r in res["runs"][a.peers_from]["rows"]}
        notes.append(f"peers' timings copied from the run {a.peers_from!r} (the peers' code did not change)")
        for row in rows:
            for k, v in peers.get(row["n"], {}).items():
                if k not in row:
                    row[k] = v
            for col, key in (("us_per_path_step", "dynamax_over_nlfilter"),
                             ("numba_us_per_path_step", "dynamax_over_nlfilter_numba")):
                if "dynamax_us_per_path_step" in row and col in row:
                    row[key] = {k: v / row[col][k] for k, v in row["dynamax_us_per_path_step"].items()}
    res.update({"benchmark": "dimensions", "problem":
                "x_i' = 0.9 x_i + 0.1 sin(x_{i+1}) + w, y_j = x_j + 0.1 x_{j+m}^2 + v, Q = 0.01 I, R = 0.1 I, "
                "m0 = 0, P0 = I, m = ceil(n/2)"})
    res.setdefault("runs", {})[a.label] = {
        "machine": {"python": platform.python_version(), "numpy": np.__version__, "cpu": platform.machine(),
                    "cores": os.cpu_count(), "jax": jax_version,
                    "note": "2 cores shared with other jobs: best of N, noisy"},
        "repeat": a.repeat, "backend": a.backend, "notes": notes, "rows": rows}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
