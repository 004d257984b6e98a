"""The time loops of the compiled run, one per rule kind, each over paths and steps: Taylor-1
(:func:`steps_taylor1_`, the EKF), the scalar batch loop (:func:`steps_scalar_`: the EKF on
``n = m = r = 1``, every path at each step), node rules (:func:`steps_nodes_`) and Taylor-2
(:func:`steps_taylor2_`, seed 004's forms), with their work arrays (``alloc_*``, allocated once per
run in NumPy).

These are sources, never called as Python: :func:`.build.steps` compiles each with the model's
functions (its first parameters, :data:`.build.FUNCTION_ARGS`) bound as globals, in a namespace of
the kernels of :mod:`.path_linalg` and :mod:`.step_kernels`.
"""

from __future__ import annotations

import math

import numpy as np

from .path_linalg import psd_check, sqrt_check, transpose
from .step_kernels import (LOG_2PI, add_gqg, condition, hess_trace, mark, meas_cov, nodes_moments, predict_cov,
                           quartic, work, write)

__all__ = ["SOURCES", "alloc_taylor1", "alloc_nodes", "alloc_taylor2", "steps_taylor1_", "steps_scalar_",
           "steps_nodes_", "steps_taylor2_"]


def alloc_taylor1(ys, m0, Q, N=0):
    """The work arrays of :func:`steps_taylor1_` (allocated once per run, in NumPy)."""
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    m, P, mp = np.empty(n), np.empty((n, n)), np.empty(n)
    F, C, Hm, S = np.empty((n, n)), np.empty((n, mdim)), np.empty((mdim, n)), np.empty((mdim, mdim))
    Gm, GQ, N = np.empty((n, r)), np.empty((n, r)), np.empty((n, n))
    yhat, FP = np.empty(mdim), np.empty((n, n))
    W, L, ev, V = np.empty((n, n)), np.empty((n, n)), np.empty(n), np.empty((n, n))
    w = work(n, mdim)
    M0 = np.empty((1, 1, 1))
    yk, l1, i1, c1 = np.empty(mdim), np.empty(1), np.empty(mdim), np.empty((mdim, mdim))
    return (m, P, mp, F, C, Hm, S, Gm, GQ, N, yhat, FP, W, L, ev, V, w, M0, yk, l1, i1, c1, np.empty((n, mdim)))


def steps_taylor1_(f, fx, h, hx, G, ys, m0, P0, p, Q, R, GQG0, G_const, offset, absent, tol, means, covs, ll, inn, icov, want, step, m, P, mp, F, C, Hm, S, Gm, GQ, N, yhat, FP, W, L, ev, V, w, M0, yk, l1, i1, c1, Ht):
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    for b in range(B):
        for i in range(n):
            m[i] = m0[b, i]
            for j in range(n):
                P[i, j] = P0[b, i, j]
        fail = -1
        for k in range(T):
            if k > 0 or offset:
                t = float(k + offset - 1)
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
                if not psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            if not absent[k]:
                t = float(k + offset)
                h(m, t, p, yhat)
                hx(m, t, p, Hm)
                meas_cov(P, Hm, R, Ht, C, S, n, mdim)  # C = P Hᵀ, S = H C + R
                for a in range(mdim):
                    yk[a] = ys[b, k, a]
                ok = condition(m, P, yk, yhat, S, C, Hm, R, True, M0, False, False, n, mdim, w, want, l1, i1, c1)
                if not ok or not psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            write(means, covs, ll, inn, icov, b, k, m, P, want, absent[k], l1, i1, c1)
        step[b] = fail
        if fail >= 0:
            mark(means, covs, ll, inn, icov, want, b, fail)


def steps_scalar_(f, fx, h, hx, G, ys, m0, P0, p, Q, R, GQG0, G_const, offset, absent, tol, outm, outP, ll, inn,
                   icov, want, step, mB, PB):
    """The EKF on one state, one measurement and one noise (``n = m = r = 1``), all paths at each
    step (the paths are independent, so the processor overlaps them: ~20× the one-path loop's
    throughput). The arithmetic of the batched NumPy EKF's scalar branch, in its order:
    ``P⁻ = F (P F) + G Q G``; ``C = P H``, ``S = H C + R``, ``K = C / S``, ``m⁺ = m⁻ + K e``,
    ``P⁺ = (1 − K H)² P⁻ + K² R``. Outputs time-major ``(T, B)`` (contiguous at each step)."""
    B, T = ys.shape[0], ys.shape[1]
    q, r = Q[0, 0], R[0, 0]
    nan = np.nan
    for b in range(B):
        mB[b] = m0[b, 0]
        PB[b] = P0[b, 0, 0]
        step[b] = -1
    for k in range(T):
        pred = k > 0 or offset
        upd = not absent[k]
        tp = float(k + offset - 1)
        tu = float(k + offset)
        for b in range(B):
            if step[b] >= 0:  # diverged earlier: NaN from its step on
                outm[k, b] = nan
                outP[k, b] = nan
                if want:
                    ll[k, b] = nan
                    inn[k, b] = nan
                    icov[k, b] = nan
                continue
            m = mB[b]
            P = PB[b]
            ok = True
            if pred:
                F = fx(m, tp, p)
                if G_const:
                    N = GQG0[0, 0]
                else:
                    g = G(m, tp, p)
                    N = g * q * g
                m = f(m, tp, p)
                P = F * (P * F) + N
                ok = math.isfinite(m) and math.isfinite(P) and not (P < -tol * max(1.0, abs(P)))
            lk, ek, sk = 0.0, nan, nan
            if ok and upd:
                y = ys[b, k, 0]
                if not math.isnan(y):
                    H = hx(m, tu, p)
                    C = P * H
                    S = H * C + r
                    K = C / S
                    e = y - h(m, tu, p)
                    m = m + K * e
                    IKH = 1.0 - K * H
                    P = IKH * IKH * P + K * K * r
                    ok = math.isfinite(m) and math.isfinite(P) and not (P < -tol * max(1.0, abs(P)))
                    if want:
                        lk = -0.5 * (e * e / S + math.log(S) + LOG_2PI) if S > 0.0 else nan
                        ek, sk = e, S
            if not ok:
                step[b] = k
                m, P, lk, ek, sk = nan, nan, nan, nan, nan
            mB[b] = m
            PB[b] = P
            outm[k, b] = m
            outP[k, b] = P
            if want:
                ll[k, b] = lk
                inn[k, b] = ek
                icov[k, b] = sk
def alloc_nodes(ys, m0, Q, N=0):
    """The work arrays of :func:`steps_nodes_` (allocated once per run, in NumPy)."""
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    pmax = max(n, mdim)
    m, P, L, W, L2 = np.empty(n), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    ev, V = np.empty(n), np.empty((n, n))
    X, GX, D = np.empty((N, n)), np.empty((N, pmax)), np.empty((N, pmax))
    mean, Cov, Cross = np.empty(pmax), np.empty((pmax, pmax)), np.empty((n, pmax))
    Gm, GQ, Nz = np.empty((n, r)), np.empty((n, r)), np.empty((n, n))
    S, C, yhat = np.empty((mdim, mdim)), np.empty((n, mdim)), np.empty(mdim)
    H0, M0 = np.empty((1, 1)), np.empty((1, 1, 1))
    yk, l1, i1, c1 = np.empty(mdim), np.empty(1), np.empty(mdim), np.empty((mdim, mdim))
    w = work(n, mdim)
    return (m, P, L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz, S, C, yhat, H0, M0, yk, l1, i1, c1, w)


def steps_nodes_(f, h, G, z, wm, wc, ys, m0, P0, p, Q, R, GQG0, G_const, offset, absent, tol, means, covs, ll, inn, icov, want, step, m, P, L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz, S, C, yhat, H0, M0, yk, l1, i1, c1, w):
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    N = z.shape[0]
    for b in range(B):
        for i in range(n):
            m[i] = m0[b, i]
            for j in range(n):
                P[i, j] = P0[b, i, j]
        fail = -1
        for k in range(T):
            for phase in range(2):
                if phase == 0 and not (k > 0 or offset):
                    continue
                if phase == 1 and absent[k]:
                    continue
                if not sqrt_check(P, L, n, tol, W, ev, V):
                    fail = k
                    break
                transpose(L, W, n, n)  # the columns of L as rows (W as scratch)
                for i in range(N):  # X_i = m + L z_i (the sigma and cubature z_i have one nonzero)
                    for j in range(n):
                        X[i, j] = m[j]
                    for q in range(n):
                        v = z[i, q]
                        if v != 0.0:
                            for j in range(n):
                                X[i, j] += v * W[q, j]
                if phase == 0:
                    t = float(k + offset - 1)
                    nodes_moments(f, X, GX, wm, wc, m, t, p, N, n, n, mean, D, Cov, Cross, False)
                    if G_const:
                        for i in range(n):
                            for j in range(n):
                                Nz[i, j] = GQG0[i, j]
                    else:  # Σ w_i G(X_i) Q G(X_i)ᵀ
                        for i in range(n):
                            for j in range(n):
                                Nz[i, j] = 0.0
                        for i2 in range(N):
                            G(X[i2], t, p, Gm)
                            add_gqg(Gm, Q, GQ, Nz, wm[i2], n, r)
                    for i in range(n):
                        m[i] = mean[i]
                        for j in range(n):
                            P[i, j] = Cov[i, j] + Nz[i, j]
                    if not psd_check(m, P, n, tol, W, L2, ev):
                        fail = k
                        break
                else:
                    t = float(k + offset)
                    nodes_moments(h, X, GX, wm, wc, m, t, p, N, mdim, n, mean, D, Cov, Cross, True)
                    for a in range(mdim):
                        yhat[a] = mean[a]
                        for c in range(mdim):
                            S[a, c] = Cov[a, c] + R[a, c]
                        for j in range(n):
                            C[j, a] = Cross[j, a]
                    for a in range(mdim):
                        yk[a] = ys[b, k, a]
                    ok = condition(m, P, yk, yhat, S, C, H0, R, False, M0, False, False, n, mdim, w, want, l1, i1, c1)
                    if not ok or not psd_check(m, P, n, tol, W, L2, ev):
                        fail = k
                        break
            if fail >= 0:
                break
            write(means, covs, ll, inn, icov, b, k, m, P, want, absent[k], l1, i1, c1)
        step[b] = fail
        if fail >= 0:
            mark(means, covs, ll, inn, icov, want, b, fail)
def alloc_taylor2(ys, m0, Q, N=0):
    """The work arrays of :func:`steps_taylor2_` (allocated once per run, in NumPy)."""
    B, T, mdim = ys.shape
    n = m0.shape[1]
    pmax = max(n, mdim)
    m, P, mp = np.empty(n), np.empty((n, n)), np.empty(n)
    F, Hm, C, S, FP = np.empty((n, n)), np.empty((mdim, n)), np.empty((n, mdim)), np.empty((mdim, mdim)), np.empty((n, n))
    Af, Ah = np.empty((n, n, n)), np.empty((mdim, n, n))
    tr, AP = np.empty(pmax), np.empty((pmax, n, n))
    Cf = np.empty((n, n))
    M = np.empty((n, n, mdim))
    yhat = np.empty(mdim)
    W, L, ev, V = np.empty((n, n)), np.empty((n, n)), np.empty(n), np.empty((n, n))
    w = work(n, mdim)
    yk, l1, i1, c1 = np.empty(mdim), np.empty(1), np.empty(mdim), np.empty((mdim, mdim))
    return (m, P, mp, F, Hm, C, S, FP, Af, Ah, tr, AP, Cf, M, yhat, W, L, ev, V, w, yk, l1, i1, c1, np.empty((n, mdim)))


def steps_taylor2_(f, fx, fxx, h, hx, hxx, ys, m0, P0, p, R, GQG0, second, dyn_kind, meas_kind, force_kind, joseph, offset, absent, tol, means, covs, ll, inn, icov, want, step, m, P, mp, F, Hm, C, S, FP, Af, Ah, tr, AP, Cf, M, yhat, W, L, ev, V, w, yk, l1, i1, c1, Ht):
    B, T, mdim = ys.shape
    n = m0.shape[1]
    for b in range(B):
        for i in range(n):
            m[i] = m0[b, i]
            for j in range(n):
                P[i, j] = P0[b, i, j]
        fail = -1
        for k in range(T):
            if k > 0 or offset:
                t = float(k + offset - 1)
                f(m, t, p, mp)
                fx(m, t, p, F)
                if second:
                    fxx(m, t, p, Af)
                    hess_trace(P, Af, n, n, tr)
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
                if not psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            if not absent[k]:
                t = float(k + offset)
                h(m, t, p, yhat)
                hx(m, t, p, Hm)
                if second:
                    hxx(m, t, p, Ah)
                    hess_trace(P, Ah, n, mdim, tr)
                    for a in range(mdim):
                        yhat[a] += 0.5 * tr[a]
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
                            for i in range(n):
                                for c in range(n):
                                    s = 0.0
                                    for q in range(n):
                                        s += P[i, q] * Ah[a, q, c]
                                    FP[i, c] = s
                            for i in range(n):
                                for j in range(n):
                                    s = 0.0
                                    for c in range(n):
                                        s += FP[i, c] * P[c, j]
                                    M[i, j, a] = s
                for a in range(mdim):
                    yk[a] = ys[b, k, a]
                ok = condition(m, P, yk, yhat, S, C, Hm, R, joseph, M, force, True, n, mdim, w, want, l1, i1, c1)
                if not ok or not psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            write(means, covs, ll, inn, icov, b, k, m, P, want, absent[k], l1, i1, c1)
        step[b] = fail
        if fail >= 0:
            mark(means, covs, ll, inn, icov, want, b, fail)


#: the loops' sources, by rule kind (``"scalar"``: the scalar batch loop)
SOURCES = {"taylor1": steps_taylor1_, "nodes": steps_nodes_, "taylor2": steps_taylor2_, "scalar": steps_scalar_}
