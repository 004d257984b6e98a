"""Phase tracking filters of seed 001 ch. 4: PLL, LQF, tensor filter, grid filter on the circle."""

import numpy as np
import pytest

from nlfilter.bilinear import phase_model
from nlfilter.filters.phase import (PLL, CircleGridFilter, LinearQuadratureFilter, PhaseTensorFilter, circle_moment,
                                    lqf_gain, pll_gain, post_processor, qr_from_P, wrap)
from nlfilter.simulate import simulate_phase


@pytest.mark.parametrize("q,r", [(1.0, 0.0083205), (0.3, 2.0), (4.0, 0.01)])
def test_lqf_gain_eq_4_18_equals_riccati_steady_state(q, r):
    """001 eq. 4.18 (closed form) = the steady state of eq. 2.43 solved by OptimalLinearFilter."""
    K = LinearQuadratureFilter(phase_model(q, r), 0.01).linear.steady_state().K
    assert K[0, 0] == pytest.approx(lqf_gain(q, r), rel=1e-10)
    assert K[1, 1] == pytest.approx(lqf_gain(q, r), rel=1e-10)
    assert abs(K[0, 1]) < 1e-12


def test_pll_phase_error_matches_tikhonov_law():
    """The first-order PLL's stationary phase error has the Tikhonov (von Mises) law with
    concentration 1/P_θℓ (P_θℓ = √(2rq), 001 eq. 4.9, is its linearized variance): Monte Carlo
    E[ε²] within 3 standard errors of the exact value (0.0513 at P = 0.05)."""
    P = 0.05
    q, r = qr_from_P(P)
    K = pll_gain(q, r)
    dt = 0.01 / K
    phi = np.linspace(-np.pi, np.pi, 200001)
    w = np.exp(np.cos(phi) / P)
    exact = float((phi ** 2 * w).sum() / w.sum())
    th, dz = simulate_phase(q, r, dt, int(4 / dt), 48, np.random.default_rng(1))
    x0 = np.stack([np.sin(th[:, 0]), np.cos(th[:, 0])], axis=-1)  # θ̂0 = atan2(m0) = θ0
    est = PLL(phase_model(q, r), dt).run(dz, x0, np.eye(2)).extras["theta"]
    per = (wrap(th - est)[:, int(0.5 / dt):] ** 2).mean(axis=1)
    mc, se = per.mean(), per.std(ddof=1) / np.sqrt(per.size)
    assert abs(mc - exact) < 3 * se, (mc, se, exact)
    assert abs(exact - P) < 0.03 * P  # the linearized value 4.9 is close at this P


def test_circle_grid_prediction_is_the_exact_heat_kernel():
    """No information (zero increments, huge r): from θ = 0, E[cos θ_t] = exp(−q t / 2) exactly."""
    q, dt, T = 0.8, 0.05, 40
    g = CircleGridFilter(phase_model(q, 1e12), dt, size=128)
    p0 = np.zeros(128)
    p0[0] = 1.0
    est = g.run(np.zeros((1, T, 2)), initial=p0)
    t = dt * np.arange(1, T + 1)
    assert np.allclose(est.means[0, :, 1], np.exp(-q * t / 2), atol=1e-12)
    assert np.allclose(est.means[0, :, 0], 0.0, atol=1e-12)


def test_optimal_filter_beats_suboptimal_on_common_noise():
    """Grid filter on the circle vs LQF and tensor filter: paired MSE of x1 (same paths)."""
    q, r = qr_from_P(0.129)
    dt = 0.01 / pll_gain(q, r)
    th, dz = simulate_phase(q, r, dt, 10000, 12, np.random.default_rng(8))
    model, m0, P0 = phase_model(q, r), np.zeros(2), 0.5 * np.eye(2)
    opt = CircleGridFilter(model, dt, size=96).run(dz).means[..., 0]
    lqf = LinearQuadratureFilter(model, dt).run(dz, m0, P0).means[..., 0]
    ten = PhaseTensorFilter(model, dt).run(dz, m0, P0).means[..., 0]
    x1 = np.sin(th)
    mse = {k: ((v - x1)[:, 500:] ** 2).mean(axis=1) for k, v in (("opt", opt), ("lqf", lqf), ("ten", ten))}
    for a, b in (("opt", "ten"), ("ten", "lqf")):  # paired differences, 3 standard errors
        d = mse[b] - mse[a]
        assert d.mean() > 3 * d.std(ddof=1) / np.sqrt(d.size), (a, b, d.mean())


def test_post_processor_peak_fig_4_3():
    """001 §4.3: at P_θℓ = 0.129 the cubic post-processor reduces the MSE of x1 by 9.2 %
    (printed to one decimal: |ours − 9.2| < 0.05)."""
    fit = post_processor(0.129)
    assert abs(fit.reduction - 9.2) < 0.05
    assert fit.gains[1] < 0 < fit.gains[0]
    lo, hi = post_processor(0.005), post_processor(5.0)  # linear filter nearly optimal / no information
    assert lo.reduction < 2.0 and hi.reduction < 1.0


def test_post_processor_independent_of_time_scale():
    """Only P_θℓ = √(2rq) matters (rescaling time maps (q, r) to (c q, r / c))."""
    a, b = post_processor(0.3, q=1.0), post_processor(0.3, q=7.0)
    assert a.reduction == pytest.approx(b.reduction, rel=1e-8)
    assert np.allclose(a.gains, b.gains, rtol=1e-8)


def test_tensor_filter_symmetric_in_x1_x2():
    q, r = qr_from_P(0.2)
    f1, f2 = PhaseTensorFilter(phase_model(q, r), 0.01).fits()
    assert np.allclose(f1.gains, f2.gains, rtol=1e-9) and f1.mse == pytest.approx(f2.mse, rel=1e-9)


def test_circle_moments_and_input_errors():
    assert circle_moment((4, 0)) == pytest.approx(3 / 8) and circle_moment((3, 1)) == 0.0
    with pytest.raises(ValueError, match="^ys"):
        PLL(phase_model(1.0, 1.0), 0.01).run(np.zeros((2, 3)), np.zeros(2), np.eye(2))
    with pytest.raises(TypeError, match="^model"):
        PLL(1.0, 0.01)
    with pytest.raises(ValueError, match="P"):
        qr_from_P(-0.1)


def _dz(T=40, paths=3, seed=2, q=1.0, r=0.5, dt=0.01):
    return simulate_phase(q, r, dt, T, paths, np.random.default_rng(seed))[1]


def test_circle_grid_missing_component_is_a_flat_likelihood():
    """A missing component of dz = a zero increment of it (|h|² = 1 cancels: exp(0) is flat);
    every increment missing = the exact heat semigroup alone, whatever the data."""
    g = CircleGridFilter(phase_model(1.0, 0.5), 0.01, size=64)
    m0, P0 = np.array([0.3, 0.5]), 0.2 * np.eye(2)
    dz = _dz()
    e = dz.copy()
    e[:, 5:20, 1] = np.nan
    z = dz.copy()
    z[:, 5:20, 1] = 0.0
    a, b = g.run(e, m0, P0), g.run(z, m0, P0)
    np.testing.assert_allclose(a.means, b.means, rtol=0, atol=1e-14)
    np.testing.assert_allclose(a.extras["theta"], b.extras["theta"], rtol=0, atol=1e-13)
    blind = g.run(dz * np.nan, m0, P0)
    np.testing.assert_allclose(blind.means, g.run(np.zeros_like(dz), m0, P0).means, rtol=0, atol=1e-14)


def test_von_mises_prior_has_the_mean_m0():
    """The prior from m0 is the von Mises law with E[(sin θ0, cos θ0)] = m0 (on the grid)."""
    g = CircleGridFilter(phase_model(1.0, 0.5), 0.01, size=256)
    m0 = np.array([[0.3, 0.5], [0.0, 0.0], [-0.6, -0.1]])
    b = g.init(m0, np.eye(2), (3,))
    mean, cov = g.summary(b)
    np.testing.assert_allclose(mean, m0, atol=1e-10)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    with pytest.raises(ValueError, match="^m0"):
        g.run(_dz(), [0.8, 0.8], np.eye(2))


def test_quadrature_filters_missing_increments_only_predict():
    """Every increment missing: no innovation, the LQF's x̂ decays as E[x_t | x0] = e^{−qt/2} m0
    (RK4 of the mean equation); the PLL's θ̂ stays at θ̂0 = atan2(m0)."""
    q, dt = 1.0, 0.01
    model, m0, P0 = phase_model(q, 0.5), np.array([0.3, 0.5]), 0.2 * np.eye(2)
    d = _dz(q=q, dt=dt) * np.nan
    t = dt * np.arange(1, d.shape[1] + 1)
    lqf = LinearQuadratureFilter(model, dt).run(d, m0, P0)
    np.testing.assert_allclose(lqf.means, np.broadcast_to(np.exp(-q * t / 2)[:, None] * m0, lqf.means.shape), rtol=1e-10)
    np.testing.assert_allclose(lqf.extras["theta"], np.arctan2(0.3, 0.5), rtol=1e-12)
    pll = PLL(model, dt).run(d, m0, P0)
    assert np.all(pll.extras["theta"] == np.arctan2(0.3, 0.5)) and np.isnan(pll.covs).all()


def test_lqf_is_the_steady_optimal_linear_filter_on_the_one_runner():
    """The LQF and the steady OptimalLinearFilter of the phase model (X0 on the circle) run the same
    affine recursion of the off-line-gain runner: equal means and covariances, with missing
    components too (a path's own covariance after a gap: larger than the steady one)."""
    from nlfilter.filters.bilinear import OptimalLinearFilter
    from nlfilter.filters.phase import X0_CIRCLE
    model, dt = phase_model(1.0, 0.5), 0.01
    dz = _dz(T=30)
    dz[0, 5, 1] = np.nan
    dz[1, 8:15] = np.nan
    m0, P0 = np.array([0.1, 0.2]), 0.4 * np.eye(2)
    a = LinearQuadratureFilter(model, dt).run(dz, m0, P0)
    b = OptimalLinearFilter(model, dt, X0=X0_CIRCLE).run(dz, m0, P0)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.covs, b.covs)
    assert a.covs[1, 14, 0, 0] > a.covs[2, 14, 0, 0] and np.array_equal(a.covs[2], a.covs[2, :1].repeat(30, 0))


def test_phase_filters_mark_a_diverged_path():
    """An overflowing increment on one path: marked (NaN from its step, θ̂ too), the others as clean."""
    dz = _dz(T=10)
    bad = dz.copy()
    bad[1, 4] = 1.7e308
    model = phase_model(1.0, 0.5)
    for flt in (PLL(model, 0.01), LinearQuadratureFilter(model, 0.01), PhaseTensorFilter(model, 0.01)):
        a = flt.run(bad, np.zeros(2), 0.5 * np.eye(2), on_divergence="mark")
        b = flt.run(dz, np.zeros(2), 0.5 * np.eye(2))
        assert a.diverged.tolist() == [False, True, False] and a.diverged_step[1] == 4, flt.name
        assert np.isnan(a.extras["theta"][1, 4:]).all() and np.isfinite(a.extras["theta"][1, :4]).all()
        np.testing.assert_array_equal(a.means[[0, 2]], b.means[[0, 2]])
