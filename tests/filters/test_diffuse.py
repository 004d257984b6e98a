"""The exact diffuse initialisation of the Kalman filter (:mod:`nlfilter.filters.diffuse`, issue 30
item 3): ``P0`` with ``inf`` in unknown directions.

Checks, each independent of the diffuse recursion:
- local level: the diffuse filter's first step identifies the level (a = y_0, P = σ²_ε), so its
  log-likelihood is −½ log 2π plus the ordinary Kalman filter's from that belief over y_1.. (Durbin
  & Koopman 2012 §2.9) — to 1e-12 (the same operations but for the first step's);
- every model: the dense limit ``log L(κ) + (q/2) log κ → log L_d``, ``q`` diffuse directions,
  with an error O(1/κ) (D&K §7.2.2): the errors at κ = 1e5 and 1e6 must have a ratio in 8–12
  (an O(1/κ) error gives 10; a wrong constant or a missed term would not shrink) and the error at
  κ = 1e6 must be below 1e-3 (measured: 2e-7 to 5e-7 on the local level);
- statsmodels' exact diffuse log-likelihood (``UnobservedComponents(use_exact_diffuse=True)``, its
  steady-state shortcut off) where statsmodels is installed: to 1e-10. Measured by hand on local
  level and local linear trend: differences 0.0 exactly with the shortcut off, ≤ 8e-9 with it on.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import UKF, KalmanFilter

YS = np.random.default_rng(0).normal(size=(3, 40, 1)).cumsum(axis=1)


def _level(se=0.8, sn=0.3):
    x = sp.Symbol("x")
    return DiscreteModel([x], f=[x], h=[x], Q=sn, R=se)


def _trend_two_sensors():
    """A local linear trend (level and slope, both diffuse) and a third state with a finite prior,
    seen by two sensors with correlated noise; some components missing."""
    lv, sl, c = sp.symbols("lv sl c")
    return DiscreteModel([lv, sl, c], f=[lv + sl, sl, 0.7 * c], h=[lv + c, 0.5 * lv - c], G=np.eye(3),
                         Q=np.diag([0.3, 0.05, 0.2]), R=[[0.8, 0.3], [0.3, 0.5]])


def _dense_limit_check(kf, ys, m0, P0_of, q, Ld):
    err = {}
    for kappa in (1e5, 1e6):
        dense = kf.run(ys, m0, P0_of(kappa), loglik=True, backend="numpy").loglik
        err[kappa] = dense + 0.5 * q * math.log(kappa) - Ld
    ratio = err[1e5] / err[1e6]
    assert np.all((ratio > 8) & (ratio < 12)), ratio  # an O(1/κ) error: ~10 from 1e5 to 1e6
    assert np.all(np.abs(err[1e6]) < 1e-3), err[1e6]


def test_local_level_against_its_closed_form_and_the_dense_limit():
    md = _level()
    est = KalmanFilter(md, start="update").run(YS, 0.0, np.inf, loglik=True)
    after = KalmanFilter(md, start="predict").run(YS[:, 1:], YS[:, 0], 0.8, loglik=True, backend="numpy")
    np.testing.assert_allclose(est.loglik, after.loglik - 0.5 * math.log(2 * math.pi), rtol=1e-12)
    np.testing.assert_allclose(est.means[:, 1:], after.means, rtol=1e-12)
    np.testing.assert_allclose(est.covs[:, 0], 0.8, rtol=1e-14)  # identified by the first measurement: P = σ²_ε
    _dense_limit_check(KalmanFilter(md, start="update"), YS, 0.0, lambda k: k, 1, est.loglik)


def test_a_multivariate_model_with_correlated_noise_and_missing_data():
    """Three states, two diffuse; two correlated sensors; a whole step and one component missing:
    the dense limit holds; the covariance is inf until the data identify the level and slope."""
    md = _trend_two_sensors()
    ys = np.random.default_rng(1).normal(size=(2, 12, 2)).cumsum(axis=1)
    ys[0, 1] = np.nan
    ys[1, 0, 1] = np.nan
    m0 = np.array([0.0, 0.0, 0.1])
    P0 = np.diag([np.inf, np.inf, 0.4])
    kf = KalmanFilter(md, start="update")
    est = kf.run(ys, m0, P0, loglik=True)
    _dense_limit_check(kf, ys, m0, lambda k: np.diag([k, k, 0.4]), 2, est.loglik)
    dense = kf.run(ys, m0, np.diag([1e8, 1e8, 0.4]), backend="numpy")
    finite = np.isfinite(est.covs).all(axis=(-1, -2))
    assert not finite[:, 0].any() and finite[:, 3:].all()  # two scalar-ish measurements per step: level+slope by step 1-2
    np.testing.assert_allclose(est.means[:, 3:], dense.means[:, 3:], rtol=1e-5, atol=1e-5)  # O(1/κ) = 1e-8 · data scale
    np.testing.assert_allclose(est.covs[:, 3:], dense.covs[:, 3:], rtol=1e-5, atol=1e-6)


def test_against_statsmodels_exact_diffuse_loglik():
    sm = pytest.importorskip("statsmodels.api", reason="statsmodels is a test-only cross-check (pip install statsmodels)")
    est = KalmanFilter(_level(), start="update").run(YS, 0.0, np.inf, loglik=True)
    for b in range(YS.shape[0]):
        mod = sm.tsa.UnobservedComponents(YS[b, :, 0], "llevel", use_exact_diffuse=True)
        mod.ssm.tolerance = 0  # its steady-state shortcut off (on: differences up to 8e-9)
        assert abs(est.loglik[b] - mod.loglike([0.8, 0.3])) < 1e-10


def test_bad_input_is_named():
    md = _level()
    kf = KalmanFilter(md)
    with pytest.raises(ValueError, match="P0: an infinite variance .* only in the filters kf, ekf, iekf"):
        UKF(md).run(YS, 0.0, np.inf)
    with pytest.raises(ValueError, match=r"P0: a diffuse prior \(inf entries\) runs on the NumPy loop .*chunk"):
        kf.run(YS, 0.0, np.inf, chunk=2)
    md3 = _trend_two_sensors()
    for P0 in (np.array([[np.inf, 0.1, 0], [0.1, 1, 0], [0, 0, 1]]), np.array([[1, np.inf, 0], [np.inf, 1, 0], [0, 0, 1]]),
               np.diag([-np.inf, 1.0, 1.0])):
        with pytest.raises(ValueError, match="P0: "):
            KalmanFilter(md3).run(np.zeros((4, 2)), np.zeros(3), P0)


def test_a_fit_from_a_diffuse_prior_finds_statsmodels_optimum():
    """simulate → fit with defaults from the diffuse prior: the local level's (σ²_ε, σ²_η) MLE is
    statsmodels' exact-diffuse MLE to 1e-3 relative (two optimizers' stopping rules on a flat
    maximum: the log-likelihoods agree to 1e-6), where statsmodels is installed; without it, the
    fit must still converge to a finite optimum above its start."""
    from nlfilter import fit
    x = sp.Symbol("x")
    q, r = sp.symbols("q r", positive=True)
    md = DiscreteModel([x], f=[x], h=[x], Q=[[q]], R=[[r]], params={q: 0.3, r: 0.8})
    g = np.random.default_rng(5)  # a local level with both noises: level walk 0.3, measurement 0.8
    ys = (np.cumsum(g.normal(0, math.sqrt(0.3), 120)) + g.normal(0, math.sqrt(0.8), 120)).reshape(1, 120, 1)
    res = fit(md, ys, {"q": 0.5, "r": 0.5}, m0=0.0, P0=np.inf, filter="kf", se=False)
    assert res.converged and np.isfinite(res.loglik)
    try:
        import statsmodels.api as sm
    except ImportError:
        return
    mod = sm.tsa.UnobservedComponents(ys[0, :, 0], "llevel", use_exact_diffuse=True)
    mod.ssm.tolerance = 0
    ref = mod.fit(disp=False, method="lbfgs", maxiter=500, pgtol=1e-10)
    est = np.array([res.params["r"], res.params["q"]])
    np.testing.assert_allclose(est, ref.params, rtol=1e-3)
    assert abs(res.loglik - ref.llf) < 1e-6 * abs(ref.llf)


def test_a_diverging_path_is_marked():
    """Data of 1e200 on one path: its diffuse log-likelihood term overflows (v² = 1e400); with
    on_divergence='mark' that path is marked at that step, NaN from there, the others as alone."""
    kf = KalmanFilter(_level(), start="update")
    ys = YS.copy()
    ys[1, 5] = 1e200
    est = kf.run(ys, 0.0, np.inf, loglik=True, on_divergence="mark")
    assert est.diverged.tolist() == [False, True, False] and est.diverged_step[1] == 5
    assert np.isnan(est.means[1, 5:]).all() and np.isfinite(est.means[1, :5]).all()
    assert est.extras["loglik_failed"][1].tolist() == [False] * 5 + [True] + [False] * (YS.shape[1] - 6)
    alone = kf.run(ys[[0, 2]], 0.0, np.inf, loglik=True)
    np.testing.assert_allclose(est.loglik[[0, 2]], alone.loglik, rtol=1e-14)
    with pytest.raises(DivergenceError):
        kf.run(ys, 0.0, np.inf, loglik=True)
