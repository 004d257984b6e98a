"""The method-of-moments Bayesian filter of seed 000: zero-order estimator and adaptive mode."""

import doctest
import warnings

import numpy as np
import pytest
from scipy import integrate

import nlfilter.bounded as BD
import nlfilter.filters.moment_bayes as MB
from nlfilter.bounded import BoundedNoiseModel
from nlfilter.filters.moment_bayes import (MomentFilterWarning, ZeroOrderMomentFilter,
                                           power_density_estimate, zero_order_estimate)
from nlfilter.moments.densities import LegendreDensity, power_density_moments, uniform_moments


@pytest.mark.parametrize("mod", [MB.zero_order, MB.first_order, MB.two_state, BD])
def test_doctests(mod):
    assert doctest.testmod(mod).failed == 0


def _z(z):
    """Scalar measurements (..., T) as the protocol's ys (..., T, 1)."""
    return np.asarray(z, dtype=float)[..., None]


@pytest.mark.parametrize("N", [1, 2, 4, 6, 12])
def test_J0_every_estimator_is_z_over_2(N):
    # 000 eqs. 3.25-3.26: with x ~ U(-1, 1) every moment estimator equals the optimal z/2
    z = np.linspace(-1.999, 1.999, 41)
    f = ZeroOrderMomentFilter(N, moments=uniform_moments(N))
    xh, fb = f.estimate(z)
    np.testing.assert_allclose(xh, z / 2, atol=1e-12)
    np.testing.assert_allclose(power_density_estimate(z, 0), z / 2, atol=1e-12)
    assert not fb.any()


@pytest.mark.parametrize("J,N", [(2, 2), (4, 4), (4, 6), (6, 8)])
def test_estimator_is_optimal_when_N_covers_J(J, N):
    z = np.linspace(-1.99, 1.99, 37)
    f = ZeroOrderMomentFilter(N, moments=power_density_moments(N, J))
    np.testing.assert_allclose(f.estimate(z)[0], power_density_estimate(z, J), atol=1e-10)


def test_estimate_against_quadrature_of_eq_3_5():
    # eq. 3.5 with the polynomial prior, by adaptive quadrature
    m = power_density_moments(4, 10)
    d = LegendreDensity.from_moments(m)
    for z in (0.05, 0.7, 1.6, -0.3):
        l, u = max(-1, z - 1), min(1, z + 1)
        num = integrate.quad(lambda x: x * float(d.pdf(x)), l, u)[0]
        den = integrate.quad(lambda x: float(d.pdf(x)), l, u)[0]
        xh, fb = zero_order_estimate(np.array(z), d)
        if den >= 1e-6 and l < num / den < u:
            assert float(xh) == pytest.approx(num / den, abs=1e-10) and not fb
        else:
            assert float(xh) == pytest.approx(0.5 * (l + u)) and fb


def test_fallback_eq_3_16_when_denominator_small():
    # N = 2, J = 10: the quadratic prior is negative near 0, so for z near 0.6 the interval
    # integral is tiny/negative or the ratio leaves (l, u) -> midpoint (l + u)/2
    f = ZeroOrderMomentFilter(2, moments=power_density_moments(2, 10))
    z = np.linspace(0.4, 0.95, 12)
    xh, fb = f.estimate(z)
    assert fb.all()
    np.testing.assert_allclose(xh, 0.5 * ((z - 1) + 1))
    assert np.isfinite(xh).all()


def test_impossible_measurement_raises_or_clips():
    f = ZeroOrderMomentFilter(2, moments=uniform_moments(2))
    with pytest.raises(ValueError, match="ys: measurement 2.5"):
        f.run(_z([[0.1, 2.5]]))
    g = ZeroOrderMomentFilter(2, moments=uniform_moments(2), outside="clip")
    r = g.run(_z([[0.1, 2.5, -3.0]]))
    np.testing.assert_allclose(r.means[..., 0], [[0.05, 1.0, -1.0]])


def test_bad_arguments():
    with pytest.raises(ValueError, match="moments"):
        ZeroOrderMomentFilter(2)
    with pytest.raises(ValueError, match="moments: expected trailing shape"):
        ZeroOrderMomentFilter(4, moments=[0.0, 0.3])
    with pytest.raises(TypeError, match="N"):
        ZeroOrderMomentFilter(2.5, moments=[0.0, 0.3])
    with pytest.raises(ValueError, match="outside"):
        ZeroOrderMomentFilter(2, moments=[0.0, 0.3], outside="nan")
    with pytest.raises(ValueError, match="support"):
        ZeroOrderMomentFilter(2, moments=[0.0, 0.3], support=(1, -1))


def test_adaptive_moments_follow_eqs_2_27_3_14_3_15():
    rng = np.random.default_rng(3)
    T, W, n0 = 65, 20, 100.0
    z = rng.uniform(-1, 1, T) + rng.uniform(-1, 1, T)
    f = ZeroOrderMomentFilter(2, adaptive=True, n0=n0, window=W)
    r = f.run(_z(z[None]))
    hist = r.extras["moments"][:, W - 1::W]  # the moments in use at the refreshes
    assert hist.shape == (1, 3, 2)  # refreshes at k = 20, 40, 60
    for j, k in enumerate((20, 40, 60)):
        mz1, mz2 = np.mean(z[:k]), np.mean(z[:k] ** 2)
        mx = np.array([mz1, mz2 - 1 / 3])  # eq. 3.14 with m_v1 = 0, m_v2 = 1/3
        want = n0 / (k + n0) * np.array([0.0, 1 / 3]) + k / (k + n0) * mx  # eq. 3.15
        np.testing.assert_allclose(hist[0, j], want, atol=1e-13)
    # steps 1..19 use the initial guess (uniform => z/2), step 20 already the refreshed moments
    np.testing.assert_allclose(r.means[0, :19, 0], z[:19] / 2, atol=1e-12)
    xh20 = f.estimate(z[19], hist[0, 0])[0]
    assert r.means[0, 19, 0] == pytest.approx(float(xh20))
    np.testing.assert_array_equal(r.extras["moments"][0, :19], np.broadcast_to([0.0, 1 / 3], (19, 2)))


def test_adaptive_converges_to_known_moment_estimator():
    # with a long record the learned moments approach the true ones: the adaptive N=2 estimator's
    # MSE approaches the known-moment one (J = 4, whose N=2 MSE is 0.151448, Table 1)
    rng = np.random.default_rng(7)
    R, T = 200, 3000
    x = np.where(rng.random((R, T)) < 0.5, -1, 1) * rng.random((R, T)) ** (1 / 5)
    z = x + rng.uniform(-1, 1, (R, T))
    r = ZeroOrderMomentFilter(2, adaptive=True).run(_z(z))
    known = ZeroOrderMomentFilter(2, moments=power_density_moments(2, 4)).run(_z(z))
    tail = slice(2000, None)
    d = ((x - r.means[..., 0]) ** 2 - (x - known.means[..., 0]) ** 2)[:, tail].mean(axis=1)
    se = d.std(ddof=1) / np.sqrt(R)
    assert abs(d.mean()) < 4 * se + 1e-3


def test_invalid_moments_warn_and_fall_back():
    rng = np.random.default_rng(0)
    z = rng.uniform(-1, 1, (5, 60)) + rng.uniform(-1, 1, (5, 60))
    f = ZeroOrderMomentFilter(12, adaptive=True, n0=0.0, window=20)
    with pytest.warns(MomentFilterWarning, match="N = 12"):
        r = f.run(_z(z))
    est, invalid = r.means[..., 0], r.extras["invalid"]
    assert np.isfinite(est).all()
    assert invalid.any()
    l, u = np.maximum(-1, z - 1), np.minimum(1, z + 1)
    np.testing.assert_allclose(est[invalid], (0.5 * (l + u))[invalid])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r2 = ZeroOrderMomentFilter(12, adaptive=True, n0=0.0, invalid_moments="ignore").run(_z(z))
    assert np.isfinite(r2.means).all()


# ------------------------------------------------------------------ first-order system

import scipy.stats as st  # noqa: E402

from nlfilter.filters.moment_bayes import FirstOrderMomentFilter  # noqa: E402
from nlfilter.filters.reference.bounded import BoundedGridFilter1D  # noqa: E402


def test_first_order_with_h0_is_the_zero_order_filter():
    # h = 0: x_{k+1} = w_k i.i.d., so each step is the zero-order estimator with the moments of w
    rng = np.random.default_rng(1)
    m = power_density_moments(4, 6)
    z = rng.uniform(-1.9, 1.9, (3, 25))
    r = FirstOrderMomentFilter(BoundedNoiseModel.first_order(0.0, 1.0), 4, w_moments=m).run(_z(z))
    xh = ZeroOrderMomentFilter(4, moments=m, eps=1e-9).estimate(z)[0]
    np.testing.assert_allclose(r.means[..., 0], xh, atol=1e-12)


def test_first_order_posterior_moments_against_quadrature():
    # one predict + update by hand: predicted moments (eq. 3.13 on h x + w), polynomial on the
    # reachable interval, posterior moments = ratios of integrals over [max(l, z-1), min(u, z+1)]
    f = FirstOrderMomentFilter(0.6, 1.0, 4, w_moments=power_density_moments(4, 2))
    m0 = np.array([0.1, 0.5, 0.05, 0.35])
    mp, lp, up = f.predict_moments(m0, np.array(-0.8), np.array(1.0), f.w_moments)
    np.testing.assert_allclose(lp, -1.48)
    np.testing.assert_allclose(up, 1.6)
    # predicted moments by direct expansion of E[(0.6 x + w)^i]
    mw = np.r_[1.0, f.w_moments]
    mx = np.r_[1.0, m0]
    from math import comb
    want = [sum(comb(i, j) * 0.6 ** j * mx[j] * mw[i - j] for j in range(i + 1)) for i in range(1, 5)]
    np.testing.assert_allclose(mp, want, atol=1e-13)
    z = 0.9
    post, lo, hi, fb = f.update_moments(mp, lp, up, np.array(z))
    d = LegendreDensity.from_moments(mp, lp, up)
    den = integrate.quad(lambda x: float(d.pdf(x)), z - 1, 1.6)[0]
    for i in range(1, 5):
        num = integrate.quad(lambda x: x ** i * float(d.pdf(x)), z - 1, 1.6)[0]
        assert float(post[i - 1]) == pytest.approx(num / den, rel=1e-9)
    assert float(lo) == pytest.approx(z - 1) and float(hi) == pytest.approx(1.6) and not fb


def test_grid_filter_exact_case_uniform_prior_uniform_likelihood():
    # h = 0 and w ~ U(-1, 1): the posterior is uniform on [max(-1, z-1), min(1, z+1)]
    g = BoundedGridFilter1D(0.0, st.uniform(-1, 2), 1.0, G=400)
    z = np.array([[0.3, -1.5, 1.9, 0.0]])
    want = 0.5 * (np.maximum(-1, z - 1) + np.minimum(1, z + 1))
    np.testing.assert_allclose(g.run(_z(z)).means[..., 0], want, atol=2.5e-3)  # cell width 0.005


def test_first_order_adaptive_learns_input_moments():
    # n0 = 0: the learned moments of w are the method-of-moments estimates through
    # kappa_i(w) = (1 - h^i) kappa_i(x); with 4000 samples they sit near the truth
    law = st.beta(0.5, 5, loc=-1, scale=2)
    rng = np.random.default_rng(11)
    R, T, h = 16, 4000, 0.5
    w = law.rvs(size=(R, T + 200), random_state=rng)
    x = np.zeros(R)
    xs = np.empty((R, T + 200))
    for k in range(T + 200):
        xs[:, k] = x
        x = h * x + w[:, k]
    z = xs[:, 200:] + rng.uniform(-1, 1, (R, T))
    r = FirstOrderMomentFilter(h, 1.0, 3, adaptive=True, n0=0.0, window=T).run(_z(z))
    learned = r.extras["w_moments"][:, -1]
    true = np.array([law.moment(i) for i in (1, 2, 3)])
    se = learned.std(axis=0, ddof=1) / np.sqrt(R)
    assert np.all(np.abs(learned.mean(axis=0) - true) < 4 * se + 1e-3)


def test_first_order_impossible_measurement():
    f = FirstOrderMomentFilter(0.5, 1.0, 2, w_moments=uniform_moments(2))
    with pytest.raises(ValueError, match="ys: measurement 3.5"):
        f.run(_z([0.0, 3.5]))
    g = FirstOrderMomentFilter(0.5, 1.0, 2, w_moments=uniform_moments(2), outside="clip")
    r = g.run(_z([0.0, 3.5, 0.2]))
    # step 1: reachable interval h [-1, 1] + [-1, 1] = [-1.5, 1.5]; z - 1 = 2.5 beyond it -> end point 1.5
    assert np.isfinite(r.means).all() and r.means[1, 0] == pytest.approx(1.5)
    with pytest.raises(ValueError, match="h"):
        FirstOrderMomentFilter(1.0, 1.0, 2, w_moments=uniform_moments(2))
    with pytest.raises(ValueError, match="w_moments"):
        FirstOrderMomentFilter(0.5, 1.0, 2)


# ------------------------------------------------------------------ second-order system

from nlfilter.filters.moment_bayes import SecondOrderMomentFilter, linear_map_moments  # noqa: E402
from nlfilter.moments.densities import LegendreDensity2D  # noqa: E402


def test_linear_map_moments_exact_on_discrete_laws():
    # x and w with finitely many atoms: E[(A x + b w)^(i,j)] by enumeration
    N = 4
    A = np.array([[0.6, 0.1], [-0.2, -0.5]])
    b = np.array([1.0, 0.7])
    xa = np.array([[0.3, -1.0], [1.2, 0.4], [-0.7, 0.9]])
    px = np.array([0.2, 0.5, 0.3])
    wa = np.array([-0.5, 0.8])
    pw = np.array([0.4, 0.6])
    M = np.array([[np.sum(px * xa[:, 0] ** i * xa[:, 1] ** j) for j in range(N + 1)] for i in range(N + 1)])
    mw = np.array([np.sum(pw * wa ** i) for i in range(1, N + 1)])
    ys = xa[:, None, :] @ A.T + wa[None, :, None] * b
    pp = px[:, None] * pw[None]
    want = np.array([[np.sum(pp * ys[..., 0] ** i * ys[..., 1] ** j) for j in range(N + 1)] for i in range(N + 1)])
    mask = np.add.outer(np.arange(N + 1), np.arange(N + 1)) <= N
    np.testing.assert_allclose(linear_map_moments(M, A, b, mw)[mask], want[mask], atol=1e-13)


def test_second_order_update_against_quadrature():
    # posterior moments over box ∩ slab, against scipy dblquad with the slab as integration limits
    N = 3
    f = SecondOrderMomentFilter(np.diag([0.6, -0.5]), [1.0, 1.0], [1.0, 0.8], 1.0, N,
                                w_moments=uniform_moments(N))
    M, lo, hi = f.stationary(f.w_moments)
    z = 0.7
    post, nlo, nhi, fb = f.update_box(M, lo, hi, np.array(z))
    d = LegendreDensity2D.from_moments(M, lo, hi)
    g0 = lambda x0: max(lo[1], (z - 1 - x0) / 0.8)
    g1 = lambda x0: min(hi[1], (z + 1 - x0) / 0.8)
    x0a, x0b = max(lo[0], z - 1 - 0.8 * hi[1]), min(hi[0], z + 1 - 0.8 * lo[1])

    def I(i, j):
        fn = lambda x1, x0: x0 ** i * x1 ** j * float(d.pdf(np.array([x0, x1])))
        return integrate.dblquad(fn, x0a, x0b, g0, g1, epsabs=1e-11, epsrel=1e-10)[0]

    I00 = I(0, 0)
    for i, j in [(1, 0), (0, 1), (1, 1), (2, 1)]:
        assert post[i, j] == pytest.approx(I(i, j) / I00, rel=1e-8, abs=1e-10)
    assert not fb
    np.testing.assert_allclose(nlo, [x0a, lo[1]], atol=1e-12)


def test_second_order_wide_slab_keeps_box_moments():
    # a measurement whose slab covers the whole box changes nothing: posterior = prior moments
    f = SecondOrderMomentFilter(np.diag([0.5, 0.2]), [0.2, 0.1], [1.0, 1.0], 1.0, 4,
                                w_moments=uniform_moments(4), noise_halfwidth=5.0)
    M, lo, hi = f.stationary(f.w_moments)
    post, nlo, nhi, fb = f.update_box(M, lo, hi, np.array(0.0))
    mask = np.add.outer(np.arange(5), np.arange(5)) <= 4
    np.testing.assert_allclose(post[mask], LegendreDensity2D.from_moments(M, lo, hi).box_moments()[mask],
                               atol=1e-12)
    np.testing.assert_allclose(post[mask], M[mask], atol=1e-12)


def test_second_order_bad_input():
    with pytest.raises(ValueError, match="A: expected a stable"):
        SecondOrderMomentFilter(np.eye(2), [1, 1], [1, 1], 1.0, 2, w_moments=uniform_moments(2))
    f = SecondOrderMomentFilter(np.diag([0.5, 0.2]), [1, 1], [1, 1], 1.0, 2, w_moments=uniform_moments(2))
    with pytest.raises(ValueError, match="ys: measurement 9.0"):
        f.run(_z([0.0, 9.0]))
    g = SecondOrderMomentFilter(np.diag([0.5, 0.2]), [1, 1], [1, 1], 1.0, 2, w_moments=uniform_moments(2),
                                outside="clip")
    assert np.isfinite(g.run(_z([0.0, 9.0, 0.1])).means).all()


# ------------------------------------------------------------------ non-additive measurement

from nlfilter.filters.moment_bayes import ScaledNoiseZeroOrderFilter  # noqa: E402


def test_scaled_noise_filter_reduces_to_additive_and_matches_quadrature():
    m = power_density_moments(4, 10)
    z = np.linspace(-1.9, 1.9, 15)
    f0 = ScaledNoiseZeroOrderFilter(4, 0.0, moments=m)
    np.testing.assert_allclose(f0.estimate(z)[0], ZeroOrderMomentFilter(4, moments=m).estimate(z)[0], atol=1e-12)
    # beta = 0.4 against adaptive quadrature of eqs. 1.9-1.11 with the exact prior x^10 (N = 10)
    beta = 0.4
    f = ScaledNoiseZeroOrderFilter(10, beta, moments=power_density_moments(10, 10), nodes=64)
    for zz in (-1.2, 0.3, 1.5):
        l, u = max(-1, (zz - 1) / (1 + beta)), min(1, (zz + 1) / (1 - beta))
        num = integrate.quad(lambda x: x * 5.5 * x ** 10 / (1 + beta * x), l, u)[0]
        den = integrate.quad(lambda x: 5.5 * x ** 10 / (1 + beta * x), l, u)[0]
        assert float(f.estimate(np.array(zz))[0]) == pytest.approx(num / den, abs=1e-10)


def test_scaled_noise_moment_recovery_exact():
    # exact moments of z = x + (1 + beta x) v from those of x and v; recovery inverts them (n0 = 0)
    beta, J, N = 0.5, 4, 4
    mx = np.r_[1.0, power_density_moments(2 * N, J)]
    mv = np.r_[1.0, uniform_moments(2 * N)]
    from math import comb
    mz = [sum(comb(i, j) * mv[j] * sum(comb(j, k) * beta ** k * mx[i - j + k] for k in range(j + 1))
              for j in range(i + 1)) for i in range(1, N + 1)]
    f = ScaledNoiseZeroOrderFilter(N, beta, adaptive=True, n0=0.0)
    np.testing.assert_allclose(f.recover_moments(np.array(mz), 10), power_density_moments(N, J), atol=1e-12)


def test_polygon_clip_and_quadrature_exact():
    from nlfilter.moments.polygons import clip_halfplane as _clip_halfplane
    from nlfilter.moments.polygons import polygon_quadrature as _polygon_quadrature
    P = np.array([[[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]])
    Q = _clip_halfplane(P, np.array([1.0, 1.0]) / np.sqrt(2), np.array([0.0]))  # x + y <= 0: a triangle
    t, w = np.polynomial.legendre.leggauss(4)
    X, W = _polygon_quadrature(Q, 0.5 * (t + 1), 0.5 * w)
    assert W.sum() == pytest.approx(2.0, abs=1e-13)
    # int over the triangle x + y <= 0 of x^2 = 2/3 (half of the square's 4/3 by symmetry) and of x^3 y^2
    assert np.sum(W * X[..., 0] ** 2) == pytest.approx(2 / 3, abs=1e-13)
    want = integrate.dblquad(lambda y, x: x ** 3 * y ** 2, -1, 1, lambda x: -1.0, lambda x: -x)[0]
    assert np.sum(W * X[..., 0] ** 3 * X[..., 1] ** 2) == pytest.approx(want, abs=1e-12)


def test_polygon_update_equals_box_update_on_a_box():
    f = SecondOrderMomentFilter(np.diag([0.6, -0.5]), [1.0, 1.0], [1.0, 0.8], 1.0, 3, w_moments=uniform_moments(3))
    M, lo, hi = f.stationary(f.w_moments)
    box = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    for z in (0.7, -2.1, 3.0):
        pb, lb, hb, _ = f.update_box(M, lo, hi, np.array(z))
        pp, Q, lp, hp, _ = f.update_polygon(M, box, np.array(z))
        np.testing.assert_allclose(pp, pb, atol=1e-11)
        np.testing.assert_allclose(lp, lb, atol=1e-12)
        np.testing.assert_allclose(hp, hb, atol=1e-12)


def test_polygon_bound_contains_the_true_state():
    rng = np.random.default_rng(8)
    A, b = np.diag([0.6, -0.5]), np.array([1.0, 1.0])
    R, T = 6, 80
    x = np.zeros((R, 2))
    xs = np.empty((R, T, 2))
    for k in range(T + 100):
        if k >= 100:
            xs[:, k - 100] = x
        x = x @ A.T + rng.uniform(-1.5, 1.5, (R, 1)) * b
    zs = xs @ b + rng.uniform(-1, 1, (R, T))
    r = SecondOrderMomentFilter(BoundedNoiseModel(A, b, b, 1.5), 2, w_moments=uniform_moments(2, -1.5, 1.5)).run(_z(zs))
    lower, upper = r.extras["lower"], r.extras["upper"]
    assert np.all(lower <= xs + 1e-9) and np.all(xs <= upper + 1e-9)
    assert np.all((r.means >= lower) & (r.means <= upper))


def test_estimates_protocol_and_posterior_variance():
    rng = np.random.default_rng(2)
    z = rng.uniform(-1.5, 1.5, (3, 20))
    e = FirstOrderMomentFilter(0.5, 1.0, 4, w_moments=uniform_moments(4)).run(_z(z))
    assert e.means.shape == (3, 20, 1) and e.covs.shape == (3, 20, 1, 1) and not e.diverged.any()
    # a law on an interval of width w has variance in [0, w^2/4] (Popoviciu)
    w = (e.extras["upper"] - e.extras["lower"])[..., 0]
    assert np.all(e.covs[..., 0, 0] >= 0) and np.all(e.covs[..., 0, 0] <= w ** 2 / 4 + 1e-12)
    r2 = SecondOrderMomentFilter(np.diag([0.6, -0.5]), [1, 1], [1, 1], 1.0, 2,
                                 w_moments=uniform_moments(2)).run(_z(z[:, :8]))
    C = r2.covs
    assert np.allclose(C, np.swapaxes(C, -1, -2)) and np.all(np.linalg.eigvalsh(C) > -1e-12)


def test_per_path_known_moments_and_their_batch_check():
    # moments (B, N): each path uses its own polynomial prior (= the one-prior filter on that path)
    M = np.stack([uniform_moments(4), power_density_moments(4, 2)])
    z = np.random.default_rng(0).uniform(-1.5, 1.5, (2, 5))
    r = ZeroOrderMomentFilter(4, moments=M).run(_z(z))
    for i in range(2):
        np.testing.assert_allclose(r.means[i, :, 0], ZeroOrderMomentFilter(4, moments=M[i]).estimate(z[i])[0],
                                   atol=1e-14)
    with pytest.raises(ValueError, match=r"^moments\b"):
        ZeroOrderMomentFilter(4, moments=M).run(np.zeros((3, 2, 1)))
    assert ZeroOrderMomentFilter(4, moments=M[0]).run(np.zeros((3, 0, 1))).means.shape == (3, 0, 1)


def test_filter_objects_are_not_changed_by_run():
    # the adaptive learners' statistics live in the belief: two runs give the same result
    f = FirstOrderMomentFilter(BoundedNoiseModel.first_order(0.5, 1.0), 3, adaptive=True, window=4)
    z = _z(np.random.default_rng(4).uniform(-1.5, 1.5, (2, 30)))
    before = dict(vars(f))
    a, b = f.run(z), f.run(z)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.extras["w_moments"], b.extras["w_moments"])
    assert vars(f).keys() == before.keys() and all(vars(f)[k] is before[k] for k in before)


def test_scaled_noise_filter_clips_an_impossible_measurement():
    """Regression (documented "impossible measurements are clipped"): an outlier of 1e150 overflowed
    the adaptive learner's sample moments (z⁴ = inf) and raised a ValueError naming the internal
    ``m``, 1.7e308 diverged; now z is clipped to the possible range ``[min x − (1 + beta x) c,
    max x + (1 + beta x) c]``: the estimate is the bound of the support, nothing diverges, the
    learnt moments stay finite and the other path is untouched."""
    f = ScaledNoiseZeroOrderFilter(4, 0.3, adaptive=True, window=2)
    rng = np.random.default_rng(3)
    x = rng.uniform(-1.0, 1.0, (2, 6))
    z = x + (1 + 0.3 * x) * rng.uniform(-1.0, 1.0, (2, 6))
    clean = f.run(_z(z))
    for big in (1e150, -1e150, 1.7e308):
        e = z.copy()
        e[1, 2] = big
        res = f.run(_z(e))
        assert not res.diverged.any() and np.isfinite(res.extras["moments"]).all()
        np.testing.assert_allclose(res.means[1, 2, 0], np.sign(big), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(res.means[0], clean.means[0])
        np.testing.assert_array_equal(res.extras["moments"][0], clean.extras["moments"][0])



def test_zero_order_estimate_equals_the_ratio_of_integrals_bit_for_bit():
    # 000 eq. 3.7 from one table of Legendre values = int x f / int f by LegendreDensity.integral
    from nlfilter.filters.moment_bayes.zero_order import _interval, zero_order_estimate
    from nlfilter.moments.densities import LegendreDensity, power_density_moments
    rng = np.random.default_rng(3)
    for N in (2, 7, 12):
        m = power_density_moments(N, 6) + 0.01 * rng.standard_normal((40, N))
        d = LegendreDensity.from_moments(m)
        z = rng.uniform(-2, 2, 40)
        l, u = _interval(z, -1.0, 1.0, 1.0, "raise")
        de, nu = d.integral(l, u, 0), d.integral(l, u, 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            xh = nu / de
        fb = ~(de >= 1e-6) | ~((xh > l) & (xh < u))
        got, gfb = zero_order_estimate(z, d)
        np.testing.assert_array_equal(gfb, fb)
        np.testing.assert_array_equal(got, np.where(fb, 0.5 * (l + u), xh))


def test_zero_order_filters_take_the_zero_order_model():
    """issue 10 item 2: the zero-order filters take the problem's model (support, noise half-width,
    beta and — with known moments — the exact moments of x, E x^i = (J+1)/(J+1+i) for even i, from
    it) and give the raw form's numbers; inconsistent arguments are refused naming them."""
    from nlfilter.bounded import ZeroOrderModel
    from nlfilter.filters.moment_bayes import ScaledNoiseZeroOrderFilter, ZeroOrderMomentFilter
    md = ZeroOrderModel(4)
    xs, zs = md.simulate(30, 3, 1)
    i = np.arange(1, 5)
    exact = np.where(i % 2 == 0, 5 / (5 + i), 0.0)
    a = ZeroOrderMomentFilter(md, 4).run(zs)
    b = ZeroOrderMomentFilter(4, moments=exact).run(zs)
    np.testing.assert_array_equal(a.means, b.means)
    sm = ZeroOrderModel(4, beta=0.3)
    _, zs2 = sm.simulate(30, 3, 2)
    c = ScaledNoiseZeroOrderFilter(sm, 4, adaptive=True, window=5).run(zs2)
    d = ScaledNoiseZeroOrderFilter(4, 0.3, adaptive=True, window=5).run(zs2)
    np.testing.assert_array_equal(c.means, d.means)
    with pytest.raises(ValueError, match=r"^model: beta"):
        ZeroOrderMomentFilter(sm, 4)
    with pytest.raises(ValueError, match=r"^support: given by the model"):
        ZeroOrderMomentFilter(md, 4, support=(-2, 2))
    with pytest.raises(TypeError, match=r"^N: expected"):
        ZeroOrderMomentFilter(md)
    with pytest.raises(TypeError, match=r"^N: given twice"):
        ZeroOrderMomentFilter(4, 4)
