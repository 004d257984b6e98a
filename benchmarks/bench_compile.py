"""The first compile of the compiled loop (issue 28, item 2): CPU seconds that a process pays on
its first ``run(..., backend="numba")`` of a model (fresh process, empty ``NLFILTER_CACHE``:
numba's import, the model's generated functions, the loop's compile), the loop's speed after it
(µs per path-step, best of 5 runs), and a digest of its outputs — for this tree and, paired case
by case, for an older commit (``--before``, default the commit before the flattened loops), so
that "shorter compile, same speed, same numbers" is read off one run. ``--shared`` adds the
model-free loop (``backend="numba-shared"``): its first compile, and what a new model of the same
shape pays in a new process once that loop is on disk (the model's functions only; for the EKF's
batch-inner cases, its model-free form: the block functions and the zero tables passed in).

Cases: the EKF on one state (the scalar batch loop), the EKF and UKF at n = 2 and n = 4 (the
specialized loops: the dimensions compiled in; the EKF at n = 4 on 200 paths: the batch-inner
loop, on one path, ``ekf-n4-path``: the specialized loop), the EKF at n = 8 and 16 (the
batch-inner loop) and the UKF at n = 8 (the node rules' specialized loop) and n = 16 (the general
loop). The compile is that of a run on the case's paths (5 steps): the loop its timed runs take.
Each child inherits ``_pin``'s pinning (one core, one thread). Target: ≤ 5 s CPU at n ≤ 4, ≤ 15 s
at n = 16.
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

HERE = os.path.dirname(os.path.abspath(__file__))
CASES = {"ekf-scalar": ("EKF", 1, 1000, 200), "ekf-n2": ("EKF", 2, 200, 200), "ukf-n2": ("UKF", 2, 200, 200),
         "ekf-n4": ("EKF", 4, 200, 200), "ekf-n4-path": ("EKF", 4, 1, 20000), "ukf-n4": ("UKF", 4, 200, 200),
         "ekf-n8": ("EKF", 8, 100, 200), "ekf-n16": ("EKF", 16, 40, 100),
         "ukf-n8": ("UKF", 8, 200, 200), "ukf-n16": ("UKF", 16, 40, 100)}
BEFORE = "ded9272"  # main before the flattened loops (numba's inline="always" per call site)

CHILD = textwrap.dedent("""
    import hashlib, json, sys, time
    import numpy as np, sympy as sp
    from nlfilter import DiscreteModel
    from nlfilter.filters.ekf import EKF
    from nlfilter.filters.ukf import UKF
    name, n, B, T = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    backend, c = sys.argv[5], float(sys.argv[6])
    xs = sp.symbols(f"x0:{n}")
    f = [c * xs[i] + 0.1 * sp.sin(xs[(i + 1) % n]) for i in range(n)]
    h = [xs[0] ** 2 / 5 + xs[-1]] if n > 1 else [xs[0] ** 3]
    md = DiscreteModel(list(xs), f=f, h=h, Q=0.1 * np.eye(n), R=0.2)
    flt = {"EKF": EKF, "UKF": UKF}[name](md)
    run = lambda ys: flt.run(ys, np.zeros(n), np.eye(n), backend=backend, loglik=True, on_divergence="mark")
    ys = np.random.default_rng(1).normal(size=(B, T, 1))
    c0 = time.process_time()
    run(np.ascontiguousarray(ys[:, :5]))  # the case's paths: the loop its run takes (the EKF's depends on B)
    compile_cpu = time.process_time() - c0
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        est = run(ys)
        best = min(best, time.perf_counter() - t0)
    digest = hashlib.sha256()
    for a in (est.means, est.covs, est.extras["loglik"], est.extras["innovation"], est.extras["innovation_cov"]):
        digest.update(np.ascontiguousarray(a).tobytes())
    print(json.dumps({"compile_cpu_s": compile_cpu, "us_per_path_step": best / (B * T) * 1e6,
                      "outputs_sha256": digest.hexdigest()[:16]}))
""")


def one(case: str, src: str, backend: str = "numba", models=(0.9,)) -> list:
    """The child's numbers for ``case`` with nlfilter imported from ``src``, one fresh process per
    model of ``models`` (the chain's coefficient: the same shape, another model) in turn, all with
    one cache folder (empty at the first)."""
    name, n, B, T = CASES[case]
    got = []
    with tempfile.TemporaryDirectory(prefix="nlfilter-bench-compile-") as cache:
        env = {**os.environ, "NLFILTER_CACHE": cache, "PYTHONPATH": src}
        for c in models:
            out = subprocess.run([sys.executable, "-c", CHILD, name, str(n), str(B), str(T), backend, repr(c)], env=env,
                                 capture_output=True, text=True, check=True, timeout=1800)
            got.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return got


def tree_of(commit: str, into: str) -> str:
    """The ``src/`` of ``commit`` (git archive of this repository) unpacked in ``into``."""
    archive = subprocess.run(["git", "-C", os.path.dirname(HERE), "archive", commit, "src"], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", into], input=archive, check=True)
    return os.path.join(into, "src")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    ap.add_argument("--before", default=BEFORE, help="the commit paired with this tree ('' for none)")
    ap.add_argument("--label", default="default")
    ap.add_argument("--shared", action="store_true",
                    help="also the model-free loop (backend='numba-shared'): its first compile (an empty cache), then "
                         "a new model of the same shape in a new process (its loop on disk: the model's functions only)")
    args = ap.parse_args(argv)
    ours = os.path.join(os.path.dirname(HERE), "src")
    rows = []
    with tempfile.TemporaryDirectory(prefix="nlfilter-bench-before-") as tmp:
        before = tree_of(args.before, tmp) if args.before else None
        for case in args.cases:
            row = {"case": case, "after": one(case, ours)[0]}
            if args.shared:
                cold, warm = one(case, ours, "numba-shared", (0.9, 0.8))
                row["shared"] = {"first": cold, "new_model": warm}
                print(f"{case:10s} numba-shared: first compile {cold['compile_cpu_s']:6.2f} s CPU, a new model of its "
                      f"shape {warm['compile_cpu_s']:6.2f} s, {warm['us_per_path_step']:.3f} µs/path-step; same bits as "
                      f"its own loop: {cold['outputs_sha256'] == row['after']['outputs_sha256']}", flush=True)
            if before:
                row["before"] = b = one(case, before)[0]
                a = row["after"]
                row.update(compile_ratio=b["compile_cpu_s"] / a["compile_cpu_s"],
                           speed_ratio=b["us_per_path_step"] / a["us_per_path_step"],
                           bitwise_equal=a["outputs_sha256"] == b["outputs_sha256"])
            row["target_compile_cpu_s"] = 15.0 if CASES[case][1] > 4 else 5.0
            rows.append(row)
            a = row["after"]
            was = (f"   before {row['before']['compile_cpu_s']:6.2f} s, {row['before']['us_per_path_step']:.3f} µs"
                   f"   same bits: {row['bitwise_equal']}") if before else ""
            print(f"{case:10s} compile {a['compile_cpu_s']:6.2f} s CPU, {a['us_per_path_step']:.3f} µs/path-step{was}",
                  flush=True)
    _pin.write(os.path.join(HERE, "results", "bench_compile.json"), args.label,
               {"before_commit": args.before, "rows": rows}, benchmark="bench_compile")


if __name__ == "__main__":
    main()
