"""One trajectory, many steps: the cost per step of filtering a single path, side by side with
peers (issue 13, goal 3: one trajectory within 2× of dynamax jit and faster than filterpy).

Two models, one path each (``--steps``, default 20000):

* (a) the scalar cubic sensor of ``bench_ekf.py``: ``x[k+1] = 0.99 x[k] + w``, ``y = x³ + v``,
  Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1;
* (b) the n = 4 sin-coupled chain of ``bench_dimensions.py`` (``chain(4)``, m = 2 measurements,
  m0 = 0, P0 = I).

Columns, in one run, µs per step (best of ``--repeat``, 3):

* nlfilter ``EKF``, ``UKF`` and ``SecondOrderFilter`` (form ``"truncated"``) through the NumPy loop
  (``backend="numpy"``, on the first ``--numpy-steps`` steps, 2000: its cost per step does not
  depend on the length) and through the compiled loop (``backend="numba"``; compile time, the
  first run on 10 steps, reported apart);
* filterpy ``ExtendedKalmanFilter`` / ``UnscentedKalmanFilter`` (a Python loop over steps, the
  helpers of ``bench_dimensions.py``);
* dynamax ``extended_kalman_filter`` / ``unscented_kalman_filter`` in float64 under ``jit``, no
  ``vmap`` (one trajectory; compile time reported apart);
* the second-order filter has no peer: nlfilter only.

The largest |difference| of filtered means is reported for numba against numpy (the NumPy steps)
and for each peer against nlfilter numba over all steps, with the same start: filterpy predicts
first (nlfilter ``start="predict"``), dynamax updates first (nlfilter's default). Writes
``benchmarks/results/bench_single_path.json`` with the machine, versions, rows and the ratios
dynamax / numba, filterpy / numba and numpy / numba (> 1: nlfilter numba faster). No timing is
asserted anywhere.

Run: ``PYTHONPATH=src python benchmarks/bench_single_path.py [--steps 20000] [--repeat 3] [--quick]``
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import sys

import numpy as np
import sympy as sp

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from bench_dimensions import _np_fns, best_of, chain, compiled, dynamax_chain, dynamax_pair, filterpy_pair  # noqa: E402

from nlfilter import DiscreteModel  # noqa: E402
from nlfilter.filters import EKF, UKF, SecondOrderFilter  # noqa: E402
from nlfilter.filters import compiled as _numba_loop  # noqa: E402,F401  (numba imported outside the compile times)
from nlfilter.simulate import simulate  # noqa: E402

OUT = pathlib.Path(__file__).parent / "results" / "bench_single_path.json"
A, Q, R = 0.99, 0.01, 0.1  # the cubic sensor of bench_ekf.py (1 - dt, dt = 0.01)


def cubic() -> DiscreteModel:
    x = sp.Symbol("x")
    return DiscreteModel([x], [A * x], [x**3], Q=Q, R=R, name="cubic sensor")


def cubic_np():
    """The cubic sensor's ``(fx, hx, F, H)`` for filterpy, on a state ``(1,)``."""
    return (lambda x, dt=None: A * x, lambda x: x**3, lambda x: np.array([[A]]),
            lambda x: np.array([[3 * x[0] ** 2]]))


def cubic_jax(jnp):
    return (jnp.array([0.5]), jnp.array([[0.1]]), lambda x: A * x, jnp.array([[Q]]), lambda x: x**3,
            jnp.array([[R]]))


def problems():
    """name -> (model, m0, P0, filterpy functions, dynamax spec)."""
    return {"cubic sensor (n=1)": (cubic(), np.array([0.5]), np.array([[0.1]]), cubic_np(), cubic_jax),
            "chain (n=4)": (chain(4), np.zeros(4), np.eye(4), _np_fns(4),
                            lambda jnp: dynamax_chain(4, 2, jnp))}


def maxdiff(a, b):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


def measure(name, md, m0, P0, fns, spec, a):
    sim = simulate(md, a.steps, paths=1, rng=13, m0=m0, P0=P0)
    ys = np.ascontiguousarray(sim.ys)  # (1, T, m)
    T, Tn = a.steps, min(a.numpy_steps, a.steps)
    n = len(m0)
    row = {"problem": name, "n": int(n), "m": int(ys.shape[-1]), "steps": T, "numpy_steps": Tn,
           "us_per_step": {}, "compile_seconds": {}, "max_abs_difference_of_means": {}}
    us, comp, diff = row["us_per_step"], row["compile_seconds"], row["max_abs_difference_of_means"]
    filters = {"ekf": EKF(md), "ukf": UKF(md), "second-order": SecondOrderFilter(md, form="truncated")}
    numba_means = {}
    for k, flt in filters.items():
        t, ref = best_of(lambda: flt.run(ys[:, :Tn], m0, P0), a.repeat)
        us.setdefault("nlfilter_numpy", {})[k] = t / Tn * 1e6
        first, t, est = compiled(flt, ys, m0, P0, a.repeat)
        us.setdefault("nlfilter_numba", {})[k] = t / T * 1e6
        comp.setdefault("nlfilter_numba", {})[k] = first
        numba_means[k] = est.means[0]
        diff[f"{k}_numba_vs_numpy"] = maxdiff(est.means[0, :Tn], ref.means[0])
    try:
        t_fp, fp_means = filterpy_pair(fns, ys, m0, P0, Q * np.eye(n), R * np.eye(ys.shape[-1]),
                                       a.repeat)
        us["filterpy"] = t_fp
        for k in t_fp:  # filterpy predicts first
            pred = (EKF if k == "ekf" else UKF)(md, start="predict").run(ys, m0, P0, backend="numba").means
            diff[f"{k}_filterpy_vs_numba"] = maxdiff(fp_means[k][0], pred[0])
    except ImportError as exc:
        row["notes"] = [f"filterpy not installed: {exc}"]
    try:
        t_dm, c_dm, dm_means, row["jax"] = dynamax_pair(spec, ys[0], a.repeat, vmap=False)
        us["dynamax"] = t_dm
        comp["dynamax"] = c_dm
        for k in t_dm:
            diff[f"{k}_dynamax_vs_numba"] = maxdiff(dm_means[k], numba_means[k])
    except ImportError as exc:
        row.setdefault("notes", []).append(f"dynamax/jax not installed: {exc}")
    nb = us["nlfilter_numba"]
    row["ratios"] = {f"{col}_over_numba": {k: v / nb[k] for k, v in us[col].items()}
                     for col in ("dynamax", "filterpy", "nlfilter_numpy") if col in us}
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--numpy-steps", type=int, default=2000, help="steps of the NumPy loop (per step reported)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="smoke size: 300 steps, 100 NumPy steps, 1 repeat")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    if a.quick:
        a.steps, a.numpy_steps, a.repeat = 300, 100, 1
    rows = []
    for name, (md, m0, P0, fns, spec) in problems().items():
        row = measure(name, md, m0, P0, fns, spec, a)
        rows.append(row)
        print(json.dumps(row), flush=True)
    versions = {"python": platform.python_version(), "numpy": np.__version__}
    for mod in ("numba", "jax", "dynamax", "filterpy"):
        try:
            versions[mod] = __import__(mod).__version__
        except (ImportError, AttributeError):
            versions[mod] = None
    res = {"benchmark": "single path", "quick": a.quick,
           "problems": {"cubic sensor (n=1)": "x' = 0.99 x + w, y = x^3 + v, Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1",
                        "chain (n=4)": "bench_dimensions.chain(4): x_i' = 0.9 x_i + 0.1 sin(x_{i+1}) + w, "
                                       "y_j = x_j + 0.1 x_{j+2}^2 + v, Q = 0.01 I, R = 0.1 I, m0 = 0, P0 = I"},
           "machine": {**versions, "cpu": platform.machine(), "cores": os.cpu_count(),
                       "note": "2 cores shared with other jobs (machine shared): best of N, noisy"},
           "repeat": a.repeat, "units": "µs per step of one trajectory; compile seconds apart",
           "second_order_form": "truncated (no peer)", "rows": rows}
    out = pathlib.Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2, ensure_ascii=False) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
