"""Model construction (issue 13, goal 4): second derivatives and G's derivatives generated on first
call, shared by every with_params copy, and equal bitwise to the code generated eagerly before."""

import copy

import numpy as np
import pytest
import sympy as sp
from sympy.printing.numpy import NumPyPrinter

from nlfilter import DiscreteModel, SDEModel
from nlfilter.filters.ekf import EKF
from nlfilter.filters.second_order import SecondOrderFilter
from nlfilter.codegen import ArrayPrinter, nothing_to_share
from nlfilter.model_functions import Batched, Kernel, LazyKernels

LAZY = ("f_xx", "h_xx", "G_x", "G_xx")
ALL = ("f", "f_x", "f_xx", "h", "h_x", "h_xx", "G", "G_x", "G_xx")


def eager(model):
    """The model with every derivative generated at once as before the change (``jacobian`` and
    nested ``sp.diff`` of the symbolic expressions), bound to the model's values."""
    ex, states, time, ps = model.expressions, model.states, model.time, model._psyms
    fM, hM, GM = ex["f"], ex["h"], ex["G"]
    n, m, r = model.n, model.m, model.r
    x = sp.Matrix(states)
    fx, hx = fM.jacobian(x), hM.jacobian(x)
    fxx = [[[sp.diff(fx[i, j], s) for s in states] for j in range(n)] for i in range(n)]
    hxx = [[[sp.diff(hx[i, j], s) for s in states] for j in range(n)] for i in range(m)]
    Gx = [[[sp.diff(GM[i, a], s) for s in states] for a in range(r)] for i in range(n)]
    Gxx = [[[[sp.diff(GM[i, a], s, u) for u in states] for s in states] for a in range(r)] for i in range(n)]
    flat = lambda nested: list(np.array(nested, dtype=object).ravel())  # noqa: E731
    specs = {"f": (list(fM), (n,)), "f_x": (list(fx), (n, n)), "f_xx": (flat(fxx), (n, n, n)),
             "h": (list(hM), (m,)), "h_x": (list(hx), (m, n)), "h_xx": (flat(hxx), (m, n, n)),
             "G": (list(GM), (n, r)), "G_x": (flat(Gx), (n, r, n)), "G_xx": (flat(Gxx), (n, r, n, n))}
    ref = copy.copy(model)
    ref._kernels = dict(model._kernels)
    ref._kernels.update({k: Kernel(e, states, time, shape, ps) for k, (e, shape) in specs.items()})
    ref._lazy = LazyKernels({})
    ref._bind(model._values)
    return ref


def _chain():
    x1, x2, x3, a = sp.symbols("x1 x2 x3 a")
    return DiscreteModel([x1, x2, x3], [0.9 * x1, 0.9 * x2 + a * x1**2, 0.9 * x3 + 0.1 * x2**2],
                         [x1, x3**2 / 2 + x1 * x2], Q=0.01 * np.eye(3), R=0.1 * np.eye(2), params={a: 0.1})


def _chain_tv():
    return _chain().with_params(a=np.linspace(0.05, 0.2, 6))


def _timed_state_G():
    x1, x2, k, q = sp.symbols("x1 x2 k q")
    return DiscreteModel([x1, x2], [x1 + 0.1 * sp.sin(k) * x2, 0.95 * x2 - 0.05 * x1**3],
                         [x1 * x2 + k, sp.cos(x1)], G=[[1 + 0.1 * x1**2], [sp.sin(x2) * x1]], Q=[[q]],
                         R=0.2 * np.eye(2), params={q: 0.3}, time=k)


def _state_R():
    x1, x2 = sp.symbols("x1 x2")
    return DiscreteModel([x1, x2], [x1 + 0.1 * x2, 0.9 * x2 - 0.1 * x1**2], [sp.sqrt(x1**2 + x2**2 + 1)],
                         Q=0.01 * np.eye(2), R=[[0.05 + 0.01 * x1**2]])


def _sde_fold():
    x, q = sp.symbols("x q")
    return SDEModel([x], [-x**3], [x], G=[[1 + x**2 / 4]], Q=[[q]], R=0.1,
                    params={q: 0.5}).with_params(q=np.array([0.5, 0.7, 0.9]), dt=0.1)


def _linear():
    rng = np.random.default_rng(3)
    F = rng.standard_normal((5, 5)) * 0.3
    return DiscreteModel.linear(F, rng.standard_normal((2, 5)), 0.01 * np.eye(5), 0.1 * np.eye(2))


def _non_additive():
    x, w = sp.symbols("x w")
    return DiscreteModel([x], [0.9 * x + sp.sin(x) * w + 0.1 * w**2], [x**2], Q=0.1, R=0.2, noise=[w])


MODELS = {"chain": _chain, "chain-time-varying": _chain_tv, "timed-state-G": _timed_state_G,
          "state-R": _state_R, "sde-folded-Q": _sde_fold, "linear": _linear, "non-additive": _non_additive}


@pytest.mark.parametrize("name", list(MODELS))
def test_lazy_derivatives_equal_eager_bitwise(name):
    model = MODELS[name]()
    assert not model._lazy.built  # nothing generated beyond f, h, G and the Jacobians
    ref = eager(model)
    rng = np.random.default_rng(0)
    ts = [0, 2, 0.15] if model.kind == "sde" else [0, 2]
    for shape in [(model.n,), (7, model.n), (3, 4, model.n)]:
        x = rng.standard_normal(shape)
        for t in ts:
            for key in ALL:
                got, want = getattr(model, key)(x, t), getattr(ref, key)(x, t)
                assert got.shape == want.shape == (*shape[:-1], *getattr(ref, key).shape), key
                np.testing.assert_array_equal(got, want, err_msg=key)
            if not model.R_constant:
                np.testing.assert_array_equal(model.R_of(x, t), ref.R_of(x, t))
    for key in LAZY:  # after the first call, the model holds the generated function itself
        fn = getattr(model, key)
        assert isinstance(fn, Batched) or type(fn).__name__ == "Folded", key
    assert model.is_linear == (name == "linear") and model.G_constant == (name not in ("timed-state-G", "sde-folded-Q", "non-additive"))


def test_constant_G_derivatives_are_zeros_without_sympy():
    model = _linear()
    model.G_xx(np.zeros(5))
    kn = model._lazy.built["G_xx"]
    assert kn.const and kn.value.shape == (5, 5, 5, 5) and not kn.value.any()


def test_copies_share_lazily_built_code():
    m = _chain()
    early = m.with_params(a=0.5)  # a copy made before any second derivative was generated
    x = np.random.default_rng(1).standard_normal((4, 3))
    v = early.f_xx(x, 0)  # builds the kernel, once, in the store every copy shares
    kn = m._lazy.built["f_xx"]
    late = m.with_params(a=0.2)
    assert late.f_xx.kernel is kn and m.f_xx.kernel is kn and early.f_xx.kernel is kn
    np.testing.assert_array_equal(v, eager(early).f_xx(x, 0))
    np.testing.assert_array_equal(m.f_xx(x, 0), eager(m).f_xx(x, 0))  # its own parameter value
    np.testing.assert_array_equal(late.f_xx(x, 0), eager(late).f_xx(x, 0))
    assert not np.array_equal(m.f_xx(x, 0), early.f_xx(x, 0))
    plain = copy.copy(_chain())  # a plain copy (no with_params) still evaluates its own values
    np.testing.assert_array_equal(plain.h_xx(x, 0), eager(plain).h_xx(x, 0))


def test_ekf_without_hessians_and_require():
    m = _chain()
    m.require("f", "f_x", "f_xx", "h_xx", "G_x", "G_xx")  # the model gives them ...
    assert not m._lazy.built  # ... without generating them
    ys = np.random.default_rng(2).standard_normal((3, 6, 2))
    est = EKF(m).run(ys, np.zeros(3), 0.1 * np.eye(3))
    assert "f_xx" not in m._lazy.built and "h_xx" not in m._lazy.built
    ref = EKF(eager(_chain())).run(ys, np.zeros(3), 0.1 * np.eye(3))
    np.testing.assert_array_equal(est.means, ref.means)
    np.testing.assert_array_equal(est.covs, ref.covs)
    so = SecondOrderFilter(m).run(ys, np.zeros(3), 0.1 * np.eye(3))
    assert {"f_xx", "h_xx"} <= set(m._lazy.built)
    so_ref = SecondOrderFilter(eager(_chain())).run(ys, np.zeros(3), 0.1 * np.eye(3))
    np.testing.assert_array_equal(so.means, so_ref.means)
    fn = DiscreteModel.from_functions(1, 1, lambda x, t=0: 0.9 * x, lambda x, t=0: x**3, Q=0.1, R=0.1,
                                      f_x=lambda x, t=0: np.full((*x.shape, 1), 0.9),
                                      h_x=lambda x, t=0: (3 * x**2)[..., None])
    with pytest.raises(ValueError, match="f_xx, h_xx"):
        fn.require("f_x", "f_xx", "h_xx", by="SecondOrderFilter")
    with pytest.raises(ValueError, match="f_xx"):
        SecondOrderFilter(fn)


def test_code_without_cse_only_when_cse_finds_nothing():
    """Where the screen skips common-subexpression elimination, lambdify with it writes the same
    code (so the numbers cannot move); where CSE would share something the screen refuses."""
    import inspect

    xs = sp.symbols("x1:7")
    rng = np.random.default_rng(5)
    cases = []
    for trial in range(12):
        F = np.round(rng.standard_normal((4, 6)), trial % 3 + 1)
        F[rng.random(F.shape) < 0.3] = 0.0
        if trial % 4 == 1:
            F[0, 0], F[1, 2] = 1.0, -1.0
        M = sp.Matrix(F.tolist()) * sp.Matrix(xs)
        if trial % 4 == 2:
            M = M + sp.Matrix([0.5, -0.25, 0, 1.5])
        if trial % 4 == 3:
            M = sp.Matrix([sp.Integer(2) * xs[0] - xs[1], xs[2] + sp.Rational(1, 3), -xs[3], 3 * xs[4] - 7 * xs[5]])
        cases.append(list(M))
    cases += [[xs[0] + xs[1], xs[0] + xs[1] + xs[2]], [2.0 * xs[0] + xs[1], -2.0 * xs[0]], [xs[0] * xs[1]],
              [xs[0] + 1, xs[1] + 1], [-xs[0] - xs[1], xs[0] + xs[1] + xs[2]]]
    printer = lambda: ArrayPrinter({"fully_qualified_modules": False, "inline": True,  # noqa: E731
                                "allow_unknown_functions": True})
    skipped = 0
    for exprs in cases:
        with_cse = sp.cse(exprs)[0]
        if nothing_to_share(exprs):
            skipped += 1
            assert not with_cse, exprs
            a = inspect.getsource(sp.lambdify(list(xs), exprs, modules="numpy", cse=True, printer=printer()))
            b = inspect.getsource(sp.lambdify(list(xs), exprs, modules="numpy", cse=False, printer=printer()))
            assert a == b, exprs
    assert skipped >= 8
    assert not nothing_to_share([xs[0] + xs[1], xs[0] + xs[1] + xs[2]])
    assert not nothing_to_share([xs[0] ** 2])


class _Reference(ArrayPrinter):
    def _print_Mul(self, expr):  # the printer without the c*s shortcut
        return NumPyPrinter._print_Mul(self, expr)


def test_printer_shortcut_writes_the_same_text():
    settings = {"fully_qualified_modules": False, "inline": True, "allow_unknown_functions": True}
    p, ref = ArrayPrinter(settings), _Reference(settings)
    x, y, lam = sp.symbols("x y lambda")
    rng = np.random.default_rng(7)
    coeffs = list(rng.standard_normal(20) * 10.0 ** rng.integers(-12, 12, 20)) + [1.0, -1.0, 0.5, -2.0, 1e300, -5e-324]
    for c in coeffs:
        for s in (x, lam):
            e = sp.Mul(sp.Float(c), s)
            if e.is_Mul and len(e.args) == 2:
                assert p.doprint(e) == ref.doprint(e), e
            row = sp.Float(c) * s + 0.25 * y - 3 * x * y - sp.Float(c) * y**2
            assert p.doprint(row) == ref.doprint(row), row
