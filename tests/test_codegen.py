"""The one code generator (issue 27, item 4): nlfilter.codegen writes the compiled loop's kernels
with the same text as filters/compiled.py's own generators did, and every printer follows one float
policy (repr of a finite double)."""

import math

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter import codegen
from nlfilter.codegen import (ArrayPrinter, FullPrecisionPrinter, ScalarPrinter, array_source, first_derivatives,
                              jacobian, lambdify_numpy, scalar_source)


def _models():
    x1, x2, x3, a, k, q = sp.symbols("x1 x2 x3 a k q")
    chain = DiscreteModel([x1, x2, x3], [0.9 * x1, 0.9 * x2 + a * x1**2, 0.9 * x3 + 0.1 * x2**2],
                          [x1, x3**2 / 2 + x1 * x2], Q=0.01 * np.eye(3), R=0.1 * np.eye(2), params={a: 0.1})
    timed = DiscreteModel([x1, x2], [x1 + 0.1 * sp.sin(k) * x2, 0.95 * x2 - 0.05 * x1**3],
                          [x1 * x2 + k, sp.cos(x1)], G=[[1 + 0.1 * x1**2], [sp.sin(x2) * x1]], Q=[[q]],
                          R=0.2 * np.eye(2), params={q: 0.3}, time=k)
    erf = DiscreteModel([x1, x2], [x1 + 0.1 * sp.erf(x2), sp.exp(-0.3 * x1) * x2 + 1 / 3.0],
                        [sp.atan2(x2, 1 + x1**2)], Q=np.eye(2), R=[[0.5]])
    return {"chain": chain, "timed": timed, "erf": erf}


# the text filters/compiled.py's _source/_scalar_source wrote at main ba07295 (the numba kernels)
GOLDEN = {
    "g_G": """def g_G(x, t, p, out):
    x_0 = x[0]
    x_1 = x[1]
    out[0, 0] = 0.1*x_0**2 + 1
    out[1, 0] = x_0*math.sin(x_1)""",
    "g_fx": """def g_fx(x, t, p, out):
    x_0 = x[0]
    t_ = t
    out[0, 0] = 1
    out[0, 1] = 0.1*math.sin(t_)
    out[1, 0] = -0.15000000000000002*x_0**2
    out[1, 1] = 0.95""",
    "g_fxx": """def g_fxx(x, t, p, out):
    p_0 = p[0]
    for i0 in range(3):
        for i1 in range(3):
            for i2 in range(3):
                out[i0, i1, i2] = 0.0
    out[1, 0, 0] = 2*p_0
    out[2, 1, 1] = 0.2""",
    "s_f": """def s_f(x_0, t, p):
    p_0 = p[0]
    t_ = t
    return float(p_0*x_0 + x_0**3/(x_0**2 + 1) + 0.1*math.sin(t_))""",
}


def test_sources_keep_the_compiled_loops_text():
    """The kernels' text as the compiled loop wrote it (sparse zeros in one loop, CSE, full-precision
    floats: -0.15000000000000002 = 3 * -0.05, not SymPy's 15 digits)."""
    models = _models()
    m, ex = models["timed"], models["timed"].expressions
    assert array_source("g_G", list(ex["G"]), (2, 1), m.states, m.time, m._psyms) == GOLDEN["g_G"]
    assert array_source("g_fx", list(jacobian(ex["f"], m.states)), (2, 2), m.states, m.time,
                        m._psyms) == GOLDEN["g_fx"]
    m, ex = models["chain"], models["chain"].expressions
    fxx = first_derivatives(list(jacobian(ex["f"], m.states)), m.states)
    assert array_source("g_fxx", fxx, (3, 3, 3), m.states, m.time, m._psyms) == GOLDEN["g_fxx"]
    x, k, a = sp.symbols("x k a")
    assert scalar_source("s_f", a * x + 0.1 * sp.sin(k) + x**3 / (1 + x**2), x, k, [a]) == GOLDEN["s_f"]
    ns = {"math": math}
    exec(GOLDEN["g_fx"], ns)  # the text runs: f_x of the timed model at x = (2, 0), k = 1
    out = np.empty((2, 2))
    ns["g_fx"](np.array([2.0, 0.0]), 1.0, np.array([0.3]), out)
    # the model's NumPy f_x: the same arithmetic but NumPy's sin for math.sin (1 ulp apart at most)
    np.testing.assert_allclose(out, models["timed"].f_x(np.array([2.0, 0.0]), 1), rtol=1e-15, atol=0)
    assert out[1, 0] == -0.15000000000000002 * 4.0


@pytest.mark.parametrize("name", ["chain", "timed", "erf"])
def test_compiled_loop_generates_through_codegen(name):
    """The compiled loop's kernels are codegen's text (one generator): the source it compiles for
    f, f_x, f_xx, h, h_x, h_xx and G is ``array_source``'s, character for character (the chain's
    f_xx has 27 entries with more than 8 zeros: the loop of zeros). numba compiles lazily: nothing
    is compiled here."""
    from nlfilter.filters.compiled.kernels import KERNELS, model_kernels
    model = _models()[name]
    model_kernels(model, second=True)
    store = KERNELS[model._kernels["f"]]
    ex, states, time, ps = model.expressions, model.states, model.time, model._psyms
    n, m, r = model.n, model.m, model.r
    fx, hx = jacobian(ex["f"], states), jacobian(ex["h"], states)
    specs = {"f": (list(ex["f"]), (n,)), "f_x": (list(fx), (n, n)), "h": (list(ex["h"]), (m,)),
             "h_x": (list(hx), (m, n)), "G": (list(ex["G"]), (n, r)),
             "f_xx": (first_derivatives(list(fx), states), (n, n, n)),
             "h_xx": (first_derivatives(list(hx), states), (m, n, n))}
    for w, (exprs, shape) in specs.items():
        assert store[w].source == array_source("g_" + w.replace("_", ""), exprs, shape, states, time, ps), w
    zero_loop = array_source("g", specs["f_xx"][0], (n, n, n), states, time, ps)
    assert ("for i0 in range" in zero_loop) == (name == "chain")


def test_one_float_policy():
    """Every printer writes a finite float as repr(float): the shortest text that reads back to the
    same double (so the generated NumPy function returns the constant exactly: tolerance 0)."""
    x = sp.Symbol("x")
    values = [0.1 + 2**-50, 1 / 3, -2.5e-300, 1e300, 5e-324, math.pi, 123456789.12345679]
    for v in values:
        c = sp.Float(v)
        want = repr(abs(v))
        for pr in (FullPrecisionPrinter(), ArrayPrinter(), ScalarPrinter()):
            assert pr.doprint(sp.Float(abs(v))) == want
            assert want in pr.doprint(c * x), (type(pr).__name__, v)
        assert float(lambdify_numpy([x], c + 0 * x)(0.0)) == v
        assert codegen.float_text(v) == repr(v)
    assert codegen.float_text(float("inf")) is None
    assert ScalarPrinter().doprint(sp.oo) == "math.inf"
