"""The continuous-discrete filters' prediction on the compiled loop, one path at a time: the kinds
``"cd-taylor1"`` of :class:`~nlfilter.filters.ekf.ContinuousDiscreteEKF` (Jazwinski 1970, ch. 8),
``"cd-taylor2"`` of :class:`~nlfilter.filters.second_order.ContinuousDiscreteSecondOrderFilter` (seed
004 eqs. 35-36 without their measurement terms) and ``"cd-nodes"`` of the continuous-discrete UKF,
CKF, GHKF and SLF (Särkkä 2007; :func:`predict_cd_nodes_`).

Between measurements, the moment equations of the Gaussian closure
(:func:`~nlfilter.filters.skeleton.moment_rhs`; for the Taylor rules, :class:`~nlfilter.filters.rules.Taylor1`
and :class:`~nlfilter.filters.rules.Taylor2`, third moments neglected, f_xx in the mean only)::

    dm/dt = f(m) [+ ½ (P f_xx)],   dP/dt = P Fᵀ + F P + G Q Gᵀ      (F = f_x(m), G = G(m))

integrated over the measurement interval ``dt`` by RK4 or Euler in ``substeps`` steps, P
symmetrized after each (:func:`~nlfilter.filters.skeleton.propagate`, :func:`~nlfilter.ode.ode_step`,
in their order of operations: the stage points ``x + (h/2) k``, the combination
``x + h/6 (k₁ + 2k₂ + 2k₃ + k₄)``), then the divergence test; at the measurements the discrete
EKF's or the second-order filter's update (:func:`~.rule_kernels.update_taylor1_`,
:func:`~.rule_kernels.update_taylor2_`). The compiled loop takes models whose f, h, G do not depend on
the time, on a regular grid (:func:`~.support.static_refusal`; the second-order filters a G free of
the state, as in discrete time): the stages' times are then never read.

``ks``: what the discrete update reads — the Taylor-2 update's five entries (``second``, the ½
terms; the form's kinds; ``joseph``; the Taylor-1 update reads none), the node rules' table ``(z, wm,
wc)`` — then the integrator (:func:`constants`); ``ws``: the update's work arrays
(:data:`~.rule_kernels.ALLOC` of its kind), which the node rules' prediction shares.
"""

from __future__ import annotations

import numpy as np

from .path_linalg import psd_check, psd_root, symmetrize
from .step_kernels import add_gqg, nodes_gqg, nodes_moments, nodes_points
from .support import CD_KINDS, jit

__all__ = ["KERNELS", "SOURCES", "constants", "predict_cd_", "predict_cd_nodes_", "stage_", "combine_"]


def constants(dt: float, substeps: int, scheme: str, n: int, r: int) -> tuple:
    """The integrator's entry of ``ks`` (its last): ``(dt, substeps, rk4, xm, xP, km, kP, fv, F, tr,
    Gm, GQ, N, FP, W, L, ev)`` — the interval, the scheme, and the work arrays of the predictions (the
    stage point, the stages' slopes, the model's values there)."""
    e = np.empty
    return (float(dt), int(substeps), scheme == "rk4", e(n), e((n, n)), e((4, n)), e((4, n, n)), e(n), e((n, n)),
            e(n), e((n, r)), e((n, r)), e((n, n)), e((n, n)), e((n, n)), e((n, n)), e(n))


def stage_(m, P, xm, xP, km, kP, st, hs, n):
    """The integrator's stage point ``st`` into ``(xm, xP)`` (0: the substep's start, 1-2: half a
    step along the previous slope, 3: a whole step, as :func:`~nlfilter.ode.ode_step`'s RK4); returns
    its time past the substep's start."""
    if st == 0:
        for i in range(n):
            xm[i] = m[i]
            for j in range(n):
                xP[i, j] = P[i, j]
        return 0.0
    hh = hs if st == 3 else 0.5 * hs
    for i in range(n):
        xm[i] = m[i] + hh * km[st - 1, i]
        for j in range(n):
            xP[i, j] = P[i, j] + hh * kP[st - 1, i, j]
    return hh


def combine_(m, P, km, kP, hs, rk4, n):
    """The substep from its stages' slopes (``x + h/6 (k₁ + 2k₂ + 2k₃ + k₄)``, Euler ``x + h k₁``),
    P symmetrized after it (:func:`~nlfilter.filters.skeleton.propagate`)."""
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


def predict_cd_(f, fx, fxt, G, m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``(m, P)`` from one measurement time to the next (step ``t``'s interval) by the Taylor rules:
    the moment equations integrated (see the module docstring), with ``½ (P f_xx)`` in ``dm/dt``
    where the rule is of second order (``ks[0]``; ``fxt``: the model's contraction over the Hessian's
    non-zeros, :func:`~.kernels.model_kernels`); False where the path fails the divergence test."""
    second = ks[0]
    dt, substeps, rk4, xm, xP, km, kP, fv, F, tr, Gm, GQ, N, FP, W, L, ev = ks[5]
    r = Q.shape[0]
    if G_const:
        for i in range(n):
            for j in range(n):
                N[i, j] = GQG0[i, j]
    hs = dt / substeps
    for js in range(substeps):
        s0 = t * dt + js * hs  # (the stages' times: read by no model the loop takes)
        for st in range(4 if rk4 else 1):
            ss = s0 + stage(m, P, xm, xP, km, kP, st, hs, n)
            f(xm, ss, p, fv)  # dm/dt = f [+ ½ (P f_xx)]
            fx(xm, ss, p, F)
            if second:
                fxt(xm, ss, p, xP, tr)  # (P f_xx)
                for i in range(n):
                    fv[i] += 0.5 * tr[i]
            for i in range(n):
                km[st, i] = fv[i]
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
        combine(m, P, km, kP, hs, rk4, n)
    return psd_check(m, P, n, tol, W, L, ev)


def predict_cd_nodes_(f, G, m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """The same by a node rule (``ks[:3] = (z, wm, wc)``, Särkkä 2007): at each stage point the
    nodes ``X_i`` of ``(xm, xP)``, ``dm/dt = Σ wm_i f(X_i)``, ``dP/dt = C + Cᵀ + E[G Q Gᵀ]`` with
    ``C = Σ wc_i (X_i − xm)(f(X_i) − dm/dt)ᵀ`` and ``E[G Q Gᵀ] = Σ wm_i G(X_i) Q G(X_i)ᵀ`` (G Q Gᵀ
    where G is constant); False where a stage's covariance has no root (NumPy's moments are NaN
    there) or the path fails the divergence test."""
    z, wm, wc = ks[0], ks[1], ks[2]
    dt, substeps, rk4, xm, xP, km, kP = ks[3][:7]
    L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz = ws[:14]
    Pc = ws[20]
    r = Q.shape[0]
    N = z.shape[0]
    if G_const:
        for i in range(n):
            for j in range(n):
                Nz[i, j] = GQG0[i, j]
    hs = dt / substeps
    for js in range(substeps):
        s0 = t * dt + js * hs  # (the stages' times: read by no model the loop takes)
        for st in range(4 if rk4 else 1):
            ss = s0 + stage(m, P, xm, xP, km, kP, st, hs, n)
            if not nodes_points(xm, xP, z, X, L, W, ev, V, n, N, tol, Pc):
                return False
            Pc[0, 0] = np.nan  # L: the factor of this stage's xP, not of the P psd_root_ tested
            nodes_moments(f, X, GX, wm, wc, xm, ss, p, N, n, n, mean, D, Cov, Cross, True)
            if not G_const:  # Σ wm_i G(X_i) Q G(X_i)ᵀ
                nodes_gqg(G, X, Q, Gm, GQ, Nz, wm, ss, p, N, n, r)
            for i in range(n):
                km[st, i] = mean[i]
                for j in range(n):
                    kP[st, i, j] = Cross[i, j] + Cross[j, i] + Nz[i, j]
        combine(m, P, km, kP, hs, rk4, n)
    return psd_root(m, P, n, tol, W, L2, ev, L, Pc)


#: the kinds' predictions (:mod:`.rule_kernels` pairs them with the discrete updates: the EKF's, the
#: second-order filters')
KERNELS = {kind: (predict_cd_nodes_ if kind == "cd-nodes" else predict_cd_,) for kind in CD_KINDS}
#: the helper kernels (compiled with the kinds' loops, :mod:`.build`)
SOURCES = (stage_, combine_)

stage = jit(stage_, _nrt=False)
combine = jit(combine_, _nrt=False)
