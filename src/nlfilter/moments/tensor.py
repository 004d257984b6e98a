"""Tensor (monomial) moment systems of polynomial Itô SDEs, and their exact steady states.

Seed 001 (Vallot 1981) §3.1 and Appendices A-B write, by hand, the bilinear equation satisfied by
the vector ``x_[p]`` of all monomials of a bilinear process up to order ``p``::

    d x_[p] = A x_[p] dt + Σ_i B_i x_[p] dw_i                                   (001 eq. 3.13, A.2)

and propagate its moments. This module generates ``A`` and ``B_i`` from the Itô rule (001 eq. 2.16)
for any polynomial SDE whose monomial set closes, and solves for the moments' steady state directly.

Polynomials are dicts ``{exponent tuple: coefficient}``. Coefficients may be floats (numerics) or
SymPy expressions (to compare generated systems with the thesis' symbolic appendices); only
``+`` and ``*`` are used on them.

The Itô rule on a monomial ``x^α`` of ``dx = f dt + G dβ``, ``E dβ dβᵀ = Q dt``::

    d x^α = (Σ_i f_i ∂_i x^α + ½ Σ_ij (G Q Gᵀ)_ij ∂_i ∂_j x^α) dt + Σ_a (Σ_i G_ia ∂_i x^α) dβ_a

The drift part is the generator ``L x^α`` (row of ``A``), the bracket of ``dβ_a`` the row of ``B_a``.

Steady state. ``d/dt E[m] = Σ_m' A_mm' E[m'] + b_m`` (``b`` = coefficient of the constant monomial).
When the dynamics conserve quantities (on the circle ``x1² + x2² = 1``, so every ``E[|x|^{2k}]`` is
constant), ``A`` is singular and a least-squares or sparse solver may return a finite but wrong
answer. :func:`steady_state` checks the rank, identifies the conserved functionals (the left null
vectors ``ℓ`` of ``A``: ``d/dt ℓᵀμ = ℓᵀ b = 0``), fixes them from the initial moments, and raises
:class:`~nlfilter.errors.SingularSystemError` when the steady state is not unique.

Built on the moment engine (:mod:`nlfilter.moments.ito`): the generator ``L x^α``, the closed
hull and the moment equations ``(A, c)`` are the engine's. This module adds what the tensor
methods of seed 001 need beyond it: the *noise* coefficients of ``d x^α`` (the ``B_i`` of the
bilinear lift, which the engine's ``σ = G Q Gᵀ`` form does not keep), closure under them, and a
steady-state solve that scales the moments, finds conserved functionals, imposes them and checks
uniqueness (candidates to move into ``nlfilter.moments.solve``).

>>> sde = PolySDE.from_sympy(*_ou_example())     # dx = -x dt + dw, E dw² = 2 dt
>>> ms = moment_system(sde, closed_set(sde, [(2,)]))
>>> ms.monomials, steady_state(ms).tolist()      # E[x²] = 1
([(2,)], [1.0])
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations_with_replacement
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sps
import sympy as sp

from ..errors import NLFilterError, NotPolynomialError
from .solve import gaussian_scale, linear_steady_state

Monomial = tuple
Poly = dict


class MomentsNotClosedError(NLFilterError, ValueError):
    """The monomials reachable from the requested ones by the Itô generator exceed the size cap:
    the moment hierarchy does not close (a drift of degree > 1 raises the degree)."""


# ----------------------------------------------------------------------------- polynomials
def poly_add(p: Poly, q: Poly, c=1) -> Poly:
    out = dict(p)
    for e, v in q.items():
        out[e] = out.get(e, 0) + c * v
    return out


def poly_mul(p: Poly, q: Poly) -> Poly:
    out: Poly = {}
    for e1, v1 in p.items():
        for e2, v2 in q.items():
            e = tuple(a + b for a, b in zip(e1, e2))
            out[e] = out.get(e, 0) + v1 * v2
    return out


def poly_pow(p: Poly, k: int, n: int) -> Poly:
    out: Poly = {(0,) * n: 1}
    for _ in range(k):
        out = poly_mul(out, p)
    return out


def poly_clean(p: Poly, tol: float = 0.0) -> Poly:
    """Drop zero coefficients (exact zeros for SymPy, ``|c| <= tol`` for floats)."""
    out = {}
    for e, v in p.items():
        if isinstance(v, sp.Basic):
            v = sp.expand(v)
            if v == 0:
                continue
        elif abs(v) <= tol:
            continue
        out[e] = v
    return out


def poly_from_sympy(expr, symbols, *, numeric: bool = True) -> Poly:
    """``expr`` (polynomial in ``symbols``) as a dict; floats if ``numeric``, else SymPy."""
    expr = sp.sympify(expr)
    if expr == 0:
        return {}
    try:
        P = sp.Poly(sp.expand(expr), *symbols)
    except sp.PolynomialError as exc:
        raise NotPolynomialError(f"expression {expr} is not a polynomial in {list(symbols)}") from exc
    out = {}
    for e, c in P.terms():
        if c.free_symbols & set(symbols):
            raise NotPolynomialError(f"expression {expr} is not a polynomial in {list(symbols)}")
        if numeric:
            try:
                c = float(c)
            except TypeError as exc:
                raise ValueError(f"expression {expr}: coefficient {c} has free symbols "
                                 f"{sorted(map(str, c.free_symbols))}; give their values") from exc
        out[tuple(int(a) for a in e)] = c
    return out


def poly_to_sympy(p: Poly, symbols):
    return sp.Add(*[c * sp.Mul(*[s ** a for s, a in zip(symbols, e)]) for e, c in p.items()])


def monomial_str(e: Monomial, names: Sequence[str]) -> str:
    parts = [n if a == 1 else f"{n}^{a}" for n, a in zip(names, e) if a]
    return "*".join(parts) or "1"


def monomials_upto(n: int, degree: int, *, weights=None, constant: bool = False) -> list:
    """All monomials in ``n`` variables of (weighted) degree 1..``degree`` (and ``()^0`` if
    ``constant``), ordered by degree, then lexicographically decreasing."""
    w = np.ones(n, dtype=int) if weights is None else np.asarray(weights, dtype=int)
    out = []
    for d in range(0 if constant else 1, degree + 1):
        for combo in combinations_with_replacement(range(n), d):
            e = [0] * n
            for i in combo:
                e[i] += 1
            out.append(tuple(e))
    out = [e for e in out if int(np.dot(w, e)) <= degree]
    return sorted(set(out), key=lambda e: (int(np.dot(w, e)), sum(e), tuple(-a for a in e)))


# ------------------------------------------------------------------------------ the SDE
@dataclass
class PolySDE:
    """``dx = f(x) dt + G(x) dβ``, ``E dβ dβᵀ = Q dt``, with ``f``, ``G`` polynomial.

    ``drift``: n polys; ``diffusion``: n x r nested list of polys; ``Q``: r x r (numbers or SymPy);
    ``names``: variable names (for messages and tables).
    """

    drift: list
    diffusion: list
    Q: object
    names: list

    def __post_init__(self):
        self.n = len(self.drift)
        self.r = len(self.diffusion[0]) if self.diffusion and self.diffusion[0] is not None else 0
        Q = self.Q
        # D = G Q Gᵀ as n x n polys (the Itô correction), built once
        D = [[{} for _ in range(self.n)] for _ in range(self.n)]
        for i in range(self.n):
            for j in range(self.n):
                acc: Poly = {}
                for a in range(self.r):
                    for b in range(self.r):
                        qab = Q[a][b] if isinstance(Q, list) else Q[a, b]
                        if qab == 0:
                            continue
                        acc = poly_add(acc, poly_mul(self.diffusion[i][a], self.diffusion[j][b]), qab)
                D[i][j] = poly_clean(acc)
        self._D = D
        from ..polynomials import Polynomial
        from .ito import PolynomialSDE
        n = self.n
        self.engine = PolynomialSDE(tuple(Polynomial(dict(p), n) for p in self.drift),
                                    tuple(tuple(Polynomial(dict(D[i][j]), n) for j in range(n)) for i in range(n)))
        self._gen_cache: dict = {}
        self._noise_cache: dict = {}
        self.numeric = not any(isinstance(v, sp.Basic) for p in self.drift for v in p.values())

    @classmethod
    def from_sympy(cls, states, f, G, Q, *, numeric: bool = True, names=None):
        """From SymPy expressions ``f`` (n), ``G`` (n x r) in ``states`` and covariance ``Q``."""
        states = list(states)
        n = len(states)
        fM = sp.Matrix(f).reshape(n, 1)
        GM = sp.Matrix(G)
        if GM.shape[0] != n:
            raise ValueError(f"G: expected {n} rows, got shape {GM.shape}")
        drift = [poly_clean(poly_from_sympy(fM[i], states, numeric=numeric)) for i in range(n)]
        diff = [[poly_clean(poly_from_sympy(GM[i, a], states, numeric=numeric)) for a in range(GM.shape[1])]
                for i in range(n)]
        QM = sp.Matrix(Q) if not np.isscalar(Q) else sp.Matrix([[Q]])
        if numeric:
            Qv = np.array(QM.tolist(), dtype=float)
        else:
            Qv = [[sp.sympify(QM[a, b]) for b in range(QM.shape[1])] for a in range(QM.shape[0])]
        if (Qv.shape[0] if numeric else len(Qv)) != GM.shape[1]:
            raise ValueError(f"Q: expected {GM.shape[1]}x{GM.shape[1]}, got {QM.shape}")
        return cls(drift, diff, Qv, list(names) if names is not None else [str(s) for s in states])

    def generator(self, e: Monomial) -> Poly:
        """Drift part ``L x^e`` of ``d x^e`` (001 eq. 2.16), from the moment engine."""
        out = self._gen_cache.get(e)
        if out is None:
            out = poly_clean(dict(self.engine.generator(tuple(e)).terms))
            self._gen_cache[e] = out
        return out

    def noise(self, e: Monomial) -> list:
        """Coefficients of ``dβ_a`` in ``d x^e``: ``Σ_i G_ia ∂_i x^e`` for each noise ``a``."""
        out = self._noise_cache.get(e)
        if out is not None:
            return out
        res = []
        for a in range(self.r):
            acc: Poly = {}
            for i in range(self.n):
                if e[i] == 0 or not self.diffusion[i][a]:
                    continue
                d1 = list(e)
                d1[i] -= 1
                acc = poly_add(acc, poly_mul(self.diffusion[i][a], {tuple(d1): 1}), e[i])
            res.append(poly_clean(acc))
        self._noise_cache[e] = res
        return res


def _ou_example():
    x = sp.Symbol("x")
    return [x], [-x], [[1]], 2.0


# ---------------------------------------------------------------------------- closed sets
def closed_set(sde: PolySDE, seeds: Sequence[Monomial], *, max_size: int = 20000,
               with_noise: bool = False) -> list:
    """Smallest set of monomials containing ``seeds`` and closed under the generator (and, if
    ``with_noise``, under the noise coefficients too, as the bilinear lift ``x_[p]`` needs).
    The constant monomial is left out. Raises :class:`MomentsNotClosedError` past ``max_size``.
    (The engine's :func:`~nlfilter.moments.ito.closed_hull` without the noise option; here the
    generator is the engine's, cached per monomial, so the system is assembled in one pass.)"""
    zero = (0,) * sde.n
    seen = set()
    stack = []
    for s in seeds:
        s = tuple(int(a) for a in s)
        if len(s) != sde.n:
            raise ValueError(f"seeds: monomial {s} has {len(s)} exponents, expected {sde.n}")
        if s != zero and s not in seen:
            seen.add(s)
            stack.append(s)
    while stack:
        e = stack.pop()
        nxt = list(sde.generator(e))
        if with_noise:
            for p in sde.noise(e):
                nxt.extend(p)
        for m in nxt:
            if m != zero and m not in seen:
                seen.add(m)
                stack.append(m)
                if len(seen) > max_size:
                    raise MomentsNotClosedError(
                        f"closed_set: more than max_size={max_size} monomials reachable from {list(seeds)[:4]}; "
                        f"the moment equations of this SDE do not close (e.g. reached "
                        f"{monomial_str(m, sde.names)})")
    return sorted(seen, key=lambda e: (sum(e), tuple(-a for a in e)))


# ---------------------------------------------------------------------------- moment system
@dataclass
class MomentSystem:
    """``d/dt μ = A μ + b`` for ``μ_k = E[monomials[k]]`` (constant monomial excluded)."""

    monomials: list
    A: object  # scipy.sparse.csr_matrix (numeric) or sympy.Matrix (symbolic)
    b: object
    names: list

    @property
    def index(self) -> dict:
        return {m: k for k, m in enumerate(self.monomials)}

    def labels(self) -> list:
        return [monomial_str(m, self.names) for m in self.monomials]


def moment_system(sde: PolySDE, monomials: Sequence[Monomial]) -> MomentSystem:
    """Moment equations ``d/dt μ = A μ + b`` of a closed monomial set (see :func:`closed_set`),
    the rows being the engine's generator ``L x^α``."""
    mons = [tuple(m) for m in monomials if any(m)]
    idx = {m: k for k, m in enumerate(mons)}
    zero = (0,) * sde.n
    N = len(mons)
    if sde.numeric:  # as the engine's moment_equations, from the cached engine generator
        rows, cols, vals = [], [], []
        b = np.zeros(N)
        for k, m in enumerate(mons):
            for e, c in sde.generator(m).items():
                if e == zero:
                    b[k] += c
                elif e in idx:
                    rows.append(k)
                    cols.append(idx[e])
                    vals.append(c)
                else:
                    raise MomentsNotClosedError(f"moment_system: monomial set not closed: "
                                                f"L({monomial_str(m, sde.names)}) has {monomial_str(e, sde.names)}")
        return MomentSystem(mons, sps.csr_matrix((vals, (rows, cols)), shape=(N, N)), b, sde.names)
    # symbolic coefficients (e.g. to compare with 001's appendices): the engine's generator, dense SymPy
    A = sp.zeros(N, N)
    b = sp.zeros(N, 1)
    for k, m in enumerate(mons):
        for e, c in sde.generator(m).items():
            if e == zero:
                b[k] += c
            elif e in idx:
                A[k, idx[e]] += c
            else:
                raise MomentsNotClosedError(f"moment_system: monomial set not closed at {m} -> {e}")
    return MomentSystem(mons, A, b, sde.names)


def bilinear_lift(sde: PolySDE, monomials: Sequence[Monomial]):
    """The bilinear system ``d z = A z dt + Σ_a B_a z dβ_a`` of ``z`` = the given monomials
    (the constant monomial may be included, e.g. last, as in 001 Appendices A-B).

    Returns dense ``(A, [B_a])`` (NumPy or SymPy). Raises if the set is not closed under the
    generator and the noise coefficients.
    """
    mons = [tuple(m) for m in monomials]
    idx = {m: k for k, m in enumerate(mons)}
    N = len(mons)
    sym = not sde.numeric
    A = sp.zeros(N, N) if sym else np.zeros((N, N))
    Bs = [sp.zeros(N, N) if sym else np.zeros((N, N)) for _ in range(sde.r)]
    for k, m in enumerate(mons):
        for e, c in sde.generator(m).items():
            if e not in idx:
                raise MomentsNotClosedError(f"bilinear_lift: L({monomial_str(m, sde.names)}) has "
                                            f"{monomial_str(e, sde.names)}, not in the monomial set")
            A[k, idx[e]] += c
        for a, p in enumerate(sde.noise(m)):
            for e, c in p.items():
                if e not in idx:
                    raise MomentsNotClosedError(f"bilinear_lift: noise {a} of {monomial_str(m, sde.names)} "
                                                f"has {monomial_str(e, sde.names)}, not in the monomial set")
                Bs[a][k, idx[e]] += c
    return A, Bs


# ------------------------------------------------------------------------------ steady state
def conserved_functionals(ms: MomentSystem, *, tol: float = 1e-9):
    """Left null vectors ``ℓ`` of ``A`` (rows of the returned ``(k, N)`` array): the linear
    combinations of moments the dynamics conserve (``d/dt ℓᵀμ = ℓᵀ b``)."""
    A = ms.A.toarray()
    U, s, Vt = np.linalg.svd(A)
    scale = s[0] if s.size and s[0] > 0 else 1.0
    rank = int(np.sum(s > tol * scale))
    return U[:, rank:].T, Vt[rank:], rank


def steady_state(ms: MomentSystem, *, initial: Callable | dict | None = None, tol: float = 1e-9,
                 check_stable: bool = True, scale: np.ndarray | None = None) -> np.ndarray:
    """Steady state ``μ∞`` of ``d/dt μ = A μ + b``: the engine's
    :func:`~nlfilter.moments.solve.linear_steady_state` (rescaled, conservation-aware)."""
    return linear_steady_state(ms.A, ms.b, indices=ms.monomials, labels=ms.labels(), initial=initial,
                               scale=scale, tol=tol, check_stable=check_stable)


def moments(sde: PolySDE, wanted: Sequence[Monomial], *, initial=None, max_size: int = 20000,
            _rescale: bool = True) -> dict:
    """Steady-state ``E[m]`` for each monomial in ``wanted`` (and every monomial of the closed
    set it needs), as a dict (the constant monomial maps to 1)."""
    mons = closed_set(sde, wanted, max_size=max_size)
    ms = moment_system(sde, mons)
    scale = None
    if _rescale and max(sum(m) for m in mons) > 4:  # typical magnitudes from the second moments first
        sq = []
        for v in range(sde.n):
            e = [0] * sde.n
            e[v] = 2
            sq.append(tuple(e))
        m2 = moments(sde, sq, initial=initial, max_size=max_size, _rescale=False)
        sigma = np.sqrt(np.maximum([m2[e] for e in sq], 1e-300))
        sigma = np.where(sigma > 1e-150, sigma, 1.0)
        scale = gaussian_scale(ms.monomials, sigma)
    mu = steady_state(ms, initial=initial, scale=scale)
    out = {m: float(v) for m, v in zip(ms.monomials, mu)}
    out[(0,) * sde.n] = 1.0
    return out


def expectation(p: Poly, mom: dict) -> float:
    """``E[p]`` from a dict of monomial moments."""
    try:
        return float(sum(c * mom[e] for e, c in p.items()))
    except KeyError as exc:
        raise ValueError(f"expectation: moment of {exc.args[0]} not computed; add it to `wanted`") from None


__all__ = ["PolySDE", "MomentSystem", "MomentsNotClosedError", "closed_set", "moment_system",
           "bilinear_lift", "steady_state", "conserved_functionals", "moments", "expectation",
           "monomials_upto", "monomial_str", "poly_from_sympy", "poly_to_sympy", "poly_mul",
           "poly_add", "poly_pow", "poly_clean"]

