import numpy as np
import pytest

from nlfilter.moments import gaussian_moments, monomials
from nlfilter.moments.quadrature import cubature5_rule, expect_gaussian, gauss_hermite_rule


def _monomial_values(x, exps):
    return np.stack([np.prod(x ** np.array(e), axis=-1) for e in exps], axis=-1)


@pytest.mark.parametrize("rule,n,deg", [("gauss-hermite", 2, 9), ("gauss-hermite", 3, 5), ("cubature5", 6, 5),
                                        ("cubature5", 3, 5)])
def test_rules_exact_on_polynomials(rule, n, deg):
    rng = np.random.default_rng(n)
    mean = rng.normal(size=(2, n))
    L = rng.normal(size=(2, n, n)) * 0.5
    cov = L @ np.swapaxes(L, -1, -2) + 0.2 * np.eye(n)
    exps = monomials(n, deg)
    got = expect_gaussian(lambda x: _monomial_values(x, exps), mean, cov, rule=rule, points=5)
    np.testing.assert_allclose(got, gaussian_moments(mean, cov, exps), rtol=1e-9, atol=1e-9)


def test_nonpolynomial_closed_forms():
    # E sin(x) = sin(m) e^{-P/2}, E exp(x) = e^{m + P/2}
    m, P = np.array([[0.3], [1.2]]), np.array([[[0.5]], [[2.0]]])
    got = expect_gaussian(lambda x: np.concatenate([np.sin(x), np.exp(x)], axis=-1), m, P, points=30)
    want = np.stack([np.sin(m[:, 0]) * np.exp(-P[:, 0, 0] / 2), np.exp(m[:, 0] + P[:, 0, 0] / 2)], axis=-1)
    np.testing.assert_allclose(got, want, rtol=1e-10)


def test_weights_and_errors():
    z, w = gauss_hermite_rule(2, 4)
    assert z.shape == (16, 2) and w.sum() == pytest.approx(1.0)
    z, w = cubature5_rule(4)
    assert z.shape == (2 * 16 + 1, 4) and w.sum() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="rule"):
        expect_gaussian(np.sin, np.zeros(1), np.eye(1), rule="simpson")
    with pytest.raises(ValueError, match="cov"):
        expect_gaussian(np.sin, np.zeros(2), np.eye(3))
