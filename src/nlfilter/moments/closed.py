"""Closed monomial sets: the closed hull, the closedness test, the bilinear (tensor) lift.

A set of monomials is *closed* when the Itô generator ``L`` maps its span (with the constant) into
itself: its moment equations have no missing moments and are exact (bilinear systems with all
monomials of one degree, a linear SDE with all monomials up to a degree …).

Closed under the noise coefficients too (seed 001 eqs. 2.16, 3.13, Appendices A-B), the vector
``x_[p]`` of the monomials obeys the bilinear equation ``d x_[p] = A x_[p] dt + Σ_a B_a x_[p] dβ_a``;
SymPy coefficients (``exact=True``) reproduce the thesis' symbolic appendices entry by entry.

* :func:`closed_hull` — the smallest closed set containing given monomials (optionally closed
  under the noise coefficients :meth:`~nlfilter.moments.ito.PolynomialSDE.noise_terms` too);
* :func:`is_closed` — whether a set is closed under the generator;
* :func:`bilinear_lift` — ``(A, [B_a])`` of a closed monomial set, from an SDE that keeps its
  noise columns G (seed 001 eq. 3.13).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import sympy as sp

from ..errors import MomentsNotClosedError
from ..polynomials import monomial_name
from .equations import _check_indices, degree_order
from .ito import PolynomialSDE, as_polynomial_sde, moment_equations

__all__ = ["closed_hull", "is_closed", "bilinear_lift"]


def closed_hull(sde, start: Sequence[tuple], *, max_size: int = 20000, with_noise: bool = False) -> list[tuple]:
    """The smallest set of monomials containing ``start`` and closed under the generator (and,
    if ``with_noise``, under the noise coefficients :meth:`PolynomialSDE.noise_terms` too, as the
    bilinear lift ``x_[p]`` of seed 001 eq. 3.13 needs). The constant monomial is not added: it
    enters through ``c``. Raises :class:`~nlfilter.errors.MomentsNotClosedError` (a
    ``ValueError``) when the set grows past ``max_size`` (the hierarchy does not close, e.g. a
    cubic drift).

    >>> import sympy as sp
    >>> x, y = sp.symbols("x y")
    >>> sde = PolynomialSDE.from_sympy([x, y], f=[-x, x - y], sigma=[[1, 0], [0, 0]])
    >>> closed_hull(sde, [(1, 1)])
    [(2, 0), (1, 1)]
    """
    sde = as_polynomial_sde(sde)
    n = sde.n
    todo = list(_check_indices(start, n))
    seen = set(todo)
    zero = (0,) * n
    while todo:
        g = todo.pop()
        nxt = list(sde.generator(g).terms)
        if with_noise:
            for p in sde.noise_terms(g):
                nxt.extend(p.terms)
        for e in nxt:
            if e != zero and e not in seen:
                seen.add(e)
                todo.append(e)
                if len(seen) > max_size:
                    raise MomentsNotClosedError(
                        f"start: the moment hierarchy from {list(start)[:3]} does not close within "
                        f"max_size={max_size} monomials (reached {monomial_name(e, sde.names)}, degree {sum(e)})")
    return sorted(seen, key=degree_order)


def bilinear_lift(sde: PolynomialSDE, indices: Sequence[tuple]):
    """The bilinear system ``d z = A z dt + Σ_a B_a z dβ_a`` of ``z`` = the monomials ``indices``
    (001 eqs. 3.13, A.2; the constant monomial may be included, e.g. last, as in 001
    Appendices A-B). Rows: the generator ``L x^γ`` and the noise coefficients of ``d x^γ``.

    Returns dense ``(A, [B_a])``: NumPy, or SymPy when a coefficient is symbolic or exact.
    Raises :class:`~nlfilter.errors.MomentsNotClosedError` if the set is not closed under both.

    >>> x = sp.Symbol("x")
    >>> sde = PolynomialSDE.from_sympy([x], [-x], G=[[1]], Q=2.0)     # dx = -x dt + dw, E dw² = 2 dt
    >>> A, (B,) = bilinear_lift(sde, [(1,), (2,), (0,)])            # z = (x, x², 1)
    >>> A.tolist(), B.tolist()
    ([[-1.0, 0.0, 0.0], [0.0, -2.0, 2.0], [0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0], [2.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    """
    if not isinstance(sde, PolynomialSDE):
        raise TypeError(f"sde: expected a PolynomialSDE with its noise columns, got {type(sde).__name__}")
    mons = _check_indices(indices, sde.n)
    idx = {m: k for k, m in enumerate(mons)}
    N = len(mons)
    sym = not sde.is_numeric
    A = sp.zeros(N, N) if sym else np.zeros((N, N))
    Bs = [sp.zeros(N, N) if sym else np.zeros((N, N)) for _ in range(sde.r)]
    for k, m in enumerate(mons):
        for e, c in sde.generator(m).terms.items():
            if e not in idx:
                raise MomentsNotClosedError(f"indices: L({monomial_name(m, sde.names)}) has "
                                            f"{monomial_name(e, sde.names)}, not in the monomial set")
            A[k, idx[e]] += c
        for a, p in enumerate(sde.noise_terms(m)):
            for e, c in p.terms.items():
                if e not in idx:
                    raise MomentsNotClosedError(f"indices: noise {a} of {monomial_name(m, sde.names)} "
                                                f"has {monomial_name(e, sde.names)}, not in the monomial set")
                Bs[a][k, idx[e]] += c
    return A, Bs


def is_closed(sde, indices: Sequence[tuple]) -> bool:
    """True when the generator maps span{x^γ : γ ∈ indices} ∪ {1} into itself."""
    return moment_equations(sde, indices).closed
