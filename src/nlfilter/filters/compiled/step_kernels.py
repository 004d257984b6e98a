"""One-path step kernels of the compiled loop (allocating nothing): the predicted and measurement
covariances of the Taylor rules, the node rules' points and weighted moments, the second-order terms of seed
004 (eqs. 9, 18-23), the update of :func:`~nlfilter.filters.linalg.gaussian_update` with partly
missing measurements, and writing or marking (NaN) a path's outputs.

Each kernel is written as Python (``name_``, whose source :mod:`.build` compiles again inlined
for the specialized loops) and compiled as ``name`` (numba, without reference counting).
"""

from __future__ import annotations

import math

import numpy as np

from .path_linalg import chol, lu, lu_solve, mm, sqrt_check, symmetrize, transpose
from .support import jit

__all__ = ["SOURCES", "LOG_2PI", "work", "predict_cov", "meas_cov", "add_gqg", "condition", "write", "mark",
           "nodes_moments", "nodes_gqg", "nodes_points", "hess_trace", "quartic"]


def predict_cov_(F, P, N, out, T1, T2, n):
    """``out = F P Fᵀ + N`` (``out`` may be ``P``; ``T1``, ``T2`` scratch)."""
    transpose(F, T1, n, n)
    mm(P, T1, T2, n, n, n, False)  # P Fᵀ
    for i in range(n):
        for j in range(n):
            out[i, j] = N[i, j]
    mm(F, T2, out, n, n, n, True)


def meas_cov_(P, H, R, Ht, C, S, n, mdim):
    """``C = P Hᵀ`` and ``S = H C + R`` (the linearized measurement moments)."""
    transpose(H, Ht, mdim, n)
    mm(P, Ht, C, n, n, mdim, False)
    for a in range(mdim):
        for c in range(mdim):
            S[a, c] = R[a, c]
    mm(H, C, S, mdim, n, mdim, True)


def add_gqg_(G, Q, GQ, out, w, n, r):
    """``out += w · G Q Gᵀ`` (``GQ`` scratch)."""
    for i in range(n):
        for a in range(r):
            s = 0.0
            for c in range(r):
                s += G[i, c] * Q[c, a]
            GQ[i, a] = s
    for i in range(n):
        for j in range(n):
            s = 0.0
            for a in range(r):
                s += GQ[i, a] * G[j, a]
            out[i, j] += w * s


def condition_(m, P, y, yhat, S, C, H, R, joseph, M, forcing, screen, n, mdim, w, want, ll_out, inn_out, cov_out):
    """The update of :func:`~nlfilter.filters.linalg.gaussian_update` on one path (``m``, ``P`` in
    place): the observed components ``o`` of ``y``, ``K = C_o S_oo⁻¹`` (row by row: ``K_i =
    S_oo⁻¹ C_o,i``, S symmetric, as NumPy's ``solve(S, Cᵀ)ᵀ``), Joseph form ``(I − K H_o) P (I − K
    H_o)ᵀ + K R_oo Kᵀ`` with ``H`` or ``P − K S_oo Kᵀ``, symmetrized; the forcing ``Σ_k M_ijk
    [S⁻¹e]_k`` when ``forcing``; ``screen``: S must be positive definite (Taylor-2). Writes the
    likelihood outputs when ``want``. Returns False for a failed path (singular or screened-out S)."""
    idx, So, Sc, Co, Ho, Ro, K, Kt, KR, e, piv, u, IKH, IKHt, T1 = w
    mo = 0
    for i in range(mdim):
        if not math.isnan(y[i]):
            mo += 1
    if mo == mdim:  # the common case: every component observed
        for i in range(mdim):
            idx[i] = i
    else:  # (filling idx in the counting loop above costs ~60 ns a call: a store-to-load stall)
        q = 0
        for i in range(mdim):
            if not math.isnan(y[i]):
                idx[q] = i
                q += 1
    if screen:  # the innovation covariance must be positive definite (gaussian._pd_mask)
        if mdim == 1:
            if not S[0, 0] > 0.0:
                return False
        else:
            for i in range(mdim):
                for j in range(mdim):
                    So[i, j] = 0.5 * (S[i, j] + S[j, i])
            if not chol(So, T1, mdim):
                return False
    if want:
        for i in range(mdim):
            inn_out[i] = y[i] - yhat[i]  # NaN where missing
            for j in range(mdim):
                cov_out[i, j] = S[i, j] if mo > 0 else np.nan
    if mo == 0:  # nothing measured on this path: K = 0 (P symmetrized, as the batched update does)
        if want:
            ll_out[0] = 0.0
        symmetrize(P, n)
        return True
    for a in range(mo):  # the observed blocks
        ia = idx[a]
        e[a] = y[ia] - yhat[ia]
        for c in range(mo):
            So[a, c] = S[ia, idx[c]]
            Sc[a, c] = So[a, c]
            Ro[a, c] = R[ia, idx[c]]
        for j in range(n):
            Ho[a, j] = H[ia, j]
    for i in range(n):
        for a in range(mo):
            Co[i, a] = C[i, idx[a]]
    ok, sign, logdet = lu(So, piv, mo)
    if not ok:
        return False
    for i in range(n):  # K_i = S_oo⁻¹ C_o,i
        for a in range(mo):
            u[a] = Co[i, a]
        lu_solve(So, piv, mo, u)
        for a in range(mo):
            K[i, a] = u[a]
            Kt[a, i] = u[a]
    if want or forcing:
        for a in range(mo):
            u[a] = e[a]
        lu_solve(So, piv, mo, u)  # S_oo⁻¹ e
        if want:
            if sign > 0:
                q = 0.0
                for a in range(mo):
                    q += e[a] * u[a]
                ll_out[0] = -0.5 * (q + logdet + mo * LOG_2PI)
            else:
                ll_out[0] = np.nan
    for i in range(n):
        v = 0.0
        for a in range(mo):
            v += K[i, a] * e[a]
        m[i] += v
    if n == 1 and mdim == 1:  # gaussian_update's scalar branch, its products in its order (not
        k1 = K[0, 0]  # (1 − K H) P (1 − K H) + (K R) K: each order rounds apart, 1e-16 a step that
        if joseph:  # a cubic sensor grows to 1e-11 over 200 steps)
            a1 = 1.0 - k1 * Ho[0, 0]
            P[0, 0] = a1 * a1 * P[0, 0] + k1 * k1 * Ro[0, 0]
        else:
            P[0, 0] = P[0, 0] - k1 * k1 * Sc[0, 0]
    elif joseph:  # (I − K H_o) P (I − K H_o)ᵀ + K R_oo Kᵀ
        for i in range(n):
            for j in range(n):
                IKH[i, j] = 1.0 if i == j else 0.0
            for a in range(mo):
                v = K[i, a]
                for j in range(n):
                    IKH[i, j] -= v * Ho[a, j]
        mm(IKH, P, T1, n, n, n, False)
        transpose(IKH, IKHt, n, n)
        mm(T1, IKHt, P, n, n, n, False)
        mm(K, Ro, KR, n, mo, mo, False)
        mm(KR, Kt, P, n, mo, n, True)
    else:  # P − K S_oo Kᵀ
        mm(K, Sc, KR, n, mo, mo, False)
        for i in range(n):
            for a in range(mo):
                v = KR[i, a]
                for j in range(n):
                    P[i, j] -= v * Kt[a, j]
    if forcing:  # P += Σ_k M_ijk u_k (u = S⁻¹ e on the observed components)
        for i in range(n):
            for j in range(n):
                v = 0.0
                for a in range(mo):
                    v += M[i, j, idx[a]] * u[a]
                P[i, j] += v
    symmetrize(P, n)
    return True


LOG_2PI = math.log(2 * math.pi)


def nodes_moments_(g, X, GX, wm, wc, m, t, p, N, pdim, n, mean, D, Cov, Cross, cross):
    """``E[g] = Σ w_i g(X_i)``, ``Cov[g] = Σ wc_i D_i D_iᵀ``, ``Cov[x, g] = Σ wc_i (X_i − m) D_iᵀ``
    (``D_i = g(X_i) − E[g]``; node by node, rows contiguous)."""
    for i in range(N):
        g(X[i], t, p, GX[i])
    for a in range(pdim):
        mean[a] = 0.0
    for i in range(N):
        wi = wm[i]
        for a in range(pdim):
            mean[a] += wi * GX[i, a]
    for a in range(pdim):
        for c in range(pdim):
            Cov[a, c] = 0.0
    if cross:
        for j in range(n):
            for a in range(pdim):
                Cross[j, a] = 0.0
    for i in range(N):
        for a in range(pdim):
            D[i, a] = GX[i, a] - mean[a]
        wi = wc[i]
        for a in range(pdim):
            v = wi * D[i, a]
            for c in range(pdim):
                Cov[a, c] += v * D[i, c]
        if cross:
            for j in range(n):
                v = wi * (X[i, j] - m[j])
                if v != 0.0:
                    for a in range(pdim):
                        Cross[j, a] += v * D[i, a]


def nodes_gqg_(G, X, Q, Gm, GQ, out, wm, t, p, N, n, r):
    """``out = Σ wm_i G(X_i) Q G(X_i)ᵀ``: E[G Q Gᵀ] over the nodes (``Gm``, ``GQ`` scratch)."""
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.0
    for i2 in range(N):
        G(X[i2], t, p, Gm)
        add_gqg(Gm, Q, GQ, out, wm[i2], n, r)


def nodes_points_(m, P, z, X, L, W, ev, V, n, N, tol, Pc):
    """``X_i = m + L z_i`` (``L Lᵀ = P``: Cholesky, the eigen root where P is only semi-definite);
    False where P has no root. ``L`` is already the Cholesky factor where ``Pc`` holds ``P``'s lower
    triangle (:func:`~.path_linalg.psd_root_`, the previous kernel's test of the same P)."""
    same = False
    if n > 2:  # (for n ≤ 2 none is kept)
        same = True
        for i in range(n):
            for j in range(i + 1):
                if Pc[i, j] != P[i, j]:  # (also False for NaN)
                    same = False
    if not same and not sqrt_check(P, L, n, tol, W, ev, V):
        return False
    transpose(L, W, n, n)  # the columns of L as rows (W as scratch)
    for i in range(N):  # X_i = m + L z_i (the sigma and cubature z_i have one nonzero)
        for j in range(n):
            X[i, j] = m[j]
        for q in range(n):
            v = z[i, q]
            if v != 0.0:
                for j in range(n):
                    X[i, j] += v * W[q, j]
    return True


def hess_trace_(P, A, n, pdim, out):
    """``out_i = Σ_jl P_jl A_ijl`` (004 eqs. 9, 23)."""
    for i in range(pdim):
        s = 0.0
        for j in range(n):
            for q in range(n):
                s += P[j, q] * A[i, j, q]
        out[i] = s


def quartic_(kind, P, A, tr, n, pdim, AP, out):
    """The fourth-moment term added to ``out (pdim, pdim)``: 1 = −¼ tr tᵀ, 2 = ½ tr(A_i P A_j P)."""
    if kind == 1:
        for i in range(pdim):
            for j in range(pdim):
                out[i, j] -= 0.25 * tr[i] * tr[j]
    elif kind == 2:
        for i in range(pdim):  # (A_i P)_ac
            for a in range(n):
                for c in range(n):
                    s = 0.0
                    for q in range(n):
                        s += A[i, a, q] * P[q, c]
                    AP[i, a, c] = s
        for i in range(pdim):
            for j in range(pdim):
                s = 0.0
                for a in range(n):
                    for c in range(n):
                        s += AP[i, a, c] * AP[j, c, a]
                out[i, j] += 0.5 * s


def write_(means, covs, ll, inn, icov, b, k, m, P, want, absent, l1, i1, c1):
    """Step ``k``'s outputs of path ``b`` (a step measured on no path: log-likelihood 0, NaN innovation)."""
    n = m.shape[0]
    for i in range(n):
        means[b, k, i] = m[i]
        for j in range(n):
            covs[b, k, i, j] = P[i, j]
    if want:
        mdim = i1.shape[0]
        ll[b, k] = 0.0 if absent else l1[0]
        for i in range(mdim):
            inn[b, k, i] = np.nan if absent else i1[i]
            for j in range(mdim):
                icov[b, k, i, j] = np.nan if absent else c1[i, j]


def mark_(means, covs, ll, inn, icov, want, b, k0):
    """NaN on path ``b`` from step ``k0`` on (a diverged path)."""
    T, n = means.shape[1], means.shape[2]
    for k in range(k0, T):
        for i in range(n):
            means[b, k, i] = np.nan
            for j in range(n):
                covs[b, k, i, j] = np.nan
        if want:
            mdim = inn.shape[2]
            ll[b, k] = np.nan
            for i in range(mdim):
                inn[b, k, i] = np.nan
                for j in range(mdim):
                    icov[b, k, i, j] = np.nan


def work(n, mdim):
    """The work arrays of :func:`condition_`."""
    e = np.zeros
    return (e(mdim, np.int64), e((mdim, mdim)), e((mdim, mdim)), e((n, mdim)), e((mdim, n)), e((mdim, mdim)),
            e((n, mdim)), e((mdim, n)), e((n, mdim)), e(mdim), e(mdim, np.int64), e(max(mdim, n)), e((n, n)),
            e((n, n)), e((n, n)))




#: the Python sources of this module's kernels (compiled below; inlined by :mod:`.build`)
SOURCES = (predict_cov_, meas_cov_, add_gqg_, condition_, write_, mark_, nodes_moments_, nodes_gqg_, nodes_points_, hess_trace_,
           quartic_)

# raw functions (no reference counting, as path_linalg's); not inlined here (numba's
# inline="always" gains 30 % at n ≤ 2, nothing from n = 4, and triples the compile time: 10-20 s
# per model and rule kind against 3-7 s) — the specialized loops of build inline them
predict_cov = jit(predict_cov_, _nrt=False)
meas_cov = jit(meas_cov_, _nrt=False)
add_gqg = jit(add_gqg_, _nrt=False)
condition = jit(condition_, _nrt=False)
write = jit(write_, _nrt=False)
mark = jit(mark_, _nrt=False)
nodes_moments = jit(nodes_moments_, _nrt=False)
nodes_gqg = jit(nodes_gqg_, _nrt=False)
nodes_points = jit(nodes_points_, _nrt=False)
hess_trace = jit(hess_trace_, _nrt=False)
quartic = jit(quartic_, _nrt=False)
