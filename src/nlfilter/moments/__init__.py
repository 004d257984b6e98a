"""The moment engine: Itô rule on monomials, closures, exact closed systems, steady states.

* :mod:`.ito` — :class:`PolynomialSDE` (Itô generator, noise coefficients), :func:`moment_equations`
  (sparse ``dμ/dt = A μ + B ν + c``);
* :mod:`.equations` — :class:`MomentEquations`, the sparse container both generators fill
  (coefficients depending on time or symbols evaluated by ``.at``);
* :mod:`.discrete` — the discrete counterpart: :class:`PolynomialMap`,
  :func:`discrete_moment_equations`, :func:`gaussian_noise_moments`;
* :mod:`.closed` — :func:`closed_hull`, :func:`is_closed`, :func:`bilinear_lift` (seed 001's
  tensor systems, from the noise columns);
* :mod:`.closures` — :class:`GaussianClosure`, :class:`CumulantClosure` (cumulant neglect of order N),
  :class:`EdgeworthClosure` (Hermite quasi-moments, seed 003 eqs. 12-15, 28-33), n-dimensional;
* :mod:`.solve` — :func:`propagate` (solve_ivp), :func:`iterate` (discrete), :func:`steady_state`
  (direct sparse solve with E[1] = 1, Newton with a closure);
* :mod:`.stationary` — :func:`linear_steady_state` (closed linear systems, rescaled, conservation
  laws imposed), :func:`stationary_moments` (monomial moments at rest);
* :mod:`.quadrature` — Gauss-Hermite / cubature expectations under a Gaussian for non-polynomial
  models;
* :mod:`.expect` — :class:`PolynomialExpectations`: E[p(x)] for many polynomials from kept moments
  plus a closure, compiled once (what the filters use per step).

Typical use (the moments of dx = −x³ dt + dβ, order 4, Edgeworth closure)::

    sde = PolynomialSDE.from_model(model)            # or PolynomialSDE(drift, diffusion) for any
    idx = monomials(1, 4, min_degree=1)              #   augmented polynomial state
    eq = moment_equations(sde, idx)                  # sparse A, B, c and eq.missing
    sol = propagate(eq, gaussian_moments(m0, P0, idx), t, closure=EdgeworthClosure(4))
    mu_inf = steady_state(eq, closure=EdgeworthClosure(4))
    # closed systems (eq.closed, e.g. bilinear ones): steady_state(eq) is one sparse LU solve
"""

from .closures import (CumulantClosure, EdgeworthClosure, GaussianClosure, closure_by_name,
                       gaussian_moments)
from .equations import MomentEquations, degree_order
from .ito import PolynomialSDE, moment_equations
from .discrete import PolynomialMap, discrete_moment_equations, gaussian_noise_moments
from .closed import bilinear_lift, closed_hull, is_closed
from .expect import PolynomialExpectations
from .quadrature import expect_gaussian, gauss_hermite_rule
from .solve import MomentSolution, iterate, propagate, steady_state
from .stationary import linear_steady_state, stationary_moments
from ..polynomials import Polynomial, monomials

__all__ = ["PolynomialSDE", "PolynomialMap", "MomentEquations", "moment_equations",
           "discrete_moment_equations", "closed_hull", "is_closed", "degree_order", "bilinear_lift",
           "linear_steady_state", "stationary_moments",
           "gaussian_noise_moments", "GaussianClosure", "CumulantClosure", "EdgeworthClosure",
           "closure_by_name", "gaussian_moments", "propagate", "iterate", "steady_state",
           "MomentSolution", "expect_gaussian", "gauss_hermite_rule", "Polynomial", "monomials",
           "PolynomialExpectations"]
