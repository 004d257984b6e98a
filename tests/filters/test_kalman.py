import numpy as np
import pytest
import scipy.linalg as sla
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as hst

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import DivergenceError
from nlfilter.filters.base import GaussianState
from nlfilter.filters.linalg import gaussian_update
from nlfilter.filters.ekf import EKF, ContinuousEKF
from nlfilter.filters.kalman import KalmanBucy, KalmanFilter, steady_state, steady_state_continuous
from nlfilter.filters.ukf import UKF
from nlfilter.simulate import simulate

F = [[0.95, 0.1], [0.0, 0.9]]
LIN = DiscreteModel.linear(F, [[1.0, 0.0]], np.diag([0.1, 0.2]), [[0.5]])


def _ys(model, T=200, paths=3, seed=0):
    return simulate(model, T, paths=paths, rng=seed, m0=np.zeros(model.n), P0=np.eye(model.n)).ys


def test_kf_steady_state_equals_dare():
    est = KalmanFilter(LIN).run(_ys(LIN, 400), np.zeros(2), np.eye(2))
    P_pred = sla.solve_discrete_are(np.array(F).T, np.array([[1.0, 0.0]]).T, np.diag([0.1, 0.2]), [[0.5]])
    _, Pf = steady_state(LIN)
    H = np.array([[1.0, 0.0]])
    K = P_pred @ H.T / (H @ P_pred @ H.T + 0.5)
    np.testing.assert_allclose(Pf, P_pred - K @ H @ P_pred, atol=1e-12)
    np.testing.assert_allclose(est.covs[:, -1], np.broadcast_to(Pf, (3, 2, 2)), atol=1e-10)


@pytest.mark.parametrize("cls", [EKF, UKF])
def test_nonlinear_filters_equal_kf_on_linear_model(cls):
    ys = _ys(LIN, 150)
    a = KalmanFilter(LIN).run(ys, [0.3, -0.1], np.eye(2))
    b = cls(LIN).run(ys, [0.3, -0.1], np.eye(2))
    np.testing.assert_allclose(b.means, a.means, atol=1e-12)
    np.testing.assert_allclose(b.covs, a.covs, atol=1e-12)


def test_kalman_bucy_steady_state_and_continuous_ekf():
    x1, x2 = sp.symbols("x1 x2")
    sde = SDEModel([x1, x2], [x2, -x1 - 0.5 * x2], [x1], Q=np.eye(2) * 0.3, R=[[0.2]])
    sim = simulate(sde, 3000, paths=2, rng=1, m0=[0, 0], P0=np.eye(2), dt=0.005)
    a = KalmanBucy(sde, 0.005).run(sim.ys, [0, 0], np.eye(2))
    b = ContinuousEKF(sde, 0.005).run(sim.ys, [0, 0], np.eye(2))
    np.testing.assert_allclose(a.means, b.means, atol=1e-12)
    np.testing.assert_allclose(a.covs[0, -1], steady_state_continuous(sde), atol=1e-8)


def test_missing_measurements():
    x1, x2 = sp.symbols("x1 x2")
    md = DiscreteModel.linear(F, [[1.0, 0.0], [0.0, 1.0]], np.diag([0.1, 0.2]), np.diag([0.5, 0.3]))
    ys = _ys(md, 30)
    ys[:, 10, :] = np.nan  # fully missing: predict only
    ys[:, 20, 1] = np.nan  # partly missing: update with component 0 only
    est = KalmanFilter(md).run(ys, [0, 0], np.eye(2))
    ref = KalmanFilter(md).run(ys[:, :10], [0, 0], np.eye(2))
    kf = KalmanFilter(md)
    prior = GaussianState(ref.means[:, -1], ref.covs[:, -1])
    pred = kf.predict(prior, 9)
    np.testing.assert_allclose(est.means[:, 10], pred.mean, atol=1e-14)
    # partly missing = a filter that observes the first component only at that step
    one = DiscreteModel.linear(F, [[1.0, 0.0]], np.diag([0.1, 0.2]), [[0.5]])
    before = kf.predict(GaussianState(est.means[:, 19], est.covs[:, 19]), 19)
    want = KalmanFilter(one).update(before, ys[:, 20, :1], 20)
    np.testing.assert_allclose(est.means[:, 20], want.mean, atol=1e-13)
    np.testing.assert_allclose(est.covs[:, 20], want.covs if hasattr(want, "covs") else want.cov, atol=1e-13)
    for cls in (EKF, UKF):
        np.testing.assert_allclose(cls(md).run(ys, [0, 0], np.eye(2)).means, est.means, atol=1e-11)


def test_start_conventions_agree():
    ys = _ys(LIN, 20)
    upd = KalmanFilter(LIN, start="update")
    pre = KalmanFilter(LIN, start="predict")
    m0, P0 = np.array([0.2, 0.1]), np.eye(2)
    after = upd.predict(GaussianState(m0, P0), 0)
    a = upd.run(ys, after.mean, after.cov)
    b = pre.run(ys, m0, P0)
    np.testing.assert_allclose(a.means, b.means, atol=1e-13)


def test_divergence_raises_and_marks():
    x = sp.Symbol("x")
    md = DiscreteModel([x], [x**3], [0], Q=0.0, R=1.0)  # y carries no information: path 0 blows up
    ys = np.zeros((2, 8, 1))
    m0 = np.array([[1e3], [0.5]])
    with pytest.raises(ValueError, match="ys: expected finite"):
        EKF(md).run(np.full((2, 8, 1), np.inf), m0, 1.0)
    with np.errstate(over="ignore", invalid="ignore"):
        with pytest.raises(DivergenceError, match="at step") as info:
            EKF(md).run(ys, m0, 1.0)
        est = EKF(md).run(ys, m0, 1.0, on_divergence="mark")
    assert info.value.paths == (0,)
    assert est.diverged.tolist() == [True, False] and est.diverged_step[0] == info.value.step > 0
    k = info.value.step
    assert np.isnan(est.means[0, k:]).all() and np.isfinite(est.means[0, :k]).all()
    assert np.isfinite(est.means[1]).all()


@pytest.mark.parametrize("bad,match", [
    (dict(m0=[0.0, 0.0, 0.0]), "m0: expected trailing shape"),
    (dict(P0=[[1.0, 0.2], [0.0, 1.0]]), "P0: expected a symmetric"),
    (dict(P0=[[1.0, 2.0], [2.0, 1.0]]), "P0: expected a positive semi-definite"),
    (dict(ys=np.zeros((3, 4, 2))), "ys: expected trailing shape"),
])
def test_bad_run_inputs(bad, match):
    args = dict(ys=np.zeros((3, 4, 1)), m0=[0.0, 0.0], P0=np.eye(2))
    args.update(bad)
    with pytest.raises(ValueError, match=match):
        KalmanFilter(LIN).run(args["ys"], args["m0"], args["P0"])


def test_bad_options():
    with pytest.raises(ValueError, match="start: expected one of"):
        KalmanFilter(LIN, start="later")
    with pytest.raises(ValueError, match="on_divergence"):
        KalmanFilter(LIN).run(np.zeros((1, 2, 1)), [0, 0], np.eye(2), on_divergence="ignore")
    with pytest.raises(ValueError, match="KalmanFilter needs a linear model"):
        x = sp.Symbol("x")
        KalmanFilter(DiscreteModel([x], [x], [x**2], Q=1.0, R=1.0))
    with pytest.raises(ValueError, match="dt: expected a positive"):
        x = sp.Symbol("x")
        ContinuousEKF(SDEModel([x], [-x], [x], Q=1.0, R=1.0), dt=-0.1)
    with pytest.raises(TypeError, match="expects a DiscreteModel"):
        x = sp.Symbol("x")
        EKF(SDEModel([x], [-x], [x], Q=1.0, R=1.0))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(hst.integers(0, 10_000))
def test_update_keeps_covariance_symmetric_psd(seed):
    rng = np.random.default_rng(seed)
    n, m = 3, 2
    A = rng.normal(size=(5, n, n))
    P = A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(n)
    H = rng.normal(size=(5, m, n)) * 10 ** rng.uniform(-3, 3)
    R = np.diag(10 ** rng.uniform(-6, 1, size=m))
    C = P @ np.swapaxes(H, -1, -2)
    S = H @ C + R
    out = gaussian_update(GaussianState(np.zeros((5, n)), P), rng.normal(size=(5, m)), np.zeros((5, m)), S, C, H=H, R=R)
    np.testing.assert_array_equal(out.cov, np.swapaxes(out.cov, -1, -2))
    scale = np.abs(P).max()
    assert np.linalg.eigvalsh(out.cov).min() >= -1e-9 * scale


def test_continuous_ekf_rk4_and_euler_converge_to_the_same_ito_filter():
    """The innovation K dy is an Itô increment (gain at the step start), so RK4 and Euler differ
    by O(dt) and the gap shrinks with dt. (Holding dy/dt constant inside RK4 stages converged to
    the Stratonovich filter instead: a gap of ≈ 0.021 that did not shrink.)"""
    x = sp.Symbol("x")
    md = SDEModel([x], [-x], [x + 0.5 * x**2], G=[[0.5]], Q=1.0, R=0.1)
    fine = np.random.default_rng(3).normal(size=(200, 400, 1)) * np.sqrt(0.0025) * np.sqrt(0.1) + 0.0025
    gaps = {}
    for dt, group in ((0.01, 4), (0.0025, 1)):
        dys = fine.reshape(200, -1, group, 1).sum(axis=2)
        e = ContinuousEKF(md, dt, scheme="euler").run(dys, 0.5, 0.3).means[:, -1, 0]
        r = ContinuousEKF(md, dt, scheme="rk4").run(dys, 0.5, 0.3).means[:, -1, 0]
        gaps[dt] = np.mean(np.abs(e - r))
    assert gaps[0.0025] < gaps[0.01] / 2.5, gaps


def test_ukf_marks_a_path_whose_covariance_has_no_cholesky_factor():
    x = sp.Symbol("x")
    md = DiscreteModel([x], [x], [x], Q=0.0, R=1.0)
    ukf = UKF(md)
    ys = np.zeros((2, 3, 1))
    P0 = np.array([[[1.0]], [[-1.0]]])  # path 1 starts with a negative variance
    with pytest.raises(ValueError, match="P0"):
        ukf.run(ys, 0.0, P0)
    bad = GaussianState(np.zeros((2, 1)), P0)
    out = ukf.predict(bad, 0)
    assert np.isnan(out.mean[1]).all() and np.isfinite(out.mean[0]).all()


def _time_varying_functions(time_invariant=False):
    """x[k+1] = a(k) x + b(k) + w, y = c(k) x + v, a(k) = 0.9 + 0.1 sin k (f, h read k)."""
    a = lambda k: 0.9 + 0.1 * np.sin(k)  # noqa: E731
    c = lambda k: 1.0 + 0.5 * np.cos(0.7 * k)  # noqa: E731
    return DiscreteModel.from_functions(
        1, 1, lambda x, k=0: a(k) * x + 0.2 * k, lambda x, k=0: c(k) * x,
        f_x=lambda x, k=0: np.full((*np.shape(x)[:-1], 1, 1), a(k)),
        h_x=lambda x, k=0: np.full((*np.shape(x)[:-1], 1, 1), c(k)),
        Q=[[0.1]], R=[[0.3]], is_linear=True, time_invariant=time_invariant)


def test_kf_on_time_varying_from_functions_model_reads_time():
    """issue 10 item 8.1: a from_functions model expresses time only through the t argument of its
    callables, so the KF must not freeze F, b, H at k = 0; it equals the EKF (exact on a linear
    model) and differs from the k = 0-frozen filter."""
    md = _time_varying_functions()
    assert md.time_invariant is False
    ys = np.random.default_rng(3).normal(size=(4, 40, 1)) + np.arange(40)[:, None]
    kf = KalmanFilter(md).run(ys, [0.5], [[1.0]])
    ekf = EKF(md).run(ys, [0.5], [[1.0]])
    np.testing.assert_allclose(kf.means, ekf.means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(kf.covs, ekf.covs, rtol=0, atol=1e-12)
    frozen = KalmanFilter(_time_varying_functions(time_invariant=True)).run(ys, [0.5], [[1.0]])
    assert np.max(np.abs(frozen.means - kf.means)) > 1.0  # the k = 0 answer is far off
    np.testing.assert_allclose(frozen.means[:, 0], kf.means[:, 0], atol=1e-12)  # same first update


def test_time_invariant_flag():
    x, k = sp.symbols("x k")
    assert DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0).time_invariant
    assert DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0, time=k).time_invariant  # k unused
    assert not DiscreteModel([x], [0.9 * x + k], [x], Q=1.0, R=1.0, time=k).time_invariant
    assert not DiscreteModel([x], [0.9 * x], [x], G=[[1 + k]], Q=1.0, R=1.0, time=k).time_invariant
    with pytest.raises(TypeError, match="time_invariant: expected True or False, got str"):
        DiscreteModel.from_functions(1, 1, lambda x, k=0: x, lambda x, k=0: x, Q=[[1.0]], R=[[1.0]],
                                     time_invariant="yes")
