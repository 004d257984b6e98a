"""EKF speed, side by side with peers in one run (issue: foundation, item 11).

Scalar discrete cubic sensor ``x[k+1] = (1 − dt) x[k] + w``, ``y = x³ + v`` (dt = 0.01,
Q = 0.01, R = 0.1), 1000 paths × 1000 steps:

* nlfilter ``EKF`` (batched over paths, generic: SymPy-generated f, h and Jacobians);
* a 20-line hand-vectorised NumPy EKF (what generality may cost);
* filterpy ``ExtendedKalmanFilter``, a Python loop per path and step (timed on a subset of
  paths, reported per path-step), with ``predict_x`` overridden to propagate with f;
* dynamax ``extended_kalman_filter`` in float64 under ``jit`` + ``vmap`` (compile time reported
  apart from the run time);
* nlfilter's compiled loop (``run(..., backend="numba")``: the scalar EKF's batch loop; compile
  time apart);
* a plain C loop (``gcc -O3``, built here with ctypes when gcc is on the machine; stores the means
  and variances), in two orders: all paths at each step (contiguous state, time-major output: what
  a C programmer would write for a batch) and one path at a time (issue 13, goal 2: the scalar
  batch path within 10× of C).

Each time is the best of five runs. Writes ``benchmarks/results/bench_ekf.json`` with seconds per
path-step, the ratios (and whether the targets are met), and the
largest difference of the filtered means between the implementations. Needs
``pip install ".[bench]"``; peers that are not installed are reported as missing.

Run: ``python benchmarks/bench_ekf.py [--paths 1000 --steps 1000 --filterpy-paths 10]``
"""

from __future__ import annotations

import argparse
import ctypes
import json
import pathlib
import platform
import shutil
import subprocess
import tempfile
import time

import numpy as np
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters.ekf import EKF
from nlfilter.simulate import simulate

DT, Q, R, M0, P0 = 0.01, 0.01, 0.1, 0.5, 0.1


def model():
    x = sp.Symbol("x")
    return DiscreteModel([x], [(1 - DT) * x], [x**3], Q=Q, R=R, name="cubic sensor")


def hand_ekf(ys, m0, P0):
    """The reference point: a hand-vectorised scalar EKF (update first, as nlfilter's default)."""
    m = np.full(ys.shape[0], m0)
    P = np.full(ys.shape[0], P0)
    out = np.empty(ys.shape[:2])
    for k in range(ys.shape[1]):
        if k:
            m, P = (1 - DT) * m, (1 - DT) ** 2 * P + Q
        H = 3 * m**2
        S = H * P * H + R
        K = P * H / S
        m = m + K * (ys[:, k] - m**3)
        P = (1 - K * H) ** 2 * P + K * R * K
        out[:, k] = m
    return out


C_SOURCE = r"""
#include <stddef.h>
/* all paths at each step: the state of every path in mw, Pw; outputs time-major (T, B) */
void ekf_steps(const double *ys, int B, int T, double m0, double P0, double a, double q, double r,
               double *means, double *covs, double *mw, double *Pw) {
    for (int b = 0; b < B; b++) { mw[b] = m0; Pw[b] = P0; }
    for (int k = 0; k < T; k++) {
        for (int b = 0; b < B; b++) {
            double m = mw[b], P = Pw[b];
            if (k) { m = a * m; P = a * a * P + q; }
            double H = 3 * m * m, S = H * P * H + r, K = P * H / S;
            m = m + K * (ys[(size_t)b * T + k] - m * m * m);
            double I = 1 - K * H;
            P = I * I * P + K * r * K;
            mw[b] = m; Pw[b] = P;
            means[(size_t)k * B + b] = m; covs[(size_t)k * B + b] = P;
        }
    }
}
/* one path at a time: outputs path-major (B, T) */
void ekf_paths(const double *ys, int B, int T, double m0, double P0, double a, double q, double r,
               double *means, double *covs) {
    for (int b = 0; b < B; b++) {
        double m = m0, P = P0;
        for (int k = 0; k < T; k++) {
            if (k) { m = a * m; P = a * a * P + q; }
            double H = 3 * m * m, S = H * P * H + r, K = P * H / S;
            m = m + K * (ys[(size_t)b * T + k] - m * m * m);
            double I = 1 - K * H;
            P = I * I * P + K * r * K;
            means[(size_t)b * T + k] = m; covs[(size_t)b * T + k] = P;
        }
    }
}
"""


def c_loops(tmp):
    """The C loops built with ``gcc -O3`` into a shared library, or None without gcc."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    src, lib = pathlib.Path(tmp) / "ekf.c", pathlib.Path(tmp) / "ekf.so"
    src.write_text(C_SOURCE)
    subprocess.run([gcc, "-O3", "-shared", "-fPIC", str(src), "-o", str(lib)], check=True)
    dll = ctypes.CDLL(str(lib))
    d, i, pd = ctypes.c_double, ctypes.c_int, ctypes.POINTER(ctypes.c_double)
    dll.ekf_steps.argtypes = [pd, i, i, d, d, d, d, d, pd, pd, pd, pd]
    dll.ekf_paths.argtypes = [pd, i, i, d, d, d, d, d, pd, pd]
    return dll


def best_of(fn, repeat=5):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--filterpy-paths", type=int, default=10)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_ekf.json"))
    a = ap.parse_args()
    md = model()
    sim = simulate(md, a.steps, paths=a.paths, rng=0, m0=M0, P0=P0)
    ys = sim.ys
    ps = a.paths * a.steps
    res = {"problem": "discrete cubic sensor, dt=0.01, Q=0.01, R=0.1", "paths": a.paths, "steps": a.steps,
           "machine": {"python": platform.python_version(), "numpy": np.__version__, "cpu": platform.machine()},
           "seconds_per_path_step": {}, "notes": []}
    sec = res["seconds_per_path_step"]

    t, ours = best_of(lambda: EKF(md).run(ys, M0, P0))
    sec["nlfilter"] = t / ps
    t, hand = best_of(lambda: hand_ekf(ys[..., 0], M0, P0))
    sec["numpy_hand_vectorised"] = t / ps
    diffs = {"nlfilter_vs_hand": float(np.max(np.abs(ours.means[..., 0] - hand)))}

    try:
        from filterpy.kalman import ExtendedKalmanFilter

        class FP(ExtendedKalmanFilter):
            def predict_x(self, u=0):
                self.x = (1 - DT) * self.x

        npth = min(a.filterpy_paths, a.paths)
        pred = EKF(md, start="predict").run(ys[:npth], M0, P0)  # filterpy predicts first
        t0 = time.perf_counter()
        fp_means = np.empty((npth, a.steps))
        for p in range(npth):
            f = FP(1, 1)
            f.x, f.P, f.Q, f.R, f.F = np.array([[M0]]), np.array([[P0]]), np.array([[Q]]), np.array([[R]]), np.array([[1 - DT]])
            for k in range(a.steps):
                f.predict()
                f.update(ys[p, k], lambda x: 3 * x**2, lambda x: x**3)
                fp_means[p, k] = f.x[0, 0]
        sec["filterpy"] = (time.perf_counter() - t0) / (npth * a.steps)
        res["filterpy_paths_timed"] = npth
        diffs["nlfilter_vs_filterpy"] = float(np.max(np.abs(pred.means[..., 0] - fp_means)))
    except ImportError:
        res["notes"].append("filterpy not installed")

    try:
        import jax
        jax.config.update("jax_enable_x64", True)
        import jax.numpy as jnp
        from dynamax.nonlinear_gaussian_ssm import ParamsNLGSSM, extended_kalman_filter

        params = ParamsNLGSSM(initial_mean=jnp.array([M0]), initial_covariance=jnp.array([[P0]]),
                              dynamics_function=lambda x: (1 - DT) * x, dynamics_covariance=jnp.array([[Q]]),
                              emission_function=lambda x: x**3, emission_covariance=jnp.array([[R]]))
        run = jax.jit(jax.vmap(lambda y: extended_kalman_filter(params, y).filtered_means))
        yj = jnp.asarray(ys)
        t0 = time.perf_counter()
        run(yj).block_until_ready()
        first = time.perf_counter() - t0
        t, dm = best_of(lambda: run(yj).block_until_ready())
        sec["dynamax"] = t / ps
        res["dynamax_compile_seconds"] = first - t
        res["jax"] = jax.__version__
        diffs["nlfilter_vs_dynamax"] = float(np.max(np.abs(ours.means[..., 0] - np.asarray(dm)[..., 0])))
        res["notes"].append("dynamax's psd_solve adds a 1e-9 diagonal boost to S and updates P - K S K^T "
                            "(no Joseph form): its gains differ from the exact ones by ~1e-9 relative, which "
                            "the cubic sensor's EKF amplifies along some paths; filterpy and the hand EKF, "
                            "exact, agree with nlfilter to 1e-11")
    except ImportError as exc:
        res["notes"].append(f"dynamax/jax not installed: {exc}")

    t0 = time.perf_counter()
    EKF(md).run(ys[:2, :10], M0, P0, backend="numba")
    res["numba_compile_seconds"] = time.perf_counter() - t0
    t, comp = best_of(lambda: EKF(md).run(ys, M0, P0, backend="numba"))
    sec["nlfilter_numba"] = t / ps
    diffs["numba_vs_numpy"] = float(np.max(np.abs(comp.means - ours.means)))

    with tempfile.TemporaryDirectory() as tmp:
        dll = c_loops(tmp)
        if dll is None:
            res["notes"].append("gcc not found: no C loop")
        else:
            yc = np.ascontiguousarray(ys[..., 0])
            ptr = lambda arr: arr.ctypes.data_as(ctypes.POINTER(ctypes.c_double))  # noqa: E731
            B, T = yc.shape
            mt, Pt, mw, Pw = np.empty((T, B)), np.empty((T, B)), np.empty(B), np.empty(B)
            mp, Pp = np.empty((B, T)), np.empty((B, T))
            args = (B, T, M0, P0, 1 - DT, Q, R)
            t, _ = best_of(lambda: dll.ekf_steps(ptr(yc), *args, ptr(mt), ptr(Pt), ptr(mw), ptr(Pw)))
            sec["c_all_paths_each_step"] = t / ps
            t, _ = best_of(lambda: dll.ekf_paths(ptr(yc), *args, ptr(mp), ptr(Pp)))
            sec["c_one_path_at_a_time"] = t / ps
            diffs["c_vs_hand_numpy"] = float(max(np.abs(mt.T - hand).max(), np.abs(mp - hand).max()))
            c_best = min(sec["c_all_paths_each_step"], sec["c_one_path_at_a_time"])
            res["numba_over_c"] = sec["nlfilter_numba"] / c_best
            res["numpy_over_c"] = sec["nlfilter"] / c_best
            res["targets"] = {"numba_within_10x_of_c": res["numba_over_c"] <= 10}

    res["max_abs_difference_of_means"] = diffs
    res["speedup_of_nlfilter"] = {k: sec[k] / sec["nlfilter"] for k in sec if k != "nlfilter"}
    res.setdefault("targets", {}).update({"vs_filterpy": ">= 300", "vs_dynamax": ">= 3"})
    speed = res["speedup_of_nlfilter"]
    res["targets_met"] = {"vs_filterpy": speed["filterpy"] >= 300 if "filterpy" in speed else None,
                          "vs_dynamax": speed["dynamax"] >= 3 if "dynamax" in speed else None}
    pathlib.Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(a.out).write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
