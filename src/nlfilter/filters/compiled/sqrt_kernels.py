"""The square-root filters' kernels of the compiled loop (``sr-kf``, ``sr-ekf``: rule kind
``"sqrt-taylor1"``; ``sr-ukf``, ``sr-ckf``, ``sr-ghkf``, ``sr-slf``: ``"sqrt-nodes"``), the steps of
:mod:`nlfilter.filters.square_root` on one path, allocating nothing. The template's ``P``
(:func:`.loops.steps_`) holds the lower-triangular factor ``S`` (``P = S Sᵀ``); the run reports
``S Sᵀ`` symmetrized, as :meth:`~nlfilter.filters.square_root.SquareRootFilter.summary`.

* :func:`tria_`: ``L`` with ``L Lᵀ = A Aᵀ`` by Householder reflections from the right (the rows of
  ``A`` reduced in turn: ``A Θ = [L 0]``, Θ orthogonal), the diagonal made non-negative: the ``Lᵀ``
  of NumPy's QR of ``Aᵀ`` (:func:`~nlfilter.filters.triangular.tria`), to rounding.
* :func:`downdate_`: the rank-one Cholesky downdate of :func:`~nlfilter.filters.triangular.downdate`
  (hyperbolic rotations, the same arithmetic); False where the result is not positive definite
  (a negative zeroth weight that the standard filter's covariance could not carry either: the path
  diverges there, reported as the NumPy loop reports it).
* :func:`array_update_`: the measurement update in array form, ``tria([[Y, R^½], [X, 0]]) =
  [[S_y, 0], [K̄, S⁺]]``, ``m⁺ = m⁻ + K̄ S_y⁻¹ (y − ŷ)``; missing components: their rows of ``Y``
  zeroed, ``R`` replaced by its observed block (unit diagonal elsewhere); the log-likelihood from
  the innovation factor (:func:`~nlfilter.filters.square_root.factor_info`).

The predict and update kernels have the signatures of :mod:`.rule_kernels`; ``ks`` holds
``(Q^½, R^½)`` (nodes: ``(z, wm, wc, Q^½, R^½)``, the rule's table as data), the roots the NumPy
filter takes (``SquareRootFilter._root``).
"""

from __future__ import annotations

import math

import numpy as np

from .path_linalg import mm, sqrt_check
from .step_kernels import LOG_2PI
from .support import jit

__all__ = ["SOURCES", "KERNELS", "ALLOC", "tria", "downdate", "array_update", "alloc_sqrt"]


def tria_(A, p, q, v):
    """``A[:p, :p] = L`` (lower-triangular, ``L_ii ≥ 0``) with ``L Lᵀ = A Aᵀ`` of ``A[:p, :q]``
    (Householder: row ``k`` reflected onto ``e_k``, the reflection applied to the rows below);
    columns ``q..p-1`` taken as zeros when ``q < p``. Non-finite entries give NaN."""
    for j in range(q, p):
        for i in range(p):
            A[i, j] = 0.0
    qq = max(p, q)
    for k in range(p):
        s = 0.0
        for j in range(k, qq):
            s += A[k, j] * A[k, j]
        norm = math.sqrt(s)
        if norm == 0.0:
            continue
        alpha = A[k, k]
        beta = -norm if alpha >= 0.0 else norm
        for j in range(k + 1, qq):
            v[j] = A[k, j]
        v[k] = alpha - beta
        vv = v[k] * v[k] + (s - alpha * alpha)
        if vv > 0.0:
            for i in range(k + 1, p):
                d = 0.0
                for j in range(k, qq):
                    d += A[i, j] * v[j]
                d = 2.0 * d / vv
                for j in range(k, qq):
                    A[i, j] -= d * v[j]
        A[k, k] = beta
        for j in range(k + 1, qq):
            A[k, j] = 0.0
    for j in range(p):  # non-negative diagonal: the column's sign
        if A[j, j] < 0.0:
            for i in range(j, p):
                A[i, j] = -A[i, j]


def downdate_(L, x, p):
    """``L Lᵀ − x xᵀ`` as ``L`` (lower-triangular ``L[:p, :p]``, ``x`` destroyed); False where it is
    not positive definite (``L_kk² ≤ x_k²`` with ``x_k ≠ 0``, or NaN)."""
    for k in range(p):
        Lkk, xk = L[k, k], x[k]
        if xk == 0.0:
            continue
        r2 = Lkk * Lkk - xk * xk
        if not r2 > 0.0:
            return False
        r = math.sqrt(r2)
        c, s = r / Lkk, xk / Lkk
        L[k, k] = r
        for i in range(k + 1, p):
            col = (L[i, k] - s * x[i]) / c
            L[i, k] = col
            x[i] = c * x[i] - s * col
    return True


def array_update_(m, S, y, yhat, A, c, NV, nneg, R, LR, n, mdim, tol, want, l1, i1, c1, v, Rm, Lm, W, ev, V, u):
    """The array-form update on one path (module docstring). ``A[:mdim, :c]`` holds ``Y``,
    ``A[mdim:mdim+n, :c]`` ``X`` (the columns of positive weight), ``NV[:nneg]`` the downdates
    ``[Y_i, X_i]`` of negative weights; ``LR``: ``R^½``. Updates ``m`` and ``S`` in place; False
    where the path fails (a downdate, a singular innovation factor, a non-finite result)."""
    p, q = mdim, c + mdim
    mo = 0
    for a in range(p):
        if not math.isnan(y[a]):
            mo += 1
    if want:  # S = Y Yᵀ + R − Σ neg (all components, before the missing ones are dropped)
        for a in range(p):
            for b in range(p):
                s = 0.0
                for j in range(c):
                    s += A[a, j] * A[b, j]
                c1[a, b] = s + R[a, b]
        for i in range(nneg):
            for a in range(p):
                for b in range(p):
                    c1[a, b] -= NV[i, a] * NV[i, b]
    if mo < p:  # the observed block of R (unit diagonal elsewhere), the missing rows of Y zeroed
        for a in range(p):
            for b in range(p):
                both = math.isnan(y[a]) or math.isnan(y[b])
                Rm[a, b] = (1.0 if a == b else 0.0) if both else R[a, b]
            if math.isnan(y[a]):
                for j in range(c):
                    A[a, j] = 0.0
                for i in range(nneg):
                    NV[i, a] = 0.0
        if not sqrt_check(Rm, Lm, p, tol, W, ev, V):
            return False
    else:
        for a in range(p):
            for b in range(p):
                Lm[a, b] = LR[a, b]
    for a in range(p):
        for b in range(p):
            A[a, c + b] = Lm[a, b]
    for i in range(n):
        for b in range(p):
            A[p + i, c + b] = 0.0
    tria(A, p + n, q, v)
    for i in range(nneg):
        for j in range(p + n):
            v[j] = NV[i, j]
        if not downdate(A, v, p + n):
            return False
    for a in range(p):
        if not A[a, a] > 0.0:  # a singular (or non-finite) innovation factor
            return False
    for a in range(p):  # u = S_y⁻¹ (y − ŷ), 0 where missing
        e = 0.0 if math.isnan(y[a]) else y[a] - yhat[a]
        for b in range(a):
            e -= A[a, b] * u[b]
        u[a] = e / A[a, a]
    for i in range(n):
        s = 0.0
        for a in range(p):
            s += A[p + i, a] * u[a]
        m[i] = m[i] + s
        for j in range(n):
            S[i, j] = A[p + i, p + j] if j <= i else 0.0
    if want:
        uu, logdet = 0.0, 0.0
        for a in range(p):
            uu += u[a] * u[a]
            logdet += math.log(A[a, a])
            i1[a] = y[a] - yhat[a]  # NaN where missing
        l1[0] = -0.5 * (uu + 2.0 * logdet + mo * LOG_2PI)
        if mo == 0:
            for a in range(p):
                for b in range(p):
                    c1[a, b] = np.nan
    return finite(m, S, n)


def finite_(m, S, n):
    """Whether the path's mean and factor are finite (``S Sᵀ`` of a finite factor passes the
    divergence test of :func:`~nlfilter.filters.linalg.bad_paths`)."""
    for i in range(n):
        if not math.isfinite(m[i]):
            return False
        for j in range(n):
            if not math.isfinite(S[i, j]):
                return False
    return True


def alloc_sqrt(n, mdim, r, N=0):
    """The work arrays of the square-root kernels (``N`` nodes; 0: Taylor-1)."""
    e = np.empty
    N1 = max(N, 1)
    cols = n + r + N1 * (1 + r) + mdim + n
    big = max(n, mdim)
    return (e((n + mdim, cols)), e(cols + n + mdim), e((N1, n)), e((N1, big)), e((N1, big)), e((n, r)), e((n, r)),
            e((n, n)), e(n), e(mdim), e((mdim, n)), e((N1 * (1 + r) + 1, n + mdim)),
            e((mdim, mdim)), e((mdim, mdim)), e((mdim, mdim)), e(mdim), e((mdim, mdim)), e(mdim))


def predict_sqrt_taylor1_(f, fx, G, m, S, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``m⁻ = f(m)``, ``S⁻ = tria([F S, G(m) Q^½])``."""
    A, v, X, GX, D, Gm, GL, F, mp, yhat, Hm, NV, Rm, Lm, W, ev, V, u = ws
    Lq = ks[0]
    r = Lq.shape[0]
    f(m, t, p, mp)
    fx(m, t, p, F)
    G(m, t, p, Gm)
    mm(F, S, A, n, n, n, False)  # F S in the first n columns (A's rows are longer: mm writes [:n, :n])
    mm(Gm, Lq, GL, n, r, r, False)
    for i in range(n):
        for j in range(r):
            A[i, n + j] = GL[i, j]
    tria(A, n, n + r, v)
    for i in range(n):
        m[i] = mp[i]
        for j in range(n):
            S[i, j] = A[i, j] if j <= i else 0.0
    return finite(m, S, n)


def update_sqrt_taylor1_(h, hx, m, S, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
    """``ŷ = h(m⁻)``, the array update of ``[[H S⁻, R^½], [S⁻, 0]]``."""
    A, v, X, GX, D, Gm, GL, F, mp, yhat, Hm, NV, Rm, Lm, W, ev, V, u = ws
    h(m, t, p, yhat)
    hx(m, t, p, Hm)
    mm(Hm, S, A, mdim, n, n, False)  # H S⁻
    for i in range(n):
        for j in range(n):
            A[mdim + i, j] = S[i, j]
    return array_update(m, S, y, yhat, A, n, NV, 0, R, ks[1], n, mdim, tol, want, l1, i1, c1, v, Rm, Lm, W, ev, V, u)


def sr_points_(m, S, z, X, n, N):
    """``X_i = m + S z_i``."""
    for i in range(N):
        for j in range(n):
            s = m[j]
            for q in range(n):
                s += z[i, q] * S[j, q]
            X[i, j] = s


def sr_moments_(GX, wm, N, pdim, mean, D):
    """``mean = Σ wm_i GX_i``, ``D_i = GX_i − mean``."""
    for a in range(pdim):
        s = 0.0
        for i in range(N):
            s += wm[i] * GX[i, a]
        mean[a] = s
    for i in range(N):
        for a in range(pdim):
            D[i, a] = GX[i, a] - mean[a]


def sr_split_(D, wc, N, pdim, A, NV, off):
    """The columns ``√wc_i D_i`` of the nodes of positive weight into ``A[off:off+pdim]`` and the
    downdates ``√|wc_i| D_i`` of those of negative weight into ``NV[:, off:off+pdim]``; returns
    their counts ``(c, nneg)``."""
    c, nneg = 0, 0
    for i in range(N):
        w = math.sqrt(abs(wc[i]))
        if wc[i] > 0.0:
            for a in range(pdim):
                A[off + a, c] = D[i, a] * w
            c += 1
        elif wc[i] < 0.0:
            for a in range(pdim):
                NV[nneg, off + a] = D[i, a] * w
            nneg += 1
    return c, nneg


def predict_sqrt_nodes_(f, G, m, S, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``m⁻ = Σ wm_i f(X_i)``, ``S⁻ = tria([√wc_i (f(X_i) − m⁻), noise])`` (``wc_i > 0``), downdated
    by the nodes of negative weight; the noise ``G(m) Q^½``, or ``√wm_i G(X_i) Q^½`` for a G of the state."""
    A, v, X, GX, D, Gm, GL, F, mp, yhat, Hm, NV, Rm, Lm, W, ev, V, u = ws
    z, wm, wc, Lq = ks[0], ks[1], ks[2], ks[3]
    N, r = z.shape[0], Lq.shape[0]
    sr_points(m, S, z, X, n, N)
    for i in range(N):
        f(X[i], t, p, GX[i])
    sr_moments(GX, wm, N, n, mp, D)
    c, nneg = sr_split(D, wc, N, n, A, NV, 0)
    if G_const:
        G(m, t, p, Gm)
        mm(Gm, Lq, GL, n, r, r, False)
        for a in range(n):
            for j in range(r):
                A[a, c + j] = GL[a, j]
        c += r
    else:
        for i in range(N):
            if wm[i] == 0.0:
                continue
            G(X[i], t, p, Gm)
            mm(Gm, Lq, GL, n, r, r, False)
            w = math.sqrt(abs(wm[i]))
            for j in range(r):
                if wm[i] > 0.0:
                    for a in range(n):
                        A[a, c] = GL[a, j] * w
                    c += 1
                else:
                    for a in range(n):
                        NV[nneg, a] = GL[a, j] * w
                    nneg += 1
    tria(A, n, c, v)
    for i in range(nneg):
        for a in range(n):
            v[a] = NV[i, a]
        if not downdate(A, v, n):
            return False
    for i in range(n):
        m[i] = mp[i]
        for j in range(n):
            S[i, j] = A[i, j] if j <= i else 0.0
    return finite(m, S, n)


def update_sqrt_nodes_(h, m, S, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
    """``ŷ = Σ wm_i h(X_i)``, the array update of ``[[√wc_i (h(X_i) − ŷ), R^½], [√wc_i (X_i − m⁻), 0]]``
    (``wc_i > 0``), downdated by ``√|wc_i| [h(X_i) − ŷ, X_i − m⁻]`` for ``wc_i < 0``."""
    A, v, X, GX, D, Gm, GL, F, mp, yhat, Hm, NV, Rm, Lm, W, ev, V, u = ws
    z, wm, wc, LR = ks[0], ks[1], ks[2], ks[4]
    N = z.shape[0]
    sr_points(m, S, z, X, n, N)
    for i in range(N):
        h(X[i], t, p, GX[i])
    sr_moments(GX, wm, N, mdim, yhat, D)
    for i in range(N):  # Z_i = X_i − m⁻ (GX is free again)
        for j in range(n):
            GX[i, j] = X[i, j] - m[j]
    sr_split(D, wc, N, mdim, A, NV, 0)
    c, nneg = sr_split(GX, wc, N, n, A, NV, mdim)
    return array_update(m, S, y, yhat, A, c, NV, nneg, R, LR, n, mdim, tol, want, l1, i1, c1, v, Rm, Lm, W, ev, V, u)


#: the helpers' Python sources (compiled in the generated loops of the square-root kinds, :mod:`.build`)
SOURCES = (tria_, downdate_, array_update_, finite_, sr_points_, sr_moments_, sr_split_)
#: the kernels' sources by rule kind: ``(predict, update)``
KERNELS = {"sqrt-taylor1": (predict_sqrt_taylor1_, update_sqrt_taylor1_),
           "sqrt-nodes": (predict_sqrt_nodes_, update_sqrt_nodes_)}
#: their work arrays by rule kind
ALLOC = {"sqrt-taylor1": alloc_sqrt, "sqrt-nodes": alloc_sqrt}

tria = jit(tria_, _nrt=False)
downdate = jit(downdate_, _nrt=False)
finite = jit(finite_, _nrt=False)
sr_points = jit(sr_points_, _nrt=False)
sr_moments = jit(sr_moments_, _nrt=False)
sr_split = jit(sr_split_, _nrt=False)
array_update = jit(array_update_, _nrt=False)
