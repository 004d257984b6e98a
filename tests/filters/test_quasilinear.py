"""QLF / MQLF (seed 003): hand-derived coefficients, linear-model equivalences, off-line error
analysis against Monte Carlo."""
import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import NotPolynomialError
from nlfilter.filters.kalman import KalmanBucy, KalmanFilter
from nlfilter.filters.quasilinear import (MQLF, QLF, DiscreteQuasilinearFilter, QuasilinearFilter,
                                          statistical_linearization)
from nlfilter.moments import EdgeworthClosure
from nlfilter.simulate import simulate

x = sp.Symbol("x")


@pytest.fixture(scope="module")
def oh_shin():
    return SDEModel([x], [-x**3], [x], Q=0.05, R=0.05)


def test_coefficients_match_paper_formulas(oh_shin):
    """003 (after eq. 23): QLF ā0 = 2α1³ − 3α1α2, ā1 = −3α2; eq. 26: MQLF a0 = −α3,
    a1 = (−α4 + α1α3)/(α2 − α1²), both along the filters' own moment solutions."""
    g = QLF(oh_shin, 0.01).offline([4.0], [[0.05]], 100)
    a1_, a2_ = g.moments[:, 0], g.moments[:, 1]
    np.testing.assert_allclose(g.a0[:, 0], 2 * a1_**3 - 3 * a1_ * a2_, rtol=1e-10)
    np.testing.assert_allclose(g.a1[:, 0, 0], -3 * a2_, rtol=1e-10)
    np.testing.assert_allclose(g.b1[:, 0, 0], 1.0, rtol=1e-12)  # h = x: b1 = 1, b0 = m
    gm = MQLF(oh_shin, 0.01).offline([4.0], [[0.05]], 100)
    al = gm.moments
    np.testing.assert_allclose(gm.a0[:, 0], -al[:, 2], rtol=1e-10)
    np.testing.assert_allclose(gm.a1[:, 0, 0], (-al[:, 3] + al[:, 0] * al[:, 2]) / (al[:, 1] - al[:, 0] ** 2),
                               rtol=1e-9)
    # eq. 22/25: P' = 2 a1 P − P²/R + Q — central differences of the dense solution (h = 1e-4)
    t = gm.t[1:-1]
    dP = (gm.dense(t + 1e-4)[-1] - gm.dense(t - 1e-4)[-1]) / 2e-4
    P = gm.P[1:-1, 0, 0]
    np.testing.assert_allclose(dP, 2 * gm.a1[1:-1, 0, 0] * P - P**2 / 0.05 + 0.05, rtol=1e-4, atol=1e-6)


def test_linear_model_qlf_equals_kalman_bucy():
    model = SDEModel([x], [-0.7 * x], [2 * x], Q=0.5, R=0.3)
    sim = simulate(model, 200, paths=5, rng=0, m0=[1.0], P0=[[0.4]], dt=0.01)
    for F in (QLF, MQLF):
        est = F(model, 0.01, substeps=8).run(sim.ys, [1.0], [[0.4]])
        kb = KalmanBucy(model, 0.01, substeps=8).run(sim.ys, [1.0], [[0.4]])
        np.testing.assert_allclose(est.means, kb.means, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(est.covs, kb.covs, rtol=1e-6, atol=1e-9)


def test_discrete_qlf_linear_equals_kalman_filter():
    x1, x2 = sp.symbols("x1 x2")
    model = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, -0.2 * x1 + 0.8 * x2], [x1 + x2], Q=np.diag([0.3, 0.1]),
                          R=0.5)
    sim = simulate(model, 30, paths=4, rng=1, m0=[0.5, -0.5], P0=np.eye(2))
    est = DiscreteQuasilinearFilter(model, closure=EdgeworthClosure(4)).run(sim.ys, [0.5, -0.5], np.eye(2))
    kf = KalmanFilter(model).run(sim.ys, [0.5, -0.5], np.eye(2))
    np.testing.assert_allclose(est.means, kf.means, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(est.covs, kf.covs, rtol=1e-9, atol=1e-12)


def test_offline_mse_agrees_with_monte_carlo(oh_shin):
    """The issue's check: the off-line MSE (joint (x, x̂) moments, Edgeworth-4) of QLF and MQLF
    agrees with Monte Carlo within 3 standard errors, at t = 1 and averaged over t ∈ (0.5, 1]."""
    sim = simulate(oh_shin, 100, paths=3000, rng=11, m0=[4.0], P0=[[0.05]], dt=0.01, substeps=10)
    for F in (QLF, MQLF):
        f = F(oh_shin, 0.01)
        ea = f.error_analysis([4.0], [[0.05]], 100)
        e2 = (f.run(sim.ys, [4.0], [[0.05]]).means[..., 0] - sim.xs[..., 0]) ** 2
        end = e2[:, -1]
        assert abs(end.mean() - ea.mse[-1, 0]) < 3 * end.std(ddof=1) / np.sqrt(end.size)
        avg = e2[:, 50:].mean(axis=1)
        assert abs(avg.mean() - ea.mse[51:, 0].mean()) < 3 * avg.std(ddof=1) / np.sqrt(avg.size)


def test_statistical_linearization_nonpolynomial_gaussian_closure():
    """f = −sin x under N(m, K): a1 = E f' = −cos(m) e^{−K/2} (Stein), a0 = −sin(m) e^{−K/2}."""
    model = SDEModel([x], [-sp.sin(x)], [x], Q=0.2, R=0.1)
    g = QLF(model, 0.01).offline([1.0], [[0.3]], 50)
    m, K = g.m[:, 0], g.K[:, 0, 0]
    np.testing.assert_allclose(g.a1[:, 0, 0], -np.cos(m) * np.exp(-K / 2), rtol=1e-8)
    np.testing.assert_allclose(g.a0[:, 0], -np.sin(m) * np.exp(-K / 2), rtol=1e-8)
    with pytest.raises(NotPolynomialError, match=r"sin\(x\)"):
        MQLF(model, 0.01)


def test_statistical_linearization_formula_batched():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(3, 2))
    K = np.eye(2) * 0.5 + 0.1
    # f(x) = A x exactly: a1 = A
    A = np.array([[1.0, 2.0], [0.5, -1.0]])
    Ef = m @ A.T
    Efx = np.einsum("ij,...jk->...ik", A, K + m[..., :, None] * m[..., None, :])
    a0, a1 = statistical_linearization(m, np.broadcast_to(K, (3, 2, 2)), Ef, Efx)
    np.testing.assert_allclose(a1, np.broadcast_to(A, (3, 2, 2)), rtol=1e-12)


def test_bad_input(oh_shin):
    f = QLF(oh_shin, 0.01)
    with pytest.raises(ValueError, match="m0"):
        f.run(np.zeros((2, 5, 1)), np.zeros((2, 1)), [[0.1]])
    with pytest.raises(TypeError, match="closure"):
        QuasilinearFilter(oh_shin, 0.01, closure="edgeworth")
    with pytest.raises(ValueError, match="order"):
        MQLF(oh_shin, 0.01, order=2)
    with pytest.raises(ValueError, match="dys"):
        f.run(np.zeros((2, 5, 2)), [4.0], [[0.05]])


def test_gain_error_analysis_linear_kalman_bucy_equals_riccati():
    """For a linear model with the Kalman-Bucy gain the joint-moment MSE is the Riccati P(t) (exact:
    the joint system closes, every closure is exact)."""
    from nlfilter.filters.quasilinear import gain_error_analysis
    model = SDEModel([x], [-x], [2 * x], Q=1.0, R=0.5)
    f = QLF(model, 0.01)
    g = f.offline([0.3], [[0.8]], 200)
    ea = gain_error_analysis(model, lambda t: f._coeff(g.dense(t)), [0.3], [[0.8]], g.t, order=2)
    np.testing.assert_allclose(ea.mse[:, 0], g.P[:, 0, 0], rtol=1e-6, atol=1e-9)
    # a deliberately detuned constant gain: MSE from the scalar Lyapunov ODE p' = 2(−1 − 2k)p + 1 + k²·0.5
    k = 0.3
    ea2 = gain_error_analysis(model, lambda t: (np.array([[-1 - 2 * k]]), np.zeros(1), np.array([[k]])),
                              [0.0], [[0.8]], np.linspace(0, 2, 21), order=2)
    a, b = -2 * (1 + 2 * k), 1 + 0.5 * k**2
    t = np.linspace(0, 2, 21)
    np.testing.assert_allclose(ea2.mse[:, 0], -b / a + (0.8 + b / a) * np.exp(a * t), rtol=1e-6)
