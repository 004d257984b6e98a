"""Sparse multivariate polynomials: ``{exponent tuple: coefficient}``.

The moment engine (:mod:`nlfilter.moments`) works on polynomials in the state ``x ∈ Rⁿ`` stored as
a dict from multi-indices ``γ = (γ_1, …, γ_n)`` to coefficients. A coefficient is a float, or a
SymPy expression in the *coefficient symbols* (the time symbol of a model, or any parameter
left symbolic, e.g. the tabulated gains of a filter whose error is analysed off-line); the
moment equations keep such coefficients apart and evaluate them numerically (see
:class:`nlfilter.moments.equations.MomentEquations`).

Numbers are stored as floats, unless the polynomial is *exact* (``exact=True``): then every
coefficient is a SymPy expression, numbers stay rational and coefficients are expanded, so that
generated systems can be compared entry by entry with hand-derived symbolic ones (seed 001,
Appendices A-B). Exactness propagates through arithmetic.

>>> import sympy as sp
>>> x, y = sp.symbols("x y")
>>> p = Polynomial.from_sympy(x**2 * y - 3 * x + 1, [x, y])
>>> sorted(p.terms.items())
[((0, 0), 1.0), ((1, 0), -3.0), ((2, 1), 1.0)]
>>> p.diff(0).to_sympy([x, y])
2.0*x*y - 3.0
>>> float(p.expect({(0, 0): 1.0, (1, 0): 2.0, (2, 1): 5.0}))
0.0
"""

from __future__ import annotations

import numbers
from typing import Mapping

import numpy as np
import sympy as sp

from .errors import NotPolynomialError

__all__ = ["Polynomial", "monomials", "monomial_name", "as_polynomial", "add_exp", "sub_exp", "unit_exp"]


def add_exp(a: tuple, b: tuple) -> tuple:
    return tuple(i + j for i, j in zip(a, b))


def sub_exp(a: tuple, b: tuple) -> tuple:
    return tuple(i - j for i, j in zip(a, b))


def unit_exp(n: int, i: int, k: int = 1) -> tuple:
    """The exponent tuple of ``x_i^k`` among ``n`` variables: ``(0, .., k, .., 0)``.

    >>> unit_exp(3, 1, 2)
    (0, 2, 0)
    """
    e = [0] * n
    e[i] = k
    return tuple(e)


def _clean(c):
    """A coefficient as float when it is a number, else the SymPy expression."""
    if isinstance(c, numbers.Number) and not isinstance(c, bool):
        return float(c)
    c = sp.sympify(c)
    if c.is_number:
        return float(c)
    return c


def _is_zero(c) -> bool:
    return (isinstance(c, float) and c == 0.0) or (not isinstance(c, float) and c == 0)


def monomial_name(e: tuple, names) -> str:
    """``x^γ`` written with variable ``names``, e.g. ``x*y^2`` (``1`` for the constant)."""
    parts = [n if a == 1 else f"{n}^{a}" for n, a in zip(names, e) if a]
    return "*".join(parts) or "1"


class Polynomial:
    """A polynomial in ``nvars`` variables, ``terms = {γ: coefficient}`` (immutable by convention).

    Coefficients are floats or SymPy expressions in symbols other than the state (time, gains);
    with ``exact=True`` all are SymPy (rational numbers kept, see the module docstring).
    Arithmetic: ``+``, ``-``, ``*`` (with polynomials or scalars), ``**`` (non-negative int).
    """

    __slots__ = ("nvars", "terms", "exact")

    def __init__(self, terms: Mapping[tuple, object] | None = None, nvars: int | None = None, *,
                 exact: bool = False):
        terms = dict(terms or {})
        if nvars is None:
            if not terms:
                raise ValueError("nvars: expected the number of variables for an empty polynomial, got None")
            nvars = len(next(iter(terms)))
        out = {}
        for e, c in terms.items():
            e = tuple(int(i) for i in e)
            if len(e) != nvars or min(e, default=0) < 0:
                raise ValueError(f"terms: exponent {e} is not a multi-index of length {nvars} "
                                 "with non-negative entries")
            c = sp.expand(sp.sympify(c)) if exact else _clean(c)
            if not _is_zero(c):
                out[e] = c
        self.nvars = int(nvars)
        self.terms = out
        self.exact = bool(exact)

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def constant(cls, c, nvars: int, *, exact: bool = False) -> "Polynomial":
        return cls({(0,) * nvars: c}, nvars, exact=exact)

    @classmethod
    def variable(cls, i: int, nvars: int, *, exact: bool = False) -> "Polynomial":
        e = [0] * nvars
        e[i] = 1
        return cls({tuple(e): 1}, nvars, exact=exact)

    @classmethod
    def from_sympy(cls, expr, states, *, name: str = "expression", numeric: bool = False,
                   exact: bool = False) -> "Polynomial":
        """Convert a SymPy expression, polynomial in ``states`` (coefficients may contain other
        symbols such as time). Raises :class:`~nlfilter.errors.NotPolynomialError` naming the
        offending term otherwise. ``numeric``: require number coefficients (``ValueError``
        naming the free symbols otherwise); ``exact``: keep SymPy coefficients (see the module
        docstring)."""
        states = list(states)
        expr = sp.expand(sp.sympify(expr))
        if not expr.is_polynomial(*states):
            bad = [t for t in sp.Add.make_args(expr) if not t.is_polynomial(*states)]
            raise NotPolynomialError(
                f"{name}: term {bad[0] if bad else expr} is not polynomial in the state "
                f"{[str(s) for s in states]}; an exact moment method needs polynomial f, GQGᵀ and h "
                "(use Gauss-Hermite expectations, nlfilter.moments.quadrature, for this model)")
        poly = sp.Poly(expr, *states)
        for _, c in poly.terms():
            if c.has(sp.I, sp.zoo, sp.oo, sp.S.NegativeInfinity, sp.nan):
                raise ValueError(f"{name}: coefficient {c} of {expr} is not real/finite; expected real, finite "
                                 "coefficients")
        if numeric:
            for _, c in poly.terms():
                if c.free_symbols:
                    raise ValueError(f"{name}: coefficient {c} of {expr} has free symbols "
                                     f"{sorted(map(str, c.free_symbols))}; expected numbers (give their values)")
        return cls({e: c for e, c in poly.terms()}, len(states), exact=exact)

    # -- algebra --------------------------------------------------------------------------
    def _coerce(self, other) -> "Polynomial":
        if isinstance(other, Polynomial):
            if other.nvars != self.nvars:
                raise ValueError(f"other: polynomial in {other.nvars} variables, expected {self.nvars}")
            return other
        return Polynomial.constant(other, self.nvars, exact=self.exact)

    def __add__(self, other):
        other = self._coerce(other)
        t = dict(self.terms)
        for e, c in other.terms.items():
            t[e] = t[e] + c if e in t else c
        return Polynomial(t, self.nvars, exact=self.exact or other.exact)

    __radd__ = __add__

    def __neg__(self):
        return Polynomial({e: -c for e, c in self.terms.items()}, self.nvars, exact=self.exact)

    def __sub__(self, other):
        return self + (-self._coerce(other))

    def __rsub__(self, other):
        return self._coerce(other) - self

    def __mul__(self, other):
        other = self._coerce(other)
        t: dict = {}
        for e1, c1 in self.terms.items():
            for e2, c2 in other.terms.items():
                e = add_exp(e1, e2)
                c = c1 * c2
                t[e] = t[e] + c if e in t else c
        return Polynomial(t, self.nvars, exact=self.exact or other.exact)

    __rmul__ = __mul__

    def __pow__(self, k: int):
        if not isinstance(k, numbers.Integral) or k < 0:
            raise ValueError(f"k: expected a non-negative integer power, got {k!r}")
        out = Polynomial.constant(1, self.nvars, exact=self.exact)
        base = self
        while k:
            if k & 1:
                out = out * base
            base = base * base
            k >>= 1
        return out

    def __eq__(self, other):
        if not isinstance(other, Polynomial):
            return NotImplemented
        return self.nvars == other.nvars and (self - other).terms == {}

    def __repr__(self):
        return f"Polynomial({self.terms!r}, nvars={self.nvars})"

    def diff(self, i: int) -> "Polynomial":
        """∂/∂x_i."""
        t = {}
        for e, c in self.terms.items():
            if e[i]:
                d = list(e)
                d[i] -= 1
                t[tuple(d)] = c * e[i]
        return Polynomial(t, self.nvars, exact=self.exact)

    def clean(self, tol: float = 0.0) -> "Polynomial":
        """Without the number coefficients of modulus ``<= tol`` (symbolic ones are kept)."""
        return Polynomial({e: c for e, c in self.terms.items() if not (isinstance(c, float) and abs(c) <= tol)},
                          self.nvars, exact=self.exact)

    def pad(self, nvars: int) -> "Polynomial":
        """The same polynomial in ``nvars >= self.nvars`` variables (the new ones last)."""
        if nvars < self.nvars:
            raise ValueError(f"nvars: expected at least {self.nvars}, got {nvars}")
        z = (0,) * (nvars - self.nvars)
        return Polynomial({e + z: c for e, c in self.terms.items()}, nvars, exact=self.exact)

    # -- inspection -----------------------------------------------------------------------
    @property
    def degree(self) -> int:
        return max((sum(e) for e in self.terms), default=0)

    def weighted_degree(self, weights) -> float:
        return max((sum(w * i for w, i in zip(weights, e)) for e in self.terms), default=0)

    @property
    def is_numeric(self) -> bool:
        """True when every coefficient is a number (no time or gain symbols)."""
        return all(isinstance(c, float) for c in self.terms.values())

    @property
    def symbols(self) -> set:
        s = set()
        for c in self.terms.values():
            if not isinstance(c, float):
                s |= c.free_symbols
        return s

    def subs(self, values: Mapping) -> "Polynomial":
        """Substitute numbers for coefficient symbols (``{symbol: value}``)."""
        return Polynomial({e: (c if isinstance(c, float) else c.subs(values)) for e, c in self.terms.items()},
                          self.nvars, exact=self.exact)

    def to_sympy(self, states):
        states = list(states)
        return sp.Add(*[sp.sympify(c) * sp.Mul(*[s ** k for s, k in zip(states, e)])
                        for e, c in self.terms.items()]) if self.terms else sp.Integer(0)

    # -- numbers --------------------------------------------------------------------------
    def __call__(self, x) -> np.ndarray:
        """Evaluate at a batch ``x (..., nvars)`` (numeric coefficients only)."""
        if not self.is_numeric:
            raise ValueError(f"polynomial: has symbolic coefficients {sorted(map(str, self.symbols))}; "
                             "substitute them with .subs() first")
        x = np.asarray(x)
        out = np.zeros(x.shape[:-1], dtype=np.result_type(x, float))
        for e, c in self.terms.items():
            term = c
            for i, k in enumerate(e):
                if k:
                    term = term * x[..., i] ** k
            out = out + term
        return out

    def expect(self, moments) -> np.ndarray:
        """E[p(x)] = Σ_γ c_γ E[x^γ] from raw moments: a mapping ``{γ: value}`` or a callable
        ``moments(γ)`` (values may be batched arrays)."""
        get = moments if callable(moments) else moments.__getitem__
        if not self.is_numeric:
            raise ValueError(f"polynomial: has symbolic coefficients {sorted(map(str, self.symbols))}; "
                             "substitute them with .subs() first")
        total = 0.0
        for e, c in self.terms.items():
            total = total + c * get(e)
        return total


def as_polynomial(value, nvars: int, *, states=None, name: str = "polynomial") -> Polynomial:
    """Accept a :class:`Polynomial`, a dict ``{γ: c}``, a number, or a SymPy expression in
    ``states``."""
    if isinstance(value, Polynomial):
        if value.nvars != nvars:
            raise ValueError(f"{name}: polynomial in {value.nvars} variables, expected {nvars}")
        return value
    if isinstance(value, Mapping):
        return Polynomial(value, nvars)
    if isinstance(value, numbers.Number):
        return Polynomial.constant(value, nvars)
    if isinstance(value, sp.Basic):
        if states is None:
            raise TypeError(f"{name}: a SymPy expression needs the state symbols (states=...)")
        return Polynomial.from_sympy(value, states, name=name)
    raise TypeError(f"{name}: expected a Polynomial, a dict {{exponent: coefficient}}, a number or a "
                    f"SymPy expression, got {type(value).__name__}")


def monomials(n: int, max_degree: int, *, min_degree: int = 0, weights=None) -> list[tuple]:
    """All multi-indices γ ∈ Nⁿ with ``min_degree ≤ Σ w_i γ_i ≤ max_degree`` (weights default 1),
    ordered by (weighted) degree, then reverse-lexicographically (x_1 first).

    >>> monomials(2, 2)
    [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]
    >>> len(monomials(6, 6, min_degree=1))
    923
    """
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
        raise ValueError(f"n: expected a positive integer, got {n!r}")
    if isinstance(max_degree, bool) or not isinstance(max_degree, numbers.Integral) or max_degree < 0:
        raise ValueError(f"max_degree: expected a non-negative integer, got {max_degree!r}")
    w = [1] * n if weights is None else list(weights)
    if len(w) != n or any(not (wi > 0) for wi in w):
        raise ValueError(f"weights: expected {n} positive numbers, got {weights!r}")
    out = []

    def rec(prefix, i, used):
        if i == n:
            out.append(tuple(prefix))
            return
        k = 0
        while used + k * w[i] <= max_degree + 1e-12:
            rec(prefix + [k], i + 1, used + k * w[i])
            k += 1

    rec([], 0, 0)
    out = [e for e in out if sum(a * b for a, b in zip(w, e)) >= min_degree - 1e-12]
    out.sort(key=lambda e: (sum(a * b for a, b in zip(w, e)), tuple(-i for i in e)))
    return out
