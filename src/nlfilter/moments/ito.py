"""The Itô generator on monomials: linear moment equations, closed-set detection.

Continuous time (seed 003 eq. 11, seed 001 eqs. 2.36, 3.8-3.9). For the Itô SDE
``dx = f(x, t) dt + G dβ``, ``E dβ dβᵀ = Q dt`` with polynomial ``f`` and ``σ = G Q Gᵀ``, every
monomial ``x^γ`` obeys::

    d E[x^γ]/dt = E[ Σ_s f_s ∂_s x^γ + ½ Σ_{s,h} σ_sh ∂_s ∂_h x^γ ]          (003 eq. 11)

The right side is again a polynomial, so for a chosen set of monomials ``μ = (E[x^γ])_{γ∈S}``::

    dμ/dt = A(t) μ + B(t) ν + c(t)

where ``ν`` are the moments of the monomials the generator reaches outside ``S`` (``missing``)
and ``c`` collects the constant monomial (``E[1] = 1``) unless ``(0,…,0)`` is in ``S``.
``ν`` is empty exactly when ``S`` is *closed* (bilinear systems with S = all monomials of one
degree, a linear SDE with S = all monomials up to a degree …); then the moments are exact.
Otherwise a closure (:mod:`nlfilter.moments.closures`) gives ``ν`` from ``μ``.

Noise coefficients and the bilinear lift (seed 001 eqs. 2.16, 3.13, Appendices A-B). With the
noise columns ``G`` kept (not only σ), the Itô rule gives the whole differential of a monomial::

    d x^γ = L x^γ dt + Σ_a (Σ_i G_ia ∂_i x^γ) dβ_a

When a set of monomials is closed under both ``L`` and the noise coefficients
(:func:`closed_hull` with ``with_noise=True``), its vector ``x_[p]`` obeys the bilinear equation
``d x_[p] = A x_[p] dt + Σ_a B_a x_[p] dβ_a`` (:func:`bilinear_lift`); SymPy coefficients
(``exact=True``) reproduce the thesis' symbolic appendices entry by entry.

Discrete time: ``x[k+1] = f(x[k]) + G(x[k]) w[k]`` with ``w`` independent of ``x`` and known
moments gives ``μ[k+1] = A μ[k] + B ν[k] + c`` from ``E[x_{k+1}^γ] = E[(f + G w)^γ]``
(:func:`discrete_moment_equations`).

Front doors
-----------
* :class:`PolynomialSDE` — drift and diffusion ``σ = GQGᵀ`` as :class:`~nlfilter.polynomials.Polynomial`
  objects (``from_model(SDEModel)``, ``from_sympy(states, f, sigma)`` or direct dicts), for any
  augmented state (e.g. (state, linear estimate) of seed 001);
* :func:`moment_equations` — sparse ``(A, B, c)`` and the list of missing monomials;
* :func:`closed_hull` / :func:`is_closed` — the smallest closed set containing given monomials
  (optionally closed under the noise coefficients too);
* :func:`bilinear_lift` — ``d x_[p] = A x_[p] dt + Σ_a B_a x_[p] dβ_a`` of a closed monomial set
  (seed 001 eq. 3.13), from an SDE that keeps its noise columns G;
* :class:`PolynomialMap` and :func:`discrete_moment_equations` — the discrete counterpart.

Coefficients may depend on time or on other symbols (e.g. tabulated gains): the matrices are then
stored as ``Σ_j g_j(t, symbols) (A_j, B_j, c_j)`` and evaluated with :meth:`MomentEquations.at`.

Example: Ornstein-Uhlenbeck ``dx = -x dt + dβ`` (Q = 2): d E[x²]/dt = -2 E[x²] + 2.

>>> import sympy as sp
>>> x = sp.Symbol("x")
>>> sde = PolynomialSDE.from_sympy([x], f=[-x], sigma=[[2]])
>>> eq = moment_equations(sde, [(1,), (2,)])
>>> eq.A.toarray().tolist(), eq.c.tolist(), eq.closed
([[-1.0, 0.0], [0.0, -2.0]], [0.0, 2.0], True)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
import scipy.sparse as sps
import sympy as sp

from ..errors import MomentsNotClosedError
from ..models import lambdify_numpy
from ..polynomials import Polynomial, add_exp, as_polynomial, monomial_name, monomials

__all__ = ["PolynomialSDE", "PolynomialMap", "MomentEquations", "moment_equations",
           "discrete_moment_equations", "closed_hull", "is_closed", "generator", "bilinear_lift", "as_polynomial_sde",
           "gaussian_noise_moments",
           "monomials", "degree_order"]


def degree_order(e: tuple):
    """Sort key: total degree, then x_1 before x_2 (the order of :func:`~nlfilter.polynomials.monomials`)."""
    return (sum(e), tuple(-i for i in e))


# ---------------------------------------------------------------------------------------------
# coefficient groups: a coefficient c = Σ_j w_j g_j with numbers w_j and symbolic factors g_j
# ---------------------------------------------------------------------------------------------
class _Groups:
    def __init__(self):
        self.exprs: list = [sp.Integer(1)]
        self.ids: dict = {sp.Integer(1): 0}

    def split(self, c) -> list[tuple[int, float]]:
        if isinstance(c, float):
            return [(0, c)]
        out = []
        for term in sp.Add.make_args(sp.expand(c)):
            w, rest = term.as_coeff_Mul()
            if rest not in self.ids:
                self.ids[rest] = len(self.exprs)
                self.exprs.append(rest)
            out.append((self.ids[rest], float(w)))
        return out


def _split_poly(p: Polynomial, groups: _Groups):
    return [(e, groups.split(c)) for e, c in p.terms.items()]


@dataclass(frozen=True)
class PolynomialSDE:
    """Itô SDE ``dx = f dt + G dβ`` in polynomial form: ``drift`` (n polynomials f_s) and
    ``diffusion`` (n x n symmetric polynomials σ = G Q Gᵀ).

    ``symbols``: the coefficient symbols (time first when given); ``states``: SymPy symbols of the
    state if known (for messages and conversions); ``names``: variable names (default from
    ``states``, else x1..xn). Use :meth:`from_model` for an :class:`~nlfilter.models.SDEModel`,
    :meth:`from_sympy` for expressions, or build it from :class:`Polynomial` objects / dicts for
    an augmented state.

    Noise columns (optional, :meth:`from_noise` or ``from_sympy(..., G=..., Q=...)``): ``noise``
    (n x r polynomials G) and ``noise_cov`` (r x r, Q). The moments need only σ; the bilinear lift
    ``d x_[p] = A x_[p] dt + Σ_a B_a x_[p] dβ_a`` of seed 001 (eqs. 3.13, A.2) needs the
    coefficient of each ``dβ_a`` in ``d x^γ``, :meth:`noise_terms` (see :func:`bilinear_lift`).
    """

    drift: tuple
    diffusion: tuple
    time: object = None
    states: tuple | None = None
    symbols: tuple = field(default=())
    noise: tuple | None = None
    noise_cov: object = field(default=None, compare=False)
    names: tuple | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        n = len(self.drift)
        if n == 0:
            raise ValueError("drift: expected n >= 1 polynomials, got none")
        drift = tuple(as_polynomial(p, n, name=f"drift[{i}]") for i, p in enumerate(self.drift))
        if len(self.diffusion) != n or any(len(row) != n for row in self.diffusion):
            raise ValueError(f"diffusion: expected an {n} x {n} matrix of polynomials (σ = G Q Gᵀ), "
                             f"got {len(self.diffusion)} row(s)")
        diff = tuple(tuple(as_polynomial(p, n, name=f"diffusion[{i}][{j}]") for j, p in enumerate(row))
                     for i, row in enumerate(self.diffusion))
        for i in range(n):
            for j in range(i):
                if diff[i][j] != diff[j][i]:
                    raise ValueError(f"diffusion: expected a symmetric matrix, entries [{i}][{j}] and "
                                     f"[{j}][{i}] differ")
        object.__setattr__(self, "drift", drift)
        object.__setattr__(self, "diffusion", diff)
        syms = set()
        for p in drift + tuple(q for row in diff for q in row):
            syms |= p.symbols
        order = ([self.time] if self.time is not None else []) + sorted(syms - {self.time}, key=str)
        object.__setattr__(self, "symbols", tuple(order))
        if self.noise is not None:
            G = tuple(tuple(as_polynomial(p, n, name=f"noise[{i}][{a}]") for a, p in enumerate(row))
                      for i, row in enumerate(self.noise))
            r = len(G[0]) if G else 0
            if len(G) != n or any(len(row) != r for row in G):
                raise ValueError(f"noise: expected an {n} x r matrix of polynomials (G), got rows of lengths "
                                 f"{[len(row) for row in G]}")
            object.__setattr__(self, "noise", G)
        if self.names is None:
            names = [str(v) for v in self.states] if self.states is not None else [f"x{i + 1}" for i in range(n)]
            object.__setattr__(self, "names", tuple(names))
        elif len(self.names) != n:
            raise ValueError(f"names: expected {n} names, got {len(self.names)}")
        object.__setattr__(self, "_exact", any(p.exact for p in self._polys()))

    @property
    def n(self) -> int:
        return len(self.drift)

    @property
    def r(self) -> int:
        """Number of noise columns (0 when only σ is known)."""
        return len(self.noise[0]) if self.noise else 0

    def _polys(self) -> tuple:
        """Every polynomial of the SDE: drift, diffusion, noise columns."""
        return (self.drift + tuple(q for row in self.diffusion for q in row)
                + tuple(q for row in (self.noise or ()) for q in row))

    @property
    def is_numeric(self) -> bool:
        """True when every coefficient is a float (no symbols, not exact)."""
        return all(p.is_numeric for p in self._polys())

    @classmethod
    def from_noise(cls, drift, G, Q=None, *, time=None, states=None, names=None) -> "PolynomialSDE":
        """From the drift (n polynomials), the noise columns ``G`` (n x r polynomials) and the
        noise covariance ``Q`` (r x r numbers or SymPy expressions; default I): σ = G Q Gᵀ."""
        n = len(drift)
        G = tuple(tuple(as_polynomial(p, n, name=f"G[{i}][{a}]") for a, p in enumerate(row)) for i, row in enumerate(G))
        if len(G) != n:
            raise ValueError(f"G: expected {n} rows, got {len(G)}")
        r = len(G[0]) if G else 0
        Q = np.eye(r) if Q is None else Q
        Qa = Q if isinstance(Q, sp.MatrixBase) else np.asarray(Q, dtype=object if _symbolic(Q) else float)
        if Qa.shape != (r, r):
            raise ValueError(f"Q: expected shape ({r}, {r}) for {r} noise column(s), got {Qa.shape}")
        exact = any(p.exact for row in G for p in row)
        sigma = []
        for i in range(n):
            row = []
            for j in range(n):
                acc = Polynomial({}, n, exact=exact)
                for a in range(r):
                    for b in range(r):
                        qab = float(Qa[a, b]) if isinstance(Qa[a, b], (float, np.floating)) else Qa[a, b]
                        if qab != 0:
                            acc = acc + (G[i][a] * G[j][b]) * qab
                row.append(acc)
            sigma.append(tuple(row))
        return cls(tuple(drift), tuple(sigma), time=time, states=states, noise=G, noise_cov=Qa,
                   names=None if names is None else tuple(names))

    @classmethod
    def from_sympy(cls, states, f, sigma=None, *, G=None, Q=None, time=None, exact: bool = False,
                   names=None) -> "PolynomialSDE":
        """From SymPy: ``f`` (n expressions) and either ``sigma`` (n x n, σ = G Q Gᵀ) or the noise
        columns ``G`` (n x r) with their covariance ``Q`` (r x r or a scalar; default I).
        ``exact``: exact SymPy coefficients (see :mod:`nlfilter.polynomials`)."""
        states = list(states)
        n = len(states)
        fM = sp.Matrix(f)
        drift = [Polynomial.from_sympy(e, states, name=f"f[{i}]", exact=exact) for i, e in enumerate(fM)]
        if (sigma is None) == (G is None):
            raise ValueError("sigma, G: expected exactly one of sigma (σ = G Q Gᵀ) and G (noise columns)")
        if sigma is not None and Q is not None:
            raise ValueError("Q: the noise covariance goes with G (noise columns), not with sigma = G Q Gᵀ")
        if G is not None:
            GM = sp.Matrix(G)
            if GM.shape[0] != n:
                raise ValueError(f"G: expected {n} rows, got shape {GM.shape}")
            Gp = [[Polynomial.from_sympy(GM[i, a], states, name=f"G[{i},{a}]", exact=exact) for a in range(GM.shape[1])]
                  for i in range(n)]
            if Q is not None and np.ndim(Q) == 0 and not isinstance(Q, sp.MatrixBase):
                Q = [[Q]]
            if Q is not None and (exact or _symbolic(Q)):
                Q = sp.Matrix(Q)
            return cls.from_noise(drift, Gp, Q, time=time, states=tuple(states), names=names)
        sM = sp.Matrix(sigma)
        if sM.shape != (n, n):
            raise ValueError(f"sigma: expected shape ({n}, {n}), got {sM.shape}")
        diff = [[Polynomial.from_sympy(sM[i, j], states, name=f"GQGᵀ[{i},{j}]", exact=exact) for j in range(n)]
                for i in range(n)]
        return cls(tuple(drift), tuple(map(tuple, diff)), time=time, states=tuple(states),
                   names=None if names is None else tuple(names))

    @classmethod
    def from_model(cls, model) -> "PolynomialSDE":
        """From an :class:`~nlfilter.models.SDEModel` given in SymPy (``model.sym``); raises
        :class:`~nlfilter.errors.NotPolynomialError` naming a non-polynomial term."""
        if getattr(model, "sym", None) is None:
            raise TypeError("model: the moment engine needs a model stated in SymPy (model.sym), "
                            "not one built from callables")
        G = model.sym["G"]
        sigma = sp.expand(G * sp.Matrix(model.Q.tolist()) * G.T)
        return cls.from_sympy(model.states, model.sym["f"], sigma, time=model.time)

    def generator(self, gamma: tuple) -> Polynomial:
        """The polynomial ``L x^γ`` (003 eq. 11; 001 eq. 2.16), cached per monomial."""
        gamma = tuple(gamma)
        key = ("L", gamma)
        if key in self._cache:
            return self._cache[key]
        n = self.n
        exact = self._exact
        out = Polynomial({}, n, exact=exact)
        mono = Polynomial({gamma: 1}, n, exact=exact)
        half = sp.Rational(1, 2) if exact else 0.5
        for s in range(n):
            if gamma[s]:
                out = out + self.drift[s] * mono.diff(s)
        for s in range(n):
            for h in range(n):
                d2 = mono.diff(s).diff(h)
                if d2.terms:
                    out = out + half * self.diffusion[s][h] * d2
        self._cache[key] = out
        return out

    def noise_terms(self, gamma: tuple) -> list:
        """The coefficients of ``dβ_a`` in ``d x^γ``: ``Σ_i G_ia ∂_i x^γ`` for a = 1..r (001 eq. 2.16),
        cached per monomial. Needs the noise columns."""
        gamma = tuple(gamma)
        key = ("noise", gamma)
        if key in self._cache:
            return self._cache[key]
        if self.noise is None:
            raise ValueError("sde: the noise columns G are not known (built from σ = G Q Gᵀ); build it with "
                             "PolynomialSDE.from_noise or from_sympy(..., G=...)")
        n = self.n
        mono = Polynomial({gamma: 1}, n, exact=self._exact)
        out = []
        for a in range(self.r):
            acc = Polynomial({}, n, exact=mono.exact)
            for i in range(n):
                if gamma[i] and self.noise[i][a].terms:
                    acc = acc + self.noise[i][a] * mono.diff(i)
            out.append(acc)
        self._cache[key] = out
        return out


def _symbolic(Q) -> bool:
    return any(isinstance(v, sp.Basic) and not v.is_number for v in np.asarray(Q, dtype=object).ravel())


def generator(sde: PolynomialSDE, gamma) -> Polynomial:
    """``L x^γ`` as a :class:`Polynomial` (003 eq. 11)."""
    return sde.generator(tuple(gamma))


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


def matvec(M, v) -> np.ndarray:
    """``M @ v`` over the last axis of a batch ``v (..., K)`` (M sparse or dense)."""
    v = np.asarray(v)
    flat = v.reshape(-1, v.shape[-1])
    return np.asarray((M @ flat.T).T).reshape(*v.shape[:-1], M.shape[0])


class MomentEquations:
    """Linear moment equations ``dμ/dt = A μ + B ν + c`` (continuous) or ``μ⁺ = A μ + B ν + c``
    (discrete) over the kept monomials ``indices`` with the ``missing`` monomials ``ν``.

    Attributes: ``indices`` (list of γ), ``missing`` (list of γ), ``index`` / ``missing_index``
    (γ -> position), ``kind`` ("continuous"/"discrete"), ``symbols`` (coefficient symbols),
    ``closed`` (no missing moments). ``A``, ``B`` (scipy.sparse CSR), ``c`` (ndarray) when the
    coefficients are constant; otherwise :meth:`at`.
    """

    def __init__(self, indices, missing, groups, exprs, symbols, kind):
        self.indices = list(indices)
        self.missing = list(missing)
        self.index = {g: i for i, g in enumerate(self.indices)}
        self.missing_index = {g: i for i, g in enumerate(self.missing)}
        self.kind = kind
        self.symbols = tuple(symbols)
        self._groups = groups  # list of (A_j, B_j, c_j)
        self._exprs = exprs
        if len(groups) > 1:  # A(w) = Σ_j w_j A_j on the union pattern: data = W w, one lambdified call for w
            self._weights = lambdify_numpy(self.symbols, list(exprs[1:]))
            self._A = _union([g[0] for g in groups])
            self._B = _union([g[1] for g in groups])
            self._C = np.stack([g[2] for g in groups], axis=-1)

    @property
    def closed(self) -> bool:
        return not self.missing

    @property
    def constant(self) -> bool:
        return len(self._groups) == 1

    def _const(self, k):
        if not self.constant:
            raise ValueError(f"moment equations: coefficients depend on {[str(s) for s in self.symbols]}; "
                             "use .at(t, values) to evaluate A, B, c")
        return self._groups[0][k]

    @property
    def A(self):
        return self._const(0)

    @property
    def B(self):
        return self._const(1)

    @property
    def c(self):
        return self._const(2)

    def at(self, t=None, values: Mapping | None = None):
        """``(A, B, c)`` at time ``t`` with the other coefficient symbols set by ``values``
        ({symbol or name: number or callable of t})."""
        if self.constant:
            return self._groups[0]
        vals = self._values(t, values)
        w = np.array([1.0, *self._weights(*vals)], dtype=float)
        return _union_at(self._A, w), _union_at(self._B, w), self._C @ w

    def _values(self, t, values):
        values = dict(values or {})
        byname = {str(k): v for k, v in values.items()}
        out = []
        for i, s in enumerate(self.symbols):
            if str(s) in byname:
                v = byname[str(s)]
            elif i == 0 and t is not None and self._has_time:
                v = t
            else:
                raise ValueError(f"values: coefficient symbol {s} needs a value (given {sorted(byname)})")
            out.append(v(t) if callable(v) else v)
        return out

    _has_time = False

    def rhs(self, mu, nu=None, t=None, values=None):
        """``A μ + B ν + c`` for a batch ``mu (..., K)``, ``nu (..., M)``."""
        A, B, c = self.at(t, values)
        out = matvec(A, mu) + c
        if self.missing:
            if nu is None:
                raise ValueError(f"nu: the system is not closed; expected the {len(self.missing)} missing "
                                 "moments (use a closure)")
            out = out + matvec(B, nu)
        return out

    def __repr__(self):
        return (f"MomentEquations({self.kind}, {len(self.indices)} moments, {len(self.missing)} missing, "
                f"{len(self._groups)} coefficient group(s))")


def _union(mats):
    """CSR structure of the union of the patterns of ``mats`` and the sparse map ``W`` (nnz, groups)
    from group weights to its data: ``Σ_j w_j mats[j]`` has data ``W @ w``."""
    shape = mats[0].shape
    coo = [sps.coo_matrix(M) for M in mats]
    lin = np.concatenate([c.row.astype(np.int64) * shape[1] + c.col for c in coo])
    gid = np.concatenate([np.full(c.nnz, j) for j, c in enumerate(coo)])
    uniq, pos = np.unique(lin, return_inverse=True)
    W = sps.csr_matrix((np.concatenate([c.data for c in coo]), (pos, gid)), shape=(uniq.size, len(mats)))
    rows, cols = np.divmod(uniq, shape[1])
    return np.searchsorted(rows, np.arange(shape[0] + 1)), cols, W, shape


def _union_at(U, w):
    indptr, cols, W, shape = U
    return sps.csr_matrix((W @ w, cols, indptr), shape=shape)


def _assemble(indices, rows_terms, groups: _Groups, symbols, kind, time):
    """rows_terms: per kept index, dict {(exponent, group id): weight}."""
    index = {g: i for i, g in enumerate(indices)}
    n = len(indices[0])
    zero = (0,) * n
    missing = set()
    for terms in rows_terms:
        for (e, _), _w in terms.items():
            if e not in index and e != zero:
                missing.add(e)
    missing = sorted(missing, key=degree_order)
    mindex = {g: i for i, g in enumerate(missing)}
    ng = len(groups.exprs)
    data = [([], [], [], [], [], [], np.zeros(len(indices))) for _ in range(ng)]
    for r, terms in enumerate(rows_terms):
        for (e, gid), w in terms.items():
            if w == 0.0:
                continue
            ar, ac, ad, br, bc, bd, c = data[gid]
            if e in index:
                ar.append(r), ac.append(index[e]), ad.append(w)
            elif e == zero:
                c[r] += w
            else:
                br.append(r), bc.append(mindex[e]), bd.append(w)
    K, M = len(indices), len(missing)
    mats = []
    for ar, ac, ad, br, bc, bd, c in data:
        A = sps.csr_matrix((ad, (ar, ac)), shape=(K, K))
        B = sps.csr_matrix((bd, (br, bc)), shape=(K, M))
        mats.append((A, B, c))
    eq = MomentEquations(indices, missing, mats, groups.exprs, symbols, kind)
    eq._has_time = time is not None and len(symbols) > 0 and symbols[0] == time
    return eq


def _check_indices(indices, n):
    idx = []
    seen = set()
    for g in indices:
        g = tuple(int(i) for i in g)
        if len(g) != n or min(g) < 0:
            raise ValueError(f"indices: {g} is not a multi-index of length {n} with non-negative entries")
        if g in seen:
            raise ValueError(f"indices: {g} appears twice")
        seen.add(g)
        idx.append(g)
    if not idx:
        raise ValueError("indices: expected at least one monomial, got none")
    return idx


def as_polynomial_sde(sde) -> PolynomialSDE:
    """``sde`` itself if a :class:`PolynomialSDE`, else the polynomial SDE of an
    :class:`~nlfilter.models.SDEModel` stated in SymPy (:meth:`PolynomialSDE.from_model`)."""
    if isinstance(sde, PolynomialSDE):
        return sde
    if getattr(sde, "kind", None) == "sde":
        return PolynomialSDE.from_model(sde)
    raise TypeError(f"sde: expected a PolynomialSDE or an SDEModel, got {type(sde).__name__}")


def moment_equations(sde, indices: Sequence[tuple]) -> MomentEquations:
    """The moment equations ``dμ/dt = A μ + B ν + c`` for the monomials ``indices``
    (003 eq. 11; 001 eqs. 3.8-3.9).

    Parameters
    ----------
    sde : :class:`PolynomialSDE` or :class:`~nlfilter.models.SDEModel` (stated in SymPy)
    indices : sequence of multi-indices γ (tuples of length n); e.g. ``monomials(n, N, min_degree=1)``

    Returns
    -------
    :class:`MomentEquations` with sparse ``A (K, K)``, ``B (K, M)``, ``c (K,)`` and ``missing``.
    """
    sde = as_polynomial_sde(sde)
    n = sde.n
    indices = _check_indices(indices, n)
    groups = _Groups()
    drift = [_split_poly(p, groups) for p in sde.drift]
    diff = [[_split_poly(p, groups) for p in row] for row in sde.diffusion]
    rows = []
    for g in indices:
        terms: dict = {}
        for s in range(n):
            gs = g[s]
            if not gs:
                continue
            base = list(g)
            base[s] -= 1
            for e, parts in drift[s]:  # 003 eq. 11, first sum: γ_s f_s x^(γ - e_s)
                ee = add_exp(e, base)
                for gid, w in parts:
                    terms[(ee, gid)] = terms.get((ee, gid), 0.0) + gs * w
        for s in range(n):
            for h in range(s, n):
                if s == h:
                    k = g[s] * (g[s] - 1) * 0.5  # 003 eq. 11, second sum: ½ γ_s(γ_s-1) σ_ss
                    if not k:
                        continue
                    base = list(g)
                    base[s] -= 2
                else:
                    k = g[s] * g[h]  # third sum: γ_s γ_h σ_sh (s < h, σ symmetric)
                    if not k:
                        continue
                    base = list(g)
                    base[s] -= 1
                    base[h] -= 1
                for e, parts in diff[s][h]:
                    ee = add_exp(e, base)
                    for gid, w in parts:
                        terms[(ee, gid)] = terms.get((ee, gid), 0.0) + k * w
        rows.append(terms)
    symbols = _symbols_for(sde.time, groups)
    return _assemble(indices, rows, groups, symbols, "continuous", sde.time)


def _symbols_for(time, groups: _Groups):
    syms = set()
    for e in groups.exprs:
        syms |= sp.sympify(e).free_symbols
    rest = sorted(syms - {time}, key=str)
    return tuple(([time] if time is not None and time in syms else []) + rest) if syms else ()


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
