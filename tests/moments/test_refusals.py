"""Issue 15 items 3-4: the moment engine refuses what it cannot answer (no moments of a law that
does not exist; bounded work), each with a ValueError naming the argument, what was given and
what was expected. Every case runs in well under a second."""

import numpy as np
import pytest
import scipy.sparse as sps
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.errors import ClosureDivergedError, NoStationaryLawError, SingularSystemError
from nlfilter.filters.quasilinear import DiscreteQuasilinearFilter
from nlfilter.moments import (GaussianClosure, PolynomialSDE, discrete_moment_equations, monomials,
                              moment_equations, propagate, stationary_moments, steady_state)
from nlfilter.moments.closures import Closure, gaussian_moments
from nlfilter.moments.quadrature import (MAX_POINTS, cubature5_rule, expect_gaussian, gauss_hermite_rule,
                                         gaussian_rule)
from nlfilter.moments.stationary import moment_space_violation

x, y = sp.symbols("x y")


# -- no moments of a law that does not exist -----------------------------------------------------

def test_unstable_linear_drift_has_no_stationary_law():
    """dx = x dt + dβ: the issue's E[x²] = −0.5; now the mean's eigenvalue +1 is named."""
    eq = moment_equations(PolynomialSDE.from_sympy([x], [x], [[1.0]]), monomials(1, 2, min_degree=1))
    with pytest.raises(NoStationaryLawError, match=r"eqs: no stationary law: .*eigenvalue \+1 \(real part ≥ 0\) "
                                                   r"on E\[x1\] \(the drift's linear part\)"):
        steady_state(eq)
    with pytest.raises(ValueError):  # a ValueError, and what stationary_moments raises on the same system
        steady_state(eq)
    with pytest.raises(SingularSystemError, match="grow without bound"):
        stationary_moments(PolynomialSDE.from_sympy([x], [x], [[1.0]]), [(2,)])


def test_multiplicative_noise_fourth_moment_diverges():
    """dx = −x dt + x dw₁ + dw₂: E x² settles (rate −1) but E x⁴ grows (rate +2): the issue's E[x⁴] = −3."""
    sde = PolynomialSDE.from_sympy([x], [-x], G=[[x, 1]])
    assert steady_state(moment_equations(sde, monomials(1, 2, min_degree=1)))[1] == pytest.approx(1.0)
    with pytest.raises(NoStationaryLawError, match=r"eigenvalue \+2 \(real part ≥ 0\) on E\[x1\^4\]"):
        steady_state(moment_equations(sde, monomials(1, 4, min_degree=1)))


def test_unstable_2d_drift_and_constant_monomial():
    """A 2-D drift with eigenvalues 0.2 ± 0.95i (the issue's covariance with eigenvalue −0.77),
    with and without the constant monomial kept."""
    sde = PolynomialSDE.from_sympy([x, y], [0.5 * x + y, -x - 0.1 * y], [[1, 0], [0, 1]])
    for lo in (0, 1):
        with pytest.raises(NoStationaryLawError, match=r"eigenvalue 0\.2\+0\.9539j .* on E\[x1\], E\[x2\]"):
            steady_state(moment_equations(sde, monomials(2, 2, min_degree=lo)))


def test_discrete_unstable_map_has_no_stationary_law():
    """x[k+1] = 2x + w: the issue's −0.333; refused by the modulus of the map's eigenvalue."""
    eq = discrete_moment_equations(DiscreteModel([x], [2 * x], [x], Q=1.0, R=1.0), monomials(1, 2, min_degree=1))
    with pytest.raises(NoStationaryLawError, match=r"discrete moment equations have eigenvalue \+2 \(modulus ≥ 1\) "
                                                   r"on E\[x1\] \(the map's linear part\)"):
        steady_state(eq)
    stable = discrete_moment_equations(DiscreteModel([x], [0.5 * x], [x], Q=1.0, R=1.0), monomials(1, 2))
    np.testing.assert_allclose(steady_state(stable), [1.0, 0.0, 4 / 3], rtol=1e-12, atol=1e-15)


def test_conserved_modes_keep_their_diagnosis():
    """Brownian motion (zero eigenvalues, not growth) still gets the singular-system message."""
    eq = moment_equations(PolynomialSDE.from_sympy([x], [0 * x], [[1.0]]), [(1,), (2,)])
    with pytest.raises(SingularSystemError, match="grows linearly"):
        steady_state(eq)


class _Repelling(Closure):
    """For dx = −x³ dt + dβ: E x³ := −E x (so dE x/dt = +E x) and E x⁴ := E x² (so E x² = ½):
    a realizable fixed point (m = 0, E x² = E x⁴ = ½) that repels."""

    order = 2
    name = "repelling"

    def __call__(self, indices, values, wanted):
        values = np.asarray(values)
        return np.stack([-values[..., 0], values[..., 1]], axis=-1)

    def jacobian(self, indices, values, wanted, *, sparse=False):
        J = np.array([[-1.0, 0.0], [0.0, 1.0]])
        return sps.csr_matrix(J) if sparse else J


class _Unrealizable(Closure):
    """E x³ := E x − 2, E x⁴ := E x² − 2.5: the fixed point m = 2, E x² = 3 has variance −1."""

    order = 2
    name = "unrealizable"

    def __call__(self, indices, values, wanted):
        values = np.asarray(values)
        return np.stack([values[..., 0] - 2.0, values[..., 1] - 2.5], axis=-1)

    def jacobian(self, indices, values, wanted, *, sparse=False):
        J = np.eye(2)
        return sps.csr_matrix(J) if sparse else J


def test_closure_steady_state_must_attract_and_be_a_law():
    eq = moment_equations(PolynomialSDE.from_sympy([x], [-x**3], [[1.0]]), [(1,), (2,)])
    with pytest.raises(NoStationaryLawError, match=r"closure: the steady state of the repelling-closed moment "
                                                   r"equations is unstable \(eigenvalue \+1 .* of their Jacobian\)"):
        steady_state(eq, closure=_Repelling(), guess=[0.1, 0.4])
    with pytest.raises(NoStationaryLawError, match=r"closure: .* not the moments of any law: the variance of x1 is "
                                                   r"-1 < 0; the closure failed"):
        steady_state(eq, closure=_Unrealizable(), guess=[1.0, 2.0])
    with pytest.raises(ClosureDivergedError):  # what these cases raised before: still caught as such
        steady_state(eq, closure=_Unrealizable(), guess=[1.0, 2.0])
    good = steady_state(eq, closure=GaussianClosure())  # dx = −x³ dt + dβ, Gaussian: 6 (E x²)² = 1
    np.testing.assert_allclose(good, [0.0, 1 / np.sqrt(6)], atol=1e-12)


def test_moment_space_conditions():
    names = ["x1", "x2"]
    idx = monomials(1, 4, min_degree=1)
    assert moment_space_violation(idx, [0.0, 1.0, 0.0, 3.0], names) is None  # N(0, 1)
    assert "even moment E[x1^4] = -3 is negative" in moment_space_violation(idx, [0.0, 1.0, 0.0, -3.0], names)
    assert "Hankel matrix of the moments of x1" in moment_space_violation([(2,), (4,)], [1.0, 0.5], names)  # E x⁴ < (E x²)²
    assert "moment matrix" in moment_space_violation(idx, [0.0, 1.0, 0.0, 0.5], names)
    two = monomials(2, 2, min_degree=2)  # bilinear sets: no means, raw second moments
    assert moment_space_violation(two, [1.0, 0.5, 1.0], names) is None
    assert "second-moment matrix" in moment_space_violation(two, [1.0, 2.0, 1.0], names)
    assert "covariance" in moment_space_violation(monomials(2, 2, min_degree=1), [0, 0, 1.0, 2.0, 1.0], names)


# -- bounded work ---------------------------------------------------------------------------------

def test_gauss_hermite_refuses_what_it_cannot_compute():
    with pytest.raises(ValueError, match=r"points: expected at most 300 Gauss-Hermite nodes per axis .* got 400"):
        gauss_hermite_rule(1, 400)
    with pytest.raises(ValueError, match=r"points, n: points\*\*n = 10\*\*8: the rule would have 1e\+08 nodes"):
        gauss_hermite_rule(8, 10)
    with pytest.raises(ValueError, match=r"points, n: points\*\*n = 10\*\*8"):
        expect_gaussian(np.cos, np.zeros(8), np.eye(8), rule="gauss-hermite", points=10)
    with pytest.raises(ValueError, match=r"n: 2n² \+ 1 = 180001: the rule would have"):
        cubature5_rule(300)
    with pytest.raises(ValueError, match="points: expected a positive integer, got 0"):
        gaussian_rule(2, "cubature5", 0)
    z, w = gauss_hermite_rule(1, 120)  # well inside the limit: finite, positive, exact moments
    assert np.all(w > 0) and abs(w.sum() - 1) < 1e-12 and abs(w @ z[:, 0] ** 4 - 3) < 1e-11
    assert MAX_POINTS == 300


def test_gaussian_moments_refuses_a_negative_variance():
    with pytest.raises(ValueError, match=r"cov: expected a positive semi-definite matrix, got smallest eigenvalue -1"):
        gaussian_moments([0.0], [[-1.0]], [(2,)])
    with pytest.raises(ValueError, match="cov: expected a positive semi-definite"):
        gaussian_moments(np.zeros((3, 2)), np.broadcast_to([[1.0, 2.0], [2.0, 1.0]], (3, 2, 2)), [(1, 1)])
    with pytest.raises(ValueError, match="mean: expected finite values"):
        gaussian_moments([np.nan], [[1.0]], [(2,)])
    assert gaussian_moments([1.0], [[0.0]], [(2,)]).tolist() == [1.0]  # a point mass is a law


def test_from_sympy_refuses_a_negative_diffusion():
    with pytest.raises(ValueError, match=r"diffusion: expected σ = G Q Gᵀ positive semi-definite, got the constant "
                                         r"σ\[0\]\[0\] = -1 < 0"):
        PolynomialSDE.from_sympy([x], [-x], sigma=[[-1]])
    with pytest.raises(ValueError, match=r"diffusion: .* constant matrix \[\[1.0, 2.0\], \[2.0, 1.0\]\] with "
                                         r"eigenvalue -1 < 0"):
        PolynomialSDE.from_sympy([x, y], [-x, -y], sigma=[[1, 2], [2, 1]])
    with pytest.raises(ValueError, match=r"Q: expected a finite positive semi-definite noise covariance, got "
                                         r"\[\[-1.0\]\]"):
        PolynomialSDE.from_sympy([x], [-x], G=[[1]], Q=-1)
    # accepted: G of any sign, a state-dependent σ (Wright-Fisher x(1 − x) < 0 outside [0, 1]), symbols
    assert PolynomialSDE.from_sympy([x], [-x], G=[[-2]]).diffusion[0][0].terms == {(0,): 4.0}
    PolynomialSDE.from_sympy([x], [0.5 - x], sigma=[[x * (1 - x)]])
    PolynomialSDE.from_sympy([x], [-x], sigma=[[sp.Symbol("q")]])


def test_propagate_refuses_non_finite_times():
    eq = moment_equations(PolynomialSDE.from_sympy([x], [-x], [[1.0]]), [(1,), (2,)])
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match=r"t0: expected a finite start time, got"):
            propagate(eq, [1.0, 1.0], [0.0, 1.0], t0=bad)
    with pytest.raises(ValueError, match=r"t_eval: expected finite values"):
        propagate(eq, [1.0, 1.0], [0.0, np.nan])
    with pytest.raises(ValueError, match=r"t0: expected a start time ≤ t_eval\[0\] = 0, got 0.5"):
        propagate(eq, [1.0, 1.0], [0.0, 1.0], t0=0.5)
    sol = propagate(eq, [1.0, 1.0], [0.5, 1.0], t0=0.0)  # a finite t0 before t_eval is fine
    assert sol.values[-1, 0] == pytest.approx(np.exp(-1.0), rel=1e-7)


def test_error_analysis_refuses_huge_orders_up_front():
    f = DiscreteQuasilinearFilter(DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x], Q=0.1, R=0.5))
    with pytest.raises(ValueError, match=r"order: expected an order whose joint moment system .* at most 120 "
                                         r"moments, got order=30 with 495"):
        f.error_analysis([2.0], [[0.2]], 5, order=30)
    with pytest.raises(ValueError, match=r"got order=15 with 135"):
        f.error_analysis([2.0], [[0.2]], 5, order=15)
