"""Generated moment equations against hand derivations (seed 003 eqs. 24, 27) and closed forms."""
import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel, DiscreteModel
from nlfilter.errors import NotPolynomialError
from nlfilter.moments import (PolynomialMap, PolynomialSDE, closed_hull, discrete_moment_equations,
                              gaussian_moments, gaussian_noise_moments, is_closed, moment_equations,
                              monomials, propagate)

x, y, t = sp.symbols("x y t")


def test_oh_shin_eqs_24_27():
    """003 eq. 27 (eq. 24 is its first two rows): dα1 = −α3, dα2 = −2α4 + Q, dα3 = −3α5 + 3Qα1,
    dα4 = −4α6 + 6Qα2."""
    Q = 0.05
    model = SDEModel([x], [-x**3], [x], Q=Q, R=0.05)
    eq = moment_equations(model, monomials(1, 4, min_degree=1))
    assert eq.missing == [(5,), (6,)]
    A, B, c = eq.A.toarray(), eq.B.toarray(), eq.c
    np.testing.assert_array_equal(A, [[0, 0, -1, 0], [0, 0, 0, -2], [3 * Q, 0, 0, 0], [0, 6 * Q, 0, 0]])
    np.testing.assert_array_equal(B, [[0, 0], [0, 0], [-3, 0], [0, -4]])
    np.testing.assert_array_equal(c, [0, Q, 0, 0])
    eq2 = moment_equations(model, [(1,), (2,)])  # eq. 24
    assert eq2.missing == [(3,), (4,)]
    np.testing.assert_array_equal(eq2.B.toarray(), [[-1, 0], [0, -2]])


def test_generator_matches_sympy_ito_formula_2d():
    """L x^γ against a direct SymPy evaluation of Σ f_s ∂_s + ½ Σ σ_sh ∂_s∂_h, with state-dependent
    diffusion and a time-dependent coefficient."""
    f = [-x**3 + x * y, -y + sp.cos(t) * x**2]
    G = sp.Matrix([[1 + x, 0], [y, 2]])
    Q = sp.Matrix([[sp.Rational(1, 2), sp.Rational(1, 10)], [sp.Rational(1, 10), 1]])
    sigma = sp.expand(G * Q * G.T)
    sde = PolynomialSDE.from_sympy([x, y], f, sigma, time=t)
    for g in [(1, 0), (2, 1), (0, 3), (2, 2)]:
        mono = x**g[0] * y**g[1]
        want = sum(fs * sp.diff(mono, s) for fs, s in zip(f, [x, y]))
        want += sp.Rational(1, 2) * sum(sigma[i, j] * sp.diff(mono, a, b)
                                         for i, a in enumerate([x, y]) for j, b in enumerate([x, y]))
        got = sde.generator(g).to_sympy([x, y])
        d = sp.Poly(sp.expand(got - want).subs(t, 0.7), x, y)
        assert max((abs(float(cf)) for cf in d.coeffs()), default=0.0) < 1e-12
    eq = moment_equations(sde, monomials(2, 2, min_degree=1))
    assert not eq.constant
    A, B, c = eq.at(t=0.3)
    # row of E[y]: dE[y]/dt = −E[y] + cos(t) E[x²]
    r = eq.index[(0, 1)]
    assert A[r, eq.index[(0, 1)]] == -1.0
    assert A[r, eq.index[(2, 0)]] == pytest.approx(np.cos(0.3))


def test_at_with_symbols_equals_numbers_substituted():
    """Symbolic coefficients: ``at(values)`` (the groups summed on their union pattern) equals the
    equations built with the numbers substituted, for a discrete map with products of symbols."""
    from nlfilter.polynomials import Polynomial
    a, b, k = sp.symbols("a b k")
    f = [a * x - b * x**3 + k * y, b * y + a * k * x * y + 1]
    G = [[1, 0], [a, k * x]]
    vals = {a: 0.7, b: -0.2, k: 1.3}

    def eqs(sub):
        P = lambda e: Polynomial.from_sympy(sp.sympify(e).subs(sub), [x, y])  # noqa: E731
        pm = PolynomialMap(tuple(map(P, f)), tuple(tuple(map(P, row)) for row in G),
                           gaussian_noise_moments([[0.5, 0.1], [0.1, 0.3]]))
        return discrete_moment_equations(pm, monomials(2, 3, min_degree=1))

    sym, num = eqs({}), eqs(vals)
    assert not sym.constant and num.constant and sym.missing == num.missing
    A, B, c = sym.at(values={str(s): v for s, v in vals.items()})
    np.testing.assert_allclose(A.toarray(), num.A.toarray(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(B.toarray(), num.B.toarray(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(c, num.c, rtol=1e-12, atol=1e-12)


def test_ou_all_orders_exact():
    """dx = −a x dt + s dβ: the moments up to order 6 close and equal the Gaussian moments of
    m(t) = m0 e^{−at}, P(t) = P0 e^{−2at} + s²(1 − e^{−2at})/(2a)."""
    a, s2, m0, P0 = 1.5, 0.8, 2.0, 0.3
    model = SDEModel([x], [-a * x], [x], Q=s2, R=1.0)
    idx = monomials(1, 6, min_degree=1)
    eq = moment_equations(model, idx)
    assert eq.closed and is_closed(model, idx)
    ts = np.array([0.0, 0.2, 0.7, 2.0])
    sol = propagate(eq, gaussian_moments([m0], [[P0]], idx), ts)
    m = m0 * np.exp(-a * ts)
    P = P0 * np.exp(-2 * a * ts) + s2 * (1 - np.exp(-2 * a * ts)) / (2 * a)
    want = gaussian_moments(m[:, None], P[:, None, None], idx)
    np.testing.assert_allclose(sol.values, want, rtol=1e-6, atol=1e-9)


def test_time_dependent_drift():
    """dx = (−x + t) dt: E[x](t) = t − 1 + (m0 + 1) e^{−t}."""
    model = SDEModel([x], [-x + t], [x], Q=0.0, R=1.0, time=t)
    eq = moment_equations(model, [(1,)])
    sol = propagate(eq, [2.0], np.linspace(0, 2, 5))
    np.testing.assert_allclose(sol.values[:, 0], sol.t - 1 + 3 * np.exp(-sol.t), rtol=1e-7)


def test_closed_hull_bilinear_and_polynomial_signal():
    # bilinear: dx = A x dt + (N x) dβ  — second moments are a closed set
    sde = PolynomialSDE.from_sympy([x, y], [-x + y, -2 * y], [[(0.5 * y)**2, 0], [0, 0]])
    hull = closed_hull(sde, [(2, 0)])
    assert set(hull) == {(2, 0), (1, 1), (0, 2)}
    assert is_closed(sde, hull)
    # a linear filter driven by a polynomial signal: (x, z) with dz = (x³ − z) dt, dx = −x dt + dβ:
    # weighted degree (x: 1, z: 3) up to 6 is closed
    sde2 = PolynomialSDE.from_sympy([x, y], [-x, x**3 - y], [[1, 0], [0, 0]])
    idx = monomials(2, 6, min_degree=1, weights=[1, 3])
    assert is_closed(sde2, idx)
    with pytest.raises(ValueError, match="does not close"):
        closed_hull(PolynomialSDE.from_sympy([x], [-x**3], [[1]]), [(1,)], max_size=50)


def test_not_polynomial_model_names_term():
    model = SDEModel([x], [-sp.sin(x)], [x], Q=1.0, R=1.0)
    with pytest.raises(NotPolynomialError, match=r"sin\(x\)"):
        moment_equations(model, [(1,)])
    with pytest.raises(TypeError, match="sde"):
        moment_equations("model", [(1,)])
    with pytest.raises(ValueError, match="indices"):
        moment_equations(SDEModel([x], [-x], [x], Q=1.0, R=1.0), [(1, 0)])


def test_discrete_linear_gaussian_exact():
    """x' = a x + w, w ~ N(0, q): E x'^2 = a² E x² + q, E x'^4 = a⁴ E x⁴ + 6 a² q E x² + 3 q²."""
    a, q = 0.9, 0.4
    model = DiscreteModel([x], [a * x], [x], Q=q, R=1.0)
    eq = discrete_moment_equations(model, monomials(1, 4, min_degree=1))
    assert eq.closed
    A, c = eq.A.toarray(), eq.c
    np.testing.assert_allclose(A[1], [0, a**2, 0, 0])
    np.testing.assert_allclose(c, [0, q, 0, 3 * q**2])
    np.testing.assert_allclose(A[3], [0, 6 * a**2 * q, 0, a**4])


def test_discrete_polynomial_map_against_monte_carlo_free_expansion():
    """x' = x − 0.1 x³ + (1 + 0.5 x) w with Laplace-like noise moments: rows equal the SymPy
    expansion of E_w[(f + G w)^γ]."""
    wm = {0: 1.0, 1: 0.0, 2: 2.0, 3: 0.0, 4: 24.0, 5: 0.0, 6: 720.0}
    pm = PolynomialMap(({(1,): 1.0, (3,): -0.1},), (({(0,): 1.0, (1,): 0.5},),), lambda b: wm[b[0]])
    eq = discrete_moment_equations(pm, [(1,), (2,), (3,)])
    w = sp.Symbol("w")
    for g in [(2,), (3,)]:
        expr = sp.expand((x - sp.Rational(1, 10) * x**3 + (1 + x / 2) * w) ** g[0])
        poly = sp.Poly(expr, x, w)
        want = {}
        for (ex, ew), cf in poly.terms():
            want[ex] = want.get(ex, 0.0) + float(cf) * wm[ew]
        r = eq.index[g]
        got = {}
        for j, e in enumerate(eq.indices):
            if eq.A[r, j]:
                got[e[0]] = eq.A[r, j]
        for j, e in enumerate(eq.missing):
            if eq.B[r, j]:
                got[e[0]] = eq.B[r, j]
        if eq.c[r]:
            got[0] = eq.c[r]
        assert got.keys() == {k for k, v in want.items() if v}
        for k in got:
            assert got[k] == pytest.approx(want[k], rel=1e-13)


def test_gaussian_noise_moments_isserlis():
    m = gaussian_noise_moments([[1.0, 0.3], [0.3, 2.0]])
    assert m((2, 2)) == pytest.approx(1.0 * 2.0 + 2 * 0.3**2)
    assert m((1, 1)) == pytest.approx(0.3)
    assert m((3, 1)) == pytest.approx(3 * 1.0 * 0.3)


def test_six_dimensional_cubic_generation_size():
    xs = sp.symbols("x1:7")
    f = [-xi**3 + 0.5 * xs[(i + 1) % 6] for i, xi in enumerate(xs)]
    sde = PolynomialSDE.from_sympy(xs, f, sp.eye(6) * 0.3)
    eq = moment_equations(sde, monomials(6, 6, min_degree=1))
    assert len(eq.indices) == 923
    assert all(sum(g) in (7, 8) for g in eq.missing)


def test_noise_columns_give_sigma_and_noise_terms():
    """dx = -x dt + x dβ1 + 2 dβ2, Q = [[1, .5], [.5, 4]]: σ = G Q Gᵀ and d x² = ... + 2x² dβ1 + 4x dβ2."""
    sde = PolynomialSDE.from_sympy([x], [-x], G=[[x, 2]], Q=[[1.0, 0.5], [0.5, 4.0]])
    assert sde.r == 2 and sde.names == ("x",)
    assert sde.diffusion[0][0].terms == {(2,): 1.0, (1,): 2.0, (0,): 16.0}
    assert [p.terms for p in sde.noise_terms((2,))] == [{(2,): 2.0}, {(1,): 4.0}]
    assert sde.generator((2,)) == PolynomialSDE.from_sympy([x], [-x], [[x**2 + 2 * x + 16]]).generator((2,))
    with pytest.raises(ValueError, match="noise columns"):
        PolynomialSDE.from_sympy([x], [-x], [[1]]).noise_terms((1,))
    with pytest.raises(ValueError, match="sigma, G"):
        PolynomialSDE.from_sympy([x], [-x], [[1]], G=[[1]])
    with pytest.raises(ValueError, match=r"Q: expected shape \(2, 2\)"):
        PolynomialSDE.from_sympy([x], [-x], G=[[x, 2]], Q=1.0)
