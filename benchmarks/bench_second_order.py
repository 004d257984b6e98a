"""Speed of the second-order filters (seed 004): paths × steps per second, batched over paths, on
the NumPy loop and the compiled loop side by side (``--columns``).

    PYTHONPATH=src python benchmarks/bench_second_order.py [--paths 10000] [--columns numpy numba] [--out FILE]

Cases: the falling body (n = 3, continuous dynamics with RK4 substeps, discrete range measurements)
for every form, the scalar quadratic problem (discrete) and the state-noise SDE (continuous). Each
column is ``run(..., backend=COLUMN)`` (``default``: no ``backend=``), its first call (a compile or a
cache load) apart from the best of the others (``_pin.first_and_best``, wall and CPU seconds); a
row gives each column's path-steps per second and the compiled loop's speed over the NumPy loop's.
No timing is asserted anywhere.
"""

from __future__ import annotations

import _pin  # (first: one core, one thread; its first_and_best times the columns)

import argparse  # noqa: E402
import pathlib  # noqa: E402

import numpy as np  # noqa: E402

from nlfilter import problems as pb  # noqa: E402
from nlfilter.filters.second_order import (ContinuousDiscreteSecondOrderFilter, ContinuousSecondOrderFilter,  # noqa: E402
                                           SecondOrderFilter)
from nlfilter.simulate import simulate  # noqa: E402

FORMS = ("first-order", "truncated", "truncated-jazwinski", "modified", "gaussian")


def _row(flt, ys, m0, P0, columns, repeat, **fields):
    """One case: each column's first call and best (seconds), path-steps per second, and the compiled
    loop's speed-up over the NumPy loop (best CPU time)."""
    work = ys.shape[0] * ys.shape[1]
    row = dict(fields)
    for col in columns:
        kw = {} if col == "default" else {"backend": col}
        try:
            timing, _ = _pin.first_and_best(lambda kw=kw: flt.run(ys, m0, P0, on_divergence="mark", **kw), repeat)
        except TypeError as exc:  # a filter or model the compiled loop does not take: why, in the row
            row[col] = {"refused": str(exc).split(": ", 1)[-1]}
            continue
        row[col] = {"first_s": timing["first"], "best_s": timing["best"], "best_cpu_s": timing["best_cpu"],
                    "path_steps_per_s": work / timing["best"]}
        if col == "default":
            row[col]["backend"] = flt.backend_for(ys.shape[0], ys.shape[1])[0]
    if "best_cpu_s" in row.get("numpy", {}) and "best_cpu_s" in row.get("numba", {}):
        row["numba_over_numpy_cpu"] = row["numpy"]["best_cpu_s"] / row["numba"]["best_cpu_s"]
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=10_000)
    ap.add_argument("--steps", type=int, default=20, help="measurement steps per run")
    ap.add_argument("--substeps", type=int, default=20, help="RK4 substeps per falling-body interval")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_second_order.json"))
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    ap.add_argument("--columns", nargs="+", choices=["default", "numpy", "numba"], default=["numpy", "numba"],
                    help="the loops timed: run(..., backend=COLUMN); default: no backend=")
    ap.add_argument("--repeat", type=int, default=3, help="calls per column, the first (compile) apart")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    rows = []

    fb = pb.falling_body()
    ys = fb.model.h(np.broadcast_to(fb.x0, (args.paths, args.steps, 3)), 0.0) + 100.0 * rng.standard_normal(
        (args.paths, args.steps, 1))
    for form in FORMS:
        flt = ContinuousDiscreteSecondOrderFilter(fb.model, fb.dt, form=form, substeps=args.substeps,
                                                  start="predict")
        rows.append(_row(flt, ys, fb.m0, fb.P0, args.columns, args.repeat, problem="falling-body", form=form,
                         paths=args.paths, steps=args.steps, substeps=args.substeps))

    q = pb.quadratic()
    sim = simulate(q.model, args.steps, paths=args.paths, rng=rng, m0=q.m0, P0=q.P0)
    for form in ("first-order", "truncated", "gaussian"):
        flt = SecondOrderFilter(q.model, form=form)
        rows.append(_row(flt, sim.ys, q.m0, q.P0, args.columns, args.repeat, problem="quadratic", form=form,
                         paths=args.paths, steps=args.steps))

    s = pb.state_noise()
    sim = simulate(s.model, args.steps, paths=args.paths, rng=rng, m0=s.m0, P0=s.P0, dt=s.dt, substeps=2)
    for form in ("first-order", "truncated", "gaussian"):
        for inn in ("ito", "update"):
            flt = ContinuousSecondOrderFilter(s.model, s.dt, form=form, innovation=inn)
            rows.append(_row(flt, sim.ys, s.m0, s.P0, args.columns, args.repeat, problem="state-noise", form=form,
                             innovation=inn, paths=args.paths, steps=args.steps))

    _pin.write(args.out, args.label, {"rows": rows}, benchmark="second_order")
    for r in rows:
        cols = "  ".join(f"{c} {r[c]['path_steps_per_s']:12.0f}" if "refused" not in r[c] else f"{c} {'refused':>12s}"
                         for c in args.columns if c in r)
        ratio = r.get("numba_over_numpy_cpu")
        print(f"{r['problem']:13s} {r['form']:20s} {r.get('innovation', ''):7s} {cols} path-steps/s"
              + (f"  compiled {ratio:.1f}x" if ratio else ""))


if __name__ == "__main__":
    main()
