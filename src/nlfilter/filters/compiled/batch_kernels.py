"""The kernels and the loop of the EKF's batch-inner loop (:mod:`.batch_loop`): a block of paths,
``nb ≤ NB``, each state a structure of arrays with the paths last (``m (n, NB)``, ``P (n, n, NB)``).

Products loop over the entries, then the paths, then the summation index (``s`` in a register; the
summation lengths are constants of the generated module, ``ns``, ``ms``, ``rs`` for ``n``, ``mdim``,
``r``, so the compiler unrolls the sum and vectorizes over the paths). The loops around a loop over the
paths run to the dimensions read from the arrays (``n``, ``mdim``, ``r``): compiled in, each would be
unrolled into a copy of the vectorized path loop (its alias checks and remainder loop) per entry — code
that took a quarter of the first compile at n = 4 (more above), for no speed. The Cholesky factors and
triangular solves keep a sum per path in ``acc`` (their trip counts vary). One array stored per loop
body: the compiler does not vectorize a loop storing two (it cannot tell that they do not overlap the
arrays read) — a symmetric product stores its upper triangle, :func:`bmirror_` the lower one after
(2.4× faster at n = 16). Sums run in the one-path kernels' order (:func:`~.step_kernels.predict_cov_`,
:func:`~.step_kernels.meas_cov_`, :func:`~.step_kernels.condition_`'s Joseph form).

The products with F and H (``P Fᵀ``, ``F (P Fᵀ)``, ``P Hᵀ``, ``H C``, ``K H``) sum over the
Jacobians' structural non-zeros only: ``q = FZ[j, z]`` for ``z < kf``, tables of the model
(:func:`.batch_loop.patterns`, constants of the generated module, as ``kf``, ``kh``, ``kt``) —
where a Jacobian has no zero, :func:`.batch_loop.source` writes ``q = z`` (every index). A term
skipped is ``0 · x``: the sum is the same to the last bit where ``x`` is finite (but for the sign
of an exact zero). ``P`` is finite there (screened), and a non-finite ``C`` or ``K`` makes the
mean non-finite with or without the zero terms; a non-finite ``P Fᵀ`` is made to fail the screen
as its zero terms would (``F (P Fᵀ)`` is then NaN), so a path diverges at the same step.

Sources, never called as Python: :func:`.batch_loop.source` compiles them in the module of the
one-path kernels (``psd_check``, ``mark``, ``update1``: :func:`~.rule_kernels.update_taylor1_`) and
the model's block functions (``fb, fxb, hb, hxb, Gb``); the loop calls each kernel itself (one level
of calls: :mod:`.batch_loop` on the compile). The block's divergence test is :mod:`.batch_screen`'s."""

from __future__ import annotations

import math

import numpy as np

from .batch_screen import bgather_, bpd_ok_, bscreen_, kill_, settle_

__all__ = ["SOURCES"]


def bchol_(A, L, n, nb, d, acc, ok):
    """The lower Cholesky factors of the lanes of ``A`` into ``L`` (``d``: 1 / its diagonal); ``ok[b]``
    set to 0.0 where lane ``b`` has none (its ``L`` then meaningless)."""
    for j in range(n):
        for b in range(nb):
            acc[b] = A[j, j, b]
        for q in range(j):
            for b in range(nb):
                acc[b] -= L[j, q, b] * L[j, q, b]
        for b in range(nb):  # (one array stored per loop: the square roots and divisions vectorize)
            ok[b] = ok[b] if acc[b] > 0.0 else 0.0
        for b in range(nb):
            s = acc[b]
            L[j, j, b] = math.sqrt(s) if s > 0.0 else 1.0
        for b in range(nb):
            d[b] = 1.0 / L[j, j, b]
        for i in range(j + 1, n):
            for b in range(nb):
                acc[b] = A[i, j, b]
            for q in range(j):
                for b in range(nb):
                    acc[b] -= L[i, q, b] * L[j, q, b]
            for b in range(nb):
                L[i, j, b] = acc[b] * d[b]


def bmirror_(P, n, nb):
    """The lower triangle of every lane of ``P`` from its upper one. (A product storing both
    ``P[i, j]`` and ``P[j, i]`` in one loop body is not vectorized: the two stores may alias.)"""
    for i in range(n):
        for j in range(i + 1, n):
            for b in range(nb):
                P[j, i, b] = P[i, j, b]


def bpredict_(t, p, Q, GQG0, G_const, n, r, nb, bw):
    """``m⁻ = f(m)``, ``P⁻ = F (P Fᵀ) + G Q Gᵀ`` on the block (:func:`~.rule_kernels.predict_taylor1_`)."""
    (Mb, Pb, Mp, F, Gm, N, Wn, T1, Yh, H, C, S, Ls, E, K, KR, u, A, okv, Li, LiS, dv, acc, qv, ldv, irr,
     dead, GQ) = bw
    fb(Mb, t, p, Mp, nb)
    fxb(Mb, t, p, F, nb)
    if G_const:
        for i in range(n):
            for j in range(n):
                v = GQG0[i, j]
                for b in range(nb):
                    N[i, j, b] = v
    else:  # N_ij = Σ_a (G Q)_ia G_ja (add_gqg_)
        Gb(Mb, t, p, Gm, nb)
        for i in range(n):
            for a in range(r):
                for b in range(nb):
                    s = 0.0
                    for c in range(rs):
                        s += Gm[i, c, b] * Q[c, a]
                    GQ[a, b] = s
            for j in range(n):
                for b in range(nb):
                    s = 0.0
                    for a in range(rs):
                        s += GQ[a, b] * Gm[j, a, b]
                    N[i, j, b] = s
    for i in range(n):  # Wn = P Fᵀ (Wn_ij = Σ_q P_iq F_jq over the q of table FZ's row j)
        for j in range(n):
            for b in range(nb):
                s = 0.0
                for z in range(kf):
                    q = FZ[j, z]
                    s += Pb[i, q, b] * F[j, q, b]
                Wn[i, j, b] = s
    for i in range(n):  # P = N + F Wn, symmetric: the upper triangle, then mirrored (bmirror)
        for j in range(i, n):
            for b in range(nb):
                s = N[i, j, b]
                for z in range(kf):
                    q = FZ[i, z]
                    s += F[i, q, b] * Wn[q, j, b]
                Pb[i, j, b] = s
    if kf < ns:  # a term F_iq Wn_qj skipped is 0 where Wn_qj is finite: P⁻ made NaN where it is not
        for b in range(nb):
            acc[b] = 0.0
        for q in range(n):
            for b in range(nb):
                s = acc[b]
                for j in range(ns):
                    s += Wn[q, j, b] * 0.0
                acc[b] = s
        for b in range(nb):
            Pb[0, 0, b] += acc[b]
    bmirror(Pb, n, nb)
    for i in range(n):
        for b in range(nb):
            Mb[i, b] = Mp[i, b]


def binnov_(ys, k, t, lo, nb, n, mdim, p, R, bw):
    """The innovation of the block at step ``k`` (``t``): ``ŷ``, ``H``, ``C = P Hᵀ``, ``S = H C + R``,
    a Cholesky factor of S (``okv[b]`` 0.0 where lane ``b`` has none), ``e = y − ŷ``."""
    (Mb, Pb, Mp, F, Gm, N, Wn, T1, Yh, H, C, S, Ls, E, K, KR, u, A, okv, Li, LiS, dv, acc, qv, ldv, irr,
     dead, GQ) = bw
    hb(Mb, t, p, Yh, nb)
    hxb(Mb, t, p, H, nb)
    for i in range(n):  # C = P Hᵀ (C_ia = Σ_q P_iq H_aq over the q of table HZ's row a)
        for a in range(mdim):
            for b in range(nb):
                s = 0.0
                for z in range(kh):
                    q = HZ[a, z]
                    s += Pb[i, q, b] * H[a, q, b]
                C[i, a, b] = s
    for a in range(mdim):  # S = R + H C
        for c in range(mdim):
            v = R[a, c]
            for b in range(nb):
                s = v
                for z in range(kh):
                    q = HZ[a, z]
                    s += H[a, q, b] * C[q, c, b]
                S[a, c, b] = s
    for a in range(mdim):  # (a loop of its own: one store per loop body keeps the loops vectorized)
        for c in range(mdim):
            for b in range(nb):
                LiS[a, c, b] = S[a, c, b]
    for b in range(nb):
        okv[b] = 1.0
    bchol(S, Ls, mdim, nb, dv, acc, okv)
    for a in range(mdim):  # e = y − ŷ; Li: 1 / the factor's diagonal
        for b in range(nb):
            E[a, b] = ys[lo + b, k, a] - Yh[a, b]
        for b in range(nb):
            Li[a, b] = 1.0 / Ls[a, a, b]


def bupdate_(nb, n, mdim, R, want, bw, step, lo, k):
    """The update of the block from :func:`binnov_`'s innovation: the lanes measured in full with a
    Cholesky factor of S batched; the others (``irr``), updated by the one-path kernel in the loop,
    take its results (kept in ``Mp``, ``Wn``) and fail where it failed (``ldv`` 0)."""
    (Mb, Pb, Mp, F, Gm, N, Wn, T1, Yh, H, C, S, Ls, E, K, KR, u, A, okv, Li, LiS, dv, acc, qv, ldv, irr,
     dead, GQ) = bw
    for i in range(n):  # K_i = S⁻¹ C_i (forward and back substitution)
        for a in range(mdim):
            for b in range(nb):
                acc[b] = C[i, a, b]
            for c in range(a):
                for b in range(nb):
                    acc[b] -= Ls[a, c, b] * u[c, b]
            for b in range(nb):
                u[a, b] = acc[b] * Li[a, b]
        for a in range(mdim - 1, -1, -1):
            for b in range(nb):
                acc[b] = u[a, b]
            for c in range(a + 1, mdim):
                for b in range(nb):
                    acc[b] -= Ls[c, a, b] * K[i, c, b]
            for b in range(nb):
                K[i, a, b] = acc[b] * Li[a, b]
    if want:
        blik(E, Ls, Li, u, acc, qv, irr, nb, mdim)
    for i in range(n):  # m += K e; A = I − K H
        for b in range(nb):
            s = 0.0
            for a in range(ms):
                s += K[i, a, b] * E[a, b]
            Mb[i, b] += s
        for j in range(n):  # (over the a of table HT's row j: H's column j)
            v = 1.0 if i == j else 0.0
            for b in range(nb):
                s = v
                for z in range(kt):
                    a = HT[j, z]
                    s -= K[i, a, b] * H[a, j, b]
                A[i, j, b] = s
    for i in range(n):  # T1 = A P
        for j in range(n):
            for b in range(nb):
                s = 0.0
                for q in range(ns):
                    s += A[i, q, b] * Pb[q, j, b]
                T1[i, j, b] = s
    for i in range(n):  # KR = K R
        for a in range(mdim):
            for b in range(nb):
                s = 0.0
                for c in range(ms):
                    s += K[i, c, b] * R[c, a]
                KR[i, a, b] = s
    for i in range(n):  # P = T1 Aᵀ + KR Kᵀ, symmetric: the upper triangle, then mirrored
        for j in range(i, n):
            for b in range(nb):
                s = 0.0
                for q in range(ns):
                    s += T1[i, q, b] * A[j, q, b]
                for a in range(ms):
                    s += KR[i, a, b] * K[j, a, b]
                Pb[i, j, b] = s
    bmirror(Pb, n, nb)
    for b in range(nb):  # the one-path lanes' results
        if irr[b] and not dead[b]:
            for i in range(ns):
                Mb[i, b] = Mp[i, b]
                for j in range(ns):
                    Pb[i, j, b] = Wn[i, j, b]
            if ldv[b] == 0.0:
                kill(Mb, Pb, b, ns, dead, step, lo, k)


def blik_(E, Ls, Li, u, acc, qv, irr, nb, mdim):
    """``qv[b] = −½ (eᵀ S⁻¹ e + log det S + m log 2π)`` on the batched lanes (``irr`` 0)."""
    for b in range(nb):
        acc[b] = 1.0  # the product of the factor's diagonal
    for a in range(mdim):
        for b in range(nb):
            s = E[a, b]
            for c in range(a):
                s -= Ls[a, c, b] * u[c, b]
            u[a, b] = s * Li[a, b]
            acc[b] *= Ls[a, a, b]
    for b in range(nb):
        if irr[b] == 0.0:
            q = 0.0
            for a in range(ms):
                q += u[a, b] * u[a, b]
            x = acc[b]
            if 1e-150 < x < 1e150:
                ld = 2.0 * math.log(x)
            else:  # the product out of range: the sum of the logarithms
                ld = 0.0
                for a in range(ms):
                    ld += 2.0 * math.log(Ls[a, a, b])
            qv[b] = -0.5 * (q + ld + ms * LOG_2PI)


def steps_batch_(ys, m0, P0, p, Q, R, GQG0, G_const, offset, absent, tol, means, covs, ll, inn, icov, want, step,
                 ks, ws, m, P, yk, l1, i1, c1):
    """The EKF over blocks of ``NB`` paths (the arguments of :func:`.loops.steps_`; ``ws``: the
    one-path kernels' work arrays and the block's, :func:`.batch_loop.alloc`)."""
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    w1, bw = ws
    (Mb, Pb, Mp, F, Gm, N, Wn, T1, Yh, H, C, S, Ls, E, K, KR, u, A, okv, Li, LiS, dv, acc, qv, ldv, irr,
     dead, GQ) = bw
    nbmax = NB
    for lo in range(0, B, nbmax):
        nb = min(nbmax, B - lo)
        for b in range(nb):
            step[lo + b] = -1
            dead[b] = 0
            for i in range(ns):
                Mb[i, b] = m0[lo + b, i]
                for j in range(ns):
                    Pb[i, j, b] = P0[lo + b, i, j]
        for k in range(T):
            for b in range(nb):
                irr[b] = 0.0
            if k > 0 or offset:
                bpredict(float(k + offset - 1), p, Q, GQG0, G_const, n, r, nb, bw)
                settle(Mb, Pb, n, nb, tol, bw[7], bw[17], dv, acc, okv, dead, irr, step, lo, k, m, P, w1[10], w1[11],
                       w1[12])
            if not absent[k]:
                t = float(k + offset)
                binnov(ys, k, t, lo, nb, n, mdim, p, R, bw)
                for b in range(nb):  # the lanes the one-path kernel updates (partly missing y, no factor of S)
                    bad = okv[b] == 0.0
                    for a in range(ms):
                        bad = bad or math.isnan(ys[lo + b, k, a])
                    if bad and not dead[b]:
                        irr[b] = 1.0
                        bgather(Mb, Pb, b, m, P, ns)
                        for a in range(mdim):
                            yk[a] = ys[lo + b, k, a]
                        ok = update1(m, P, yk, t, p, R, tol, want, l1, i1, c1, ks, w1, ns, ms)
                        for i in range(n):  # kept in Mp, Wn (free until the next predict); outputs in E, LiS, qv
                            Mp[i, b] = m[i]
                            for j in range(n):
                                Wn[i, j, b] = P[i, j]
                        qv[b] = l1[0]
                        for a in range(mdim):
                            E[a, b] = i1[a]
                            for c in range(mdim):
                                LiS[a, c, b] = c1[a, c]
                        ldv[b] = 1.0 if ok else 0.0
                bupdate(nb, n, mdim, R, want, bw, step, lo, k)
                settle(Mb, Pb, n, nb, tol, bw[7], bw[17], dv, acc, okv, dead, irr, step, lo, k, m, P, w1[10], w1[11],
                       w1[12])
            for b in range(nb):
                if dead[b]:
                    continue
                g = lo + b
                for i in range(ns):
                    means[g, k, i] = Mb[i, b]
                    for j in range(ns):
                        covs[g, k, i, j] = Pb[i, j, b]
                if want:
                    ll[g, k] = 0.0 if absent[k] else qv[b]
                    for a in range(ms):
                        inn[g, k, a] = np.nan if absent[k] else E[a, b]
                        for c in range(ms):
                            icov[g, k, a, c] = np.nan if absent[k] else LiS[a, c, b]
        for b in range(nb):
            if step[lo + b] >= 0:
                mark(means, covs, ll, inn, icov, want, lo + b, step[lo + b])


#: the loop and its kernels, in the order the generated module defines them
SOURCES = (bchol_, bpd_ok_, bmirror_, bscreen_, bgather_, kill_, settle_, bpredict_, binnov_, blik_, bupdate_,
           steps_batch_)
