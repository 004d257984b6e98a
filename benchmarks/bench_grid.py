"""Grid filter speed and the BLAS thread cliff (issue 13, goal 5), side by side in one run.

A 1-D nonlinear model ``x' = 0.9 x + 0.5 sin x + w`` (Q = 0.5), ``y = x³/10 + v`` (R = 0.1) on a
401-point grid over [−6, 6], 100 paths × 200 steps:

* nlfilter ``GridFilter`` as shipped (``blas_threads = 1``: the run loop limits BLAS to one
  thread through threadpoolctl, once per run);
* the same filter with ``blas_threads = None`` (the BLAS library's default threads: the old
  behaviour);
* a hand-written dense point-mass filter (kernel matrix, ``p @ K``, likelihood, normalize: 10
  lines of NumPy), with the default BLAS threads and with one thread.

Best of ``--repeat`` runs; writes ``benchmarks/results/bench_grid.json`` (µs per path-step, the
ratios, the largest difference of the filtered means between nlfilter and the hand-written grid,
the BLAS libraries and their default threads). The machine was shared when noted. The one
benchmark not pinned to one core and one thread (``NLFILTER_BENCH_PIN=0`` before :mod:`_pin`): it
measures the thread count itself.

Run: ``python benchmarks/bench_grid.py [--paths 100 --steps 200 --points 401 --repeat 3]``
"""

from __future__ import annotations

import os

os.environ["NLFILTER_BENCH_PIN"] = "0"  # the one unpinned benchmark: it measures the BLAS thread count itself
import _pin  # noqa: E402,F401  (first: the record of what was (not) pinned, the JSON)

import argparse  # noqa: E402
import json  # noqa: E402
import pathlib  # noqa: E402

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402
from threadpoolctl import threadpool_info, threadpool_limits  # noqa: E402

from nlfilter import DiscreteModel, simulate  # noqa: E402
from nlfilter.filters import GridFilter  # noqa: E402


def model():
    x = sp.Symbol("x")
    return DiscreteModel([x], [0.9 * x + 0.5 * sp.sin(x)], [x**3 / 10], Q=0.5, R=0.1, name="grid-bench")


def hand_grid(ys, X, m0, P0, Q, R):
    """A dense point-mass filter written directly (the yardstick of goal 5)."""
    f = 0.9 * X + 0.5 * np.sin(X)
    K = np.exp(-0.5 * (X[None, :] - f[:, None]) ** 2 / Q)
    K /= K.sum(axis=1, keepdims=True)
    h = X**3 / 10
    p = np.exp(-0.5 * (X - m0) ** 2 / P0)
    p = np.broadcast_to(p / p.sum(), (ys.shape[0], X.size)).copy()
    means = np.empty(ys.shape[:2])
    for k in range(ys.shape[1]):
        if k:
            p = p @ K
        p = p * np.exp(-0.5 * (ys[:, k, :1] - h[None, :]) ** 2 / R)
        p /= p.sum(axis=1, keepdims=True)
        means[:, k] = p @ X
    return means


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=100)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--points", type=int, default=401)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--shared", action="store_true", help="note in the JSON that the machine was shared")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_grid.json"))
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    a = ap.parse_args(argv)
    md = model()
    ys = simulate(md, a.steps, paths=a.paths, rng=0, m0=[0.0], P0=[[1.0]]).ys
    flt = GridFilter(md, (-6.0, 6.0), a.points)
    flt.run(ys[:2], [0.0], [[1.0]])  # kernel built and cached outside the timings
    X = flt.X[:, 0]
    per = a.paths * a.steps / 1e6  # seconds -> µs per path-step
    res = {}
    res["nlfilter (1 BLAS thread, shipped)"], est = _pin.best_of(lambda: flt.run(ys, [0.0], [[1.0]]), a.repeat)
    flt.blas_threads = None
    res["nlfilter (default BLAS threads)"], _ = _pin.best_of(lambda: flt.run(ys, [0.0], [[1.0]]), a.repeat)
    res["hand-written (default BLAS threads)"], hand = _pin.best_of(lambda: hand_grid(ys, X, 0.0, 1.0, 0.5, 0.1), a.repeat)
    with threadpool_limits(1, user_api="blas"):
        res["hand-written (1 BLAS thread)"], _ = _pin.best_of(lambda: hand_grid(ys, X, 0.0, 1.0, 0.5, 0.1), a.repeat)
    us = {k: v / per for k, v in res.items()}
    out = {"task": f"grid filter, {a.points} points, {a.paths} paths x {a.steps} steps, best of {a.repeat}",
           "us_per_path_step": us,
           "ratio_default_threads_over_shipped": us["nlfilter (default BLAS threads)"] / us["nlfilter (1 BLAS thread, shipped)"],
           "ratio_shipped_over_hand_1_thread": us["nlfilter (1 BLAS thread, shipped)"] / us["hand-written (1 BLAS thread)"],
           "target": "no thread cliff; no worse than a hand-written dense grid",
           "max_abs_mean_difference_vs_hand": float(np.max(np.abs(est.means[..., 0] - hand))),
           "blas": [{k: i.get(k) for k in ("internal_api", "num_threads", "version")} for i in threadpool_info()
                    if i.get("user_api") == "blas"],
           "shared": a.shared}
    print(json.dumps(out, indent=2))
    _pin.write(a.out, a.label, out, benchmark="grid")


if __name__ == "__main__":
    main()
