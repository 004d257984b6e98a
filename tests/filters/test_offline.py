"""The off-line-gain runner (filters/offline.py): missing data and the covariance it reports."""

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter.bilinear import BilinearModel
from nlfilter.filters import QLF, DiscreteOptimalLinearFilter, DiscreteQuasilinearFilter, OptimalLinearFilter
from nlfilter.filters.base import ode_step
from nlfilter.filters.linalg import symmetrize

x1, x2, x = sp.symbols("x1 x2 x")
R2 = np.array([[0.2, 0.08], [0.08, 0.1]])
LIN2 = DiscreteModel([x1, x2], [0.95 * x1 + 0.1 * x2, 0.9 * x2], [x1, x2], Q=np.diag([0.1, 0.2]), R=R2)
M0, P0 = np.array([0.3, -0.2]), np.diag([0.5, 0.4])


def test_discrete_missing_component_reports_the_covariance_of_the_gain_used():
    """Path 0 misses component 1 at step 2: the gain's column 1 is dropped and, from then on, the
    path reports the Joseph-form covariance of the recursion actually run (the schedule's gains at
    the later steps); path 1, fully observed, keeps the schedule's covariance bit for bit."""
    ys = simulate(LIN2, 6, paths=2, rng=3, m0=M0, P0=P0).ys
    e = ys.copy()
    e[0, 2, 1] = np.nan
    flt = DiscreteQuasilinearFilter(LIN2)
    est = flt.run(e, M0, P0)
    sch = flt.init(M0, P0, (1,), steps=6).schedule
    sch.ensure(5)
    m, P = M0.copy(), P0.copy()
    for k in range(6):
        if k:
            F, b, _, _, Q, _ = sch.models[k - 1]
            m, P = F @ m + b, symmetrize(F @ P @ F.T + Q)
        _, _, H, d, _, S = sch.models[k]
        K = sch.gains[k].copy()
        y = e[0, k].copy()
        if np.isnan(y).any():
            K[:, np.isnan(y)] = 0.0
            y = np.nan_to_num(y)
        m = m + K @ (y - H @ m - d)
        IKH = np.eye(2) - K @ H
        P = symmetrize(IKH @ P @ IKH.T + K @ S @ K.T)
        np.testing.assert_allclose(est.means[0, k], m, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(est.covs[0, k], P, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(est.covs[1, k], sch.filt[k])
    assert np.all(np.linalg.eigvalsh(est.covs[0, 2] - sch.filt[2]) > 0)  # less information: larger P


def test_discrete_linear_model_is_the_kalman_filter_with_missing_data():
    """On a linear Gaussian model the off-line gains are the Kalman filter's while every component is
    observed; a whole missing step on every path is the Kalman prediction (P⁻ reported). Later the
    schedule keeps the gains scheduled for full observation (the Kalman filter re-optimizes), and the
    reported covariance, that of the gain used, is never below the Kalman filter's."""
    from nlfilter.filters import KalmanFilter
    ys = simulate(LIN2, 6, paths=3, rng=4, m0=M0, P0=P0).ys
    e = ys.copy()
    e[:, 3] = np.nan
    a = DiscreteQuasilinearFilter(LIN2).run(e, M0, P0)
    b = KalmanFilter(LIN2).run(e, M0, P0)
    np.testing.assert_allclose(a.means[:, :4], b.means[:, :4], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(a.covs[:, :4], b.covs[:, :4], rtol=1e-10, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(a.covs[:, 4:] - b.covs[:, 4:]) > -1e-12)
    assert np.any(np.abs(a.means[:, 4:] - b.means[:, 4:]) > 1e-6)


def test_bilinear_discrete_filter_accepts_missing_data():
    model = BilinearModel([[0.9]], [[1.0]], G=[[[0.3]]], B=[[1.0]], M=[[[0.2]]], R=[[0.3]], discrete=True)
    ys = np.random.default_rng(0).normal(size=(2, 5, 1))
    e = ys.copy()
    e[0, 2] = np.nan
    flt = DiscreteOptimalLinearFilter(model)
    a, b = flt.run(e, [0.0], [[1.0]]), flt.run(ys, [0.0], [[1.0]])
    np.testing.assert_array_equal(a.means[1], b.means[1])
    np.testing.assert_array_equal(a.means[0, :2], b.means[0, :2])
    assert a.covs[0, 2, 0, 0] > b.covs[0, 2, 0, 0] and np.isfinite(a.means).all()


def _drift_only(A, b, Q, m, P, dt, substeps, scheme):
    mean = ode_step(lambda v, s: A @ v + b, m, 0.0, dt, substeps=substeps, scheme=scheme)
    cov = ode_step(lambda M, s: A @ M + M @ A.T + Q, P, 0.0, dt, substeps=substeps, scheme=scheme, finish=symmetrize)
    return mean, cov


def test_continuous_missing_increment_is_the_drift_of_the_linearized_model():
    """QLF (ito convention) on a linear SDE: a missing increment on path 0 leaves dm = (a1 m + b) dt
    and dP/dt = a1 P + P a1ᵀ + Q from the previous estimate; path 1 is unchanged."""
    model = SDEModel([x], [-x], [x], Q=1.0, R=0.5)
    dt, k = 0.01, 3
    dys = simulate(model, 6, paths=2, rng=1, m0=[0.5], P0=[[0.3]], dt=dt).ys
    e = dys.copy()
    e[0, k] = np.nan
    flt = QLF(model, dt)
    a, b = flt.run(e, [0.5], [[0.3]]), flt.run(dys, [0.5], [[0.3]])
    np.testing.assert_array_equal(a.means[1], b.means[1])
    np.testing.assert_array_equal(a.covs[1], b.covs[1])
    m, P = _drift_only(np.array([[-1.0]]), np.zeros(1), np.array([[1.0]]), b.means[0, k - 1], b.covs[0, k - 1],
                       dt, flt.substeps, flt.scheme)
    np.testing.assert_allclose(a.means[0, k], m, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a.covs[0, k], P, rtol=1e-9, atol=1e-12)


def test_continuous_bilinear_missing_increment_is_the_drift():
    """OptimalLinearFilter (held convention, steady gains): a missing increment is one scheme step of
    dẑ/dt = F ẑ, dP/dt = F P + P Fᵀ + Σ G X Gᵀ from the previous estimate."""
    model = BilinearModel([[-1.0]], [[1.0]], G=[[[0.3]]], B=[[1.0]], R=[[1.0]])
    dt, k = 0.01, 3
    dys = np.random.default_rng(2).normal(scale=0.1, size=(2, 6, 1))
    e = dys.copy()
    e[0, k] = np.nan
    flt = OptimalLinearFilter(model, dt)
    a, b = flt.run(e, [0.0], [[0.5]]), flt.run(dys, [0.0], [[0.5]])
    np.testing.assert_array_equal(a.means[1], b.means[1])
    aug, ss = model.augmented(0), flt.steady_state()
    Q = np.einsum("aij,jk,alk->il", aug.G, ss.X, aug.G)
    z = np.append(b.means[0, k - 1], 1.0)  # augmented z = (x, 1); the constant has no error
    Pz = np.zeros((2, 2))
    Pz[:1, :1] = b.covs[0, k - 1]
    m, P = _drift_only(aug.F, np.zeros(model.N), Q, z, Pz, dt, 1, "rk4")
    np.testing.assert_allclose(a.means[0, k], m[:1], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(a.covs[0, k], P[:1, :1], rtol=1e-12, atol=1e-14)


def test_joint_analysis_reproduces_joint_process_on_a_bilinear_model():
    """The one joint (x, x̂) analysis of precomputed gains (offline_analysis.gain_error_analysis), fed the
    optimal linear filter's steady gain on dx = −x dt + 0.3 x dβ₁ + dβ₂, dy = x dt + dv written as an
    SDEModel, reaches the stationary E(x − x̂)² that joint_process's exact moments give (and the
    filter's own steady P, exact for bilinear systems)."""
    from nlfilter.filters.bilinear import TensorFilter
    from nlfilter.filters.offline_analysis import gain_error_analysis
    from nlfilter.moments.closures import GaussianClosure
    bil = BilinearModel([[-1.0]], [[1.0]], G=[[[0.3]]], B=[[1.0]], R=[[1.0]])
    sde = SDEModel([x], [-x], [x], G=[[0.3 * x, 1.0]], Q=np.eye(2), R=1.0)
    ss = OptimalLinearFilter(bil, 0.01).steady_state()
    aug, n = bil.augmented(0), bil.n
    K = ss.K[:n]
    F = aug.F[:n, :n] - K @ aug.H[:, :n]
    u = aug.F[:n, n] - K @ aug.H[:, n]
    s2 = 1.0 / (2.0 - 0.09)  # stationary variance c²/−(2a + b²)
    ea = gain_error_analysis(sde, lambda t: (F, u, K), [0.0], [[s2]], 30, dt=0.5,
                             closure=GaussianClosure(), order=2)
    fit = TensorFilter(bil, 0.01, degree=3).fit()[0]  # joint_process + its stationary moments
    np.testing.assert_allclose(ea.mse[-1, 0], fit.mse_linear, rtol=1e-6)
    np.testing.assert_allclose(fit.mse_linear, ss.P[0, 0], rtol=1e-9)


def test_joint_analysis_one_length_convention_for_both_time_kinds():
    """issue 10 item 4: both time kinds report run's T rows (continuous: t0 + (k + 1) dt; discrete:
    k = 0 .. T − 1) and the prior's MSE diag P0 + (m0 − xhat0)² in the separate field ``prior``."""
    from nlfilter.filters.offline_analysis import gain_error_analysis
    sde = SDEModel([x], [-x], [x], Q=1.0, R=1.0)
    ec = gain_error_analysis(sde, lambda t: (np.array([[-1.5]]), np.zeros(1), np.array([[0.5]])), [1.0], [[0.4]],
                             7, dt=0.25, t0=1.0, xhat0=[1.5], order=2)
    assert ec.mse.shape == (7, 1) and ec.solution.t.shape == (7,)
    np.testing.assert_allclose(ec.t, 1.0 + 0.25 * np.arange(1, 8), rtol=1e-15)
    dm = DiscreteModel([x], [0.8 * x], [x], Q=0.2, R=0.4)
    coef = lambda k: (np.array([[0.3]]), np.eye(1), np.zeros(1), np.array([[0.8]]), np.zeros(1))  # noqa: E731
    ed = gain_error_analysis(dm, coef, [1.0], [[0.4]], 7, xhat0=[1.5], order=2)
    assert ed.mse.shape == (7, 1)
    np.testing.assert_array_equal(ed.t, np.arange(7))
    for ea in (ec, ed):
        np.testing.assert_allclose(ea.prior, [0.4 + 0.25], rtol=1e-12)
    with pytest.raises(ValueError, match="dt"):
        gain_error_analysis(sde, lambda t: (np.eye(1), np.zeros(1), np.eye(1)), [1.0], [[0.4]], 7)
    with pytest.raises(ValueError, match="dt, t0"):
        gain_error_analysis(dm, coef, [1.0], [[0.4]], 7, dt=0.1)
    with pytest.raises(ValueError, match="noise_moment"):
        gain_error_analysis(sde, lambda t: (np.eye(1), np.zeros(1), np.eye(1)), [1.0], [[0.4]], 7, dt=0.1,
                            noise_moment=lambda b: 0.0)


def test_every_off_line_gain_filter_runs_on_the_one_runner():
    """One affine recursion in the code base: every registered filter of the family "off-line
    gains" is an OfflineGainFilter, except the PLL (its loop is nonlinear in θ̂, 001 eq. 4.8)."""
    from nlfilter.filters import REGISTRY
    from nlfilter.filters.offline import OfflineGainFilter
    off = {n for n, c in REGISTRY.items() if c.family == "off-line gains"}
    assert {"tensor", "updated-innovations", "pseudo-observables", "lqf", "phase-tensor"} <= off
    assert {n for n in off if not issubclass(REGISTRY[n], OfflineGainFilter)} == {"pll"}


def test_run_leaves_the_filter_unchanged_and_the_horizon_reaches_init():
    """A run passes its horizon (steps, t0) to ``init`` instead of storing it on the filter (issue
    27): the filter's attributes are the same objects after a run, and a time-varying schedule
    built by ``init`` for that horizon gives the run's covariances bit for bit (same code path)."""
    model = BilinearModel([[-1.0]], [[1.0]], G=[[[0.3]]], B=[[1.0]], R=[[1.0]])
    flt = OptimalLinearFilter(model, 0.01, gains="time-varying")
    before = dict(vars(flt))
    dys = np.random.default_rng(4).normal(scale=0.1, size=(2, 5, 1))
    est = flt.run(dys, [0.0], [[0.5]], t0=0.2)
    assert vars(flt).keys() == before.keys() and all(vars(flt)[k] is v for k, v in before.items())
    sch = flt.init([0.0], [[0.5]], (1,), steps=5, t0=0.2).schedule
    np.testing.assert_array_equal(est.covs[0, -1], sch.cov(5)[:1, :1])
