"""Moment-engine speed: generate the moment equations of a 6-dimensional polynomial SDE with
cubic drift up to order 6 (923 moments) and solve for its steady state (issue 4 targets: < 1 s
each). Writes JSON (default benchmarks/results/bench_moments.json; the run ``--label``).

    PYTHONPATH=src python benchmarks/bench_moments.py [--out FILE] [--repeat 3]
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread)

import argparse  # noqa: E402
import pathlib  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import sympy as sp  # noqa: E402

from nlfilter.moments import (EdgeworthClosure, PolynomialSDE, moment_equations, monomials,  # noqa: E402
                              steady_state)


def model6():
    xs = sp.symbols("x1:7")
    # cubic drift with a linear ring coupling, constant diffusion
    f = [-xi**3 - xi + sp.Rational(1, 2) * xs[(i + 1) % 6] for i, xi in enumerate(xs)]
    return PolynomialSDE.from_sympy(xs, f, (sp.eye(6) * sp.Rational(3, 10)).tolist())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "bench_moments.json"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    a = ap.parse_args(argv)
    sde = model6()
    idx = monomials(6, 6, min_degree=1)
    gen, solve_closed, solve_closure = [], [], []
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        eq = moment_equations(sde, idx)
        gen.append(time.perf_counter() - t0)
    # closed linear part: steady state of the linear SDE (drift without the cubic term), same 923 moments
    xs = sde.states
    lin = PolynomialSDE.from_sympy(xs, [-xi + sp.Rational(1, 2) * xs[(i + 1) % 6] for i, xi in enumerate(xs)],
                                   (sp.eye(6) * sp.Rational(3, 10)).tolist())
    eql = moment_equations(lin, idx)
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        steady_state(eql)
        solve_closed.append(time.perf_counter() - t0)
    # with the cubic drift: order-6 system closed by the Edgeworth-6 closure, Newton with the exact sparse
    # Jacobian; the first call compiles the closure's plan (kept in the closure object), later calls reuse it
    clo = EdgeworthClosure(6)
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        mu = steady_state(eq, closure=clo)
        solve_closure.append(time.perf_counter() - t0)
    res = {"n_states": 6, "order": 6, "n_moments": len(eq.indices), "n_missing": len(eq.missing),
           "generate_seconds_min": min(gen), "generate_seconds_all": gen,
           "steady_state_closed_seconds_min": min(solve_closed),
           "steady_state_edgeworth6_first_call_seconds": solve_closure[0],
           "steady_state_edgeworth6_seconds_min": min(solve_closure[1:] or solve_closure),
           "steady_state_E_x1^2": float(mu[eq.index[(2, 0, 0, 0, 0, 0)]]),
           "targets_seconds": {"generate": 1.0, "steady_state": 1.0}}
    print(json.dumps(res, indent=2))
    _pin.write(a.out, a.label, res, benchmark="moments")


if __name__ == "__main__":
    main()
