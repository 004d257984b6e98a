"""Bootstrap particle filter against Chopin's ``particles`` (issue 13, goal 6), side by side in one run.

The model ``x' = 0.9 x + 0.5 sin x + w`` (Q = 0.5), ``y = x³/10 + v`` (R = 0.1), x0 ~ N(0, 1); both
filters are bootstrap filters with systematic resampling when ESS < N/2:

* nlfilter ``ParticleFilter`` (batched over paths: ``--paths`` records at once, per-path streams);
* ``particles`` (``particles.SMC`` on ``state_space_models.Bootstrap``, one record at a time).

Timings: best of ``--repeat``, µs per path-step at ``--particles`` particles. Check: the two
log-likelihood estimates of each record (both unbiased for the *likelihood*), averaged over
``--replicates`` independent runs, agree within their standard errors (the JSON lists the
z-scores: mean z² ≈ 1 expected). Against the grid filter's log-evidence (401 points: exact to
the grid's accuracy) both are low by about half the variance of one run's log-estimate (Jensen:
E log L̂ ≈ log L − Var(log L̂)/2), the same for both implementations, so those z are negative.

Run: ``python benchmarks/bench_particle.py [--paths 20 --steps 100 --particles 1000 --replicates 8]``
(``pip install particles`` for the peer; reported missing otherwise).
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread)

import argparse  # noqa: E402
import json  # noqa: E402
import pathlib  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402

from nlfilter import DiscreteModel, simulate  # noqa: E402
from nlfilter.evaluate import loglik  # noqa: E402
from nlfilter.filters import GridFilter, ParticleFilter  # noqa: E402


def model():
    x = sp.Symbol("x")
    return DiscreteModel([x], [0.9 * x + 0.5 * sp.sin(x)], [x**3 / 10], Q=0.5, R=0.1, name="particle-bench")


def peer_model():
    from particles import distributions as dists
    from particles import state_space_models as ssm

    class Cubic(ssm.StateSpaceModel):
        def PX0(self):
            return dists.Normal(loc=0.0, scale=1.0)

        def PX(self, t, xp):
            return dists.Normal(loc=0.9 * xp + 0.5 * np.sin(xp), scale=np.sqrt(0.5))

        def PY(self, t, xp, x):
            return dists.Normal(loc=x**3 / 10, scale=np.sqrt(0.1))

    return Cubic()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--replicates", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--shared", action="store_true", help="note in the JSON that the machine was shared")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_particle.json"))
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    a = ap.parse_args(argv)
    md = model()
    ys = simulate(md, a.steps, paths=a.paths, rng=0, m0=[0.0], P0=[[1.0]]).ys
    N = a.particles
    pf = ParticleFilter(md, N)
    per = a.paths * a.steps / 1e6
    t = min(_time(lambda: pf.run(ys, [0.0], [[1.0]], rng=1)) for _ in range(a.repeat))
    out = {"task": f"bootstrap PF, {N} particles, {a.paths} records x {a.steps} steps, best of {a.repeat}",
           "us_per_path_step": {"nlfilter": t / per}}
    ours = loglik(pf, ys, [0.0], [[1.0]], replicates=a.replicates, rng=2)
    grid = GridFilter(md, (-7.0, 7.0), 401).run(ys, [0.0], [[1.0]], loglik=True).loglik
    out["loglik"] = {"grid (exact to its resolution)": grid.tolist(), "nlfilter mean": ours.value.tolist(),
                     "nlfilter se": ours.stderr.tolist(),
                     "z nlfilter vs grid": ((ours.value - grid) / ours.stderr).tolist()}
    try:
        import particles
    except ImportError:
        out["particles"] = "not installed (pip install particles)"
    else:
        peer = peer_model()

        def run_peer(p, seed):
            np.random.seed(seed)  # particles draws from NumPy's global generator
            fk = particles.state_space_models.Bootstrap(ssm=peer, data=list(ys[p, :, 0]))
            alg = particles.SMC(fk=fk, N=N, resampling="systematic", ESSrmin=0.5)
            alg.run()
            return alg.logLt

        tp = min(_time(lambda: [run_peer(p, 0) for p in range(a.paths)]) for _ in range(a.repeat))
        out["us_per_path_step"]["particles"] = tp / per
        out["ratio particles / nlfilter"] = tp / t
        vals = np.array([[run_peer(p, 100 + r) for p in range(a.paths)] for r in range(a.replicates)])
        m, se = vals.mean(axis=0), vals.std(axis=0, ddof=1) / np.sqrt(a.replicates)
        out["loglik"].update({"particles mean": m.tolist(), "particles se": se.tolist(),
                              "z particles vs grid": ((m - grid) / se).tolist(),
                              "z nlfilter vs particles": ((ours.value - m) / np.hypot(ours.stderr, se)).tolist()})
        out["particles_version"] = getattr(particles, "__version__", "?")
    out["shared"] = a.shared
    _pin.write(a.out, a.label, out, benchmark="particle")
    print(json.dumps({k: v for k, v in out.items() if k != "loglik"}, indent=2))
    z = out["loglik"]
    print({k: (round(float(np.mean(np.square(v))), 2), round(float(np.max(np.abs(v))), 2))
           for k, v in z.items() if k.startswith("z")}, "(mean z², max |z|)")


def _time(fn):
    s = time.perf_counter()
    fn()
    return time.perf_counter() - s


if __name__ == "__main__":
    main()
