"""The continuous-time (Itô) filters' step on the compiled loop: the kind ``"ito"`` of
:class:`~nlfilter.filters.gaussian.ContinuousGaussianFilter` over a Taylor rule (the continuous EKF,
the continuous second-order filters of seed 004 eqs. 35-37), one path at a time.

The step of :meth:`ContinuousGaussianFilter._step <nlfilter.filters.gaussian.ContinuousGaussianFilter>`
(``innovation="ito"``), in its order of operations (:func:`~nlfilter.filters.skeleton.ito_gain`,
:func:`~nlfilter.filters.skeleton.ito_rhs`, :func:`~nlfilter.ode.ode_step`)::

    K₀, M₀ R⁻¹ at (m, P) (the gain at the step's start; missing components do not update)
    (m, P) ← the dt terms integrated by RK4 or Euler over dt in ``substeps`` (P symmetrized after each)
    m ← m + K₀ dy₀,   P ← sym(P + Σ_k (M₀ R⁻¹)_ijk dy₀_k)  (the forcing, where the form has one)

The whole step is the template's ``update`` (it sees the increment); its ``predict`` does nothing
(:func:`predict_ito_`), and the run hands the loop no step as absent: the NumPy loop steps every
increment, measured or not. The time of step ``k`` is ``k dt`` (the compiled loop takes models
whose f, h, G do not depend on the time; :func:`~.support.static_refusal`).

``ks = (Rinv, GQG0, Q, dt, substeps, rk4, second, force, gfix, Rdt, meas_kind)``: ``R⁻¹`` (the model's, as
:func:`~nlfilter.filters.checks.continuous_precision`), ``G Q Gᵀ`` where G is fixed (``gfix``; else
``G(x) Q G(x)ᵀ`` at each point), the rule's switches (``force``: 0 none, 1 truncated-Jazwinski, 2 Gaussian; :data:`~nlfilter.filters.rules.FORM_TABLE`),
``R/dt`` and the form's fourth-moment term of the innovation covariance (``meas_kind``: 0 none, 2
Gaussian; −¼ forms, whose S the NumPy loop screens batch-wide, are refused with ``loglik``) for
``run(..., loglik=True)``.
"""

from __future__ import annotations

import math

import numpy as np

from .cd_kernels import combine, stage
from .path_linalg import lu, lu_solve, mm, psd_check, symmetrize
from .step_kernels import LOG_2PI, add_gqg, hess_trace, meas_cov, quartic
from .support import jit

__all__ = ["ALLOC", "KERNELS", "SOURCES", "alloc_ito", "ito_terms_", "likelihood_", "predict_ito_", "update_ito_"]


def alloc_ito(n, mdim, r, N=0):
    """The work arrays of the Itô kernels."""
    e = np.empty
    pmax = max(n, mdim)
    return (e(n), e((n, n)), e((4, n)), e((4, n, n)), e(n), e((n, n)), e((n, n, n)), e(mdim), e((mdim, n)),
            e((mdim, n, n)), e((n, r)), e((n, r)), e((n, n)), e((n, mdim)), e((n, mdim)), e((n, n, mdim)),
            e((n, n, mdim)), e(pmax), e((n, n)), e((n, mdim)), e((n, n, mdim)), e((mdim, mdim)), e(mdim), e(mdim),
            np.zeros(mdim, np.int64), e((mdim, mdim)), np.zeros(mdim, np.int64), e(mdim), e((n, n)), e((n, n)),
            e(n), e((n, n)), e(mdim), e((mdim, n)), e((n, mdim)), e((n, mdim)), e((mdim, mdim)), e((pmax, n, n)),
            e(mdim))


def predict_ito_(m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """Nothing: the continuous step is all in :func:`update_ito_` (it needs the increment)."""
    return True


def ito_terms_(P, Hm, ob, Ri, hv, Ah, tr, second, force, measure, PHt, K, M, MR, T1, n, mdim):
    """The measurement terms of :func:`~nlfilter.filters.skeleton.ito_gain` at one point, from the
    model's ``Hm = h_x``, ``hv = h`` and ``Ah = h_xx`` there: the rows of H masked by ``ob`` (1 observed,
    0 missing), ``PHt = P Hᵀ``, ``K = PHt R⁻¹`` (``Ri``: the observed block's precision); with
    ``measure`` ``hv ← (h + ½(P h_xx)) · ob`` (``tr``: the trace, second order); with ``force`` the
    forcing ``MR = (M · ob) R⁻¹`` (1: ``M_ijk = −½ P_ij (P h_xx)_k``, 2: ``(P h_xx⁽ᵏ⁾ P)_ij``)."""
    for a in range(mdim):
        for j in range(n):
            Hm[a, j] = Hm[a, j] * ob[a]
    for i in range(n):  # P Hᵀ
        for a in range(mdim):
            s = 0.0
            for j in range(n):
                s += P[i, j] * Hm[a, j]
            PHt[i, a] = s
    for i in range(n):  # K = P Hᵀ R⁻¹
        for c in range(mdim):
            s = 0.0
            for a in range(mdim):
                s += PHt[i, a] * Ri[a, c]
            K[i, c] = s
    if second and (measure or force == 1):
        hess_trace(P, Ah, n, mdim, tr)
    if measure:
        for a in range(mdim):
            v = hv[a] + 0.5 * tr[a] if second else hv[a]
            hv[a] = v * ob[a]
    if force == 0:
        return True
    for a in range(mdim):  # M (n, n, mdim)
        if force == 1:
            for i in range(n):
                for j in range(n):
                    M[i, j, a] = -0.5 * P[i, j] * tr[a]
        else:
            for i in range(n):  # (P h_xx^(a))_ib
                for b in range(n):
                    s = 0.0
                    for q in range(n):
                        s += P[i, q] * Ah[a, q, b]
                    T1[i, b] = s
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for q in range(n):
                        s += T1[i, q] * P[q, j]
                    M[i, j, a] = s
    for i in range(n):  # (M · ob) R⁻¹
        for j in range(n):
            for c in range(mdim):
                s = 0.0
                for a in range(mdim):
                    s += M[i, j, a] * ob[a] * Ri[a, c]
                MR[i, j, c] = s
    return True  # (a value: the specialized loops make this kernel a function of its own, .build)


def likelihood_(m, P, y, Rdt, dt, second, meas_kind, Ah, tr, yl, Hl, Ht, C, S, AP, yd, idx, So, piv, u, l1, i1, c1, n,
                mdim):
    """The step's likelihood outputs (``l1``, ``i1``, ``c1``) from ``(m, P)`` at its start: the
    rule's measurement moments ``ŷ = h [+ ½(P h_xx)]``, ``S = H P Hᵀ + R/dt`` [+ the form's
    fourth-moment term] (:func:`~nlfilter.filters.skeleton.condition` with ``R/dt``), the density
    ``log N(dy/dt; ŷ, S)`` of the observed components, reported for ``dy``: innovation ``dt e``,
    covariance ``dt² S``, ``− m_obs log dt`` (:func:`~nlfilter.filters.linalg.innovation_info` with
    ``scale=dt``; NaN where the observed block of S is not positive definite). ``yl``, ``Hl``,
    ``Ah``: h, h_x and h_xx at ``m`` (the model's functions are called by the kernel, never passed
    on: numba could not keep a loop that passes them on disk)."""
    if second:
        hess_trace(P, Ah, n, mdim, tr)
        for a in range(mdim):
            yl[a] = yl[a] + 0.5 * tr[a]
    meas_cov(P, Hl, Rdt, Ht, C, S, n, mdim)  # C = P Hᵀ, S = H C + R/dt
    if second:
        quartic(meas_kind, P, Ah, tr, n, mdim, AP, S)
    mo = 0
    for a in range(mdim):
        yd[a] = y[a] / dt
        if not math.isnan(y[a]):
            idx[mo] = a
            mo += 1
    dt2 = dt * dt
    for a in range(mdim):
        i1[a] = dt * (yd[a] - yl[a])  # NaN where missing
        for b in range(mdim):
            c1[a, b] = dt2 * S[a, b] if mo > 0 else np.nan
    if mo == 0:  # nothing measured: the step adds nothing
        l1[0] = 0.0
        return True
    for a in range(mo):
        u[a] = yd[idx[a]] - yl[idx[a]]
        for b in range(mo):
            So[a, b] = S[idx[a], idx[b]]
    for a in range(mo):  # e kept in yd (u becomes S_oo⁻¹ e)
        yd[a] = u[a]
    ok, sign, logdet = lu(So, piv, mo)
    if not ok or not sign > 0.0:
        l1[0] = np.nan
        return True
    lu_solve(So, piv, mo, u)  # S_oo⁻¹ e
    q = 0.0
    for a in range(mo):
        q += yd[a] * u[a]
    l1[0] = -0.5 * (q + logdet + mo * LOG_2PI) - mo * math.log(dt)
    return True  # (a value: the specialized loops make this kernel a function of its own, .build)


def update_ito_(f, fx, fxx, h, hx, hxx, G, m, P, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
    """One Itô step of the continuous Gaussian filter from ``(m, P)`` at step ``t`` (its index) on the
    increment ``y = dy`` (see the module docstring); False where the path fails (a singular observed
    block of R, or the step's covariance fails the divergence test)."""
    Rinv, GQG0, Q, dt, substeps, rk4, second, force, gfix, Rdt, meas_kind = ks
    (x0m, x0P, km, kP, fv, F, Af, hv, Hm, Ah, Gm, GQ, N, PHt, K, M, MR, tr, FP, K0, MR0, Ri, ob, dy0, idx, Ro, piv,
     u, T1, W, ev, L, yl, Hl, Ht, C, S, AP, yd) = ws
    r = Q.shape[0]
    mo = 0
    for a in range(mdim):  # the observed components, the increment with 0 where missing
        if math.isnan(y[a]):
            ob[a] = 0.0
            dy0[a] = 0.0
        else:
            ob[a] = 1.0
            dy0[a] = y[a]
            idx[mo] = a
            mo += 1
    if mo == mdim:
        for a in range(mdim):
            for c in range(mdim):
                Ri[a, c] = Rinv[a, c]
    else:  # the observed block's precision, zero in the missing rows and columns (observed_precision)
        for a in range(mdim):
            for c in range(mdim):
                Ri[a, c] = 0.0
        for a in range(mo):
            for c in range(mo):
                Ro[a, c] = R[idx[a], idx[c]]
        ok = lu(Ro, piv, mo)[0]
        if mo > 0 and not ok:
            return False
        for c in range(mo):
            for a in range(mo):
                u[a] = 1.0 if a == c else 0.0
            lu_solve(Ro, piv, mo, u)
            for a in range(mo):
                Ri[idx[a], idx[c]] = u[a]
    ts = t * dt
    hx(m, ts, p, Hm)  # the gain at the step's start (Itô)
    if second:
        hxx(m, ts, p, Ah)
    ito_terms(P, Hm, ob, Ri, hv, Ah, tr, second, force, False, PHt, K0, M, MR0, T1, n, mdim)
    if want:  # the likelihood of dy/dt ~ N(ŷ, S), S = Cov[h] + R/dt at the step's start (ContinuousGaussianFilter._step_info)
        h(m, ts, p, yl)
        hx(m, ts, p, Hl)
        likelihood(m, P, y, Rdt, dt, second, meas_kind, Ah, tr, yl, Hl, Ht, C, S, AP, yd, idx, Ro, piv, u, l1, i1, c1, n,
                   mdim)
    hs = dt / substeps
    for js in range(substeps):
        s0 = ts + js * hs
        for st in range(4 if rk4 else 1):  # the stage point (x0m, x0P) and its time (.cd_kernels.stage_)
            ss = s0 + stage(m, P, x0m, x0P, km, kP, st, hs, n)
            # the dt terms at the stage point (ito_rhs)
            fx(x0m, ss, p, F)
            f(x0m, ss, p, fv)
            hx(x0m, ss, p, Hm)
            h(x0m, ss, p, hv)
            if second:
                hxx(x0m, ss, p, Ah)
            ito_terms(x0P, Hm, ob, Ri, hv, Ah, tr, second, force, True, PHt, K, M, MR, T1, n, mdim)
            for i in range(n):
                v = 0.0
                for a in range(mdim):
                    v += K[i, a] * hv[a]
                km[st, i] = fv[i] - v
            if second:
                fxx(x0m, ss, p, Af)
                hess_trace(x0P, Af, n, n, tr)
                for i in range(n):
                    km[st, i] = km[st, i] + 0.5 * tr[i]
            if gfix:
                for i in range(n):
                    for j in range(n):
                        N[i, j] = GQG0[i, j]
            else:
                G(x0m, ss, p, Gm)
                for i in range(n):
                    for j in range(n):
                        N[i, j] = 0.0
                add_gqg(Gm, Q, GQ, N, 1.0, n, r)
            mm(F, x0P, FP, n, n, n, False)
            for i in range(n):
                for j in range(n):
                    v = 0.0
                    for a in range(mdim):
                        v += K[i, a] * PHt[j, a]
                    w = FP[i, j] + FP[j, i] + N[i, j] - v
                    if force != 0:
                        v = 0.0
                        for a in range(mdim):
                            v += MR[i, j, a] * hv[a]
                        w = w - v
                    kP[st, i, j] = w
        combine(m, P, km, kP, hs, rk4, n)  # the substep, P symmetrized (.cd_kernels.combine_)
    for i in range(n):  # + K₀ dy (the Itô increment)
        v = 0.0
        for a in range(mdim):
            v += K0[i, a] * dy0[a]
        m[i] = m[i] + v
    if force != 0:
        for i in range(n):
            for j in range(n):
                v = 0.0
                for a in range(mdim):
                    v += MR0[i, j, a] * dy0[a]
                P[i, j] = P[i, j] + v
        symmetrize(P, n)
    return psd_check(m, P, n, tol, W, L, ev)


#: the Python sources of this module's helper kernels (compiled below; inlined by :mod:`.build`)
SOURCES = (ito_terms_, likelihood_)
#: the kind's kernels and work arrays (merged into :mod:`.rule_kernels`' tables)
KERNELS = {"ito": (predict_ito_, update_ito_)}
ALLOC = {"ito": alloc_ito}

ito_terms = jit(ito_terms_, _nrt=False)
likelihood = jit(likelihood_, _nrt=False)
