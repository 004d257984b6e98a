"""Moment closures: the missing (higher) moments as functions of the kept ones, n-dimensional.

A closure of order ``N`` reads the raw moments ``E[x^γ]`` of every monomial of total degree
``≤ N`` (they must all be kept) and returns the raw moment of any other monomial under an
approximating density:

* :class:`GaussianClosure` (N = 2) — the normal density N(m, K): Isserlis' recursion
  ``μ_{α+e_i} = Σ_j K_ij α_j μ_{α-e_j}`` for central moments (003 eq. 23 in one dimension);
* :class:`CumulantClosure` (cumulant neglect of order N) — all cumulants of order > N are zero;
  the multivariate moment-cumulant recursion ``μ_{α} = Σ_{β ≤ α-e_i} C(α-e_i, β) κ_{β+e_i}
  μ_{α-e_i-β}`` (central moments, so κ of order 1 is 0);
* :class:`EdgeworthClosure` (Hermite quasi-moment closure of order N, 003 eqs. 12-15, 28-33) —
  ``p* = N(m, K)[1 + Σ_{3≤|ν|≤N} c_ν/ν! H_ν(x-m)]`` with the quasi-moments
  ``c_ν = E[G_ν(x-m)]``. With ``G_ν(u) = E_z[(u + i z)^ν]``, ``z ~ N(0, K)``, one has
  ``c_ν = Σ_{β ≤ ν} C(ν, β) i^|β| γ_β μ_{ν-β}`` and, inversely,
  ``μ_α = Σ_{β ≤ α} C(α, β) γ_β c_{α-β}`` (γ = central moments of N(0, K)); the closure sets
  ``c_ν = 0`` for ``|ν| > N`` (the biorthogonality of 003 eq. 12 makes these the moments of p*).
  In one dimension with N = 4 this gives the paper's eqs. 31-33: ``μ_5 = 10 D c_3``,
  ``μ_6 = 15 D³ + 15 D c_4``.

For N = 2 all three coincide with the Gaussian closure; for a Gaussian density every closure is
exact. All computations are batched: a moment value may be an array ``(...,)`` over paths (and
complex, so the Jacobian of a closure can be taken by complex step).

>>> import numpy as np
>>> from nlfilter.polynomials import monomials
>>> kept = monomials(1, 2)                       # E[1], E[x], E[x²]
>>> vals = np.array([1.0, 1.0, 3.0])             # mean 1, variance 2
>>> GaussianClosure()(kept, vals, [(3,), (4,)]).tolist()   # E x³ = m³ + 3 m D, E x⁴ = 3D²+6m²D+m⁴
[7.0, 25.0]
"""

from __future__ import annotations

import numbers
from math import comb
from typing import Sequence

import numpy as np

from .._validate import as_float_array, choice, covariance, finite, shown
from ..polynomials import add_exp, monomials, unit_exp

__all__ = ["Closure", "GaussianClosure", "CumulantClosure", "EdgeworthClosure", "closure_by_name",
           "kept_order", "gaussian_moments", "raw_to_central", "central_to_raw"]


def _below(alpha):
    """All β ≤ α componentwise, with the multinomial weight Π C(α_i, β_i)."""
    out = [((), 1)]
    for a in alpha:
        out = [(b + (k,), w * comb(a, k)) for b, w in out for k in range(a + 1)]
    return out


def _minus(a, i, k=1):
    b = list(a)
    b[i] -= k
    return tuple(b)


def _pow_mean(m, e):
    val = 1.0
    for mi, k in zip(m, e):
        if k:
            val = val * mi ** k
    return val


def raw_to_central(raw: dict, alpha: tuple, mean):
    """E[(x-m)^α] = Σ_{β≤α} C(α,β) (-m)^(α-β) E[x^β]."""
    total = 0.0
    for b, w in _below(alpha):
        d = tuple(a - bb for a, bb in zip(alpha, b))
        total = total + w * ((-1) ** sum(d)) * _pow_mean(mean, d) * raw[b]
    return total


def central_to_raw(central, alpha: tuple, mean):
    """E[x^α] = Σ_{β≤α} C(α,β) m^(α-β) E[(x-m)^β] (``central`` a callable β -> value)."""
    total = 0.0
    for b, w in _below(alpha):
        if sum(b) == 1:
            continue  # central first moments vanish
        d = tuple(a - bb for a, bb in zip(alpha, b))
        total = total + w * _pow_mean(mean, d) * central(b)
    return total


class _Plan:
    """A closure compiled once for given (kept, wanted) monomials: registers holding the inputs,
    1, 0 and every intermediate; statements ``r_t = Σ_k c_k r_{a_k} r_{b_k}`` grouped in levels
    (a level only reads earlier levels) and evaluated vectorized over the batch and the level."""

    def __init__(self, n_inputs: int):
        self.n_in = n_inputs
        self.ONE, self.ZERO = n_inputs, n_inputs + 1
        self.size = n_inputs + 2
        self.level = [0] * self.size
        self.stmts: list = []
        self.levels = None

    def sumprod(self, terms) -> int:
        terms = [(float(c), a, b) for c, a, b in terms if c != 0 and a != self.ZERO and b != self.ZERO]
        if not terms:
            return self.ZERO
        if len(terms) == 1 and terms[0][0] == 1.0 and terms[0][2] == self.ONE:
            return terms[0][1]
        t = self.size
        self.size += 1
        lev = 1 + max(max(self.level[a], self.level[b]) for _, a, b in terms)
        self.level.append(lev)
        self.stmts.append((t, lev, terms))
        return t

    def compile(self):
        by: dict = {}
        for t, lev, terms in self.stmts:
            by.setdefault(lev, []).append((t, terms))
        self.levels = []
        for lev in sorted(by):
            tg, cf, aa, bb, starts = [], [], [], [], []
            for t, terms in by[lev]:
                starts.append(len(cf))
                tg.append(t)
                for c, a, b in terms:
                    cf.append(c), aa.append(a), bb.append(b)
            self.levels.append((np.array(tg), np.array(starts), np.array(cf), np.array(aa), np.array(bb)))
        self.stmts = None
        return self

    def run(self, values: np.ndarray) -> np.ndarray:
        """All registers for ``values (..., n_inputs)``, register axis FIRST: ``(size, ...)``."""
        V = np.empty((self.size, *values.shape[:-1]), dtype=np.result_type(values, float))
        V[:self.n_in] = np.moveaxis(values, -1, 0)
        V[self.ONE] = 1.0
        V[self.ZERO] = 0.0
        extra = (None,) * (values.ndim - 1)
        for tg, starts, cf, a, b in self.levels:  # register-first: gathers read contiguous rows
            V[tg] = np.add.reduceat(V[a] * V[b] * cf[(slice(None), *extra)], starts, axis=0)
        return V

    def jacobian(self, values: np.ndarray, out: np.ndarray, *, sparse: bool = False):
        """``∂V[out]/∂inputs (len(out), n_inputs)`` at one point ``values (n_inputs,)``: forward mode,
        one sparse product per level (dV[t] = Σ c (V[b] dV[a] + V[a] dV[b])); CSR when ``sparse``."""
        import scipy.sparse as sps

        V = self.run(np.asarray(values, dtype=float))
        row = np.full(self.size, -1)  # register -> row of the stacked derivative blocks
        row[:self.n_in] = np.arange(self.n_in)
        blocks = [sps.identity(self.n_in, format="csr"), sps.csr_matrix((2, self.n_in))]  # inputs, ONE/ZERO
        row[self.ONE], row[self.ZERO] = self.n_in, self.n_in + 1
        nrows = self.n_in + 2
        dV = sps.vstack(blocks, format="csr")
        for tg, starts, cf, a, b in self.levels:
            rows = np.repeat(np.arange(len(tg)), np.diff(np.append(starts, len(cf))))
            D = sps.csr_matrix((np.concatenate([cf * V[b], cf * V[a]]),
                                (np.concatenate([rows, rows]), np.concatenate([row[a], row[b]]))),
                               shape=(len(tg), nrows))
            new = D @ dV
            row[tg] = nrows + np.arange(len(tg))
            nrows += len(tg)
            dV = sps.vstack([dV, new], format="csr")
        J = dV[row[out]]
        return J if sparse else J.toarray()


class Closure:
    """Base class. ``order`` N: the kept moments must contain every monomial of degree ≤ N.

    ``closure(kept_indices, kept_values (..., K), wanted) -> (..., W)`` returns raw moments of
    the ``wanted`` monomials (kept ones are passed through). The computation is compiled once per
    pair (kept, wanted) into a vectorized plan (cached), so repeated calls are cheap.
    """

    order: int = 2
    name: str = "closure"

    def __call__(self, indices: Sequence[tuple], values, wanted: Sequence[tuple]) -> np.ndarray:
        values = np.asarray(values)
        last = self.__dict__.get("_last")
        if (last is not None and last[0] is indices and last[1] is wanted  # same lists as last call: skip re-keying
                and last[3] == (len(indices), len(wanted))):
            plan, out = last[2]
            if values.shape[-1] != plan.n_in:
                raise ValueError(f"values: expected trailing axis {plan.n_in} (one per kept moment), "
                                 f"got shape {values.shape}")
            return np.moveaxis(plan.run(values)[out], 0, -1)
        ind_in, want_in = indices, wanted
        indices = tuple(tuple(int(i) for i in g) for g in indices)
        wanted = tuple(tuple(int(i) for i in g) for g in wanted)
        if values.shape[-1] != len(indices):
            raise ValueError(f"values: expected trailing axis {len(indices)} (one per kept moment), "
                             f"got shape {values.shape}")
        if not wanted:
            return np.zeros((*values.shape[:-1], 0), dtype=values.dtype)
        plan, out = self.plan(indices, wanted)
        if isinstance(ind_in, list) and isinstance(want_in, list):
            self._last = (ind_in, want_in, (plan, out), (len(ind_in), len(want_in)))  # by identity and length
        return np.moveaxis(plan.run(values)[out], 0, -1)

    def jacobian(self, indices: Sequence[tuple], values, wanted: Sequence[tuple], *, sparse: bool = False):
        """``∂(wanted raw moments)/∂(kept raw moments)`` at one point: ``(W, K)`` (exact, forward mode;
        a CSR matrix when ``sparse``)."""
        indices = tuple(tuple(int(i) for i in g) for g in indices)
        wanted = tuple(tuple(int(i) for i in g) for g in wanted)
        values = np.asarray(values, dtype=float)
        if values.shape != (len(indices),):
            raise ValueError(f"values: expected shape ({len(indices)},), got {values.shape}")
        plan, out = self.plan(indices, wanted)
        return plan.jacobian(values, out, sparse=sparse)

    def plan(self, indices: tuple, wanted: tuple):
        cache = self.__dict__.setdefault("_plans", {})
        key = (indices, wanted)
        if key not in cache:
            if len(cache) > 64:
                cache.clear()
            cache[key] = self._build(indices, wanted)
        return cache[key]

    def complete(self, raw: dict, wanted: Sequence[tuple]) -> list:
        """Raw moments of ``wanted`` from the dict ``raw`` {γ: value (...,)}."""
        if not wanted:
            return []
        keys = list(raw)
        vals = np.stack(np.broadcast_arrays(*[np.asarray(raw[k]) for k in keys]), axis=-1)
        out = self(keys, vals, wanted)
        return [out[..., i] for i in range(out.shape[-1])]

    def _build(self, kept, wanted):
        n = len(wanted[0])
        zero = (0,) * n
        P = _Plan(len(kept))
        reg = {g: i for i, g in enumerate(kept)}
        reg.setdefault(zero, P.ONE)
        N = self.order
        need = [g for g in monomials(n, N) if g not in reg]
        if need:
            raise ValueError(f"indices: the {self.name} closure of order {N} needs every moment of "
                             f"degree ≤ {N}; missing {need[:5]}")
        mean = [reg[unit_exp(n, i)] for i in range(n)]
        mp = {zero: P.ONE}

        def mpow(a):  # m^a
            if a not in mp:
                i = next(k for k, v in enumerate(a) if v)
                mp[a] = P.sumprod([(1.0, mpow(_minus(a, i)), mean[i])])
            return mp[a]

        cm = {zero: P.ONE}
        for i in range(n):
            cm[unit_exp(n, i)] = P.ZERO
        for g in monomials(n, N, min_degree=2):  # E[(x-m)^g] = Σ_β C(g,β) (-m)^(g-β) E[x^β]
            terms = []
            for b, w in _below(g):
                d = tuple(x - y for x, y in zip(g, b))
                terms.append((w * (-1) ** sum(d), mpow(d), reg[b]))
            cm[g] = P.sumprod(terms)
        K = [[cm[add_exp(unit_exp(n, i), unit_exp(n, j))] for j in range(n)] for i in range(n)]
        memo = dict(cm)
        rule = self._rule(P, memo, K, n)

        def central(b):
            if b not in memo:
                memo[b] = rule(b, central)
            return memo[b]

        out = []
        for g in wanted:
            if g in reg:
                out.append(reg[g])
                continue
            terms = []  # E[x^g] = Σ_β C(g,β) m^(g-β) E[(x-m)^β]
            for b, w in _below(g):
                if sum(b) == 1:
                    continue
                terms.append((w, mpow(tuple(x - y for x, y in zip(g, b))), central(b)))
            out.append(P.sumprod(terms))
        return P.compile(), np.array(out, dtype=int)

    def _rule(self, P, cm, K, n):  # pragma: no cover
        raise NotImplementedError

    def __repr__(self):
        return f"{type(self).__name__}(order={self.order})"


def _closure_order(order) -> int:
    """The order N of a cumulant or Edgeworth closure, checked: an integer ≥ 2."""
    if isinstance(order, bool) or not isinstance(order, int) or order < 2:
        raise ValueError(f"order: expected an integer ≥ 2, got {shown(order)}")
    return order


def _isserlis(P, K, n):
    """Registers of the central moments of N(0, K): γ_α = Σ_j K_ij (α-e_i)_j γ_{α-e_i-e_j}."""
    memo = {(0,) * n: P.ONE}

    def gam(a):
        if a in memo:
            return memo[a]
        if sum(a) % 2:
            memo[a] = P.ZERO
            return P.ZERO
        i = next(k for k, v in enumerate(a) if v)
        rest = _minus(a, i)
        memo[a] = P.sumprod([(rest[j], K[i][j], gam(_minus(rest, j))) for j in range(n) if rest[j]])
        return memo[a]

    return gam


class GaussianClosure(Closure):
    """Normal closure (order 2): higher moments of N(m, K) (003 eq. 23)."""

    order = 2
    name = "gaussian"

    def _rule(self, P, cm, K, n):
        gam = _isserlis(P, K, n)
        return lambda b, central: gam(b)


class CumulantClosure(Closure):
    """Cumulant neglect of order N: cumulants of order > N set to zero (N ≥ 2)."""

    name = "cumulant"

    def __init__(self, order: int = 4):
        self.order = _closure_order(order)

    def _rule(self, P, cm, K, n):
        N = self.order
        kap: dict = {}

        def kappa(a):  # cumulant from central moments (order ≤ N); κ of order 1 is zero
            if a in kap:
                return kap[a]
            s = sum(a)
            if s <= 1 or s > N:
                kap[a] = P.ZERO
                return P.ZERO
            i = next(k for k, v in enumerate(a) if v)
            ap = _minus(a, i)
            terms = [(1.0, cm[a], P.ONE)]
            for b, w in _below(ap):
                if b == ap:
                    continue
                terms.append((-w, kappa(add_exp(b, unit_exp(n, i))), cm[tuple(x - y for x, y in zip(ap, b))]))
            kap[a] = P.sumprod(terms)
            return kap[a]

        def rule(a, central):  # μ_α = Σ_{β ≤ α-e_i} C(α-e_i, β) κ_{β+e_i} μ_{α-e_i-β}
            i = next(k for k, v in enumerate(a) if v)
            ap = _minus(a, i)
            terms = []
            for b, w in _below(ap):
                if not 1 <= sum(b) <= N - 1:
                    continue  # κ_{β+e_i} vanishes unless 2 ≤ |β|+1 ≤ N
                terms.append((w, kappa(add_exp(b, unit_exp(n, i))), central(tuple(x - y for x, y in zip(ap, b)))))
            return P.sumprod(terms)

        return rule


class EdgeworthClosure(Closure):
    """Hermite quasi-moment (Edgeworth / Gram-Charlier) closure of order N (003 eqs. 12-15, 28-33)."""

    name = "edgeworth"

    def __init__(self, order: int = 4):
        self.order = _closure_order(order)

    def quasi_moments(self, cm: dict, n: int) -> dict:
        """``c_ν`` for ``3 ≤ |ν| ≤ N`` (003 eq. 15) from central moments ``cm`` {γ: value} of every
        degree ≤ N (the covariance K is read from the second-order ones):
        c_ν = Σ_β C(ν,β) i^|β| γ_β μ_{ν-β}."""
        keys = sorted(cm, key=lambda g: (sum(g), g))
        P = _Plan(len(keys))
        reg = {g: i for i, g in enumerate(keys)}
        Kr = [[reg[add_exp(unit_exp(n, i), unit_exp(n, j))] for j in range(n)] for i in range(n)]
        creg = self._quasi(P, reg, Kr, n)[0]
        P.compile()
        V = P.run(np.stack(np.broadcast_arrays(*[np.asarray(cm[g], dtype=float) for g in keys]), axis=-1))
        return {nu: V[r] for nu, r in creg.items()}

    def _quasi(self, P, cm, K, n):
        gam = _isserlis(P, K, n)
        c = {}
        for nu in monomials(n, self.order, min_degree=3):
            terms = []
            for b, w in _below(nu):
                sb = sum(b)
                if sb % 2:
                    continue
                terms.append((w * (-1) ** (sb // 2), gam(b), cm[tuple(x - y for x, y in zip(nu, b))]))
            c[nu] = P.sumprod(terms)
        return c, gam

    def _rule(self, P, cm, K, n):
        c, gam = self._quasi(P, cm, K, n)
        N = self.order

        def rule(a, central):  # μ_α = Σ_β C(α,β) γ_β c_{α-β}, c_0 = 1, c of order 1, 2 and > N zero
            terms = []
            for b, w in _below(a):
                d = tuple(x - y for x, y in zip(a, b))
                sd = sum(d)
                if sd == 0:
                    terms.append((w, gam(b), P.ONE))
                elif 3 <= sd <= N and sum(b) % 2 == 0:
                    terms.append((w, gam(b), c[d]))
            return P.sumprod(terms)

        return rule


def closure_by_name(name: str, order: int | None = None) -> Closure:
    """``"gaussian"``, ``"cumulant"`` (order N), ``"edgeworth"`` (order N, alias ``"quasi-moment"``)."""
    name = choice("closure", name, {"gaussian", "cumulant", "edgeworth", "quasi-moment"})
    if name == "gaussian":
        if order is not None and not (isinstance(order, numbers.Integral) and order == 2):
            raise ValueError(f"order: the gaussian closure has order 2, got {shown(order)}")
        return GaussianClosure()
    if name == "cumulant":
        return CumulantClosure(4 if order is None else order)
    return EdgeworthClosure(4 if order is None else order)  # "edgeworth", "quasi-moment"


def kept_order(closure: Closure, order: int | None) -> int:
    """The order N of the kept moment set for ``closure``: ``order`` if given, else the closure's
    own order. ``order`` below the closure's order is refused: the closure reads every moment of
    degree ≤ its order, so they must all be kept. (A larger ``order`` keeps more moments than the
    closure reads: allowed, but such a set is closed less consistently and can diverge.)

    >>> kept_order(GaussianClosure(), None), kept_order(EdgeworthClosure(4), 6)
    (2, 6)
    """
    if not isinstance(closure, Closure):
        raise TypeError(f"closure: expected a Closure instance, got {type(closure).__name__}")
    if order is None:
        return closure.order
    if isinstance(order, bool) or not isinstance(order, int):
        raise ValueError(f"order: expected an integer or None (the closure's order), got {shown(order)}")
    if order < closure.order:
        raise ValueError(f"order, closure: expected order ≥ {closure.order}, the order of closure={closure!r} "
                         f"(it reads every moment of degree ≤ {closure.order}), got order={order}")
    return order


def gaussian_moments(mean, cov, indices: Sequence[tuple]) -> np.ndarray:
    """Raw moments ``E[x^γ]`` of N(mean, cov) for each γ in ``indices``; batched:
    ``mean (..., n)``, ``cov (..., n, n)`` -> ``(..., len(indices))``.

    ``cov`` must be a (batch of) finite symmetric positive semi-definite matrices: a negative
    variance has no Gaussian law, and is a ``ValueError`` naming ``cov`` and its smallest
    eigenvalue (tolerance 1e-10 relative to its largest entry).

    >>> gaussian_moments([2.0], [[1.0]], [(1,), (2,), (3,)]).tolist()
    [2.0, 5.0, 14.0]
    """
    mean = as_float_array("mean", mean, ndim_min=1)
    finite("mean", mean)
    cov = as_float_array("cov", cov)
    n = mean.shape[-1]
    if cov.shape[-2:] != (n, n):
        raise ValueError(f"cov: expected trailing shape ({n}, {n}), got {cov.shape}")
    covariance("cov", cov, n, batch=True)
    batch = np.broadcast_shapes(mean.shape[:-1], cov.shape[:-2])
    mean = np.broadcast_to(mean, (*batch, n))
    cov = np.broadcast_to(cov, (*batch, n, n))
    raw = {(0,) * n: np.ones(batch)}
    for i in range(n):
        raw[unit_exp(n, i)] = mean[..., i]
    for i in range(n):
        for j in range(i, n):
            raw[add_exp(unit_exp(n, i), unit_exp(n, j))] = cov[..., i, j] + mean[..., i] * mean[..., j]
    out = GaussianClosure().complete(raw, [tuple(g) for g in indices])
    return np.stack([np.broadcast_to(o, batch) for o in out], axis=-1)
