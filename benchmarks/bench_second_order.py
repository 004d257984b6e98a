"""Speed of the second-order filters (seed 004): paths × steps per second, batched over paths.

    PYTHONPATH=src python benchmarks/bench_second_order.py [--paths 10000] [--out FILE]

Cases: the falling body (n = 3, continuous dynamics with RK4 substeps, discrete range measurements)
for every form, the scalar quadratic problem (discrete) and the state-noise SDE (continuous). The
cost of a step is O(n³ + n²·m) per path (batched einsum); no timing is asserted anywhere.
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread)

import argparse  # noqa: E402
import pathlib  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from nlfilter import problems as pb  # noqa: E402
from nlfilter.filters.second_order import (ContinuousDiscreteSecondOrderFilter, ContinuousSecondOrderFilter,  # noqa: E402
                                           SecondOrderFilter)
from nlfilter.simulate import simulate  # noqa: E402

FORMS = ("first-order", "truncated", "truncated-jazwinski", "modified", "gaussian")


def _time(fn, repeat=2):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=10_000)
    ap.add_argument("--steps", type=int, default=20, help="measurement steps per run")
    ap.add_argument("--substeps", type=int, default=20, help="RK4 substeps per falling-body interval")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_second_order.json"))
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    rows = []

    fb = pb.falling_body()
    ys = fb.model.h(np.broadcast_to(fb.x0, (args.paths, args.steps, 3)), 0.0) + 100.0 * rng.standard_normal(
        (args.paths, args.steps, 1))
    for form in FORMS:
        flt = ContinuousDiscreteSecondOrderFilter(fb.model, fb.dt, form=form, substeps=args.substeps,
                                                  start="predict")
        sec = _time(lambda: flt.run(ys, fb.m0, fb.P0, on_divergence="mark"))
        rows.append({"problem": "falling-body", "form": form, "paths": args.paths, "steps": args.steps,
                     "substeps": args.substeps, "seconds": sec, "path_steps_per_s": args.paths * args.steps / sec})

    q = pb.quadratic()
    sim = simulate(q.model, args.steps, paths=args.paths, rng=rng, m0=q.m0, P0=q.P0)
    for form in ("first-order", "truncated", "gaussian"):
        flt = SecondOrderFilter(q.model, form=form)
        sec = _time(lambda: flt.run(sim.ys, q.m0, q.P0, on_divergence="mark"))
        rows.append({"problem": "quadratic", "form": form, "paths": args.paths, "steps": args.steps,
                     "seconds": sec, "path_steps_per_s": args.paths * args.steps / sec})

    s = pb.state_noise()
    sim = simulate(s.model, args.steps, paths=args.paths, rng=rng, m0=s.m0, P0=s.P0, dt=s.dt, substeps=2)
    for form in ("first-order", "truncated", "gaussian"):
        for inn in ("ito", "update"):
            flt = ContinuousSecondOrderFilter(s.model, s.dt, form=form, innovation=inn)
            sec = _time(lambda: flt.run(sim.ys, s.m0, s.P0, on_divergence="mark"))
            rows.append({"problem": "state-noise", "form": form, "innovation": inn, "paths": args.paths,
                         "steps": args.steps, "seconds": sec, "path_steps_per_s": args.paths * args.steps / sec})

    _pin.write(args.out, args.label, {"rows": rows}, benchmark="second_order")
    for r in rows:
        print(f"{r['problem']:13s} {r['form']:20s} {r.get('innovation', ''):7s} "
              f"{r['path_steps_per_s']:12.0f} path-steps/s")


if __name__ == "__main__":
    main()
