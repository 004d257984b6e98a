"""Closures: exact on Gaussians, equal to independent derivations (paper eqs. 31-33 in 1-D,
cumulant generating function and the Hermite expansion itself in 2-D)."""
from math import factorial

import numpy as np
import pytest
import sympy as sp

from nlfilter.moments import (CumulantClosure, EdgeworthClosure, GaussianClosure, closure_by_name,
                              gaussian_moments, monomials)

CLOSURES = [GaussianClosure(), CumulantClosure(3), CumulantClosure(4), CumulantClosure(6),
            EdgeworthClosure(4), EdgeworthClosure(6)]


@pytest.mark.parametrize("clo", CLOSURES, ids=repr)
def test_every_closure_exact_on_gaussian_2d(clo):
    rng = np.random.default_rng(1)
    mean = rng.normal(size=(3, 2))
    L = rng.normal(size=(3, 2, 2))
    cov = L @ np.swapaxes(L, -1, -2) + 0.1 * np.eye(2)
    kept = monomials(2, clo.order)
    wanted = monomials(2, 8, min_degree=clo.order + 1)
    got = clo(kept, gaussian_moments(mean, cov, kept), wanted)
    np.testing.assert_allclose(got, gaussian_moments(mean, cov, wanted), rtol=1e-11, atol=1e-10)


def _paper_edgeworth4(a1, a2, a3, a4, k):
    """003 eqs. 28-33 literally: α_k = I_k + c3/6 J_{k,3} + c4/24 J_{k,4} with the recursions of eq. 33."""
    m, D = a1, a2 - a1**2
    c3 = a3 - 3 * a1 * a2 + 2 * a1**3  # eq. 30
    c4 = a4 - 4 * a1 * a3 + 12 * a1**2 * a2 - 3 * a2**2 - 6 * a1**4
    I = {0: 1.0, 1: m, 2: D + m * m}
    for j in range(3, k + 6):
        I[j] = m * I[j - 1] + (j - 1) * D * I[j - 2]
    J = {}

    def Jf(kk, nu):
        if nu == 0:
            return I[kk]
        if nu == 1:
            return (I[kk + 1] - m * I[kk]) / D
        if (kk, nu) not in J:
            J[(kk, nu)] = (Jf(kk + 1, nu - 1) - m * Jf(kk, nu - 1) - (nu - 1) * Jf(kk, nu - 2)) / D
        return J[(kk, nu)]

    return I[k] + c3 / 6 * Jf(k, 3) + c4 / 24 * Jf(k, 4)


def test_edgeworth4_equals_paper_eqs_31_33():
    # moments of a skewed law (a shifted gamma-like set of moments): α1..α4
    a1, a2, a3, a4 = 0.7, 1.3, 2.9, 8.1
    got = EdgeworthClosure(4)(monomials(1, 4), [1.0, a1, a2, a3, a4], [(5,), (6,)])
    want = [_paper_edgeworth4(a1, a2, a3, a4, 5), _paper_edgeworth4(a1, a2, a3, a4, 6)]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    # and the central forms μ5 = 10 D c3, μ6 = 15 D³ + 15 D c4 (derived in closures.py)
    zero_mean = EdgeworthClosure(4)(monomials(1, 4), [1.0, 0.0, 2.0, 0.5, 13.0], [(5,), (6,)])
    c3, c4 = 0.5, 13.0 - 3 * 4.0
    np.testing.assert_allclose(zero_mean, [10 * 2.0 * c3, 15 * 8.0 + 15 * 2.0 * c4], rtol=1e-13)


def test_cumulant_closure_against_cumulant_generating_function_2d():
    """Moments from M(s) = exp(K(s)), K truncated at order N, against the closure fed the same
    moments up to order N."""
    N = 4
    s1, s2 = sp.symbols("s1 s2")
    rng = np.random.default_rng(3)
    kap = {g: sp.Rational(int(rng.integers(-5, 6)), 10) for g in monomials(2, N, min_degree=1)}
    kap[(2, 0)], kap[(0, 2)], kap[(1, 1)] = sp.Rational(3, 2), 1, sp.Rational(1, 5)
    Kcgf = sum(v * s1**g[0] * s2**g[1] / (factorial(g[0]) * factorial(g[1])) for g, v in kap.items())
    # M = exp(K) truncated at total degree 6: Σ_k K^k / k!, with K's polynomial powers truncated
    Kp = sp.Poly(Kcgf, s1, s2)
    trunc = lambda p: sp.Poly(sum(c * s1**e[0] * s2**e[1] for e, c in p.terms() if sum(e) <= 6), s1, s2)  # noqa: E731
    term, Mgf = sp.Poly(1, s1, s2), sp.Poly(1, s1, s2)
    for k in range(1, 7):
        term = trunc(term * Kp)
        Mgf = Mgf + term * sp.Rational(1, factorial(k))
    coeffs = dict(Mgf.terms())

    def moment(g):  # E[x^g] = g! × coefficient of s^g
        return float(coeffs.get(tuple(g), 0) * factorial(g[0]) * factorial(g[1]))

    kept = monomials(2, N)
    vals = [moment(g) for g in kept]
    wanted = [(5, 0), (3, 2), (1, 4), (4, 2), (3, 3), (0, 6)]
    got = CumulantClosure(N)(kept, vals, wanted)
    np.testing.assert_allclose(got, [moment(g) for g in wanted], rtol=1e-10)


def test_edgeworth_closure_is_moments_of_hermite_expansion_2d():
    """Build p* = N(m,K)[1 + Σ c_ν/ν! H_ν(x−m)] with H_ν = (−1)^|ν| ∂^ν N / N (003 eq. 12) in SymPy
    from the closure's quasi-moments; its moments up to order 4 must be the given ones and its
    moments of order 5-6 the closure's."""
    u1, u2 = sp.symbols("u1 u2")
    Kmat = sp.Matrix([[sp.Rational(3, 2), sp.Rational(1, 2)], [sp.Rational(1, 2), 1]])
    Ki = Kmat.inv()
    quad = (sp.Matrix([u1, u2]).T * Ki * sp.Matrix([u1, u2]))[0]
    dens = sp.exp(-quad / 2)
    clo = EdgeworthClosure(4)
    # central moments: Gaussian ones plus perturbations of order 3 and 4
    gam = {g: float(v) for g, v in zip(monomials(2, 4), gaussian_moments([0, 0], np.array(Kmat, float),
                                                                         monomials(2, 4))[...])}
    cm = dict(gam)
    for g, d in [((3, 0), 0.4), ((2, 1), -0.2), ((0, 3), 0.3), ((4, 0), 0.9), ((2, 2), 0.3), ((1, 3), -0.2)]:
        cm[g] += d
    cq = clo.quasi_moments(cm, 2)
    poly = 1
    for nu, c in cq.items():
        H = sp.simplify((-1) ** sum(nu) * sp.diff(dens, u1, nu[0], u2, nu[1]) / dens) if True else None
        poly += sp.Float(c) / (factorial(nu[0]) * factorial(nu[1])) * H
    poly = sp.expand(poly)

    def pstar_moment(g):  # E*[u^g] = E_N[u^g · poly(u)], Gaussian moments of a polynomial
        P = sp.Poly(sp.expand(u1**g[0] * u2**g[1] * poly), u1, u2)
        es = [e for e, _ in P.terms()]
        gm = gaussian_moments([0, 0], np.array(Kmat, float), es)
        return sum(float(cf) * v for (_, cf), v in zip(P.terms(), gm))

    for g in monomials(2, 4, min_degree=2):
        assert pstar_moment(g) == pytest.approx(cm[g], abs=1e-10)
    kept = monomials(2, 4)
    vals = [cm.get(g, 0.0) if sum(g) != 1 else 0.0 for g in kept]
    vals[0] = 1.0
    wanted = monomials(2, 6, min_degree=5)
    got = clo(kept, vals, wanted)
    np.testing.assert_allclose(got, [pstar_moment(g) for g in wanted], rtol=1e-9, atol=1e-9)


def test_closures_differ_past_gaussian():
    # 1-D: μ6 under cumulant-4 has the extra 10 κ3² term relative to Edgeworth-4
    kept = monomials(1, 4)
    vals = [1.0, 0.0, 1.0, 0.8, 3.5]
    e = EdgeworthClosure(4)(kept, vals, [(6,)])[0]
    c = CumulantClosure(4)(kept, vals, [(6,)])[0]
    assert c - e == pytest.approx(10 * 0.8**2)


def test_batched_complex_step_and_errors():
    kept = monomials(1, 2)
    v = np.array([[1.0, 0.5, 1.0], [1.0, 0.0, 2.0]]) + 0j
    out = GaussianClosure()(kept, v, [(4,)])
    assert out.shape == (2, 1) and np.iscomplexobj(out)
    with pytest.raises(ValueError, match="degree ≤ 4"):
        EdgeworthClosure(4)(kept, v.real, [(5,)])
    with pytest.raises(ValueError, match="values"):
        GaussianClosure()(kept, [1.0, 2.0], [(3,)])
    with pytest.raises(ValueError, match="closure"):
        closure_by_name("normal")
    with pytest.raises(ValueError, match="order"):
        CumulantClosure(1)
