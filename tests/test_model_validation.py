"""Model construction boundary (issue 15, item 1): every bad input to a model or a filter's
constructor is a ``ValueError``/``TypeError`` naming the argument, what was given and what was
expected, raised at construction (never a SymPy/NumPy internal error, a ``NameError`` at run time
or a silent NaN); the piecewise functions a model may use run through the filters and the
simulator with the derivative convention of :mod:`nlfilter.models`."""

from __future__ import annotations

import pathlib
import warnings

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.bilinear import BilinearModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import EKF, QLF, UKF, GridFilter, SecondOrderFilter, TensorFilter
from nlfilter.filters.bilinear import UpdatedInnovationsFilter
from nlfilter.filters.gaussian import ContinuousDiscreteGaussianFilter
from nlfilter.filters.rules import Taylor2
from nlfilter.modelfile import ModelFileError, load_model
from nlfilter.models import SUPPORTED_FUNCTIONS
from nlfilter.moments.ito import PolynomialSDE
from nlfilter.simulate import simulate

x, y, a, t = sp.symbols("x y a t")
LIFT = SDEModel([x], [-x], [x**3], Q=1.0, R=1.0)
BIL = BilinearModel([[-1.0]], [[1.0]], G=[[[0.3]]], B=[[1.0]], R=[[1.0]])
D1 = DiscreteModel([x], [0.9 * x], [x], Q=0.1, R=0.2)
S1 = SDEModel([x], [-x], [x], Q=0.5, R=0.1)


def _model(cls=DiscreteModel, **kw):
    args = {"f": [0.5 * x], "h": [x], "Q": 1.0, "R": 1.0, **kw}
    return cls([x], **args)


# (id, construction, exception, regex the message must match: it names the argument)
BAD = [
    ("f complex", lambda: _model(f=[sp.I * x]), ValueError, r"^f: f\[0\] = I\*x is not real/finite"),
    ("f zoo", lambda: _model(f=[sp.zoo]), ValueError, r"^f: f\[0\] = zoo is not real/finite"),
    ("f oo", lambda: _model(f=[sp.oo * x]), ValueError, r"^f: .*not real/finite"),
    ("f nan", lambda: _model(f=[sp.nan * x]), ValueError, r"^f: .*not real/finite"),
    ("f 1/0", lambda: _model(f=[x / sp.Integer(0)]), ValueError, r"^f: .*not real/finite"),
    ("f python complex", lambda: _model(f=[(1 + 2j) * x]), ValueError, r"^f: .*not real/finite"),
    ("h zoo", lambda: _model(h=[sp.zoo * x]), ValueError, r"^h: h\[0\] = zoo\*x is not real/finite"),
    ("G complex", lambda: _model(G=[[sp.I]]), ValueError, r"^G: G\[0, 0\] = I is not real/finite"),
    ("R symbolic oo", lambda: _model(R=[[a + sp.oo]], params={a: 1.0}), ValueError, r"^R: .*not real/finite"),
    ("f relation", lambda: _model(f=[sp.Gt(x, 0)]), TypeError, r"^f: expected real expressions"),
    ("param None", lambda: _model(f=[a * x], params={a: None}), TypeError, r"^a: expected a number"),
    ("param nan", lambda: _model(f=[a * x], params={a: float("nan")}), ValueError, r"^a: expected finite"),
    ("param inf", lambda: _model(f=[a * x], params={a: np.inf}), ValueError, r"^a: expected finite"),
    ("param complex", lambda: _model(f=[a * x], params={a: 1 + 2j}), TypeError, r"^a: expected a number"),
    ("param str", lambda: _model(f=[a * x], params={a: "x"}), TypeError, r"^a: expected a number"),
    ("param is a state", lambda: _model(params={x: 1.0}), ValueError,
     r"^params/inputs: .*'x'.*x is a state and a parameter"),
    ("input is a state", lambda: _model(inputs=[x]), ValueError, r"^params/inputs: .*x is a state and an input"),
    ("param is an input", lambda: _model(f=[a * x], params={a: 1.0}, inputs=[a]), ValueError,
     r"^params/inputs: .*a is a parameter and an input"),
    ("param is the time", lambda: _model(f=[x * t], params={t: 1.0}, time=t), ValueError,
     r"^params/inputs: .*t is the time and a parameter"),
    ("time is a state", lambda: _model(time=x), ValueError, r"^time: the time symbol x is also a state"),
    ("time not a symbol", lambda: _model(time="t"), TypeError, r"^time: expected a SymPy symbol"),
    ("DiracDelta", lambda: _model(f=[sp.DiracDelta(x)]), ValueError,
     r"^f: unsupported function DiracDelta\(x\) in f\[0\]; supported: exp, "),
    ("Piecewise", lambda: _model(h=[sp.Piecewise((x, x > 0), (0, True))]), ValueError,
     r"^h: unsupported function Piecewise"),
    ("gamma", lambda: _model(f=[sp.gamma(x)]), ValueError, r"^f: unsupported function gamma\(x\)"),
    ("re", lambda: _model(f=[sp.re(x)]), ValueError, r"^f: unsupported function re\(x\)"),
    ("undefined f", lambda: _model(f=[sp.Function("g")(x)]), ValueError, r"^f: undefined function g\(x\) in f\[0\]"),
    ("undefined G", lambda: _model(G=[[1 + sp.Function("g")(x)]]), ValueError,
     r"^G: undefined function g\(x\) in G\[0, 0\]"),
    ("undefined R", lambda: _model(R=[[1 + sp.Function("g")(x) ** 2]]), ValueError, r"^R: undefined function g\(x\)"),
    ("Derivative", lambda: _model(f=[sp.Derivative(x**2 * a, a)], params={a: 1.0}), ValueError,
     r"^f: unsupported expression Derivative"),
    ("SDE complex", lambda: _model(SDEModel, f=[sp.I * x]), ValueError, r"^f: .*not real/finite"),
    ("SDE DiracDelta", lambda: _model(SDEModel, h=[sp.DiracDelta(x)]), ValueError, r"^h: unsupported function"),
    ("SDE time is a state", lambda: _model(SDEModel, time=x), ValueError, r"^time: .*also a state"),
    # BilinearModel and its lift
    ("bilinear c long", lambda: BilinearModel([[-1.0]], [[1.0]], R=1.0, c=[1.0, 2.0]), ValueError,
     r"^c: expected a vector of 1 entries, got shape \(2,\)"),
    ("bilinear d short", lambda: BilinearModel(-np.eye(2), np.ones((2, 2)), R=np.eye(2), d=[1.0]), ValueError,
     r"^d: expected a vector of 2 entries, got shape \(1,\)"),
    ("bilinear c matrix", lambda: BilinearModel(-np.eye(2), np.ones((1, 2)), R=1.0, c=np.ones((2, 2))), ValueError,
     r"^c: expected a vector of 2 entries"),
    ("bilinear c sympy", lambda: BilinearModel([[-1.0]], [[1.0]], R=1.0, c=sp.Matrix([t, 1]), time=t), ValueError,
     r"^c: expected a vector of 1 entries"),
    ("bilinear F zoo", lambda: BilinearModel(sp.Matrix([[sp.zoo * t]]), [[1.0]], R=1.0, time=t), ValueError,
     r"^F: .*not real/finite"),
    ("lift degree float", lambda: BilinearModel.from_polynomial(LIFT, degree=3.5), TypeError,
     r"^degree: expected an integer, got 3.5"),
    ("lift degree 3.0", lambda: BilinearModel.from_polynomial(LIFT, degree=3.0), TypeError,
     r"^degree: expected an integer"),
    ("polynomial SDE complex", lambda: PolynomialSDE.from_sympy([x], [sp.I * x], G=[[1]], Q=np.eye(1)), ValueError,
     r"^f\[0\]: coefficient I .*not real/finite"),
    ("polynomial SDE negative diffusion", lambda: PolynomialSDE.from_sympy([x], [-x], sp.Matrix([[-1]])), ValueError,
     r"^diffusion"),
    # integer options and tolerances of filters
    ("tensor degree 3.0", lambda: TensorFilter(BIL, 0.05, degree=3.0), TypeError, r"^degree: expected an integer"),
    ("tensor degree True", lambda: TensorFilter(BIL, 0.05, degree=True), TypeError, r"^degree: expected an integer"),
    ("updated-innovations degree", lambda: UpdatedInnovationsFilter(BIL, 0.05, degree=2.5), TypeError,
     r"^degree: expected an integer"),
    ("grid size 30.7", lambda: GridFilter(D1, (-4.0, 4.0), 30.7), TypeError, r"^size: expected an integer, got 30.7"),
    ("grid size 31.0", lambda: GridFilter(D1, (-4.0, 4.0), 31.0), TypeError, r"^size: expected an integer"),
    ("grid size per axis", lambda: GridFilter(DiscreteModel([x, y], [x, y], [x], Q=np.eye(2), R=1.0),
                                              [(-4.0, 4.0)] * 2, [21, 20.5]), TypeError, r"^size: expected an integer"),
    ("qlf rtol", lambda: QLF(S1, 0.05, rtol=-1.0), ValueError, r"^rtol: expected a positive number"),
    ("qlf atol nan", lambda: QLF(S1, 0.05, atol=float("nan")), ValueError, r"^atol: expected a positive number"),
    ("qlf rtol str", lambda: QLF(S1, 0.05, rtol="x"), TypeError, r"^rtol: expected a real number"),
]


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # SymPy's, on a relation in a Matrix
@pytest.mark.parametrize("make, exc, pattern", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_construction_is_refused_naming_the_argument(make, exc, pattern):
    with pytest.raises(exc, match=pattern):
        make()


def test_the_refusal_lists_the_supported_functions():
    with pytest.raises(ValueError) as info:
        _model(f=[sp.DiracDelta(x)])
    assert all(name in str(info.value) for name in SUPPORTED_FUNCTIONS)
    assert {"Abs", "sign", "floor", "ceiling", "Heaviside", "Max", "Min", "erf"} <= set(SUPPORTED_FUNCTIONS)


# -- the piecewise functions: values as NumPy, derivatives by the stated convention -------------
X = np.array([[-1.5], [-0.25], [0.0], [0.75], [2.0]])


@pytest.mark.parametrize("expr, value, d1", [
    (sp.Abs(x), np.abs, np.sign),
    (sp.sign(x), np.sign, lambda v: 0 * v),
    (sp.floor(x), np.floor, lambda v: 0 * v),
    (sp.ceiling(x), np.ceil, lambda v: 0 * v),
    (sp.Heaviside(x), lambda v: np.heaviside(v, 0.5), lambda v: 0 * v),
    (sp.Heaviside(x, 1), lambda v: np.heaviside(v, 1.0), lambda v: 0 * v),
    (sp.Max(x, 0), lambda v: np.maximum(v, 0), lambda v: np.heaviside(v, 0.5)),
    (sp.Min(x, 0), lambda v: np.minimum(v, 0), lambda v: np.heaviside(-v, 0.5)),
    (sp.Max(x, 0, 2 * x - 1), lambda v: np.maximum(np.maximum(v, 0), 2 * v - 1),
     lambda v: np.where(v > 1, 2.0, np.where(v > 0, 1.0, np.where(v == 0, 0.5, 0.0)))),
    (sp.Abs(x**2 - 1), lambda v: np.abs(v**2 - 1), lambda v: np.sign(v**2 - 1) * 2 * v),
    (sp.erf(x), lambda v: __import__("scipy.special").special.erf(v),
     lambda v: 2 / np.sqrt(np.pi) * np.exp(-v**2)),
])
def test_piecewise_function_values_and_derivatives(expr, value, d1):
    m = DiscreteModel([x], [expr], [expr], Q=1.0, R=1.0)
    v = X[:, 0]
    np.testing.assert_allclose(m.f(X, 0)[:, 0], value(v), rtol=1e-14)
    np.testing.assert_allclose(m.f_x(X, 0)[:, 0, 0], d1(v), rtol=1e-14)
    np.testing.assert_allclose(m.h_x(X, 0)[:, 0, 0], d1(v), rtol=1e-14)
    assert np.isfinite(m.f_xx(X, 0)).all() and np.isfinite(m.h_xx(X, 0)).all()


def test_piecewise_abs_second_derivative_is_zero_off_the_kink():
    m = DiscreteModel([x], [sp.Abs(x) * x], [x], Q=1.0, R=1.0)  # x|x|: f' = 2|x|, f'' = 2 sign(x)
    np.testing.assert_allclose(m.f_x(X, 0)[:, 0, 0], 2 * np.abs(X[:, 0]))
    np.testing.assert_allclose(m.f_xx(X, 0)[:, 0, 0, 0], 2 * np.sign(X[:, 0]))


def test_model_expressions_keep_sympys_functions():
    m = DiscreteModel([x], [sp.Abs(x) + sp.Max(x, a)], [x], Q=1.0, R=1.0, params={a: 0.0})
    assert m.expressions["f"][0] == sp.Abs(x) + sp.Max(x, a)
    assert m.piecewise == {"Abs", "Max"} and D1.piecewise == frozenset()
    np.testing.assert_allclose(m.with_params(a=1.0).f(X, 0)[:, 0], np.abs(X[:, 0]) + np.maximum(X[:, 0], 1.0))


PW = DiscreteModel([x, y], [0.9 * x + 0.1 * sp.Abs(y), 0.8 * y + 0.1 * sp.Max(x, 0) - 0.05 * sp.sign(x)],
                   [sp.Abs(x) + 0.1 * sp.floor(y) + sp.Heaviside(x), sp.Min(y, 1)], Q=0.1 * np.eye(2),
                   R=0.1 * np.eye(2))
PW_SDE = SDEModel([x], [-x + 0.2 * sp.Abs(x)], [sp.Max(x, -1) + 0.1 * sp.ceiling(x)], G=[[1 + 0.1 * sp.Abs(x)]],
                  Q=0.2, R=0.1)


@pytest.mark.parametrize("make", [EKF, UKF, SecondOrderFilter], ids=["ekf", "ukf", "second-order"])
def test_piecewise_model_runs_through_the_filters_and_the_simulator(make):
    sim = simulate(PW, 15, paths=3, rng=0, m0=np.ones(2), P0=np.eye(2))
    assert np.isfinite(sim.xs).all() and np.isfinite(sim.ys).all()
    res = make(PW).run(sim.ys, m0=np.ones(2), P0=np.eye(2))
    assert np.isfinite(res.means).all() and np.isfinite(res.covs).all()


def test_piecewise_sde_model_runs_continuous_discrete():
    sim = simulate(PW_SDE, 10, paths=2, rng=1, m0=np.ones(1), P0=np.eye(1), dt=0.1)
    assert np.isfinite(sim.xs).all()
    res = ContinuousDiscreteGaussianFilter(PW_SDE, 0.1, Taylor2()).run(sim.ys, m0=np.ones(1), P0=np.eye(1))
    assert np.isfinite(res.means).all()


def test_compiled_backend_refuses_piecewise_functions_naming_backend():
    ys = np.zeros((2, 3, 2))
    with pytest.raises(TypeError, match=r"^backend: 'numba' cannot run EKF"):
        EKF(PW).run(ys, m0=np.ones(2), P0=np.eye(2), backend="numba")
    from nlfilter.filters import compiled
    if compiled.available():
        assert "Abs" in compiled.unsupported(EKF(PW))


# -- a singularity is inf/NaN in NumPy's sense, then the divergence screening -----------------
SINGULAR = DiscreteModel([x], [x / t], [x], Q=0.1, R=0.1, time=t)


def test_singularity_at_time_zero_is_numpy_inf_not_zero_division():
    with pytest.warns(RuntimeWarning):
        assert np.isinf(SINGULAR.f(np.array([[1.0]]), 0)).all()
    assert SINGULAR.f(np.array([[1.0]]), 2)[0, 0] == 0.5
    with pytest.warns(RuntimeWarning):  # f_x = 1/a, fixed, is computed when the values are bound
        zero = DiscreteModel([x], [x / a], [x], Q=0.1, R=0.1, params={a: 0.0})
    with pytest.warns(RuntimeWarning):
        assert np.isinf(zero.f(np.array([[1.0]]), 0)).all()


def test_singular_model_diverges_by_the_filters_screening():
    ys = np.zeros((2, 4, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(DivergenceError, match="non-finite"):
            EKF(SINGULAR).run(ys, m0=np.ones(1), P0=np.eye(1))
        res = EKF(SINGULAR).run(ys, m0=np.ones(1), P0=np.eye(1), on_divergence="mark")
    assert res.diverged.all()


# -- model files: the model's refusals at the offending key's line ------------------------------
FILE = """\
[model]
kind = "discrete"
states = ["x"]
[parameters]
a = {a}
[dynamics]
f = ["{f}"]
Q = [[0.1]]
[measurement]
h = ["{h}"]
R = [[0.5]]
[prior]
mean = [0.5]
cov = [[1.0]]
"""


def test_model_file_with_piecewise_functions_runs(tmp_path: pathlib.Path):
    path = tmp_path / "pw.toml"
    path.write_text(FILE.format(a=0.5, f="0.9*x + a*Abs(x) - 0.1*sign(x)", h="Max(x, 0) + erf(x)"))
    spec = load_model(path)
    sim = simulate(spec.model, 10, paths=2, rng=0, m0=spec.m0, P0=spec.P0)
    assert np.isfinite(EKF(spec.model).run(sim.ys, m0=spec.m0, P0=spec.P0).means).all()


def test_model_file_refusal_names_file_line_and_field(tmp_path: pathlib.Path, monkeypatch):
    path = tmp_path / "bad.toml"
    path.write_text(FILE.format(a=0, f="0.9*x", h="x/a"))
    with pytest.raises(ModelFileError, match=r"bad\.toml:10: measurement\.h\[0\]: got x/a \(a division by zero at the file's parameter values a = 0\)"):
        load_model(path)
    # a refusal the file's own checks do not anticipate: the model's message, at its key's line
    import nlfilter.modelfile as mf

    def refuse(*args, **kw):
        raise ValueError("h: unsupported function DiracDelta(x) in h[0]; supported: ...")
    monkeypatch.setattr(mf, "DiscreteModel", refuse)
    path.write_text(FILE.format(a=1, f="0.9*x", h="x"))
    with pytest.raises(ModelFileError, match=r"^.*bad\.toml:10: measurement\.h: got an expression the library "
                                             r"refuses \(unsupported function DiracDelta"):
        load_model(path)
