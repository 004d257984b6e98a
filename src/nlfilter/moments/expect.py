"""Expectations of polynomials from kept moments (plus a closure for the others), batched.

``E[p(x)] = Σ_γ c_γ E[x^γ]``: a fixed linear map of the moment vector
``z = [E 1, E x^γ (kept), E x^β (completed by the closure)]``. :class:`PolynomialExpectations`
compiles that map once for a list of polynomials, so filters evaluate ``E[f]``, ``E[f xᵀ]``,
``E[h]``, ``E[x^γ h]``, ``E[GQGᵀ]`` ... in one closure call and one matrix product per step.

>>> import numpy as np
>>> from nlfilter.polynomials import Polynomial, monomials
>>> from nlfilter.moments import GaussianClosure
>>> cube = Polynomial({(3,): -1.0})
>>> pe = PolynomialExpectations(monomials(1, 2, min_degree=1), [cube], GaussianClosure())
>>> pe(np.array([2.0, 5.0])).tolist()      # −E x³ for N(2, 1): −(8 + 3·2·1)
[-14.0]
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..polynomials import Polynomial
from .closures import Closure
from .equations import degree_order

__all__ = ["PolynomialExpectations", "statistical_linearization_polys"]


class PolynomialExpectations:
    """``E[p_i(x)]`` for polynomials ``polys`` from the kept raw moments ``indices`` (batched
    ``mu (..., K)`` -> ``(..., len(polys))``); monomials outside ``indices`` come from ``closure``
    (required only if there are such monomials)."""

    def __init__(self, indices: Sequence[tuple], polys: Sequence[Polynomial], closure: Closure | None = None):
        self.indices = [tuple(g) for g in indices]
        n = len(self.indices[0])
        zero = (0,) * n
        index = {g: i for i, g in enumerate(self.indices)}
        extra = set()
        for p in polys:
            if not p.is_numeric:
                raise ValueError(f"polys: coefficients must be numbers, got symbols {sorted(map(str, p.symbols))}")
            for e in p.terms:
                if e not in index and e != zero:
                    extra.add(e)
        self.extra = sorted(extra, key=degree_order)
        if self.extra and closure is None:
            raise ValueError(f"closure: moments {self.extra[:3]} are not kept; expected a closure, got None")
        self.closure = closure
        pos = {zero: 0}
        pos.update({g: 1 + i for i, g in enumerate(self.indices)})
        pos.update({g: 1 + len(self.indices) + i for i, g in enumerate(self.extra)})
        if zero in index:  # E[1] kept: read it there
            pos[zero] = 1 + index[zero]
        M = np.zeros((len(polys), 1 + len(self.indices) + len(self.extra)))
        for i, p in enumerate(polys):
            for e, c in p.terms.items():
                M[i, pos[e]] += c
        self.M = M

    def z(self, mu) -> np.ndarray:
        """``[1, μ, closure(μ)]`` along the last axis."""
        mu = np.asarray(mu)
        parts = [np.ones((*mu.shape[:-1], 1), dtype=mu.dtype), mu]
        if self.extra:
            parts.append(self.closure(self.indices, mu, self.extra))
        return np.concatenate(parts, axis=-1)

    def __call__(self, mu) -> np.ndarray:
        return self.z(mu) @ self.M.T


def statistical_linearization_polys(polys: Sequence[Polynomial], n: int) -> list[Polynomial]:
    """``[p_1, …, p_k, p_1 x_1, …, p_1 x_n, …, p_k x_n]``: what 003 eqs. 4-5 need."""
    xs = [Polynomial.variable(j, n) for j in range(n)]
    return list(polys) + [p * x for p in polys for x in xs]
