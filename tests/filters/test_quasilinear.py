"""QLF / MQLF (seed 003): hand-derived coefficients, linear-model equivalences, off-line error
analysis against Monte Carlo."""
import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import ClosureDivergedError, NotPolynomialError
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
        assert abs(avg.mean() - ea.mse[50:, 0].mean()) < 3 * avg.std(ddof=1) / np.sqrt(avg.size)


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
    with pytest.raises(ValueError, match="^ys"):
        f.run(np.zeros((2, 5, 2)), [4.0], [[0.05]])


def test_gain_error_analysis_linear_kalman_bucy_equals_riccati():
    """For a linear model with the Kalman-Bucy gain the joint-moment MSE is the Riccati P(t) (exact:
    the joint system closes, every closure is exact)."""
    from nlfilter.filters.quasilinear import gain_error_analysis
    model = SDEModel([x], [-x], [2 * x], Q=1.0, R=0.5)
    f = QLF(model, 0.01)
    g = f.offline([0.3], [[0.8]], 200)
    ea = gain_error_analysis(model, lambda t: f._coeff(g.dense(t)), [0.3], [[0.8]], 200, dt=0.01, order=2)
    np.testing.assert_array_equal(ea.t, g.t[1:])  # run's rows: t0 + (k + 1) dt
    np.testing.assert_allclose(ea.mse[:, 0], g.P[1:, 0, 0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(ea.prior, g.P[0, 0, 0], rtol=1e-6, atol=1e-9)
    # a deliberately detuned constant gain: MSE from the scalar Lyapunov ODE p' = 2(−1 − 2k)p + 1 + k²·0.5
    k = 0.3
    ea2 = gain_error_analysis(model, lambda t: (np.array([[-1 - 2 * k]]), np.zeros(1), np.array([[k]])),
                              [0.0], [[0.8]], 20, dt=0.1, order=2)
    a, b = -2 * (1 + 2 * k), 1 + 0.5 * k**2
    t = np.linspace(0, 2, 21)
    np.testing.assert_allclose(ea2.mse[:, 0], (-b / a + (0.8 + b / a) * np.exp(a * t))[1:], rtol=1e-6)


# -- discrete off-line error analysis (the library's extension of 003 Fig. 2) ---------------------------
def test_discrete_error_analysis_linear_equals_kalman_riccati():
    """Linear Gaussian model: the QLF is the Kalman filter and every joint moment set of (x, x̂) is
    closed, so the off-line MSE is the Riccati P⁺[k] (to rounding)."""
    x1, x2 = sp.symbols("x1 x2")
    model = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, -0.2 * x1 + 0.8 * x2], [x1 + x2], Q=np.diag([0.3, 0.1]),
                          R=0.5)
    ea = DiscreteQuasilinearFilter(model).error_analysis([0.5, -0.5], np.eye(2), 15)
    assert ea.solution.eqs.closed
    ys = np.zeros((1, 15, 1))  # the Riccati recursion does not depend on the data
    P = KalmanFilter(model).run(ys, [0.5, -0.5], np.eye(2)).covs[0]
    np.testing.assert_array_equal(ea.t, np.arange(15))
    np.testing.assert_allclose(ea.mse, np.diagonal(P, axis1=-2, axis2=-1), rtol=1e-10, atol=1e-12)


def test_discrete_gain_error_analysis_detuned_gain_closed_form():
    """A constant, deliberately wrong gain k on x[k+1] = a x + w, y = x + v, started off the prior mean
    (x̂⁻[0] = m0 + δ0): error mean δ⁺ = (1 − k) δ⁻, δ⁻' = a δ⁺; variance p⁺ = (1 − k)² p⁻ + k² R,
    p⁻' = a² p⁺ + Q; MSE = p⁺ + δ⁺²."""
    from nlfilter.filters.quasilinear import gain_error_analysis
    a, k, Q, R = 0.8, 0.3, 0.2, 0.4
    model = DiscreteModel([x], [a * x], [x], Q=Q, R=R)
    coef = lambda j: (np.array([[k]]), np.eye(1), np.zeros(1), np.array([[a]]), np.zeros(1))  # noqa: E731
    ea = gain_error_analysis(model, coef, [1.0], [[0.5]], 12, xhat0=[1.4], order=2)
    p, d, want = 0.5, -0.4, []
    for _ in range(12):
        p, d = (1 - k) ** 2 * p + k**2 * R, (1 - k) * d
        want.append(p + d**2)
        p, d = a**2 * p + Q, a * d
    np.testing.assert_allclose(ea.mse[:, 0], want, rtol=1e-12)


def _mc_errors(model, steps, m0, P0, paths, seed):
    sim = simulate(model, steps, paths=paths, rng=seed, m0=[m0], P0=[[P0]])
    est = DiscreteQuasilinearFilter(model).run(sim.ys, [m0], [[P0]])
    return (est.means[..., 0] - sim.xs[..., 0]) ** 2  # (paths, steps)


def test_discrete_error_analysis_cubic_drift_agrees_with_monte_carlo():
    """x[k+1] = 0.9 x − 0.05 x³ + w, y = x + v, Q = R = 0.1, x[0] ~ N(2, 0.2), 30 steps. Tolerance:
    4 standard errors of the MC mean (100 000 paths; a false alarm ~6e-5 per check, whatever the
    number of paths) plus the closure's error, estimated by the change of the analysis from
    Edgeworth-4 to Edgeworth-6 (≈ 2e-5, 0.2 se). Measured (seed 5, per-path streams): E4 within
    1.4 se at every step checked (0.3 se at k = 0, where the analysis is exactly the Kalman P⁺) and
    0.6 se on the k ≥ 10 average. The MC is sharp enough to reject the Gaussian-closure analysis at
    order 4 (moments ≤ 4 kept, higher ones Gaussian: +0.7 %, 6.6 se here; 14.3 se with 400 000
    paths, and the s.e. scales as 1/√paths: 100 000 paths keep it 2.6 s.e. clear of the 4 s.e.
    threshold, a quarter of the paths' simulation time)."""
    from nlfilter.moments import GaussianClosure
    model = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x], Q=0.1, R=0.1)
    f = DiscreteQuasilinearFilter(model)
    e4 = f.error_analysis([2.0], [[0.2]], 30).mse[:, 0]
    e6 = f.error_analysis([2.0], [[0.2]], 30, order=6).mse[:, 0]
    eg = f.error_analysis([2.0], [[0.2]], 30, closure=GaussianClosure(), order=4).mse[:, 0]  # moments ≤ 4 kept
    e2 = _mc_errors(model, 30, 2.0, 0.2, 100_000, 5)
    mc, se = e2.mean(axis=0), e2.std(axis=0, ddof=1) / np.sqrt(e2.shape[0])
    for k in (0, 2, 5, 10, 20, 29):
        assert abs(e4[k] - mc[k]) < 4 * se[k] + abs(e6[k] - e4[k]), (k, e4[k], mc[k], se[k])
    avg = e2[:, 10:].mean(axis=1)
    se_avg = avg.std(ddof=1) / np.sqrt(avg.size)
    assert abs(e4[10:].mean() - avg.mean()) < 4 * se_avg + abs(e6[10:] - e4[10:]).mean()
    assert abs(eg[10:].mean() - avg.mean()) > 4 * se_avg  # the check has the power to see a closure's error


def test_discrete_error_analysis_cubic_sensor_agrees_with_monte_carlo():
    """x[k+1] = 0.9 x + w, y = x³ + v, Q = R = 0.1, x[0] ~ N(1, 0.1). x is Gaussian and x̂ enters the
    map linearly, so the moments behind the MSE (x^j, x̂ x^j, x̂²) form a closed set whose closure
    terms are Gaussian moments of x: the analysis is exact for every closure; tolerance 4 MC standard
    errors (50 000 paths: exact, so no bias to resolve; a false alarm ~6e-5 per check at any number
    of paths). Measured (seed 7, per-path streams): within 0.8 se at every step checked."""
    from nlfilter.moments import GaussianClosure
    model = DiscreteModel([x], [0.9 * x], [x**3], Q=0.1, R=0.1)
    f = DiscreteQuasilinearFilter(model)
    e4 = f.error_analysis([1.0], [[0.1]], 25).mse[:, 0]
    eg = f.error_analysis([1.0], [[0.1]], 25, closure=GaussianClosure(), order=4).mse[:, 0]
    np.testing.assert_allclose(eg, e4, rtol=1e-9)
    e2 = _mc_errors(model, 25, 1.0, 0.1, 50_000, 7)
    mc, se = e2.mean(axis=0), e2.std(axis=0, ddof=1) / np.sqrt(e2.shape[0])
    for k in (0, 1, 3, 8, 15, 24):
        assert abs(e4[k] - mc[k]) < 4 * se[k], (k, e4[k], mc[k], se[k])


def test_discrete_error_analysis_bad_input():
    model = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x], Q=0.1, R=0.1)
    f = DiscreteQuasilinearFilter(model)
    with pytest.raises(ValueError, match="steps"):
        f.error_analysis([1.0], [[0.2]], -3)
    with pytest.raises(ValueError, match="steps"):
        f.error_analysis([1.0], [[0.2]], 0)
    with pytest.raises(ValueError, match=r"m0.*\(1,\)"):
        f.error_analysis([1.0, 2.0], [[0.2]], 5)
    with pytest.raises(ValueError, match="P0"):
        f.error_analysis([1.0], [[-0.2]], 5)
    with pytest.raises(TypeError, match="closure"):
        f.error_analysis([1.0], [[0.2]], 5, closure="gaussian")
    with pytest.raises(ValueError, match="order"):
        f.error_analysis([1.0], [[0.2]], 5, closure=EdgeworthClosure(6), order=4)
    with pytest.raises(NotPolynomialError, match="polynomial"):
        DiscreteQuasilinearFilter(DiscreteModel([x], [sp.sin(x)], [x], Q=0.1, R=0.1)).error_analysis(
            [1.0], [[0.2]], 5)


def test_error_analysis_order_defaults_to_the_closures():
    """issue 10 item 8.4: error_analysis(closure=GaussianClosure()) used the default order 4, a
    set whose 4th moments the Gaussian closure ignores; on dx = −x³dt + dβ from N(4, 0.05) that
    hybrid blew up (ClosureDivergedError). The order now defaults to the closure's (2 here)."""
    from nlfilter.moments import EdgeworthClosure, GaussianClosure
    md = SDEModel([x], [-x**3], [x], Q=0.05, R=0.05)
    f = QLF(md, 0.01)
    eg = f.error_analysis([4.0], [[0.05]], 100, closure=GaussianClosure())
    eg2 = f.error_analysis([4.0], [[0.05]], 100, closure=GaussianClosure(), order=2)
    np.testing.assert_array_equal(eg.mse, eg2.mse)
    assert eg.solution.eqs.indices == [(1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]
    np.testing.assert_allclose(eg.mse[-1, 0], 0.0123577, rtol=1e-4)  # vs Edgeworth-4 0.012554 (README)
    with pytest.raises(ClosureDivergedError):  # the hybrid the old default gave
        f.error_analysis([4.0], [[0.05]], 100, closure=GaussianClosure(), order=4)
    e6 = f.error_analysis([4.0], [[0.05]], 100, closure=EdgeworthClosure(6))
    assert max(map(sum, e6.solution.eqs.indices)) == 6
    np.testing.assert_allclose(e6.mse[-1, 0], f.error_analysis([4.0], [[0.05]], 100).mse[-1, 0], rtol=1e-4)
    # discrete: the default order follows the closure too
    dm = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x], Q=0.1, R=0.1)
    df = DiscreteQuasilinearFilter(dm)
    np.testing.assert_array_equal(df.error_analysis([2.0], [[0.2]], 12, closure=GaussianClosure()).mse,
                                  df.error_analysis([2.0], [[0.2]], 12, closure=GaussianClosure(), order=2).mse)


def test_error_analysis_refuses_order_below_the_closures():
    """An explicit order below the closure's (the closure reads moments that are not kept) is a
    ValueError up front naming both arguments, in every analysis and moment filter."""
    from nlfilter.filters.moment_filters import ConditionalMomentFilter
    from nlfilter.filters.quasilinear import gain_error_analysis
    from nlfilter.moments import EdgeworthClosure
    msg = r"order, closure: expected order ≥ 6, the order of closure=EdgeworthClosure\(order=6\) .*got order=4"
    md = SDEModel([x], [-x**3], [x], Q=0.05, R=0.05)
    with pytest.raises(ValueError, match=msg):
        QLF(md, 0.01).error_analysis([4.0], [[0.05]], 10, closure=EdgeworthClosure(6), order=4)
    with pytest.raises(ValueError, match=msg):
        gain_error_analysis(md, lambda t: (np.zeros((1, 1)), np.zeros(1), np.ones((1, 1))), [4.0], [[0.05]],
                            1, dt=0.1, closure=EdgeworthClosure(6), order=4)
    dm = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x], Q=0.1, R=0.1)
    with pytest.raises(ValueError, match=msg):
        DiscreteQuasilinearFilter(dm).error_analysis([2.0], [[0.2]], 5, closure=EdgeworthClosure(6), order=4)
    with pytest.raises(ValueError, match=msg):
        ConditionalMomentFilter(md, 0.01, closure=EdgeworthClosure(6), order=4)
    with pytest.raises(ValueError, match=msg):
        MQLF(md, 0.01, closure=EdgeworthClosure(6), order=4)
    with pytest.raises(ValueError, match="order: expected an integer or None"):
        QLF(md, 0.01).error_analysis([4.0], [[0.05]], 10, closure=EdgeworthClosure(4), order=4.0)
