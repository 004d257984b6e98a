import numpy as np
import pytest
import sympy as sp

from nlfilter.errors import NotPolynomialError
from nlfilter.polynomials import Polynomial, as_polynomial, monomials

x, y, t = sp.symbols("x y t")


def test_roundtrip_and_arithmetic_match_sympy():
    e1 = 3 * x**2 * y - x + 2
    e2 = y**3 - 0.5 * x * y
    p1, p2 = Polynomial.from_sympy(e1, [x, y]), Polynomial.from_sympy(e2, [x, y])
    for got, want in [(p1 * p2, e1 * e2), (p1 + p2, e1 + e2), (p1 - p2, e1 - e2), (p1**3, e1**3),
                      (p1.diff(1), sp.diff(e1, y))]:
        assert sp.expand(got.to_sympy([x, y]) - want) == 0
    pts = np.array([[0.3, -1.2], [2.0, 0.5]])
    want = [float(e1.subs({x: a, y: b})) for a, b in pts]
    np.testing.assert_allclose(p1(pts), want, rtol=1e-14)


def test_time_dependent_coefficients_are_kept_symbolic():
    p = Polynomial.from_sympy(sp.sin(t) * x**2 + 2 * x, [x])
    assert p.symbols == {t}
    assert p.subs({t: 0.0}).terms == {(1,): 2.0}
    with pytest.raises(ValueError, match="symbolic coefficients"):
        p(np.ones((2, 1)))


def test_not_polynomial_names_the_term():
    with pytest.raises(NotPolynomialError, match=r"sin\(x\)"):
        Polynomial.from_sympy(x**2 + sp.sin(x), [x], name="f[0]")


def test_bad_input_messages():
    with pytest.raises(ValueError, match="terms"):
        Polynomial({(1, -1): 1.0})
    with pytest.raises(TypeError, match="polynomial"):
        as_polynomial("x", 1)
    with pytest.raises(ValueError, match="max_degree"):
        monomials(2, -1)


def test_monomial_counts():
    from math import comb
    for n, d in [(1, 5), (2, 4), (3, 3), (6, 6)]:
        assert len(monomials(n, d)) == comb(n + d, d)
    assert len(monomials(6, 6, min_degree=1)) == 923
    # weighted degree: x has weight 1, y weight 3
    assert monomials(2, 3, weights=[1, 3]) == [(0, 0), (1, 0), (2, 0), (3, 0), (0, 1)]


def test_expect_is_linear_functional():
    p = Polynomial({(2,): 1.0, (0,): -1.0})
    assert p.expect({(2,): np.array([3.0, 4.0]), (0,): 1.0}).tolist() == [2.0, 3.0]


def test_exact_coefficients_stay_rational_and_clean_pad_numeric():
    q = sp.Symbol("q")
    p = Polynomial.from_sympy(q / 2 * x**2 - x, [x, y], exact=True)
    assert p.exact and p.terms == {(2, 0): q / 2, (1, 0): sp.Integer(-1)}
    d = p.diff(0) * 3  # exactness propagates: 3 q x − 3, rational numbers kept
    assert d.exact and d.terms == {(1, 0): 3 * q, (0, 0): sp.Integer(-3)}
    assert (p**2).terms[(4, 0)] == q**2 / 4
    f = Polynomial({(1, 0): 1e-17, (0, 1): 2.0}, 2)
    assert f.clean(1e-15).terms == {(0, 1): 2.0} and f.clean().terms == f.terms
    assert f.pad(3).terms == {(1, 0, 0): 1e-17, (0, 1, 0): 2.0}
    with pytest.raises(ValueError, match="nvars"):
        f.pad(1)
    with pytest.raises(ValueError, match=r"f\[0\].*free symbols \['q'\]"):
        Polynomial.from_sympy(q * x, [x], name="f[0]", numeric=True)
