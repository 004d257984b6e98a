"""The step kernels of the compiled loop, one predict and one update per rule kind (``rule.kind``):
Taylor-1 (the EKF), node rules (unscented, cubature, Gauss–Hermite, SLF: the rule's table
``(z, wm, wc)``), Taylor-2 (seed 004 eqs. 18-23 in every form of
:data:`~nlfilter.filters.rules.FORM_TABLE`) and the linear Kalman filter's (``"kalman"``:
:mod:`.kalman_loop`, the model's matrices as data in ``ks``) and the square-root filters' (``"sqrt-taylor1"``,
``"sqrt-nodes"``: :mod:`.sqrt_kernels`, the factor in place of ``P``) and the continuous Itô filters'
(``"ito"``: :mod:`.ito_kernels`, the whole step in the update) and the continuous-discrete EKF's
(``"cd-taylor1"``, ``"cd-taylor2"``, ``"cd-nodes"``: :mod:`.cd_kernels`, the moment equations
integrated, then the discrete rule's update). The time loop around them is one template
(:func:`.loops.steps_`); a kernel is all that differs between the rule kinds.

Every kernel works on one path in place (``m``, ``P``) and returns False where the path fails
(a failed square root, a singular or screened-out innovation covariance, a covariance that fails
the divergence test). The signatures are uniform::

    predict_KIND_(<f, fx, ...>, m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim) -> ok
    update_KIND_(<h, hx, ...>, m, P, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim) -> ok

``ks``: the kind's constants (nodes: ``(z, wm, wc)``; Taylor-2: ``(second, prediction kind,
innovation kind, forcing kind, joseph)``); ``ws``: its work arrays (``alloc_KIND``, allocated once
per run in NumPy). The leading parameters, the model's functions (``f, fx, fxx, h, hx, hxx, G``),
are bound as globals by :func:`.build.steps` (numba then calls them directly and can inline them;
passed as arguments they would be first-class function pointers): these are sources, compiled
there, never called as Python.
"""

from __future__ import annotations

import numpy as np

from . import cd_kernels, ito_kernels, sqrt_kernels
from .path_linalg import mm, psd_check, psd_root
from .kalman_loop import alloc_kalman, predict_kalman_, update_kalman_
from .step_kernels import (add_gqg, condition, meas_cov, nodes_gqg, nodes_moments, nodes_points, predict_cov,
                           quartic, work)

__all__ = ["KERNELS_BY_KIND", "ALLOC", "alloc_taylor1", "alloc_nodes", "alloc_taylor2"]


def alloc_taylor1(n, mdim, r, N=0):
    """The work arrays of the Taylor-1 kernels."""
    mp, F, C, Hm, S = np.empty(n), np.empty((n, n)), np.empty((n, mdim)), np.empty((mdim, n)), np.empty((mdim, mdim))
    Gm, GQ, Nn = np.empty((n, r)), np.empty((n, r)), np.empty((n, n))
    yhat, FP = np.empty(mdim), np.empty((n, n))
    W, L, ev = np.empty((n, n)), np.empty((n, n)), np.empty(n)
    return (mp, F, C, Hm, S, Gm, GQ, Nn, yhat, FP, W, L, ev, work(n, mdim), np.empty((1, 1, 1)), np.empty((n, mdim)))


def predict_taylor1_(f, fx, G, m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``m⁻ = f(m)``, ``P⁻ = F P Fᵀ + G Q Gᵀ``."""
    mp, F, C, Hm, S, Gm, GQ, N, yhat, FP, W, L, ev, w, M0, Ht = ws
    r = Q.shape[0]
    f(m, t, p, mp)
    fx(m, t, p, F)
    if G_const:
        for i in range(n):
            for j in range(n):
                N[i, j] = GQG0[i, j]
    else:  # G(m) Q G(m)ᵀ
        G(m, t, p, Gm)
        for i in range(n):
            for j in range(n):
                N[i, j] = 0.0
        add_gqg(Gm, Q, GQ, N, 1.0, n, r)
    predict_cov(F, P, N, P, FP, W, n)  # F P Fᵀ + G Q Gᵀ
    for i in range(n):
        m[i] = mp[i]
    return psd_check(m, P, n, tol, W, L, ev)


def update_taylor1_(h, hx, m, P, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
    """``ŷ = h(m)``, ``C = P Hᵀ``, ``S = H C + R``; the Joseph-form update."""
    mp, F, C, Hm, S, Gm, GQ, N, yhat, FP, W, L, ev, w, M0, Ht = ws
    h(m, t, p, yhat)
    hx(m, t, p, Hm)
    meas_cov(P, Hm, R, Ht, C, S, n, mdim)  # C = P Hᵀ, S = H C + R
    ok = condition(m, P, y, yhat, S, C, Hm, R, True, M0, False, False, n, mdim, w, want, l1, i1, c1)
    return ok and psd_check(m, P, n, tol, W, L, ev)


def alloc_nodes(n, mdim, r, N=0):
    """The work arrays of the node kernels (``N`` nodes)."""
    pmax = max(n, mdim)
    L, W, L2, ev, V = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty(n), np.empty((n, n))
    X, GX, D = np.empty((N, n)), np.empty((N, pmax)), np.empty((N, pmax))
    mean, Cov, Cross = np.empty(pmax), np.empty((pmax, pmax)), np.empty((n, pmax))
    Gm, GQ, Nz = np.empty((n, r)), np.empty((n, r)), np.empty((n, n))
    S, C, yhat = np.empty((mdim, mdim)), np.empty((n, mdim)), np.empty(mdim)
    # H0: the update's H, read by condition_ into its observed rows though unused without Joseph
    # (1 × 1, it was read out of bounds)
    Pc = np.full((n, n), np.nan)  # the P whose Cholesky factor L holds (psd_root_), none yet
    return (L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz, S, C, yhat, np.zeros((mdim, n)),
            np.empty((1, 1, 1)), work(n, mdim), Pc)


def predict_nodes_(f, G, m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``m⁻ = Σ wm_i f(X_i)``, ``P⁻ = Σ wc_i D_i D_iᵀ + Σ wm_i G(X_i) Q G(X_i)ᵀ``."""
    z, wm, wc = ks[0], ks[1], ks[2]  # (the continuous-discrete kind's: more)
    L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz, S, C, yhat, H0, M0, w, Pc = ws
    r = Q.shape[0]
    N = z.shape[0]
    if not nodes_points(m, P, z, X, L, W, ev, V, n, N, tol, Pc):
        return False
    nodes_moments(f, X, GX, wm, wc, m, t, p, N, n, n, mean, D, Cov, Cross, False)
    if G_const:
        for i in range(n):
            for j in range(n):
                Nz[i, j] = GQG0[i, j]
    else:  # Σ w_i G(X_i) Q G(X_i)ᵀ
        nodes_gqg(G, X, Q, Gm, GQ, Nz, wm, t, p, N, n, r)
    for i in range(n):
        m[i] = mean[i]
        for j in range(n):
            P[i, j] = Cov[i, j] + Nz[i, j]
    return psd_root(m, P, n, tol, W, L2, ev, L, Pc)


def update_nodes_(h, m, P, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
    """``ŷ = Σ wm_i h(X_i)``, ``S = Σ wc_i D_i D_iᵀ + R``, ``C = Σ wc_i (X_i − m) D_iᵀ``; the update."""
    z, wm, wc = ks[0], ks[1], ks[2]  # (the continuous-discrete kind's: more)
    L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz, S, C, yhat, H0, M0, w, Pc = ws
    N = z.shape[0]
    if not nodes_points(m, P, z, X, L, W, ev, V, n, N, tol, Pc):
        return False
    nodes_moments(h, X, GX, wm, wc, m, t, p, N, mdim, n, mean, D, Cov, Cross, True)
    for a in range(mdim):
        yhat[a] = mean[a]
        for c in range(mdim):
            S[a, c] = Cov[a, c] + R[a, c]
        for j in range(n):
            C[j, a] = Cross[j, a]
    ok = condition(m, P, y, yhat, S, C, H0, R, False, M0, False, False, n, mdim, w, want, l1, i1, c1)
    return ok and psd_root(m, P, n, tol, W, L2, ev, L, Pc)


def alloc_taylor2(n, mdim, r, N=0):
    """The work arrays of the Taylor-2 kernels."""
    pmax = max(n, mdim)
    mp, F, Hm, C = np.empty(n), np.empty((n, n)), np.empty((mdim, n)), np.empty((n, mdim))
    S, FP, Af, Ah = np.empty((mdim, mdim)), np.empty((n, n)), np.empty((n, n, n)), np.empty((mdim, n, n))
    tr, AP, Cf, M = np.empty(pmax), np.empty((pmax, n, n)), np.empty((n, n)), np.empty((n, n, mdim))
    yhat, W, L, ev = np.empty(mdim), np.empty((n, n)), np.empty((n, n)), np.empty(n)
    return (mp, F, Hm, C, S, FP, Af, Ah, tr, AP, Cf, M, yhat, W, L, ev, work(n, mdim), np.empty((n, mdim)))


def predict_taylor2_(f, fx, fxx, fxt, m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``m⁻ = f + ½(P f_xx)``, ``P⁻ = F P Fᵀ + G Q Gᵀ`` + the form's fourth-moment term (004 eqs.
    18-19), symmetrized. ``(P f_xx)`` by the model's contraction ``fxt`` (the Hessian's non-zeros;
    the dense sum's numbers), the Hessian ``fxx`` itself only for the Gaussian term."""
    second, dyn_kind = ks[0], ks[1]  # the prediction reads the form's prediction kind only
    mp, F, FP, Af, tr, AP, Cf, W, L, ev = ws[0], ws[1], ws[5], ws[6], ws[8], ws[9], ws[10], ws[13], ws[14], ws[15]
    f(m, t, p, mp)
    fx(m, t, p, F)
    if second:
        if dyn_kind == 2:
            fxx(m, t, p, Af)
        fxt(m, t, p, P, tr)  # (P f_xx)
        for i in range(n):
            mp[i] += 0.5 * tr[i]
    predict_cov(F, P, GQG0, Cf, FP, W, n)  # F P Fᵀ + G Q Gᵀ (004 eq. 19)
    if second:
        quartic(dyn_kind, P, Af, tr, n, n, AP, Cf)
    for i in range(n):  # symmetrized (Taylor-2)
        for j in range(n):
            P[i, j] = 0.5 * (Cf[i, j] + Cf[j, i])
    for i in range(n):
        m[i] = mp[i]
    return psd_check(m, P, n, tol, W, L, ev)


def update_taylor2_(h, hx, hxx, hxt, m, P, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
    """``ŷ = h + ½(P h_xx)``, ``S = H P Hᵀ + R`` + the form's term, the forcing ``M`` (004 eqs.
    20-23); S must be positive definite. ``(P h_xx)`` by ``hxt``, the Hessian only where a term needs it."""
    second, meas_kind, force_kind, joseph = ks[0], ks[2], ks[3], ks[4]  # (the continuous-discrete kind's: more)
    mp, F, Hm, C, S, FP, Af, Ah, tr, AP, Cf, M, yhat, W, L, ev, w, Ht = ws
    h(m, t, p, yhat)
    hx(m, t, p, Hm)
    if second:
        if meas_kind == 2 or force_kind == 2:
            hxx(m, t, p, Ah)
        hxt(m, t, p, P, tr)  # (P h_xx)
        for i in range(mdim):
            yhat[i] += 0.5 * tr[i]
    meas_cov(P, Hm, R, Ht, C, S, n, mdim)  # C = P Hᵀ, S = H C + R
    force = False
    if second:
        quartic(meas_kind, P, Ah, tr, n, mdim, AP, S)
        if force_kind == 1:  # M_ijk = −½ P_ij (P h_xx)_k
            force = True
            for i in range(n):
                for j in range(n):
                    for a in range(mdim):
                        M[i, j, a] = -0.5 * P[i, j] * tr[a]
        elif force_kind == 2:  # M_ijk = (P h_xx^(k) P)_ij
            force = True
            for a in range(mdim):
                mm(P, Ah[a], FP, n, n, n, False)  # P h_xx^(a)
                mm(FP, P, Cf, n, n, n, False)  # (P h_xx^(a)) P
                for i in range(n):
                    for j in range(n):
                        M[i, j, a] = Cf[i, j]
    ok = condition(m, P, y, yhat, S, C, Hm, R, joseph, M, force, True, n, mdim, w, want, l1, i1, c1)
    return ok and psd_check(m, P, n, tol, W, L, ev)


#: the kernels' sources by rule kind: ``(predict, update)`` (compiled by :func:`.build.steps`)
KERNELS_BY_KIND = {"taylor1": (predict_taylor1_, update_taylor1_), "nodes": (predict_nodes_, update_nodes_),
                   "taylor2": (predict_taylor2_, update_taylor2_), "kalman": (predict_kalman_, update_kalman_),
                   **sqrt_kernels.KERNELS, **ito_kernels.KERNELS,
                   "cd-taylor1": (*cd_kernels.KERNELS["cd-taylor1"], update_taylor1_),
                   "cd-taylor2": (*cd_kernels.KERNELS["cd-taylor2"], update_taylor2_),
                   "cd-nodes": (*cd_kernels.KERNELS["cd-nodes"], update_nodes_)}
#: the kernels' work arrays by rule kind: ``alloc(n, mdim, r, N) -> tuple``
ALLOC = {"taylor1": alloc_taylor1, "nodes": alloc_nodes, "taylor2": alloc_taylor2, "kalman": alloc_kalman,
         **sqrt_kernels.ALLOC, **ito_kernels.ALLOC, "cd-taylor1": alloc_taylor1,
         "cd-taylor2": alloc_taylor2, "cd-nodes": alloc_nodes}
