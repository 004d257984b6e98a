"""The continuous-discrete filters' prediction on the compiled loop: the kind ``"cd-taylor1"`` of
:class:`~nlfilter.filters.ekf.ContinuousDiscreteEKF` (Jazwinski 1970, ch. 8), one path at a time.

Between measurements, the moment equations of the Taylor-1 closure
(:func:`~nlfilter.filters.skeleton.moment_rhs` with :class:`~nlfilter.filters.rules.Taylor1`)::

    dm/dt = f(m),   dP/dt = P Fᵀ + F P + G Q Gᵀ      (F = f_x(m), G = G(m))

integrated over the measurement interval ``dt`` by RK4 or Euler in ``substeps`` steps, P
symmetrized after each (:func:`~nlfilter.filters.skeleton.propagate`, :func:`~nlfilter.ode.ode_step`,
in their order of operations: the stage points ``x + (h/2) k``, the combination
``x + h/6 (k₁ + 2k₂ + 2k₃ + k₄)``), then the divergence test; at the measurements the discrete
EKF's update (:func:`~.rule_kernels.update_taylor1_`). The compiled loop takes models whose f, h, G
do not depend on the time, on a regular grid (:func:`~.support.static_refusal`): the stages' times
are then never read.

``ks = (dt, substeps, rk4, xm, xP, km, kP)``: the interval, the integrator, and its work arrays (the
stage point, the stages' slopes), beside the Taylor-1 kernels' own (``ws``: :func:`~.rule_kernels.alloc_taylor1`).
"""

from __future__ import annotations

import numpy as np

from .path_linalg import psd_check, symmetrize
from .step_kernels import add_gqg

__all__ = ["KERNELS", "constants", "predict_cd_taylor1_"]


def constants(dt: float, substeps: int, scheme: str, n: int) -> tuple:
    """``ks`` of :func:`predict_cd_taylor1_`: ``(dt, substeps, rk4, xm, xP, km, kP)``."""
    return (float(dt), int(substeps), scheme == "rk4", np.empty(n), np.empty((n, n)), np.empty((4, n)),
            np.empty((4, n, n)))


def predict_cd_taylor1_(f, fx, G, m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``(m, P)`` from one measurement time to the next (step ``t``'s interval): the moment equations
    integrated (see the module docstring); False where the path fails the divergence test."""
    dt, substeps, rk4, xm, xP, km, kP = ks
    mp, F, C, Hm, S, Gm, GQ, N, yhat, FP, W, L, ev, w, M0, Ht = ws
    r = Q.shape[0]
    if G_const:
        for i in range(n):
            for j in range(n):
                N[i, j] = GQG0[i, j]
    hs = dt / substeps
    stages = 4 if rk4 else 1
    for js in range(substeps):
        s0 = t * dt + js * hs  # (the stages' times: read by no model the loop takes)
        for st in range(stages):  # the stage point (xm, xP)
            ss = s0
            if st == 0:
                for i in range(n):
                    xm[i] = m[i]
                    for j in range(n):
                        xP[i, j] = P[i, j]
            else:
                hh = hs if st == 3 else 0.5 * hs
                ss = s0 + hh
                for i in range(n):
                    xm[i] = m[i] + hh * km[st - 1, i]
                    for j in range(n):
                        xP[i, j] = P[i, j] + hh * kP[st - 1, i, j]
            f(xm, ss, p, mp)  # dm/dt = f
            fx(xm, ss, p, F)
            for i in range(n):
                km[st, i] = mp[i]
            if not G_const:  # G(x) Q G(x)ᵀ at the stage point
                G(xm, ss, p, Gm)
                for i in range(n):
                    for j in range(n):
                        N[i, j] = 0.0
                add_gqg(Gm, Q, GQ, N, 1.0, n, r)
            for i in range(n):  # Cov[x, f] = P Fᵀ
                for j in range(n):
                    s = 0.0
                    for q in range(n):
                        s += xP[i, q] * F[j, q]
                    FP[i, j] = s
            for i in range(n):  # dP/dt = P Fᵀ + F P + G Q Gᵀ
                for j in range(n):
                    kP[st, i, j] = FP[i, j] + FP[j, i] + N[i, j]
        if rk4:
            h6 = hs / 6
            for i in range(n):
                m[i] = m[i] + h6 * (km[0, i] + 2 * km[1, i] + 2 * km[2, i] + km[3, i])
                for j in range(n):
                    P[i, j] = P[i, j] + h6 * (kP[0, i, j] + 2 * kP[1, i, j] + 2 * kP[2, i, j] + kP[3, i, j])
        else:
            for i in range(n):
                m[i] = m[i] + hs * km[0, i]
                for j in range(n):
                    P[i, j] = P[i, j] + hs * kP[0, i, j]
        symmetrize(P, n)
    return psd_check(m, P, n, tol, W, L, ev)


#: the kind's kernels: its prediction, and the discrete EKF's update (:mod:`.rule_kernels` adds it)
KERNELS = {"cd-taylor1": (predict_cd_taylor1_,)}
