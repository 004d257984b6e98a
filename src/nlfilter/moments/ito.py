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

Noise coefficients (seed 001 eqs. 2.16, 3.13). With the noise columns ``G`` kept (not only σ),
the Itô rule gives the whole differential of a monomial::

    d x^γ = L x^γ dt + Σ_a (Σ_i G_ia ∂_i x^γ) dβ_a

(:meth:`PolynomialSDE.noise_terms`), which the closed hulls and the bilinear lift of
:mod:`nlfilter.moments.closed` use.

Front doors
-----------
* :class:`PolynomialSDE` — drift and diffusion ``σ = GQGᵀ`` as :class:`~nlfilter.polynomials.Polynomial`
  objects (``from_model(SDEModel)``, ``from_sympy(states, f, sigma)`` or direct dicts), for any
  augmented state (e.g. (state, linear estimate) of seed 001); its generator ``L x^γ`` and noise
  coefficients;
* :func:`moment_equations` — sparse ``(A, B, c)`` and the list of missing monomials
  (:class:`~nlfilter.moments.equations.MomentEquations`).

Elsewhere in :mod:`nlfilter.moments` (and still importable from here): the equation container
:mod:`.equations` (:class:`MomentEquations`, :func:`degree_order`), the discrete counterpart
:mod:`.discrete` (:class:`~nlfilter.moments.discrete.PolynomialMap`,
:func:`~nlfilter.moments.discrete.discrete_moment_equations`,
:func:`~nlfilter.moments.discrete.gaussian_noise_moments`), closed monomial sets and the bilinear
lift :mod:`.closed` (:func:`~nlfilter.moments.closed.closed_hull`,
:func:`~nlfilter.moments.closed.is_closed`, :func:`~nlfilter.moments.closed.bilinear_lift`).

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
from typing import Sequence

import numpy as np
import sympy as sp

from ..polynomials import Polynomial, add_exp, as_polynomial, monomials
from .equations import MomentEquations, _assemble, _check_indices, _Groups, _split_poly, _symbols_for, degree_order

__all__ = ["PolynomialSDE", "MomentEquations", "moment_equations", "generator", "as_polynomial_sde",
           "monomials", "degree_order"]

@dataclass(frozen=True)
class PolynomialSDE:
    """Itô SDE ``dx = f dt + G dβ`` in polynomial form: ``drift`` (n polynomials f_s) and
    ``diffusion`` (n x n symmetric polynomials σ = G Q Gᵀ; a state-independent part that is not
    positive semi-definite is refused, see :meth:`from_sympy`).

    ``symbols``: the coefficient symbols (time first when given); ``states``: SymPy symbols of the
    state if known (for messages and conversions); ``names``: variable names (default from
    ``states``, else x1..xn). Use :meth:`from_model` for an :class:`~nlfilter.models.SDEModel`,
    :meth:`from_sympy` for expressions, or build it from :class:`Polynomial` objects / dicts for
    an augmented state.

    Noise columns (optional, :meth:`from_noise` or ``from_sympy(..., G=..., Q=...)``): ``noise``
    (n x r polynomials G) and ``noise_cov`` (r x r, Q). The moments need only σ; the bilinear lift
    ``d x_[p] = A x_[p] dt + Σ_a B_a x_[p] dβ_a`` of seed 001 (eqs. 3.13, A.2) needs the
    coefficient of each ``dβ_a`` in ``d x^γ``, :meth:`noise_terms` (see :func:`~nlfilter.moments.closed.bilinear_lift`).
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
        _check_diffusion(diff)
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
        if not _symbolic(Qa) and r:
            Qf = np.asarray(Qa.tolist() if isinstance(Qa, sp.MatrixBase) else Qa, dtype=float)
            w = np.linalg.eigvalsh(0.5 * (Qf + Qf.T))
            if not np.all(np.isfinite(Qf)) or w[0] < -1e-10 * max(1.0, float(np.max(np.abs(Qf)))):
                raise ValueError(f"Q: expected a finite positive semi-definite noise covariance, got {Qf.tolist()} "
                                 f"(smallest eigenvalue {w[0]:.6g})")
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
        ``exact``: exact SymPy coefficients (see :mod:`nlfilter.polynomials`).

        ``sigma`` is the diffusion matrix itself, a covariance: a state-independent negative
        diagonal entry (``sigma=[[-1]]``) or a constant ``sigma`` with a negative eigenvalue is a
        ``ValueError`` naming ``diffusion`` (a state-dependent ``sigma`` is taken as given: it need
        only be PSD where the state lives). ``G`` may have any sign (σ = G Q Gᵀ); a numeric ``Q``
        must be positive semi-definite (``ValueError`` naming ``Q``)."""
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


def _constant_value(p: Polynomial):
    """The value of a polynomial that does not depend on the state or on symbols, else None."""
    if any(any(e) for e in p.terms):
        return None
    c = p.terms.get((0,) * p.nvars, 0.0)
    try:
        return float(c)
    except (TypeError, ValueError):
        return None


def _check_diffusion(diff):
    """σ = G Q Gᵀ is a covariance: refuse what is certainly not positive semi-definite. A
    state-independent negative diagonal entry, or a state-independent σ with a negative
    eigenvalue, is never a diffusion. A state-dependent σ needs only be PSD where the state lives
    (x(1 − x) of the Wright-Fisher diffusion is negative outside [0, 1]) and is not checked."""
    n = len(diff)
    const = [[_constant_value(q) for q in row] for row in diff]
    for i in range(n):
        d = const[i][i]
        if d is not None and d < 0:
            raise ValueError(f"diffusion: expected σ = G Q Gᵀ positive semi-definite, got the constant "
                             f"σ[{i}][{i}] = {d:.6g} < 0 (a negative diffusion coefficient)")
    if all(v is not None for row in const for v in row):
        S = np.array(const, dtype=float)
        w = np.linalg.eigvalsh(S)
        if w[0] < -1e-10 * max(1.0, float(np.max(np.abs(S)))):
            raise ValueError(f"diffusion: expected σ = G Q Gᵀ positive semi-definite, got the constant "
                             f"matrix {S.tolist()} with eigenvalue {w[0]:.6g} < 0")


def _symbolic(Q) -> bool:
    return any(isinstance(v, sp.Basic) and not v.is_number for v in np.asarray(Q, dtype=object).ravel())


def generator(sde: PolynomialSDE, gamma) -> Polynomial:
    """``L x^γ`` as a :class:`Polynomial` (003 eq. 11)."""
    return sde.generator(tuple(gamma))


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


# closed_hull, is_closed, bilinear_lift moved to .closed, which imports this module: they stay
# importable from here on first access (PEP 562), without an import cycle
