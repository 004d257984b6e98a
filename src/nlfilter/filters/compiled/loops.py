"""The time loops of the compiled run: one template over paths and steps for every rule kind
(:func:`steps_`: the prior, the predict and update kernels of the rule's kind —
:mod:`.rule_kernels` — the divergence bookkeeping, writing or marking the outputs), and the EKF's
scalar batch loop (:func:`steps_scalar_`: ``n = m = r = 1``, every path at each step).

These are sources, never called as Python: :func:`.build.steps` compiles each with its first
parameters (the kernels; the scalar loop: the model's functions, :data:`.build.FUNCTION_ARGS`)
bound as globals, in a namespace of the kernels of :mod:`.path_linalg` and :mod:`.step_kernels`.
"""

from __future__ import annotations

import math

import numpy as np

from .step_kernels import LOG_2PI, mark, write

__all__ = ["SOURCES", "alloc_path", "steps_", "steps_scalar_"]


def alloc_path(n, mdim):
    """The template's own work arrays: ``m``, ``P``, the step's measurement and likelihood outputs."""
    return np.empty(n), np.empty((n, n)), np.empty(mdim), np.empty(1), np.empty(mdim), np.empty((mdim, mdim))


def steps_(predict, update, ys, m0, P0, p, Q, R, GQG0, G_const, offset, absent, tol, means, covs, ll, inn, icov, want,
           step, ks, ws, m, P, yk, l1, i1, c1):
    """The loop of every rule kind, one path at a time: from the path's prior, at each step
    ``predict`` (after the first step, or at every step with ``offset``: ``start="predict"``) and
    ``update`` (unless no path measures the step), each returning False where the path fails;
    then its outputs written, or NaN from the failed step on (``step[b]``: that step, or −1)."""
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
                if not predict(m, P, float(k + offset - 1), p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
                    fail = k
                    break
            if not absent[k]:
                for a in range(mdim):
                    yk[a] = ys[b, k, a]
                if not update(m, P, yk, float(k + offset), p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
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
            alive = step[b] < 0  # a path that diverged earlier: NaN from its step on
            m = mB[b]
            P = PB[b]
            ok = alive
            if ok and pred:
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
                if alive:
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


#: the loops' sources: the template and the scalar batch loop
SOURCES = {"template": steps_, "scalar": steps_scalar_}
