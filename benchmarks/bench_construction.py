"""Model construction time, and the first filter run on the new model (issue 13, goal 4).

Two families of models at n = 4, 8, 12, 24, 42 states:

* ``linear``: ``DiscreteModel.linear(F, H, Q, R)`` with a dense random ``F`` (spectral radius 0.9),
  a dense random ``H`` (2 x n), ``Q = 0.01 I``, ``R = 0.1 I``, ``G`` the identity;
* ``chain``: the polynomial chain ``x_i' = 0.9 x_i + 0.1 x_{i-1}²`` (``x_1' = 0.9 x_1``), measured
  as ``y = (x_1, x_n²/2)``, ``G`` the identity.

For each: the construction (SymPy cache cleared before every repetition, so each is a cold
build), then on a fresh model the first EKF run and the first UKF run (10 paths x 20 steps; the
first run pays for whatever the model generates on first use) and a second EKF run (the
steady per-run cost), and for n <= 12 the first run of the second-order filter (which asks for the
Hessians). Each time is the best of ``--repeats`` (a repetition that takes longer than
``--slow`` seconds is not repeated). Writes ``benchmarks/results/bench_construction.json``;
``--before PATH`` embeds an earlier run (e.g. of the code before a change) beside this one.

Targets (issue 13): n = 24 under 1 s; the 42-state linear model under 5 s.

Run: ``python benchmarks/bench_construction.py [--sizes 4 8 12 24 42 --repeats 3]``
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread)

import argparse  # noqa: E402
import json  # noqa: E402
import pathlib  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402
from sympy.core.cache import clear_cache  # noqa: E402

from nlfilter import DiscreteModel  # noqa: E402
from nlfilter.filters.ekf import EKF  # noqa: E402
from nlfilter.filters.ukf import UKF  # noqa: E402
from nlfilter.simulate import simulate  # noqa: E402

PATHS, STEPS = 10, 20
PROBLEM = ("linear: DiscreteModel.linear with a dense random F (spectral radius 0.9), a dense 2 x n H, "
           "Q = 0.01 I, R = 0.1 I; chain: x_i' = 0.9 x_i + 0.1 x_{i-1}^2, y = (x_1, x_n^2/2), Q = 0.01 I, "
           "R = 0.1 I; construction with SymPy's cache cleared (cold), first EKF/UKF run on a fresh model "
           "(10 paths x 20 steps), second EKF run, first second-order run for n <= 12")


def linear(n: int) -> DiscreteModel:
    rng = np.random.default_rng(n)
    F = rng.standard_normal((n, n))
    F *= 0.9 / max(abs(np.linalg.eigvals(F)))
    H = rng.standard_normal((2, n))
    return DiscreteModel.linear(F, H, 0.01 * np.eye(n), 0.1 * np.eye(2), name=f"linear n={n}")


def chain(n: int) -> DiscreteModel:
    xs = sp.symbols(f"x1:{n + 1}")
    f = [0.9 * xs[0]] + [0.9 * xs[i] + 0.1 * xs[i - 1] ** 2 for i in range(1, n)]
    return DiscreteModel(list(xs), f, [xs[0], xs[-1] ** 2 / 2], Q=0.01 * np.eye(n), R=0.1 * np.eye(2),
                         name=f"chain n={n}")


FAMILIES = {"linear": linear, "chain": chain}


def best_of(fn, repeats: int, slow: float, fresh=None):
    """The best time of ``fn(arg)`` over ``repeats`` (``arg = fresh()`` built outside the timing)."""
    best = np.inf
    for _ in range(repeats):
        arg = fresh() if fresh is not None else None
        t = time.perf_counter()
        fn(arg)
        dt = time.perf_counter() - t
        best = min(best, dt)
        if dt > slow:
            break
    return best


def cold(make, n):
    def build(_):
        clear_cache()
        return make(n)
    return build


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 12, 24, 42])
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--slow", type=float, default=20.0, help="do not repeat a timing longer than this (s)")
    ap.add_argument("--second-order-max-n", type=int, default=12)
    ap.add_argument("--construct-only-above", type=int, default=None,
                    help="above this n time the construction only (the slow code before a change)")
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept): what code it measures")
    ap.add_argument("--before", default=None, help="an earlier JSON of this script to embed as 'before'")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_construction.json"))
    a = ap.parse_args()
    res = {"label": a.label, "problem": PROBLEM, "paths": PATHS, "steps": STEPS, "repeats": a.repeats,
           "seconds": {}, "targets": {"n=24 construction": "< 1 s", "n=42 linear construction": "< 5 s"}}
    for fam in a.families:
        make = FAMILIES[fam]
        for n in a.sizes:
            row = {}
            row["construct"] = best_of(cold(make, n), a.repeats, a.slow)
            if a.construct_only_above is not None and n > a.construct_only_above:
                res["seconds"][f"{fam} n={n}"] = row
                print(fam, n, row, flush=True)
                continue
            md0 = make(n)
            sim = simulate(md0, STEPS, paths=PATHS, rng=0, m0=np.zeros(n), P0=0.1 * np.eye(n))
            m0, P0 = np.zeros(n), 0.1 * np.eye(n)
            row["ekf_first_run"] = best_of(lambda md: EKF(md).run(sim.ys, m0, P0), a.repeats, a.slow,
                                           fresh=lambda: make(n))
            row["ukf_first_run"] = best_of(lambda md: UKF(md).run(sim.ys, m0, P0), a.repeats, a.slow,
                                           fresh=lambda: make(n))
            row["ekf_second_run"] = best_of(lambda md: EKF(md).run(sim.ys, m0, P0), a.repeats, a.slow,
                                            fresh=lambda: (EKF(md0).run(sim.ys, m0, P0), md0)[1])
            if n <= a.second_order_max_n:
                from nlfilter.filters.second_order import SecondOrderFilter
                row["second_order_first_run"] = best_of(lambda md: SecondOrderFilter(md).run(sim.ys, m0, P0),
                                                        a.repeats, a.slow, fresh=lambda: make(n))
            res["seconds"][f"{fam} n={n}"] = row
            print(fam, n, {k: round(v, 4) for k, v in row.items()}, flush=True)
    sec = res["seconds"]
    met = {}
    if "linear n=24" in sec or "chain n=24" in sec:
        met["n=24 construction"] = all(sec[k]["construct"] < 1.0 for k in ("linear n=24", "chain n=24") if k in sec)
    if "linear n=42" in sec:
        met["n=42 linear construction"] = sec["linear n=42"]["construct"] < 5.0
    res["targets_met"] = met
    if a.before:
        before = json.loads(pathlib.Path(a.before).read_text())
        res["before"] = {"seconds": before["seconds"], "machine": before.get("machine", before.get("environment")),
                         "note": before.get("label", "the code before the change")}
        res["construction_speedup"] = {k: before["seconds"][k]["construct"] / sec[k]["construct"]
                                       for k in sec if k in before["seconds"]}
    _pin.write(a.out, a.label, res, benchmark="construction")


if __name__ == "__main__":
    main()
