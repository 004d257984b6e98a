"""What the certified reference costs (issue 11): compare on the pendulum of issue 11 — x = (θ, ω),
symplectic Euler, dt = 0.1, Q = diag(2e-3, 0.05), y = sin θ + v, R = 0.02, m0 = (1.2, 0),
P0 = diag(0.5, 1) — with the automatic, self-certifying reference, beside the reference the old
automatic rule used (a 61 × 61 grid, no check) and a fixed 8000-particle filter, all on one
simulation. Records seconds, the θ MSE of each reference, the UKF's gap to it and the certificate.
No peer library offers a certified reference; the peers' particle filters are what the fixed
rows stand for. Writes JSON (default benchmarks/results/bench_reference.json).

    PYTHONPATH=src python benchmarks/bench_reference.py [--paths 300] [--steps 60] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import time
import warnings

import numpy as np
import sympy as sp

import nlfilter
from nlfilter import DiscreteModel, compare
from nlfilter.filters import GridFilter, ParticleFilter, UKF


def pendulum(g=9.81, dt=0.1):
    th, om = sp.symbols("theta omega")
    omn = om - g * dt * sp.sin(th)
    return DiscreteModel([th, om], f=[th + dt * omn, omn], h=[sp.sin(th)], Q=np.diag([2e-3, 0.05]), R=0.02,
                         name="pendulum")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--paths", type=int, default=300)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_reference.json"))
    a = ap.parse_args(argv)
    md = pendulum()
    kw = dict(paths=a.paths, m0=[1.2, 0.0], P0=np.diag([0.5, 1.0]), rng=0)
    cases = {"auto (certified)": "auto",
             "grid 61x61 (old automatic rule, unchecked)": GridFilter(md, [(-2.5, 4.0), (-6.0, 6.0)], 61),
             "particle 8000 (fixed)": ParticleFilter(md, 8000)}
    out = {"benchmark": "reference", "problem": "pendulum (issue 11)", "paths": a.paths, "steps": a.steps,
           "nlfilter": getattr(nlfilter, "__version__", "?"), "python": platform.python_version(),
           "numpy": np.__version__, "machine": platform.machine(), "cases": {}}
    for name, ref in cases.items():
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = compare(md, {"ukf": UKF(md)}, a.steps, reference=ref, **kw)
        seconds = time.perf_counter() - t0
        cert = res.params["reference"]
        label = cert["label"]
        gap_q = "gap_to_optimal" if label == "optimal" else "gap_to_reference"
        gap = res.get("ukf", gap_q, component=0)
        ref_mse = res.get(label, "mse", component=0)
        out["cases"][name] = {
            "seconds_total": round(seconds, 2), "seconds_reference_check": cert["seconds"],
            "label": label, "kind": cert["kind"], "size": cert["size"],
            "theta_mse_reference": [ref_mse.value, ref_mse.stderr], "ukf_theta_gap": [gap.value, gap.stderr],
            "rungs": [{k: r.get(k) for k in ("kind", "size", "verdict", "error", "tolerance")} for r in cert["rungs"]],
            "warnings": [str(w.message)[:200] for w in caught]}
        print(f"{name}: {seconds:.1f} s, {label}, θ MSE {ref_mse.value:.5f} ± {ref_mse.stderr:.5f}, "
              f"UKF gap {gap.value:+.5f} ± {gap.stderr:.5f}")
    path = pathlib.Path(a.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
