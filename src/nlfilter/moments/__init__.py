"""The moment engine: Itô rule on monomials, closures, exact closed systems, steady states.

* :mod:`.ito` — :class:`PolynomialSDE`, :func:`moment_equations` (sparse ``dμ/dt = A μ + B ν + c``),
  :func:`closed_hull`, discrete counterpart :func:`discrete_moment_equations`;
* :mod:`.closures` — :class:`GaussianClosure`, :class:`CumulantClosure` (cumulant neglect of order N),
  :class:`EdgeworthClosure` (Hermite quasi-moments, seed 003 eqs. 12-15, 28-33), n-dimensional;
* :mod:`.solve` — :func:`propagate` (solve_ivp), :func:`iterate` (discrete), :func:`steady_state`
  (direct sparse solve with E[1] = 1, Newton with a closure);
* :mod:`.quadrature` — Gauss-Hermite / cubature expectations under a Gaussian for non-polynomial
  models.
"""

from .closures import (CumulantClosure, EdgeworthClosure, GaussianClosure, closure_by_name,
                       gaussian_moments)
from .ito import (MomentEquations, PolynomialMap, PolynomialSDE, closed_hull, degree_order,
                  discrete_moment_equations, gaussian_noise_moments, is_closed, moment_equations)
from .quadrature import expect_gaussian, gauss_hermite_rule
from .solve import MomentSolution, iterate, propagate, steady_state
from ..polynomials import Polynomial, monomials

__all__ = ["PolynomialSDE", "PolynomialMap", "MomentEquations", "moment_equations",
           "discrete_moment_equations", "closed_hull", "is_closed", "degree_order",
           "gaussian_noise_moments", "GaussianClosure", "CumulantClosure", "EdgeworthClosure",
           "closure_by_name", "gaussian_moments", "propagate", "iterate", "steady_state",
           "MomentSolution", "expect_gaussian", "gauss_hermite_rule", "Polynomial", "monomials"]
