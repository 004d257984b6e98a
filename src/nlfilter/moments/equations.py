"""The moment-equation container: sparse ``(A, B, c)`` over kept and missing monomials.

Both moment generators (:func:`~nlfilter.moments.ito.moment_equations` in continuous time,
:func:`~nlfilter.moments.discrete.discrete_moment_equations` in discrete time) produce, per kept
monomial, a row ``{(exponent, coefficient group): weight}``; ``_assemble`` turns the rows into
:class:`MomentEquations`: ``dμ/dt = A μ + B ν + c`` (or ``μ⁺ = A μ + B ν + c``), with ``ν`` the
moments of the monomials reached outside the kept set (``missing``) and ``c`` the constant
monomial (``E[1] = 1``) unless ``(0,…,0)`` is kept.

Coefficients may depend on time or on other symbols (e.g. tabulated gains): a coefficient is split
into coefficient groups ``Σ_j w_j g_j`` (numbers ``w_j``, symbolic factors ``g_j``, ``_Groups``),
the matrices are stored as ``Σ_j g_j(t, symbols) (A_j, B_j, c_j)`` on their union sparsity pattern
and evaluated with :meth:`MomentEquations.at`.

Also here: :func:`degree_order` (the sort key of monomials), :func:`matvec` (a sparse matrix over a
batch of moment vectors) and the multi-index checks shared by the generators.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sps
import sympy as sp

from ..codegen import lambdify_numpy
from ..polynomials import Polynomial

__all__ = ["MomentEquations", "degree_order", "matvec"]


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


def _symbols_for(time, groups: _Groups):
    syms = set()
    for e in groups.exprs:
        syms |= sp.sympify(e).free_symbols
    rest = sorted(syms - {time}, key=str)
    return tuple(([time] if time is not None and time in syms else []) + rest) if syms else ()
