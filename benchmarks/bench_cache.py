"""The compiled loops' disk cache (issue 28, item 1): what a second process pays before its first
step — the same model, a cache another process filled — against the first process's compile.

Each case runs a fresh Python twice on one empty ``NLFILTER_CACHE`` (pinned alike by ``_pin``:
one core, one thread; the subprocesses inherit it): the first compiles, the second loads. The time
is from just before ``run`` (the model built, the data made) to its return on 2 paths × 5 steps,
so it is numba's import, loading or compiling the loop, and the run itself (negligible); CPU
seconds of the process (``time.process_time``) and wall seconds. Also the whole process's CPU
time (interpreter, NumPy, SymPy and nlfilter imports included), for the record.

Target: the second process ≤ 1 s before its first step.
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: pins this process and, through the environment, its children)

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap

CASES = {
    "ekf-scalar": ("EKF", 1), "ekf-n2": ("EKF", 2), "ukf-n2": ("UKF", 2), "ekf-n8": ("EKF", 8),
    "kf-n4": ("KalmanFilter", 4),
}

CHILD = textwrap.dedent("""
    import json, sys, time
    import numpy as np, sympy as sp
    from nlfilter import DiscreteModel
    from nlfilter.filters.ekf import EKF
    from nlfilter.filters.ukf import UKF
    from nlfilter.filters.kalman import KalmanFilter
    name, n = sys.argv[1], int(sys.argv[2])
    xs = sp.symbols(f"x0:{n}")
    if name == "KalmanFilter":
        f = [0.9 * xs[i] + 0.05 * xs[(i + 1) % n] for i in range(n)]
        h = [xs[0] + xs[-1]]
    else:
        f = [0.9 * xs[i] + 0.1 * sp.sin(xs[(i + 1) % n]) for i in range(n)]
        h = [xs[0] ** 2 / 5 + xs[-1]] if n > 1 else [xs[0] ** 3]
    md = DiscreteModel(list(xs), f=f, h=h, Q=0.1 * np.eye(n), R=0.2)
    flt = {"EKF": EKF, "UKF": UKF, "KalmanFilter": KalmanFilter}[name](md)
    ys = np.random.default_rng(0).normal(size=(2, 5, 1))
    c0, w0 = time.process_time(), time.perf_counter()
    flt.run(ys, np.zeros(n), np.eye(n), backend="numba")
    print(json.dumps({"cpu": time.process_time() - c0, "wall": time.perf_counter() - w0,
                      "process_cpu": time.process_time()}))
""")


def one(case: str, cache: str) -> dict:
    name, n = CASES[case]
    env = {**os.environ, "NLFILTER_CACHE": cache}
    out = subprocess.run([sys.executable, "-c", CHILD, name, str(n)], env=env, capture_output=True, text=True,
                         check=True, timeout=1800)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    ap.add_argument("--label", default="default")
    args = ap.parse_args(argv)
    rows = []
    for case in args.cases:
        with tempfile.TemporaryDirectory(prefix="nlfilter-bench-cache-") as cache:
            first, second = one(case, cache), one(case, cache)
        row = {"case": case, "first process (compiles)": first, "second process (loads)": second,
               "ratio_cpu": first["cpu"] / second["cpu"], "target_second_cpu_s": 1.0,
               "meets_target": second["cpu"] <= 1.0}
        rows.append(row)
        print(f"{case:11s} first {first['cpu']:6.2f} s CPU ({first['wall']:6.2f} wall)   second {second['cpu']:5.2f} s "
              f"CPU ({second['wall']:5.2f} wall)   {'ok' if row['meets_target'] else 'over 1 s'}", flush=True)
    _pin.write(os.path.join(os.path.dirname(__file__), "results", "bench_cache.json"), args.label, {"rows": rows},
               benchmark="bench_cache")


if __name__ == "__main__":
    main()
