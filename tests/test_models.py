import numpy as np
import pytest
import scipy.stats as st
import sympy as sp

from nlfilter import DiscreteModel, Gaussian, Independent, SDEModel


def _fd_jac(fn, x, eps=1e-6):
    """Central finite differences of fn (..., *S) w.r.t. the last axis of x: (..., *S, n)."""
    cols = []
    for j in range(x.shape[-1]):
        e = np.zeros(x.shape[-1])
        e[j] = eps
        cols.append((fn(x + e) - fn(x - e)) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("first,second", [("f", "f_x"), ("f_x", "f_xx"), ("h", "h_x"), ("h_x", "h_xx"),
                                          ("G", "G_x"), ("G_x", "G_xx")])
def test_derivatives_equal_finite_differences(nonlinear3, first, second):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(7, 3))
    num = _fd_jac(lambda z: getattr(nonlinear3, first)(z, 0), x)
    exact = getattr(nonlinear3, second)(x, 0)
    assert exact.shape == num.shape
    np.testing.assert_allclose(exact, num, atol=1e-7, rtol=1e-6)


def test_batch_shapes_and_constant_broadcast(nonlinear3):
    x = np.zeros((4, 5, 3))
    assert nonlinear3.f(x).shape == (4, 5, 3)
    assert nonlinear3.f_xx(x).shape == (4, 5, 3, 3, 3)
    assert nonlinear3.G_xx(x).shape == (4, 5, 3, 2, 3, 3)
    assert nonlinear3.h_xx(x).shape == (4, 5, 2, 3, 3)
    assert not nonlinear3.is_linear and not nonlinear3.G_constant


def test_params_and_time():
    x, a, k = sp.symbols("x a k")
    m = DiscreteModel([x], [a * x + k], [x], Q=1.0, R=1.0, params={a: 0.5}, time=k)
    assert m.f(np.array([[2.0]]), 3).tolist() == [[4.0]]


def test_linear_flag():
    assert DiscreteModel.linear([[1.0]], [[2.0]], [[1.0]], [[1.0]]).is_linear


@pytest.mark.parametrize("kw,match", [
    ({"Q": [[1.0, 0.0]]}, "Q: expected a square matrix"),
    ({"Q": [[1.0, 0.5], [0.4, 1.0]]}, "Q: expected a symmetric"),
    ({"Q": [[1.0, 2.0], [2.0, 1.0]]}, "Q: expected a positive semi-definite"),
    ({"R": [[-1.0]]}, "R: expected a positive semi-definite"),
    ({"Q": np.eye(3)}, r"Q: expected shape \(2, 2\)"),
])
def test_bad_covariances(kw, match):
    x, y = sp.symbols("x y")
    args = dict(Q=np.eye(2), R=[[1.0]])
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        DiscreteModel([x, y], [x, y], [x], **args)


def test_unknown_symbol_is_named():
    x, b = sp.symbols("x b")
    with pytest.raises(ValueError, match=r"f: uses symbol\(s\) \['b'\]"):
        DiscreteModel([x], [b * x], [x], Q=1.0, R=1.0)


def test_bad_states_type():
    with pytest.raises(TypeError, match="states"):
        DiscreteModel(["x"], [1], [1], Q=1.0, R=1.0)


def test_from_functions_missing_derivative_named():
    from nlfilter.filters.ekf import EKF
    m = DiscreteModel.from_functions(1, 1, lambda x, t=0: x, lambda x, t=0: x**3, Q=[[1.0]], R=[[1.0]])
    with pytest.raises(ValueError, match="EKF needs f_x, h_x"):
        EKF(m)


def test_noise_law_covariance_must_match_Q():
    x = sp.Symbol("x")
    with pytest.raises(ValueError, match="process_noise: its covariance"):
        DiscreteModel([x], [x], [x], Q=1.0, R=1.0, process_noise=Independent(st.uniform(-1, 2)))
    m = DiscreteModel([x], [x], [x], R=1.0, process_noise=Independent(st.uniform(-1, 2)))
    assert m.Q[0, 0] == pytest.approx(1 / 3)


def test_nonzero_mean_law_rejected():
    x = sp.Symbol("x")
    with pytest.raises(ValueError, match="zero-mean"):
        DiscreteModel([x], [x], [x], R=1.0, process_noise=Independent(st.uniform(0, 1)))


def test_sde_rejects_non_gaussian_law():
    x = sp.Symbol("x")
    with pytest.raises(ValueError, match="Brownian"):
        SDEModel([x], [-x], [x], R=1.0, process_noise=Independent(st.uniform(-1, 2)))
    assert isinstance(SDEModel([x], [-x], [x], Q=1.0, R=1.0).process_noise, Gaussian)


def test_generated_code_equals_sympy_on_powers_in_denominators():
    """Small integer powers are printed as products: their precedence must survive division."""
    x, y = sp.symbols("x y")
    exprs = [-2 * x / (x**2 + 1) ** 2, sp.sin(x) * y**3 / (y + 2) ** 4, (x + y) ** 3 - 1 / (x * y) ** 2,
             sp.sqrt(x) * y**-3, sp.exp(-(x**2)) * (1 + y) ** 2]
    m = DiscreteModel([x, y], [0 * x, 0 * y], exprs, Q=np.eye(2), R=np.eye(len(exprs)))
    pts = np.array([[0.7, 1.3], [1.9, 0.4]])
    want = np.array([[float(e.subs({x: a, y: b})) for e in exprs] for a, b in pts])
    np.testing.assert_allclose(m.h(pts), want, rtol=1e-13)


C_FULL = 0.1 + 2**-50  # 0.1000000000000009: 15 significant digits would print it as 0.100000000000001


def test_float_constants_reach_numeric_functions_bit_exactly():
    """issue 10 item 8.2: SymPy's printer writes floats with 15 significant digits; the generated
    code must carry the double itself (compared with ==, no tolerance)."""
    x, k = sp.symbols("x k")
    third = 1 / 3.0
    m = DiscreteModel([x], [C_FULL * x + third * x**2], [x / 3.0 + C_FULL * k], G=[[third + C_FULL * k]],
                      Q=1.0, R=1.0, time=k)
    one = np.array([1.0])
    assert m.f(one, 0)[0] == C_FULL + third
    assert m.f_x(np.zeros(1), 0)[0, 0] == C_FULL
    assert m.f_xx(np.zeros(1), 0)[0, 0, 0] == 2 * third
    assert m.h(one, 1.0)[0] == 1 / 3.0 + C_FULL
    assert m.h_x(np.zeros(1), 0)[0, 0] == third
    assert m.G(one, 1.0)[0, 0] == third + C_FULL



def test_float_constants_in_time_dependent_coefficients_bit_exact():
    """The moment engine's and the bilinear model's compiled coefficient functions keep the double."""
    from nlfilter.bilinear import BilinearModel
    from nlfilter.moments import PolynomialSDE, moment_equations
    x, t = sp.symbols("x t")
    eqs = moment_equations(PolynomialSDE.from_sympy([x], [-sp.sin(C_FULL * t) * x], sigma=[[1]], time=t), [(1,)])
    assert eqs.at(t=1.0)[0].toarray()[0, 0] == -np.sin(C_FULL)
    bm = BilinearModel(sp.Matrix([[-1 - C_FULL * t]]), [[1.0]], G=[[[0.5]]], R=[[1.0]], time=t)
    assert bm.F(1.0)[0, 0] == -1 - C_FULL


def test_constructor_signatures_are_visible():
    """issue 10 item 8.6: help()/inspect show the real parameters, not (*args, **kw)."""
    import inspect
    from nlfilter import BilinearModel
    from nlfilter.filters.quasilinear import MQLF, QLF, QuasilinearFilter
    want = ["states", "f", "h", "G", "Q", "R", "params", "inputs", "time", "process_noise", "measurement_noise", "name",
            "cross_noise", "noise", "meas_noise", "angles"]
    for cls in (DiscreteModel, SDEModel):
        sig = inspect.signature(cls)
        assert list(sig.parameters) == want, cls
        assert all(p.kind is not p.VAR_POSITIONAL and p.kind is not p.VAR_KEYWORD for p in sig.parameters.values())
        assert sig.parameters["time"].kind is inspect.Parameter.KEYWORD_ONLY
        assert list(inspect.signature(cls.linear).parameters) == ["F", "H", "Q", "R", "G", "process_noise",
                                                                   "measurement_noise", "name"]
    assert list(inspect.signature(BilinearModel).parameters) == ["F", "H", "G", "M", "B", "Q", "R", "c", "d",
                                                                  "time", "discrete", "names"]
    qf = [p for p in inspect.signature(QuasilinearFilter).parameters if p != "closure"]
    assert list(inspect.signature(QLF).parameters) == qf
    assert list(inspect.signature(MQLF).parameters) == list(inspect.signature(QuasilinearFilter).parameters)
    x = sp.Symbol("x")
    m = SDEModel([x], [-x], [x], None, 0.5, 0.2, name="ou")  # positional G, Q, R still work
    assert (m.Q.tolist(), m.R.tolist(), m.name) == ([[0.5]], [[0.2]], "ou")
    with pytest.raises(TypeError):
        DiscreteModel.linear([[0.5]], [[1.0]], 1.0, 1.0, time=x)  # no time symbol in a numeric linear model
