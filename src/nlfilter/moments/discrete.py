"""Moment equations in discrete time: polynomial maps with independent noise.

For ``x[k+1] = f(x[k]) + G(x[k]) w[k]`` with polynomial ``f``, ``G`` and noise ``w`` independent
of ``x`` with known moments, every monomial obeys ``E[x_{k+1}^γ] = E[(f + G w)^γ]``: expanding the
power and taking the noise moments gives ``μ[k+1] = A μ[k] + B ν[k] + c``, the discrete counterpart
of :func:`nlfilter.moments.ito.moment_equations`.

* :class:`PolynomialMap` — ``f``, ``G`` and ``noise_moment(β) -> E[w^β]`` (``from_model`` for a
  :class:`~nlfilter.models.DiscreteModel` stated in SymPy, Gaussian noise by default);
* :func:`gaussian_noise_moments` — ``β -> E[w^β]`` for a Gaussian ``w`` (Isserlis recursion);
* :func:`discrete_moment_equations` — the :class:`~nlfilter.moments.equations.MomentEquations`
  (``kind="discrete"``) of a set of monomials.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..polynomials import Polynomial, as_polynomial
from .equations import MomentEquations, _assemble, _check_indices, _Groups, _symbols_for

__all__ = ["PolynomialMap", "discrete_moment_equations", "gaussian_noise_moments"]


@dataclass(frozen=True)
class PolynomialMap:
    """Discrete polynomial dynamics ``x[k+1] = f(x[k]) + G(x[k]) w[k]``: ``f`` (n polynomials),
    ``G`` (n x r polynomials), ``noise_moment(β) -> E[w^β]`` (a callable on r-multi-indices)."""

    f: tuple
    G: tuple
    noise_moment: Callable
    time: object = None
    states: tuple | None = None

    def __post_init__(self):
        n = len(self.f)
        f = tuple(as_polynomial(p, n, name=f"f[{i}]") for i, p in enumerate(self.f))
        if len(self.G) != n:
            raise ValueError(f"G: expected {n} rows, got {len(self.G)}")
        r = len(self.G[0])
        G = tuple(tuple(as_polynomial(p, n, name=f"G[{i}][{a}]") for a, p in enumerate(row)) for i, row in
                  enumerate(self.G))
        if any(len(row) != r for row in G):
            raise ValueError("G: rows of different lengths")
        if not callable(self.noise_moment):
            raise TypeError(f"noise_moment: expected a callable β -> E[w^β], got {type(self.noise_moment).__name__}")
        object.__setattr__(self, "f", f)
        object.__setattr__(self, "G", G)

    @property
    def n(self) -> int:
        return len(self.f)

    @property
    def r(self) -> int:
        return len(self.G[0])

    @classmethod
    def from_model(cls, model, noise_moment: Callable | None = None) -> "PolynomialMap":
        """From a :class:`~nlfilter.models.DiscreteModel` in SymPy; the noise moments default to
        those of a zero-mean Gaussian with covariance ``model.Q``."""
        if getattr(model, "sym", None) is None:
            raise TypeError("model: the moment engine needs a model stated in SymPy (model.sym)")
        st = model.states
        f = [Polynomial.from_sympy(e, st, name=f"f[{i}]") for i, e in enumerate(model.sym["f"])]
        GM = model.sym["G"]
        G = [[Polynomial.from_sympy(GM[i, a], st, name=f"G[{i},{a}]") for a in range(GM.shape[1])]
             for i in range(GM.shape[0])]
        nm = noise_moment or gaussian_noise_moments(model.Q)
        return cls(tuple(f), tuple(map(tuple, G)), nm, time=model.time, states=tuple(st))


def gaussian_noise_moments(cov, mean=None) -> Callable:
    """``β -> E[w^β]`` for ``w ~ N(mean, cov)`` (Isserlis recursion, memoized).

    >>> m = gaussian_noise_moments([[2.0]])
    >>> [m((k,)) for k in range(5)]
    [1.0, 0.0, 2.0, 0.0, 12.0]
    """
    cov = np.atleast_2d(np.asarray(cov, dtype=float))
    r = cov.shape[0]
    mu = np.zeros(r) if mean is None else np.asarray(mean, dtype=float)
    memo: dict = {(0,) * r: 1.0}

    def mom(beta):
        beta = tuple(beta)
        if beta in memo:
            return memo[beta]
        i = next(k for k, b in enumerate(beta) if b)
        rest = list(beta)
        rest[i] -= 1
        rest = tuple(rest)
        val = mu[i] * mom(rest)
        for j in range(r):
            if rest[j]:
                low = list(rest)
                low[j] -= 1
                val += cov[i, j] * rest[j] * mom(tuple(low))
        memo[beta] = float(val)
        return memo[beta]

    return mom


def discrete_moment_equations(pmap: PolynomialMap, indices: Sequence[tuple]) -> MomentEquations:
    """``μ[k+1] = A μ[k] + B ν[k] + c`` from ``E[x_{k+1}^γ] = E[(f(x) + G(x) w)^γ]`` with the
    noise moments of ``pmap`` (w independent of x). Accepts a :class:`PolynomialMap` or a
    :class:`~nlfilter.models.DiscreteModel` (Gaussian noise)."""
    if not isinstance(pmap, PolynomialMap):
        if getattr(pmap, "kind", None) == "discrete":
            pmap = PolynomialMap.from_model(pmap)
        else:
            raise TypeError(f"pmap: expected a PolynomialMap or a DiscreteModel, got {type(pmap).__name__}")
    n, r = pmap.n, pmap.r
    indices = _check_indices(indices, n)
    N = n + r
    comps = []
    for i in range(n):
        p = pmap.f[i].pad(N)
        for a in range(r):
            p = p + pmap.G[i][a].pad(N) * Polynomial.variable(n + a, N)
        comps.append(p)
    powers = [{0: Polynomial.constant(1.0, N)} for _ in range(n)]

    def power(i, k):
        if k not in powers[i]:
            powers[i][k] = power(i, k - 1) * comps[i]
        return powers[i][k]

    groups = _Groups()
    rows = []
    for g in indices:
        prod = Polynomial.constant(1.0, N)
        for i in range(n):
            if g[i]:
                prod = prod * power(i, g[i])
        terms: dict = {}
        for e, c in prod.terms.items():
            wm = pmap.noise_moment(e[n:]) if any(e[n:]) else 1.0
            if wm == 0:
                continue
            for gid, w in groups.split(c):
                key = (e[:n], gid)
                terms[key] = terms.get(key, 0.0) + w * wm
        rows.append(terms)
    symbols = _symbols_for(pmap.time, groups)
    return _assemble(indices, rows, groups, symbols, "discrete", pmap.time)
