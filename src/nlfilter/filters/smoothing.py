"""Rauch–Tung–Striebel smoothing for every Gaussian filter, through its moment rule.

The forward pass is the filter's own run (:meth:`~nlfilter.filters.base.Filter.smooth`); the
backward pass needs, for each step, the filtered belief ``N(m_k, P_k)`` (the run's estimates),
the predicted belief ``N(m⁻_{k+1}, P⁻_{k+1})`` and the cross-covariance
``D_{k+1} = Cov[x_k, x_{k+1} | y_0..y_k]``, all recomputed here from the filtered moments by the
filter's rule (the statistical-linear-regression form of the smoother: Särkkä 2013, *Bayesian
Filtering and Smoothing*, Thm. 9.1 (Gaussian RTS), Alg. 9.3 (unscented), 9.4 (Gaussian/
cubature); Garcia-Fernández et al. 2017 for iterated forms)::

    D_{k+1} = Cov[x_k, f(x_k)]                                 (the rule's ``cross``)
    G_k = D_{k+1} (P⁻_{k+1})⁻¹
    mˢ_k = m_k + G_k (mˢ_{k+1} − m⁻_{k+1})
    Pˢ_k = P_k + G_k (Pˢ_{k+1} − P⁻_{k+1}) G_kᵀ

With Taylor-1 the rule's cross-covariance is ``P F_xᵀ``: the extended RTS smoother (Särkkä 2013,
Alg. 9.2); on a linear model every rule gives the Kalman (RTS) smoother exactly. Seed 004's
second-order forms and the other Taylor-2 rules use their own P⁻ (with the fourth-moment terms)
and ``Cov[x, f] = P f_xᵀ`` (third moments neglected, as in their prediction).

Continuous-discrete models: the prediction over ``[t_k, t_{k+1}]`` integrates the moment
equations together with ``C(t) = Cov[x_k, x(t)]``, ``C(t_k) = P_k``::

    dC/dt = Cov[x_k, f(x(t))] ≈ C P(t)⁻¹ Cov[x(t), f(x(t))]

(the statistical linearization of f under the Gaussian closure; exact on a linear model, where it
is ``C F(t)ᵀ``: Särkkä & Sarmavuori 2013, "Gaussian filtering and smoothing for
continuous-discrete dynamic systems", Signal Processing 93, eq. 23, type-II smoother), and
``D_{k+1} = C(t_{k+1})``.

Continuous time (a Kalman–Bucy or continuous extended filter, increments ``dy``): the backward
equations of the continuous RTS smoother (Särkkä 2013, §10.8; Leondes, Peller & Stear 1970),
integrated by Euler backwards over the filter's grid::

    dmˢ/dt = f(m) + (F + Σ P⁻¹)(mˢ − m),   Σ = G Q Gᵀ
    dPˢ/dt = (F + Σ P⁻¹) Pˢ + Pˢ (F + Σ P⁻¹)ᵀ − Σ,   F = f_x(m)

(m, P the filtered moments at t; the boundary is the filtered belief at the end).
"""

from __future__ import annotations

import numpy as np

from .beliefs import GaussianState
from .linalg import symmetrize

__all__ = ["rts", "continuous_rts"]


def _solve_right(A, B):
    """``B A⁻¹`` for batches ``A (..., n, n)`` symmetric, ``B (..., p, n)``; paths where A is
    singular or not finite get NaN (their smoothed estimates are then NaN, and such paths are
    already marked diverged by the forward pass)."""
    n = A.shape[-1]
    ok = np.all(np.isfinite(A), axis=(-1, -2)) & np.all(np.isfinite(B), axis=(-1, -2))
    safe = np.where(ok[..., None, None], A, np.eye(n))
    if n == 1:
        with np.errstate(divide="ignore", invalid="ignore"):
            out = B / safe  # (..., p, 1) / (..., 1, 1)
    else:
        try:
            out = np.swapaxes(np.linalg.solve(safe, np.swapaxes(np.where(ok[..., None, None], B, 0.0), -1, -2)), -1, -2)
        except np.linalg.LinAlgError:
            out = B @ np.linalg.pinv(safe, hermitian=True)
    return np.where(ok[..., None, None] & np.isfinite(out), out, np.nan)


def rts(means: np.ndarray, covs: np.ndarray, predict_cross, offset: int = 0):
    """The RTS backward pass over filtered moments ``means (B, T, n)``, ``covs (B, T, n, n)``.

    ``predict_cross(state, k) -> (GaussianState predicted, D (B, n, n))`` gives the prediction
    from step ``k`` of the run to step ``k + 1`` (model index ``k + offset``, the run's start
    convention) and ``D = Cov[x_k, x_{k+1}]``. Returns the smoothed ``(means, covs)``.

    >>> import numpy as np
    >>> F, Q = 0.9, 0.5      # scalar random walk, two filtered steps: the smoother revises step 0
    >>> pc = lambda s, k: (GaussianState(F * s.mean, F * F * s.cov + Q), F * s.cov)
    >>> ms, Ps = rts(np.array([[[0.0], [1.0]]]), np.array([[[[1.0]], [[0.5]]]]), pc)
    >>> round(float(ms[0, 0, 0]), 6), round(float(Ps[0, 0, 0, 0]), 6)    # G = 0.9/1.31; 1 + G² (0.5 − 1.31)
    (0.687023, 0.61768)
    """
    T = means.shape[1]
    ms, Ps = means.copy(), covs.copy()
    for k in range(T - 2, -1, -1):
        m, P = means[:, k], covs[:, k]
        pred, D = predict_cross(GaussianState(m, P), k + offset)
        G = _solve_right(pred.cov, D)  # G = D (P⁻)⁻¹
        Gt = np.swapaxes(G, -1, -2)
        ms[:, k] = m + np.einsum("...ij,...j->...i", G, ms[:, k + 1] - pred.mean)
        Ps[:, k] = symmetrize(P + G @ (Ps[:, k + 1] - pred.cov) @ Gt)
    return ms, Ps


def continuous_rts(flt, means: np.ndarray, covs: np.ndarray, t0: float):
    """The continuous RTS smoother (module docstring) over a continuous filter's estimates
    ``means (B, T, n)`` at ``t_1..t_T`` (``t_k = t0 + k dt``), by backward Euler steps of ``dt``;
    the first estimate is at ``t_1`` (the prior at ``t_0`` is not an output of the run)."""
    md, dt = flt.model, flt.dt
    T = means.shape[1]
    ms, Ps = means.copy(), covs.copy()
    for k in range(T - 1, 0, -1):  # from t_{k+1} (index k) to t_k (index k - 1)
        t = t0 + (k + 1) * dt
        m, P = means[:, k], covs[:, k]
        Sig = md.GQGT(m, t)
        SPinv = _solve_right(P, Sig)  # Σ P⁻¹ (P symmetric)
        A = md.f_x(m, t) + SPinv
        msk, Psk = ms[:, k], Ps[:, k]
        dm = md.f(m, t) + np.einsum("...ij,...j->...i", A, msk - m)
        dP = A @ Psk + Psk @ np.swapaxes(A, -1, -2) - Sig
        ms[:, k - 1] = msk - dt * dm
        Ps[:, k - 1] = symmetrize(Psk - dt * dP)
    return ms, Ps
