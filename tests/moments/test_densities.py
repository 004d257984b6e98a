"""Densities from moments (seed 000, Chapter II): Legendre projection, exact integrals, moment algebra."""

import doctest

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import integrate

import nlfilter.moments.densities as D
from nlfilter.moments.densities import (LegendreDensity, LegendreDensity2D, affine_moments,
                                        cumulants_to_moments, difference_moments, is_moment_sequence,
                                        moments_to_cumulants, power_density_moments, sum_moments,
                                        uniform_moments)


def test_doctests():
    assert doctest.testmod(D).failed == 0


def test_power_coefficients_match_eq_2_20_and_2_21():
    # 000 eqs. 2.20 (N = 2) and 2.21 (N = 4), printed to 7-8 significant digits
    rng = np.random.default_rng(1)
    for _ in range(5):
        m1, m2, m3, m4 = rng.uniform(-0.5, 0.5, 4)
        a = LegendreDensity.from_moments([m1, m2]).power_coefficients()
        np.testing.assert_allclose(a, [-1.875 * m2 + 1.125, 1.5 * m1, 5.625 * m2 - 1.875], atol=1e-12)
        a = LegendreDensity.from_moments([m1, m2, m3, m4]).power_coefficients()
        want = [7.3828125 * m4 - 8.203125 * m2 + 1.7578125, -13.125 * m3 + 9.375 * m1,
                -73.828125 * m4 + 68.90625 * m2 - 8.203125, 21.875 * m3 - 13.125 * m1,
                86.1328125 * m4 - 73.828125 * m2 + 7.3828125]
        np.testing.assert_allclose(a, want, atol=1e-12)


def test_power_coefficients_match_eq_2_22_legible_entries():
    # 000 eq. 2.22 (N = 6): a0 and a6, the entries the OCR left legible, to their printed 6 decimals
    m = np.array([0.0, 0.3, 0.0, 0.2, 0.0, 0.1])
    a = LegendreDensity.from_moments(m).power_coefficients()
    m2, m4, m6 = m[1], m[3], m[5]
    assert a[0] == pytest.approx(-29.326172 * m6 + 47.373047 * m4 - 21.533203 * m2 + 2.392578, abs=5e-6)
    assert a[6] == pytest.approx(1354.869141 * m6 - 1847.548828 * m4 + 615.849609 * m2 - 29.326172, abs=5e-6)


def test_triangular_density_error_falls_with_N_fig4():
    # 000 eq. 2.23 and Fig. 4: squared error (eq. 2.14) of the degree-N approximation of 1 - |x|
    def m(k):  # moments of the triangular density on (-1, 1)
        return 0.0 if k % 2 else 2.0 / ((k + 1) * (k + 2))

    errs = []
    for N in (0, 2, 4, 6, 8, 10, 12):
        d = LegendreDensity.from_moments([m(k) for k in range(1, N + 1)]) if N else None
        f = (lambda x: 0.5) if d is None else (lambda x, d=d: float(d.pdf(x)))
        e2 = integrate.quad(lambda x: (1 - abs(x) - f(x)) ** 2, -1, 1, points=[0.0], limit=200)[0]
        errs.append(e2)
    assert all(b < a for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 1e-2 * errs[0]  # the kink at 0 limits the rate (about N^-3), yet N = 12 gains > 100x


@pytest.mark.parametrize("J", [0, 2, 4, 6])
def test_polynomial_density_reproduced_exactly(J):
    for N in (J, J + 2, 12):
        if N == 0:
            continue
        d = LegendreDensity.from_moments(power_density_moments(N, J))
        x = np.linspace(-1, 1, 11)
        np.testing.assert_allclose(d.pdf(x), (J + 1) / 2 * x ** J, atol=1e-10)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(1, 12), st.floats(-3, 3), st.floats(0.2, 4), st.integers(0, 2 ** 31))
def test_projection_keeps_moments_up_to_N(N, a, width, seed):
    # the least-squares projection keeps all moments of order <= N (x^i lies in the space)
    rng = np.random.default_rng(seed)
    lo, hi = a, a + width
    x = rng.uniform(lo, hi, 50) ** 1  # any law on [lo, hi]: an empirical one
    m = np.array([np.mean(x ** k) for k in range(1, N + 1)])
    d = LegendreDensity.from_moments(m, lo, hi)
    np.testing.assert_allclose(d.moments(), m, rtol=1e-8, atol=1e-8 * max(1, abs(a) + width) ** N)
    assert d.integral(lo, hi, 0) == pytest.approx(1.0, abs=1e-9)


def test_subinterval_integrals_against_quad():
    m = np.array([0.1, 0.45, -0.05, 0.3, 0.02, 0.22])
    d = LegendreDensity.from_moments(m, -1.0, 1.5)
    for l, u in [(-0.7, 0.2), (0.1, 1.5), (-2, 0.4)]:
        for p in range(5):
            want = integrate.quad(lambda x: x ** p * float(d.pdf(x)), max(l, -1.0), min(u, 1.5))[0]
            assert float(d.integral(l, u, p)) == pytest.approx(want, abs=1e-11)


def test_batched_densities_and_intervals():
    ms = np.array([[0.0, 1 / 3], [0.2, 0.5]])
    lo = np.array([-1.0, 0.0])
    hi = np.array([1.0, 1.0])
    d = LegendreDensity.from_moments(ms, lo, hi)
    assert d.coef.shape == (2, 3)
    single = [LegendreDensity.from_moments(ms[i], lo[i], hi[i]) for i in range(2)]
    got = d.integral(np.array([-0.5, 0.2]), np.array([0.5, 0.9]), 1)
    want = [float(single[0].integral(-0.5, 0.5, 1)), float(single[1].integral(0.2, 0.9, 1))]
    np.testing.assert_allclose(got, want, atol=1e-14)


def test_sum_and_difference_moments_eq_3_13_3_14():
    # U(-1,1) + U(-1,1) is the triangular law on (-2, 2): moments by quadrature
    mu = uniform_moments(6)
    mz = sum_moments(mu, mu)
    tri = [integrate.quad(lambda z: z ** k * (2 - abs(z)) / 4, -2, 2, points=[0])[0] for k in range(1, 7)]
    np.testing.assert_allclose(mz, tri, atol=1e-12)
    np.testing.assert_allclose(difference_moments(mz, mu), mu, atol=1e-12)
    # batched inversion
    mx = np.array([[0.1, 0.4, 0.0, 0.3], [0.0, 0.7, 0.1, 0.6]])
    np.testing.assert_allclose(difference_moments(sum_moments(mx, mu[:4]), mu[:4]), mx, atol=1e-12)


def test_affine_and_cumulants():
    m = uniform_moments(5, 0.0, 1.0)
    np.testing.assert_allclose(affine_moments(m, 2.0, -1.0), uniform_moments(5, -1.0, 1.0), atol=1e-12)
    k = np.array([0.3, 0.2, 0.1, 0.05, -0.02])
    np.testing.assert_allclose(moments_to_cumulants(cumulants_to_moments(k)), k, atol=1e-13)
    # cumulants of U(-1,1): k2 = 1/3, k4 = -2/15
    np.testing.assert_allclose(moments_to_cumulants(uniform_moments(4)), [0, 1 / 3, 0, -2 / 15], atol=1e-14)


def test_is_moment_sequence():
    assert is_moment_sequence(power_density_moments(6, 10))
    assert is_moment_sequence(uniform_moments(5, 0.0, 2.0), 0.0, 2.0)
    assert not is_moment_sequence([0.0, 0.1, 0.0, 0.5])  # m4 > m2 impossible on [-1, 1]
    assert not is_moment_sequence([0.0, 1.2])  # variance beyond the interval
    got = is_moment_sequence(np.array([[0.0, 0.3], [0.0, 1.5]]))
    assert got.tolist() == [True, False]


def test_2d_tensor_density_from_product_moments():
    # independent components: density (3/2 x^2) * (1/2) on [-1,1]^2, total degree 2 suffices
    N = 4
    mx = np.r_[1.0, power_density_moments(N, 2)]
    my = np.r_[1.0, uniform_moments(N)]
    M = np.outer(mx, my)
    d = LegendreDensity2D.from_moments(M, [-1.0, -1.0], [1.0, 1.0])
    pts = np.array([[0.3, -0.2], [-0.9, 0.5], [0.0, 0.0]])
    np.testing.assert_allclose(d.pdf(pts), 1.5 * pts[:, 0] ** 2 * 0.5, atol=1e-12)
    B = d.box_moments()
    mask = np.add.outer(np.arange(N + 1), np.arange(N + 1)) <= N
    np.testing.assert_allclose(B[mask], M[mask], atol=1e-12)


def test_bad_input_messages():
    with pytest.raises(ValueError, match="lo, hi"):
        LegendreDensity.from_moments([0.0, 0.3], 1.0, 1.0)
    with pytest.raises(ValueError, match="moments"):
        LegendreDensity.from_moments([0.0, np.nan])
    with pytest.raises(ValueError, match="power"):
        LegendreDensity.from_moments([0.0, 0.3]).integral(0, 1, -1)
