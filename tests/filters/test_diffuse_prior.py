"""Exact diffuse priors beyond the Kalman filter's run (:mod:`nlfilter.filters.diffuse_prior`,
issue 30 item 3): the diffuse EKF and IEKF, the exact diffuse smoother, posterior draws from a
diffuse prior, and the refusal of an infinite variance by every filter without a diffuse form.

Tolerances:
- the EKF/IEKF on a linear model run the Kalman filter's operations on the same matrices: 1e-12;
- a local level's diffuse posterior is the Kalman smoother's from N(y_0, σ²_ε) at step 0 (the
  flat prior's posterior after y_0, D&K 2012 §2.9): the same algebra by another route, 1e-12;
- statsmodels' exact diffuse smoother (``UnobservedComponents``, steady-state shortcut off):
  measured differences ≤ 2e-15 on local level and local linear trend, asserted to 1e-10;
- the dense limit ``P0 = κ I``: every output differs by ``c/κ + O(1/κ²)``, so from κ = 1e6 to 1e7
  the error must shrink by 8-12 (measured 9.99999..., EKF and IEKF, filter, log-likelihood
  ``+ (q/2) log κ``, smoother, lag-one covariance) and be below 1e-5 at κ = 1e6 (measured ≤ 4e-7);
- draws: 3000 per path; mean and variance within 4.5 standard errors (24 comparisons), the
  lag-one covariance within 0.03 (its standard error ≈ √(V_k V_{k+1}/N) ≤ 0.012).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import CKF, EKF, UKF, GridFilter, IteratedEKF, KalmanFilter, ParticleFilter
from nlfilter.filters.checks import DIFFUSE_FILTERS
from nlfilter.filters.sampling import sample_posterior

YS = np.random.default_rng(0).normal(size=(2, 12, 1)).cumsum(axis=1)


def _level(se=0.8, sn=0.3):
    x = sp.Symbol("x")
    return DiscreteModel([x], f=[x], h=[x], Q=sn, R=se)


def _trend():
    lv, sl = sp.symbols("lv sl")
    return DiscreteModel([lv, sl], f=[lv + sl, sl], h=[lv], G=np.eye(2), Q=np.diag([0.3, 0.05]), R=0.8)


def _nonlinear():
    a, b = sp.symbols("a b")
    return DiscreteModel([a, b], f=[a + 0.1 * sp.sin(b), 0.8 * b], h=[a + 0.2 * a**2 / (1 + a**2), b], G=np.eye(2),
                         Q=np.diag([0.1, 0.2]), R=np.diag([0.5, 0.3]))


@pytest.mark.parametrize("cls", [EKF, IteratedEKF])
def test_extended_filters_on_a_linear_model_are_the_diffuse_kalman_filter(cls):
    md = _trend()
    ys = np.random.default_rng(1).normal(size=(2, 10, 1)).cumsum(axis=1)
    ys[0, 3] = np.nan
    P0 = np.diag([np.inf, np.inf])
    kf, flt = KalmanFilter(md, start="predict"), cls(md, start="predict")
    a, b = kf.run(ys, np.zeros(2), P0, loglik=True), flt.run(ys, np.zeros(2), P0, loglik=True)
    np.testing.assert_allclose(b.means, a.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b.loglik, a.loglik, rtol=1e-12)
    assert np.array_equal(np.isinf(a.covs), np.isinf(b.covs))
    fin = np.isfinite(a.covs)
    np.testing.assert_allclose(b.covs[fin], a.covs[fin], rtol=1e-12, atol=1e-12)
    sa, sb = kf.smooth(ys, np.zeros(2), P0), flt.smooth(ys, np.zeros(2), P0)
    np.testing.assert_allclose(sb.means, sa.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sb.covs, sa.covs, rtol=1e-12, atol=1e-12)


def test_local_level_smoother_is_the_posterior_after_the_first_measurement():
    kf = KalmanFilter(_level(), start="update")
    sm = kf.smooth(YS, 0.0, np.inf)
    after = YS.copy()
    after[:, 0] = np.nan  # step 0's belief N(y_0, σ²_ε), its measurement taken in
    ref = kf.smooth(after, YS[:, 0], 0.8, backend="numpy")
    np.testing.assert_allclose(sm.means, ref.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sm.covs, ref.covs, rtol=1e-12)
    lag, lag_ref = sm.extras["lag_one_cov"], ref.extras["lag_one_cov"]
    np.testing.assert_allclose(lag[:, :-1], lag_ref[:, :-1], rtol=1e-12)
    assert np.isnan(lag[:, -1]).all()


@pytest.mark.parametrize("trend", [False, True])
def test_smoother_against_statsmodels(trend):
    sm_api = pytest.importorskip("statsmodels.api", reason="statsmodels is a test-only cross-check")
    md, n = (_trend(), 2) if trend else (_level(), 1)
    sm = KalmanFilter(md, start="update").smooth(YS, np.zeros(n), np.diag([np.inf] * n))
    for b in range(YS.shape[0]):
        mod = sm_api.tsa.UnobservedComponents(YS[b, :, 0], "lltrend" if trend else "llevel", use_exact_diffuse=True)
        mod.ssm.tolerance = 0  # its steady-state shortcut off
        res = mod.smooth([0.8, 0.3, 0.05] if trend else [0.8, 0.3])
        np.testing.assert_allclose(sm.means[b], res.smoothed_state.T, rtol=0, atol=1e-10)
        np.testing.assert_allclose(sm.covs[b], np.moveaxis(res.smoothed_state_cov, -1, 0), rtol=0, atol=1e-10)


def _dense_ratio(errs):
    e6, e7 = errs
    assert np.all(e6 < 1e-5), e6
    ratio = e6 / e7
    assert np.all((ratio > 8) & (ratio < 12)), ratio  # c/κ: 10 from 1e6 to 1e7


@pytest.mark.parametrize("cls", [EKF, IteratedEKF])
def test_nonlinear_dense_limit(cls):
    """A nonlinear model, one diffuse direction (seen through a nonlinear h) and one finite:
    filter, diffuse log-likelihood, smoother and lag-one covariance approach the EKF/IEKF from
    P0 = diag(κ, 0.5) as O(1/κ) (module docstring)."""
    flt = cls(_nonlinear(), start="update")
    ys = np.random.default_rng(3).normal(size=(2, 10, 2))
    m0, P0 = np.array([0.3, 0.0]), np.diag([np.inf, 0.5])
    est, sm = flt.run(ys, m0, P0, loglik=True), flt.smooth(ys, m0, P0)
    assert np.isfinite(est.covs).all() and np.isfinite(sm.covs).all()  # h sees a at step 0: identified there
    errs = []
    for kappa in (1e6, 1e7):
        d = flt.run(ys, m0, np.diag([kappa, 0.5]), loglik=True, backend="numpy")
        ds = flt.smooth(ys, m0, np.diag([kappa, 0.5]), backend="numpy")
        errs.append(np.array([np.abs(d.means - est.means).max(), np.abs(d.covs - est.covs).max(),
                              np.abs(d.loglik + 0.5 * math.log(kappa) - est.loglik).max(),
                              np.abs(ds.means - sm.means).max(), np.abs(ds.covs - sm.covs).max(),
                              np.nanmax(np.abs(ds.extras["lag_one_cov"] - sm.extras["lag_one_cov"]))]))
    _dense_ratio(errs)


def test_lag_one_covariance_dense_limit_over_a_two_step_diffuse_period():
    """The local linear trend: level and slope diffuse, identified after two measurements; the
    lag-one covariance (not in statsmodels' exact diffuse output) against the dense limit."""
    kf = KalmanFilter(_trend(), start="update")
    sm = kf.smooth(YS, np.zeros(2), np.diag([np.inf, np.inf]))
    errs = [np.array([np.nanmax(np.abs(kf.smooth(YS, np.zeros(2), k * np.eye(2), backend="numpy").extras["lag_one_cov"]
                                       - sm.extras["lag_one_cov"]))]) for k in (1e6, 1e7)]
    _dense_ratio(errs)


def test_smoother_with_correlated_sensors_and_missing_data_dense_limit():
    """Level and slope diffuse, a third state finite, two sensors with correlated noise (the
    whitening), a whole step and one component missing, the prediction first: the smoother's
    means, covariances and lag-one covariances approach the dense limit as O(1/κ)."""
    lv, sl, c = sp.symbols("lv sl c")
    md = DiscreteModel([lv, sl, c], f=[lv + sl, sl, 0.7 * c], h=[lv + c, 0.5 * lv - c], G=np.eye(3),
                       Q=np.diag([0.3, 0.05, 0.2]), R=[[0.8, 0.3], [0.3, 0.5]])
    ys = np.random.default_rng(1).normal(size=(2, 8, 2)).cumsum(axis=1)
    ys[0, 1] = np.nan
    ys[1, 0, 1] = np.nan
    kf, m0 = KalmanFilter(md, start="predict"), np.array([0.0, 0.0, 0.1])
    sm = kf.smooth(ys, m0, np.diag([np.inf, np.inf, 0.4]))
    assert np.isfinite(sm.covs).all()
    errs = []
    for kappa in (1e6, 1e7):
        d = kf.smooth(ys, m0, np.diag([kappa, kappa, 0.4]), backend="numpy")
        errs.append(np.array([np.abs(d.means - sm.means).max(), np.abs(d.covs - sm.covs).max(),
                              np.nanmax(np.abs(d.extras["lag_one_cov"] - sm.extras["lag_one_cov"]))]))
    _dense_ratio(errs)


def test_posterior_draws_from_a_diffuse_prior():
    kf = KalmanFilter(_level(), start="update")
    sm = kf.smooth(YS, 0.0, np.inf)
    N = 3000
    d = sample_posterior(kf, YS, 0.0, np.inf, n=N, rng=1)[..., 0]  # (B, N, T)
    V = sm.covs[..., 0, 0]
    mu = d.mean(axis=1)
    assert np.all(np.abs(mu - sm.means[..., 0]) < 4.5 * np.sqrt(V / N))
    assert np.all(np.abs(d.var(axis=1) - V) < 4.5 * V * math.sqrt(2 / N))
    lag = np.mean((d[:, :, :-1] - mu[:, None, :-1]) * (d[:, :, 1:] - mu[:, None, 1:]), axis=1)
    assert np.abs(lag - sm.extras["lag_one_cov"][:, :-1, 0, 0]).max() < 0.03


def test_an_unidentified_direction_is_inf_and_its_draws_refused():
    """A second random walk no sensor sees: its smoothed variance is inf (never NaN), the level's
    finite; drawing from that improper posterior is refused naming P0."""
    a, b = sp.symbols("a b")
    md = DiscreteModel([a, b], f=[a, b], h=[a], G=np.eye(2), Q=0.1 * np.eye(2), R=0.5)
    kf, P0 = KalmanFilter(md), np.diag([np.inf, np.inf])
    sm = kf.smooth(YS, np.zeros(2), P0)
    assert np.isinf(sm.covs[..., 1, 1]).all() and np.isfinite(sm.covs[..., 0, 0]).all()
    assert not np.isnan(sm.means).any() and not np.isnan(sm.covs).any()
    with pytest.raises(ValueError, match="P0: the data do not identify"):
        sample_posterior(kf, YS, np.zeros(2), P0, n=2, rng=0)


def test_the_registry_says_which_filters_have_a_diffuse_form():
    from nlfilter.filters import REGISTRY
    have = sorted(name for name, cls in REGISTRY.items() if getattr(cls, "diffuse_prior", False))
    assert have == sorted(DIFFUSE_FILTERS)


def test_bad_diffuse_input_is_refused_naming_p0():
    md = _level()
    msg = r"P0: an infinite variance \(a diffuse prior\) has an exact form only in the filters kf, ekf, iekf"
    for flt in (UKF(md), CKF(md), GridFilter(md, (-5, 5), 41), ParticleFilter(md, 50)):
        with pytest.raises(ValueError, match=msg + ".*" + type(flt).__name__):
            flt.run(YS, 0.0, np.inf)
    with pytest.raises(ValueError, match=msg):
        UKF(md).smooth(YS, 0.0, np.inf)
    md2 = _trend()
    for P0 in (np.array([[np.inf, 0.1], [0.1, 1.0]]),  # an inf entry whose row is not zero
               np.array([[1.0, np.inf], [np.inf, 1.0]]),  # inf off the diagonal
               np.diag([-np.inf, np.inf]), np.diag([np.nan, np.inf]), np.diag([np.inf, -1.0])):
        for cls in (KalmanFilter, EKF, IteratedEKF):
            with pytest.raises(ValueError, match="P0: "):
                cls(md2).run(YS, np.zeros(2), P0)
            with pytest.raises(ValueError, match="P0: "):
                cls(md2).smooth(YS, np.zeros(2), P0)
    with pytest.raises(ValueError, match="alpha: the exact diffuse initialisation"):
        EKF(md).fading_memory(1.1).run(YS, 0.0, np.inf)
    with pytest.raises(ValueError, match=r"P0: a diffuse prior \(inf entries\) runs on the NumPy loop .*chunk"):
        EKF(md).smooth(YS, 0.0, np.inf, chunk=1)
    with pytest.raises(TypeError, match="loglik"):
        EKF(md).run(YS, 0.0, np.inf, loglik="yes")


def test_fit_and_fit_em_refuse_what_they_cannot_do_with_a_diffuse_prior():
    from nlfilter import fit
    from nlfilter.fitting import fit_em
    x = sp.Symbol("x")
    q = sp.Symbol("q", positive=True)
    md = DiscreteModel([x], f=[x], h=[x], Q=[[q]], R=0.8, params={q: 0.3})
    with pytest.raises(ValueError, match="P0: an infinite variance .*filter 'ukf' has none"):
        fit(md, YS, {"q": 0.5}, m0=0.0, P0=np.inf, filter="ukf", se=False)
    with pytest.raises(ValueError, match="P0: a diffuse prior .* no m0 or P0 to estimate"):
        fit_em(YS, [[1.0]], [[1.0]], [[0.3]], [[0.8]], [0.0], [[np.inf]], estimate=("Q", "P0"))
    res = fit_em(YS, [[1.0]], [[1.0]], [[0.3]], [[0.8]], [0.0], [[np.inf]], estimate=("Q", "R"), iterations=30)
    assert np.isfinite(res.Q).all() and np.all(np.diff(res.loglik) > -1e-9)  # EM raises the diffuse likelihood
