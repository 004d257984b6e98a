"""What the certified reference costs (issue 11): compare on the pendulum of issue 11 — x = (θ, ω),
symplectic Euler, dt = 0.1, Q = diag(2e-3, 0.05), y = sin θ + v, R = 0.02, m0 = (1.2, 0),
P0 = diag(0.5, 1) — and on a 2-D Van der Pol SDE (μ = 1, noise on ω, dy = x1 dt + dη), with the
automatic, self-certifying reference, beside the grid the old automatic rule built (at most
61 points per axis, no check) and a fixed 8000-particle filter, all on one simulation. Records
seconds, the x1 MSE of each reference, the filter's gap to it and the certificate.
No peer library offers a certified reference; the peers' particle filters are what the fixed
rows stand for. Writes JSON (default benchmarks/results/bench_reference.json).

    PYTHONPATH=src python benchmarks/bench_reference.py [--paths 300] [--steps 60] [--out FILE]
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread)

import argparse  # noqa: E402
import pathlib  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402

from nlfilter import DiscreteModel, SDEModel, compare  # noqa: E402
from nlfilter.filters import ContinuousEKF, GridFilter, ParticleFilter, UKF  # noqa: E402
from nlfilter.simulate import simulate  # noqa: E402


def pendulum(g=9.81, dt=0.1):
    th, om = sp.symbols("theta omega")
    omn = om - g * dt * sp.sin(th)
    return DiscreteModel([th, om], f=[th + dt * omn, omn], h=[sp.sin(th)], Q=np.diag([2e-3, 0.05]), R=0.02,
                         name="pendulum")


def van_der_pol(mu=1.0):
    x1, x2 = sp.symbols("x1 x2")
    return SDEModel([x1, x2], [x2, mu * (1 - x1**2) * x2 - x1], [x1], G=[[0.0], [1.0]], Q=0.5, R=0.1,
                    name="van der pol")


def old_rule_grid(model, sim, m0, P0, dt=None):
    """The automatic grid before issue 11: bounds from the simulated states and m0 widened by 4
    times the larger of the prior and noise s.d., spacing a quarter of the smaller, capped at 61
    points per axis (no warning)."""
    xs = sim.xs.reshape(-1, model.n)
    var = np.diagonal(model.GQGT(xs), axis1=-2, axis2=-1)
    noise = np.sqrt(np.mean(var, axis=0) * (dt or 1.0))
    prior = np.sqrt(np.diag(P0))
    small = np.minimum(noise, prior)
    small = np.where(small > 0, small, np.maximum(noise, prior))
    big = np.maximum(noise, prior)
    lo, hi = np.minimum(xs.min(axis=0), m0) - 4 * big, np.maximum(xs.max(axis=0), m0) + 4 * big
    sizes = np.clip(np.ceil((hi - lo) / (small / 4)).astype(int) + 1, 21, 61)
    kw = {"dt": dt} if dt else {}
    return GridFilter(model, [(float(a), float(b)) for a, b in zip(lo, hi)], [int(s) for s in sizes], **kw)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--paths", type=int, default=300)
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_reference.json"))
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    a = ap.parse_args(argv)
    out = {"paths": a.paths, "steps": a.steps, "problems": {}}
    pend = pendulum()
    vdp = van_der_pol()
    problems = {
        "pendulum (issue 11)": (pend, {"ukf": UKF(pend)}, dict(m0=np.array([1.2, 0.0]), P0=np.diag([0.5, 1.0])), None),
        "van der pol SDE": (vdp, {"continuous-ekf": ContinuousEKF(vdp, 0.1)},
                            dict(m0=np.array([2.0, 0.0]), P0=np.diag([0.1, 0.1])), 0.1),
    }
    for pname, (md, filters, prior, dt) in problems.items():
        kw = dict(paths=a.paths, rng=0, **prior, **({"dt": dt} if dt else {}))
        sim = simulate(md, a.steps, paths=a.paths, rng=0, **prior, **({"dt": dt, "substeps": 10} if dt else {}))
        cases = {"auto (certified)": "auto",
                 "grid (the old automatic rule: ≤ 61 per axis, unchecked)": old_rule_grid(md, sim, prior["m0"], prior["P0"], dt),
                 "particle 8000 (fixed)": ParticleFilter(md, 8000, **({"dt": dt, "substeps": 10} if dt else {}))}
        fname = next(iter(filters))
        out["problems"][pname] = {}
        for name, ref in cases.items():
            t0 = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                res, used, _ = compare(md, filters, a.steps, reference=ref, full_output=True, **kw)
            seconds = time.perf_counter() - t0
            assert np.array_equal(used.xs, sim.xs)  # simulate(rng=0) is compare(rng=0)'s simulation
            cert = res.params["reference"]
            label = cert["label"]
            gap_q = "gap_to_optimal" if label == "optimal" else "gap_to_reference"
            gap = res.get(fname, gap_q, component=0)
            ref_mse = res.get(label, "mse", component=0)
            out["problems"][pname][name] = {
                "seconds_total": round(seconds, 2), "seconds_reference_check": cert["seconds"],
                "label": label, "kind": cert["kind"], "size": cert["size"],
                "x1_mse_reference": [ref_mse.value, ref_mse.stderr], f"{fname}_x1_gap": [gap.value, gap.stderr],
                "rungs": [{k: r.get(k) for k in ("kind", "size", "verdict", "error", "tolerance")} for r in cert["rungs"]],
                "warnings": [str(w.message)[:200] for w in caught]}
            print(f"{pname} / {name}: {seconds:.1f} s, {label}, x1 MSE {ref_mse.value:.5f} ± {ref_mse.stderr:.5f}, "
                  f"{fname} gap {gap.value:+.5f} ± {gap.stderr:.5f}", flush=True)
    _pin.write(a.out, a.label, out, benchmark="reference")


if __name__ == "__main__":
    main()
