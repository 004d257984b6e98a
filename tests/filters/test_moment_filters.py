"""Conditional-moment filters: linear-model equivalences, closures beyond Gaussian, failures."""
import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import DivergenceError, NotPolynomialError
from nlfilter.filters.kalman import KalmanBucy, KalmanFilter
from nlfilter.filters.moment_filters import ConditionalMomentFilter, DiscreteConditionalMomentFilter
from nlfilter.filters.reference import GridFilter
from nlfilter.moments import CumulantClosure, EdgeworthClosure
from nlfilter.simulate import simulate

x = sp.Symbol("x")


def test_linear_continuous_equals_kalman_bucy_to_first_order():
    """On a linear model the Gaussian-closure KS filter is the Kalman-Bucy filter; both discretize
    it to first order in dt, so they agree to O(dt): halving dt halves the gap."""
    model = SDEModel([x], [-x], [2 * x], Q=1.0, R=0.5)
    gaps = []
    for dt, T in ((0.01, 100), (0.005, 200)):
        sim = simulate(model, T, paths=20, rng=4, m0=[0.5], P0=[[0.5]], dt=dt)
        a = ConditionalMomentFilter(model, dt, substeps=2).run(sim.ys, [0.5], [[0.5]])
        b = KalmanBucy(model, dt, substeps=4).run(sim.ys, [0.5], [[0.5]])
        gaps.append(np.max(np.abs(a.means - b.means)))
        assert np.max(np.abs(a.covs - b.covs)) < 0.05 * 0.5 * dt / 0.01
    assert gaps[0] < 0.05 and gaps[1] < 0.7 * gaps[0]


def test_edgeworth_filter_on_linear_gaussian_model_equals_gaussian_closure():
    """A Gaussian conditional law has zero quasi-moments of order 3-4: the order-4 filters must
    reproduce the Gaussian-closure filter."""
    model = SDEModel([x], [-x], [2 * x], Q=1.0, R=0.5)
    sim = simulate(model, 60, paths=6, rng=5, m0=[0.5], P0=[[0.5]], dt=0.01)
    g = ConditionalMomentFilter(model, 0.01).run(sim.ys, [0.5], [[0.5]])
    for clo in (EdgeworthClosure(4), CumulantClosure(4)):
        e = ConditionalMomentFilter(model, 0.01, closure=clo).run(sim.ys, [0.5], [[0.5]])
        np.testing.assert_allclose(e.means, g.means, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(e.covs, g.covs, rtol=1e-6, atol=1e-9)


def test_discrete_linear_equals_kalman_filter():
    m = DiscreteModel([x], [0.8 * x], [x], Q=0.5, R=1.0)
    sim = simulate(m, 25, paths=5, rng=2, m0=[0.0], P0=[[2.0]])
    a = DiscreteConditionalMomentFilter(m).run(sim.ys, [0.0], [[2.0]])
    b = KalmanFilter(m).run(sim.ys, [0.0], [[2.0]])
    # the update integrates the Gaussian likelihood by 24-node Gauss-Hermite: ~3e-6 relative error here
    np.testing.assert_allclose(a.means, b.means, rtol=2e-5, atol=1e-7)
    np.testing.assert_allclose(a.covs, b.covs, rtol=2e-5, atol=1e-7)
    # the step functions carry the moment belief: init -> update -> summary
    f = DiscreteConditionalMomentFilter(m)
    mean, cov = f.summary(f.update(f.init([0.0], [[2.0]], ()), np.array([[1.0]]), 0))
    assert mean[0, 0] == pytest.approx(2 / 3) and cov[0, 0, 0] == pytest.approx(2 / 3)


def test_cubic_sensor_gaussian_closure_near_optimal_and_ekf_stuck():
    """Seed 001 ch. 5 setting (q = r = 1, stationary start): the Gaussian-closure filter's MSE is
    within 5 % of the grid filter's on the same paths, the EKF's estimate never leaves 0."""
    model = SDEModel([x], [-x], [x**3], Q=1.0, R=1.0)
    sim = simulate(model, 300, paths=40, rng=8, m0=[0.0], P0=[[0.5]], dt=0.01, substeps=5)
    g = ConditionalMomentFilter(model, 0.01).run(sim.ys, [0.0], [[0.5]])
    opt = GridFilter(model, (-4.0, 4.0), size=161, dt=0.01).run(sim.ys, [0.0], [[0.5]])
    eg = np.mean((g.means - sim.xs)[:, 100:, 0] ** 2)
    eo = np.mean((opt.means - sim.xs)[:, 100:, 0] ** 2)
    assert eg < 1.05 * eo
    from nlfilter.filters.ekf import ContinuousEKF
    assert np.all(ContinuousEKF(model, 0.01).run(sim.ys, [0.0], [[0.5]]).means == 0.0)


def test_ito_update_divergence_is_flagged_never_silent():
    model = SDEModel([x], [-x], [x**3], Q=2.0, R=1.0)
    sim = simulate(model, 400, paths=30, rng=3, m0=[0.0], P0=[[1.0]], dt=0.01, substeps=5)
    f = ConditionalMomentFilter(model, 0.01, update="ito")
    est = f.run(sim.ys, [0.0], [[1.0]], on_divergence="mark")
    assert est.diverged.any()  # Euler on the KS innovation term pushes variances negative here
    d = est.diverged
    assert np.all(np.isnan(est.means[d][:, -1])) and np.all(np.isfinite(est.means[~d]))
    with pytest.raises(DivergenceError, match="step"):
        f.run(sim.ys, [0.0], [[1.0]])


def test_errors():
    with pytest.raises(NotPolynomialError, match=r"exp\(x\)"):
        ConditionalMomentFilter(SDEModel([x], [-x], [sp.exp(x)], Q=1.0, R=1.0), 0.01)
    m = SDEModel([x], [-x], [x], Q=1.0, R=1.0)
    with pytest.raises(ValueError, match="update"):
        ConditionalMomentFilter(m, 0.01, update="euler")
    with pytest.raises(ValueError, match="points"):
        ConditionalMomentFilter(m, 0.01, closure=EdgeworthClosure(4), points=3)
    with pytest.raises(TypeError, match="closure"):
        ConditionalMomentFilter(m, 0.01, closure="gaussian")
