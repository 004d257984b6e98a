"""Model parameters kept as symbols (``with_params``), time-varying parameters as arrays and
control inputs (issue 12, items 3 and 4). Every check compares numbers with an independent
computation: the model built with the values substituted, or a plain NumPy Kalman filter."""

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter.filters import CKF, EKF, UKF, GridFilter, KalmanFilter
from nlfilter.model_functions import DERIVS

x1, x2, a, b, q, r, k = sp.symbols("x1 x2 a b q r k")
F_ = [a * x1 + sp.sin(b * x2) + k / 10, x2 - a * b * x1 ** 2]
H_ = [x1 * x2 + b, sp.exp(a * x2)]
G_ = [[1 + a * x1 ** 2, 0], [b, sp.cos(x2)]]
Q_ = [[q, q / 10], [q / 10, 2 * q]]
R_ = [[r ** 2, 0], [0, r + b ** 2]]


def _substituted(values):
    sub = lambda e: sp.sympify(e).subs(values)  # noqa: E731
    num = lambda M: [[float(sub(e)) for e in row] for row in M]  # noqa: E731
    return DiscreteModel([x1, x2], [sub(e) for e in F_], [sub(e) for e in H_],
                         [[sub(e) for e in row] for row in G_], num(Q_), num(R_), time=k)


def _assert_same_functions(mA, mB, tol=1e-15):
    X = np.random.default_rng(1).normal(size=(4, 3, 2))
    for key in DERIVS:
        A, B = getattr(mA, key)(X, 2), getattr(mB, key)(X, 2)
        assert A.shape == B.shape, key
        np.testing.assert_allclose(A, B, rtol=tol, atol=tol, err_msg=key)
    np.testing.assert_allclose(mA.Q, mB.Q, rtol=tol, atol=tol)
    np.testing.assert_allclose(mA.R, mB.R, rtol=tol, atol=tol)
    np.testing.assert_allclose(mA.GQGT(X, 2), mB.GQGT(X, 2), rtol=1e-14, atol=1e-14)


def test_with_params_equals_the_substituted_model_without_generating_code(monkeypatch):
    v0 = {a: 0.9, b: 0.2, q: 0.1, r: 0.3}
    m = DiscreteModel([x1, x2], F_, H_, G_, Q_, R_, params=v0, time=k)
    _assert_same_functions(m, _substituted(v0))

    def no_codegen(*args, **kw):
        raise AssertionError("with_params must not generate code")

    monkeypatch.setattr(sp, "lambdify", no_codegen)
    v1 = {a: 0.7, b: -0.5, q: 0.25, r: 0.4}
    m1 = m.with_params({a: 0.7, "b": -0.5}, q=0.25, r=0.4)
    monkeypatch.undo()
    assert dict(m1.params) == {"a": 0.7, "b": -0.5, "q": 0.25, "r": 0.4}
    assert dict(m.params) == {"a": 0.9, "b": 0.2, "q": 0.1, "r": 0.3}  # the original is unchanged
    _assert_same_functions(m1, _substituted(v1))
    assert m1.sym["f"] == sp.Matrix([e.subs(v1) for e in F_])  # the moment engine's expressions
    assert m1.f._fixed is None and m1.f.kernel is m.f.kernel  # shared generated code
    with pytest.raises(TypeError):
        m1.params["a"] = 1.0  # a read-only view


def test_parameters_in_constant_noise_gain_keep_the_fast_paths():
    m = DiscreteModel([x1], [a * x1], [x1], G=[[sp.sqrt(q)]], Q=1.0, R=[[r]], params={a: 0.8, q: 0.3, r: 0.5})
    assert m.is_linear and m.G_constant and m.time_invariant
    assert m._GQG0 is not None and float(m.GQGT(np.zeros((2, 1)))[0, 0, 0]) == pytest.approx(0.3, abs=1e-15)
    m2 = m.with_params(q=0.6)
    assert m2.GQGT(np.zeros(1))[0, 0] == pytest.approx(0.6, abs=1e-15) and m2.R[0, 0] == 0.5


def _kf(ys, m0, P0, F, b, H, Q, R):
    """An independent Kalman filter (plain NumPy, one path): update, then predict
    ``x[k+1] = F[k] x + b[k] + w``, ``w ~ N(0, Q[k])``; NaN entries of y are missing."""
    T, n = len(ys), len(m0)
    means, covs = np.empty((T, n)), np.empty((T, n, n))
    m, P = np.array(m0, float), np.array(P0, float)
    for i in range(T):
        obs = ~np.isnan(ys[i])
        if obs.any():
            Ho, Ro = H[obs], R[np.ix_(obs, obs)]
            S = Ho @ P @ Ho.T + Ro
            K = P @ Ho.T @ np.linalg.inv(S)
            m = m + K @ (ys[i][obs] - Ho @ m)
            P = (np.eye(n) - K @ Ho) @ P
        means[i], covs[i] = m, P
        m, P = F[i] @ m + b[i], F[i] @ P @ F[i].T + Q[i]
    return means, covs


def test_time_varying_linear_model_kalman_equals_a_hand_written_filter():
    T = 12
    rng = np.random.default_rng(3)
    av, cv, qv = rng.uniform(0.5, 1.1, T), rng.uniform(-1, 1, T), rng.uniform(0.05, 0.4, T)
    c = sp.Symbol("c")
    model = DiscreteModel([x1, x2], [x1 + c * x2, a * x2], [x1], Q=[[q, 0], [0, q / 2]], R=0.5,
                          params={a: 0.9, c: 0.1, q: 0.2})
    assert model.time_invariant
    tv = model.with_params(a=av, c=cv, q=qv)
    assert not tv.time_invariant and tv.is_linear
    ys = simulate(tv, T, paths=2, rng=4, m0=[0, 0], P0=np.eye(2)).ys
    ys[0, 3] = ys[1, 7] = np.nan  # missing data
    est = KalmanFilter(tv).run(ys, np.zeros(2), np.eye(2))
    F = np.array([[[1, cv[i]], [0, av[i]]] for i in range(T)])
    Qk = np.array([np.diag([qv[i], qv[i] / 2]) for i in range(T)])
    for p in range(2):
        mm, PP = _kf(ys[p], np.zeros(2), np.eye(2), F, np.zeros((T, 2)), np.array([[1.0, 0.0]]), Qk, np.array([[0.5]]))
        np.testing.assert_allclose(est.means[p], mm, rtol=0, atol=1e-10)
        np.testing.assert_allclose(est.covs[p], PP, rtol=0, atol=1e-10)


u1 = sp.Symbol("u1")
T_IN = 15
U = 2.0 * np.sin(0.4 * np.arange(T_IN))[:, None]  # (T, 1)


def _control_model():
    return DiscreteModel([x1], [0.9 * x1 + u1], [x1], Q=0.1, R=0.2, inputs=[u1])


def _kf_input(ys, u):
    T = len(ys)
    return _kf(ys, [0.0], [[1.0]], np.full((T, 1, 1), 0.9), u.reshape(T, 1), np.eye(1),
               np.full((T, 1, 1), 0.1), np.array([[0.2]]))


@pytest.mark.parametrize("make,tol", [(KalmanFilter, 1e-9), (EKF, 1e-9), (UKF, 1e-9), (CKF, 1e-9),
                                      # grid: 301 points on [-15, 15] (spacing 0.1): the trapezoidal
                                      # rule on Gaussian densities is spectrally accurate (2e-14 seen)
                                      (lambda m: GridFilter(m, (-15.0, 15.0), 301), 1e-9)])
def test_control_input_filters_equal_a_hand_written_kalman_filter(make, tol):
    model = _control_model().with_inputs(U)
    ys = simulate(model, T_IN, paths=2, rng=5, m0=0.0, P0=1.0).ys
    ys[1, 4] = np.nan
    est = make(model).run(ys, np.zeros(1), np.eye(1))
    for p in range(2):
        mm, PP = _kf_input(ys[p], U[:, 0])
        np.testing.assert_allclose(est.means[p], mm, rtol=0, atol=tol)
        np.testing.assert_allclose(est.covs[p], PP, rtol=0, atol=tol)


def test_simulate_with_inputs_adds_the_input_response_to_the_same_noise():
    model = _control_model()
    with_u = simulate(model.with_inputs(U), T_IN, paths=3, rng=6, m0=0.0, P0=1.0)
    no_u = simulate(model.with_inputs(np.zeros_like(U)), T_IN, paths=3, rng=6, m0=0.0, P0=1.0)
    d = np.zeros(T_IN)  # d[k+1] = 0.9 d[k] + u[k]: the deterministic response (linear model)
    for i in range(T_IN - 1):
        d[i + 1] = 0.9 * d[i] + U[i, 0]
    np.testing.assert_allclose(with_u.xs[..., 0] - no_u.xs[..., 0], np.broadcast_to(d, (3, T_IN)), atol=1e-12)
    np.testing.assert_allclose(with_u.ys - no_u.ys, with_u.xs - no_u.xs, atol=1e-12)


def test_per_path_inputs_with_ukf_and_simulated_rows():
    B = 3
    Ub = np.stack([U * (1 + p) - p for p in range(B)])  # (B, T, 1): a different input per path
    model = _control_model().with_inputs(Ub)
    sim = simulate(model, T_IN, paths=B, rng=7, m0=0.0, P0=1.0)
    part = simulate(model, T_IN, paths=range(1, 3), rng=7, m0=0.0, P0=1.0)  # rows 1..2 of the same run
    np.testing.assert_array_equal(part.xs, sim.xs[1:3])
    for p in range(B):  # each path driven by its own row
        one = simulate(_control_model().with_inputs(Ub[p]), T_IN, paths=range(p, p + 1), rng=7, m0=0.0, P0=1.0)
        np.testing.assert_allclose(one.xs[0], sim.xs[p], rtol=0, atol=1e-14)
    est = UKF(model).run(sim.ys, np.zeros(1), np.eye(1))
    for p in range(B):
        mm, PP = _kf_input(sim.ys[p], Ub[p, :, 0])
        np.testing.assert_allclose(est.means[p], mm, rtol=0, atol=1e-9)
        np.testing.assert_allclose(est.covs[p], PP, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match=r"u1: a per-path parameter array of shape \(3, 15\).*chunk"):
        UKF(model).run(sim.ys, np.zeros(1), np.eye(1), chunk=2)
    with pytest.raises(ValueError, match=r"u1: a per-path parameter array.*grid filter"):
        GridFilter(model, (-15.0, 15.0), 101).run(sim.ys, np.zeros(1), np.eye(1))
    with pytest.raises(ValueError, match=r"u1: a per-path array with 3 row\(s\) for paths=2"):
        simulate(model, T_IN, paths=2, rng=7, m0=0.0, P0=1.0)


def test_sde_parameter_arrays_are_piecewise_constant_on_their_grid():
    x = sp.Symbol("x")
    m = SDEModel([x], [-a * x], [x], Q=1.0, R=1.0, params={a: 1.0})
    with pytest.raises(ValueError, match=r"dt: the parameter\(s\) \['a'\] are arrays over time"):
        m.with_params(a=[1.0, 2.0, 3.0])
    tv = m.with_params(a=[1.0, 2.0, 3.0], dt=0.5, t0=1.0)
    assert not tv.time_invariant and m.time_invariant
    one = np.ones(1)
    # t -> entry floor((t - t0)/dt + 1e-9), clipped: 0.0 -> 0, 1.0 -> 0, 1.5 -> 1, 1.99 -> 1, 2.0 -> 2, 9 -> 2
    got = [float(tv.f(one, t)[0]) for t in (0.0, 1.0, 1.5, 1.99, 2.0, 1.0 + 2 * 0.5 * (1 - 1e-12), 9.0)]
    assert got == [-1.0, -1.0, -2.0, -2.0, -3.0, -3.0, -3.0]


def test_errors_name_the_argument():
    m = DiscreteModel([x1], [a * x1], [x1], Q=[[q]], R=1.0, params={a: 0.9, q: 0.1})
    with pytest.raises(ValueError, match=r"unknown parameter 'zz'; the model's parameters are \['a', 'q'\]"):
        m.with_params(zz=1.0)
    with pytest.raises(ValueError, match=r"Q: expected a positive semi-definite.*'q': -1.0"):
        m.with_params(q=-1.0)
    short = m.with_params(a=np.full(5, 0.9))
    ys = np.zeros((1, 8, 1))
    with pytest.raises(ValueError, match=r"a: its value is an array over 5 step\(s\); step k = 5 is outside 0..4"):
        KalmanFilter(short).run(ys, np.zeros(1), np.eye(1))
    with pytest.raises(ValueError, match=r"inputs: the model declares input\(s\) \['u1'\] and none were given"):
        _control_model().f(np.zeros((2, 1)), 0)
    with pytest.raises(ValueError, match=r"inputs: the model declares input\(s\) \['u1'\]"):
        KalmanFilter(_control_model()).run(ys, np.zeros(1), np.eye(1))
    with pytest.raises(ValueError, match=r"u: expected shape \(\.\.\., T, 1\)"):
        _control_model().with_inputs(np.zeros(4))
    with pytest.raises(ValueError, match=r"model.sym: .*\['a'\]"):
        short.sym  # noqa: B018
    # an R in parameters given per step is R_k (issue 31 item 4; tests/test_per_step_noise.py), not refused
    tvR = DiscreteModel([x1], [x1], [x1], Q=1.0, R=[[r]], params={r: 0.5}).with_params(r=[1.0, 2.0, 3.0])
    assert tvR.structure == {"time-varying R"} and tvR.R_of(np.zeros((2, 1)), 1)[:, 0, 0].tolist() == [2.0, 2.0]
    with pytest.raises(ValueError, match="R: depends on time-varying parameter.*DiscreteModel only"):
        SDEModel([x1], [-x1], [x1], Q=1.0, R=[[r]], params={r: 0.5}).with_params(r=np.ones(3), dt=0.1)
    fm = DiscreteModel.from_functions(1, 1, lambda x, t=0: 0.9 * x, lambda x, t=0: x, Q=1.0, R=1.0)
    with pytest.raises(ValueError, match="with_params: a model built from_functions has no parameters"):
        fm.with_params(a=1.0)
    with pytest.raises(ValueError, match="dt: a DiscreteModel reads array entry k at step k"):
        m.with_params(a=np.ones(3), dt=0.1)
