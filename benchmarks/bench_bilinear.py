"""Speed of the off-line tensor statistics of seed 001 (targets from issue 6):

* cubic sensor, steady-state moments and cubic post-processor gains/MSE (x and x³): < 100 ms
* the same with the quintic post-processor: < 2 s
* the whole Fig. 4.3 sweep (100 values of P_θℓ, phase tracking on the circle): < 10 s

Each timing is the best of ``--repeat`` runs (the machine is shared). BLAS threads are pinned to
one before NumPy is imported (:mod:`_pin`, with the core): these are many small dense solves,
where threaded BLAS only adds contention. Writes JSON (``--out``, default ``benchmarks/results/bench_bilinear.json``).

    PYTHONPATH=src python benchmarks/bench_bilinear.py
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread)

import argparse  # noqa: E402

import numpy as np  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/results/bench_bilinear.json")
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    args = ap.parse_args(argv)

    from nlfilter.bilinear import BilinearModel
    from nlfilter.experiments.cubic_sensor import cubic_model
    from nlfilter.filters.bilinear import TensorFilter
    from nlfilter.filters.phase import post_processor

    def cubic(degree):
        lift = BilinearModel.from_polynomial(cubic_model(2.0, 1.0))
        fits = TensorFilter(lift, 0.01, targets=[0, 2], degree=degree).fit()
        return [f.mse for f in fits], len(fits[0].moments)

    def sweep():
        return [post_processor(float(P)).reduction for P in np.geomspace(0.01, 2.0, 100)]

    rows = []
    for name, fn, target in (("cubic sensor, degree 3 (x and x^3)", lambda: cubic(3), 0.1),
                             ("cubic sensor, degree 5 (x and x^3)", lambda: cubic(5), 2.0),
                             ("Fig. 4.3 sweep, 100 values of P", sweep, 10.0)):
        t, out = _pin.best_of(fn, args.repeat)
        extra = {"moments": out[1], "mse": out[0]} if name.startswith("cubic") else {"peak_reduction": max(out)}
        rows.append({"case": name, "seconds": t, "target_seconds": target, "met": t < target, **extra})
        print(f"{name:40s} {t * 1e3:9.1f} ms   (target {target * 1e3:.0f} ms)  {'ok' if t < target else 'MISSED'}")
    _pin.write(args.out, args.label, {"repeat": args.repeat, "results": rows}, benchmark="bilinear")


if __name__ == "__main__":
    main()
