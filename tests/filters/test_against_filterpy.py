"""EKF and UKF against filterpy (an independent implementation), step by step, 1e-9."""

import numpy as np
import pytest

filterpy = pytest.importorskip("filterpy")
from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter  # noqa: E402

from nlfilter.filters.base import GaussianState  # noqa: E402
from nlfilter.filters.ekf import EKF  # noqa: E402
from nlfilter.filters.ukf import UKF  # noqa: E402
from nlfilter.simulate import simulate  # noqa: E402

M0 = np.array([0.5, -0.2, 0.1])
P0 = np.diag([0.3, 0.2, 0.1])


def _const_G_model(nonlinear3):
    # filterpy adds a constant Q: evaluate our state-dependent model with G frozen at its value at 0
    import sympy as sp
    from nlfilter import DiscreteModel
    md = nonlinear3
    G0 = md.G(np.zeros(3), 0)
    return DiscreteModel(md.states, md.sym["f"], md.sym["h"], sp.Matrix(G0.tolist()), md.Q, md.R)


def test_ekf_matches_filterpy_step_by_step(nonlinear3):
    md = _const_G_model(nonlinear3)
    ys = simulate(md, 40, paths=1, rng=5, m0=M0, P0=P0, start="predict").ys[0]

    class FP(ExtendedKalmanFilter):
        def predict_x(self, u=0):  # filterpy propagates with a linear F unless told otherwise
            self.x = md.f(self.x[:, 0], 0)[:, None]

    fp = FP(3, 2)
    fp.x, fp.P, fp.Q, fp.R = M0[:, None].copy(), P0.copy(), md.GQGT(np.zeros(3)), md.R.copy()
    ours = EKF(md, start="predict").run(ys[None], M0, P0)
    for k, y in enumerate(ys):
        fp.F = md.f_x(fp.x[:, 0], 0)
        fp.predict()
        fp.update(y[:, None], lambda x: md.h_x(x[:, 0], 0), lambda x: md.h(x[:, 0], 0)[:, None])
        np.testing.assert_allclose(ours.means[0, k], fp.x[:, 0], atol=1e-9)
        np.testing.assert_allclose(ours.covs[0, k], fp.P, atol=1e-9)


def _ukf_pair(md, alpha=0.7, beta=2.0, kappa=0.5):
    """filterpy's UKF and ours with the same scaled sigma points, prior and noise (predict-first)."""
    pts = MerweScaledSigmaPoints(3, alpha=alpha, beta=beta, kappa=kappa)
    fp = UnscentedKalmanFilter(3, 2, 1.0, hx=lambda x: md.h(x, 0), fx=lambda x, dt: md.f(x, 0), points=pts)
    fp.x, fp.P, fp.Q, fp.R = M0.copy(), P0.copy(), md.GQGT(np.zeros(3)), md.R.copy()
    return fp, UKF(md, alpha=alpha, beta=beta, kappa=kappa, start="predict")


def test_ukf_matches_filterpy_step_by_step(nonlinear3):
    md = _const_G_model(nonlinear3)
    ys = simulate(md, 40, paths=1, rng=6, m0=M0, P0=P0, start="predict").ys[0]
    fp, ukf = _ukf_pair(md)
    ours = ukf.run(ys[None], M0, P0)
    for k, y in enumerate(ys):
        fp.predict()
        fp.update(y)
        np.testing.assert_allclose(ours.means[0, k], fp.x, atol=1e-9)
        np.testing.assert_allclose(ours.covs[0, k], fp.P, atol=1e-9)


def test_state_dependent_G_enters_ekf_and_ukf(nonlinear3):
    """With G(x), the EKF adds G(m) Q G(m)ᵀ and the UKF the sigma-point average of G Q Gᵀ."""
    s = GaussianState(M0, P0)
    ekf_cov = EKF(nonlinear3).predict(s, 0).cov
    F = nonlinear3.f_x(M0, 0)
    np.testing.assert_allclose(ekf_cov, F @ P0 @ F.T + nonlinear3.GQGT(M0), atol=1e-14)
    ukf_cov = UKF(nonlinear3).predict(s, 0).cov
    assert not np.allclose(ukf_cov, UKF(_const_G_model(nonlinear3)).predict(s, 0).cov)


def test_ukf_loglik_and_rts_smoother_match_filterpy(nonlinear3):
    """filterpy's UKF log-likelihood per step (log N(y; ŷ, S)) and its unscented RTS smoother
    (``UnscentedKalmanFilter.rts_smoother``) against ours (``run(..., loglik=True)``,
    ``UKF.smooth``: the RTS pass through the unscented rule) on a nonlinear model, 1e-9."""
    md = _const_G_model(nonlinear3)
    ys = simulate(md, 30, paths=1, rng=7, m0=M0, P0=P0, start="predict").ys[0]
    fp, ukf = _ukf_pair(md)
    ours = ukf.run(ys[None], M0, P0, loglik=True)
    Xs, Ps, lls = [], [], []
    for y in ys:
        fp.predict()
        fp.update(y)
        Xs.append(fp.x.copy())
        Ps.append(fp.P.copy())
        lls.append(fp.log_likelihood)
    np.testing.assert_allclose(ours.extras["loglik"][0], lls, rtol=0, atol=1e-9)
    xs, Pss, _ = fp.rts_smoother(np.array(Xs), np.array(Ps))
    sm = ukf.smooth(ys[None], M0, P0)
    np.testing.assert_allclose(sm.means[0], xs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sm.covs[0], Pss, rtol=0, atol=1e-9)


def test_kf_loglik_and_rts_smoother_match_filterpy():
    from filterpy.kalman import KalmanFilter as FPKF
    from nlfilter import DiscreteModel
    from nlfilter.filters import KalmanFilter
    F = np.array([[1.0, 0.1], [0.0, 0.95]])
    H = np.array([[1.0, 0.0]])
    Q, R = np.diag([0.01, 0.05]), np.array([[0.2]])
    md = DiscreteModel.linear(F, H, Q, R)
    m0, p0 = np.array([0.0, 1.0]), np.eye(2)
    ys = simulate(md, 50, paths=1, rng=8, m0=m0, P0=p0, start="predict").ys[0]
    fp = FPKF(2, 1)
    fp.x, fp.P, fp.F, fp.H, fp.Q, fp.R = m0.copy(), p0.copy(), F, H, Q, R
    mu, cov, _, _ = fp.batch_filter(ys)
    lls = []
    fp.x, fp.P = m0.copy(), p0.copy()
    for y in ys:
        fp.predict()
        fp.update(y)
        lls.append(fp.log_likelihood)
    kf = KalmanFilter(md, start="predict")
    ours = kf.run(ys[None], m0, p0, loglik=True)
    np.testing.assert_allclose(ours.extras["loglik"][0], lls, rtol=0, atol=1e-9)
    xs, Ps, _, _ = fp.rts_smoother(mu, cov)
    sm = kf.smooth(ys[None], m0, p0)
    np.testing.assert_allclose(sm.means[0], xs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sm.covs[0], Ps, rtol=0, atol=1e-9)
