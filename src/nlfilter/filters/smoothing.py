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

from ..angles import residual, wrap_components
from .beliefs import GaussianState
from .linalg import symmetrize

__all__ = ["rts", "continuous_rts", "backward_steps"]


#: a predicted covariance is singular on a path where its smallest eigenvalue is at most this
#: fraction of its largest: below it an eigenvalue is the rounding of the matrix's own entries
#: (each computed to ~eps·‖P⁻‖ times the few operations forming it; eps ≈ 2.2e-16, so a margin of
#: ~500 eps), and its inverse would only amplify that rounding into the gain
SINGULAR_RTOL = 1e-13


def _singular(A):
    """``(singular (...), (w, U) or None)`` for symmetric PSD ``A (..., n, n)``, finite, n ≥ 2:
    the paths where ``λ_min ≤ SINGULAR_RTOL · λ_max``. A Cholesky screen clears a batch in one
    call: ``Π_i L_ii² = det A ≤ λ_min λ_max^{n-1}`` and ``λ_max ≤ tr A``, so
    ``Π_i (L_ii² / tr A) > SINGULAR_RTOL`` on every path implies no path is singular; otherwise
    the eigendecomposition decides path by path (and serves the pseudo-inverse)."""
    try:
        L = np.linalg.cholesky(A)
        tr = np.trace(A, axis1=-2, axis2=-1)[..., None]
        piv = np.einsum("...ii->...i", L) ** 2
        if np.all(np.prod(piv / tr, axis=-1) > SINGULAR_RTOL):
            return np.zeros(A.shape[:-2], bool), None
    except np.linalg.LinAlgError:
        pass
    w, U = np.linalg.eigh(symmetrize(A))
    return ~(w[..., 0] > SINGULAR_RTOL * w[..., -1]), (w, U)


def _solve_right(A, B):
    """``B A⁺`` for batches ``A (..., n, n)`` symmetric PSD, ``B (..., p, n)``: ``B A⁻¹`` (one LU
    solve; a scalar division for n = 1) where A is nonsingular, and where it is singular
    (:func:`_singular`; a known state component: ``Q = 0`` and ``P0 = 0`` in it, an exact
    measurement) the Moore–Penrose pseudo-inverse on the range of A, its eigenvalues at most
    :data:`SINGULAR_RTOL` · λ_max dropped. The pseudo-inverse is the gain of the Gaussian
    conditional ``E[x_k | x_{k+1}] = m + D P⁻⁺ (x_{k+1} − m⁻)``, exact for a singular joint law
    (the rows of ``D = Cov[x_k, x_{k+1}]`` lie in the range of ``P⁻`` and ``x_{k+1} − m⁻`` lies
    there almost surely; Rao 1973, *Linear Statistical Inference*, §8a.2); a nonsingular path's
    gain is the solve, bitwise the same as without the singular paths. Paths where A or B is not
    finite get NaN (their smoothed estimates are then NaN, and the smoother marks them)."""
    n = A.shape[-1]
    ok = np.all(np.isfinite(A), axis=(-1, -2)) & np.all(np.isfinite(B), axis=(-1, -2))
    safe = np.where(ok[..., None, None], A, np.eye(n))
    Bs = np.where(ok[..., None, None], B, 0.0)
    if n == 1:  # a scalar variance is singular where it is 0 (or negative by rounding): gain 0
        a = safe[..., 0, 0]
        sing = ~(a > 0)
        out = Bs / np.where(sing, 1.0, a)[..., None, None]  # (..., p, 1) / (..., 1, 1)
        out = np.where(sing[..., None, None], 0.0, out)
    else:
        sing, eig = _singular(safe)
        if eig is None:
            out = np.swapaxes(np.linalg.solve(safe, np.swapaxes(Bs, -1, -2)), -1, -2)
        else:
            w, U = eig
            out = np.swapaxes(np.linalg.solve(np.where(sing[..., None, None], np.eye(n), safe),
                                              np.swapaxes(Bs, -1, -2)), -1, -2)
            keep = w > SINGULAR_RTOL * w[..., -1:]
            inv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
            pinv = (U * inv[..., None, :]) @ np.swapaxes(U, -1, -2)
            out = np.where(sing[..., None, None], Bs @ pinv, out)
    return np.where(ok[..., None, None] & np.isfinite(out), out, np.nan)


def rts(means: np.ndarray, covs: np.ndarray, predict_cross, offset: int = 0, angles=()):
    """The RTS backward pass over filtered moments ``means (B, T, n)``, ``covs (B, T, n, n)``.

    ``predict_cross(state, k) -> (GaussianState predicted, D (B, n, n))`` gives the prediction
    from step ``k`` of the run to step ``k + 1`` (model index ``k + offset``, the run's start
    convention) and ``D = Cov[x_k, x_{k+1}]``. Returns the smoothed ``(means, covs, lag)`` with
    ``lag[:, k] = Cov[x_k, x_{k+1} | y_0..y_{T-1}] = G_k Pˢ_{k+1}`` (the lag-one covariance of
    the smoothed law, for EM; NaN at the last step). ``angles``: the angular state components
    (``mˢ_{k+1} − m⁻_{k+1}`` and ``mˢ_k`` wrapped, :mod:`nlfilter.angles`).

    >>> import numpy as np
    >>> F, Q = 0.9, 0.5      # scalar random walk, two filtered steps: the smoother revises step 0
    >>> pc = lambda s, k: (GaussianState(F * s.mean, F * F * s.cov + Q), F * s.cov)
    >>> ms, Ps, _ = rts(np.array([[[0.0], [1.0]]]), np.array([[[[1.0]], [[0.5]]]]), pc)
    >>> round(float(ms[0, 0, 0]), 6), round(float(Ps[0, 0, 0, 0]), 6)    # G = 0.9/1.31; 1 + G² (0.5 − 1.31)
    (0.687023, 0.61768)
    """
    T = means.shape[1]
    ms, Ps = means.copy(), covs.copy()
    lag = np.full_like(covs, np.nan)
    for k in range(T - 2, -1, -1):
        m, P = means[:, k], covs[:, k]
        pred, D = predict_cross(GaussianState(m, P), k + offset)
        G = _solve_right(pred.cov, D)  # G = D (P⁻)⁻¹
        Gt = np.swapaxes(G, -1, -2)
        ms[:, k] = wrap_components(m + np.einsum("...ij,...j->...i", G, residual(ms[:, k + 1], pred.mean, angles)),
                                   angles)
        Ps[:, k] = symmetrize(P + G @ (Ps[:, k + 1] - pred.cov) @ Gt)
        lag[:, k] = G @ Ps[:, k + 1]
    return ms, Ps, lag


def backward_steps(flt, ys, first: int = 0):
    """``(predict_cross, offset)`` of a discrete Gaussian filter's backward pass (:func:`rts`, the
    backward sampler of :mod:`~nlfilter.filters.sampling`, the fixed-lag smoother of
    :mod:`~nlfilter.filters.fixed_lag`): the filter's rule from step ``k`` of the run to ``k + 1``
    with ``D = Cov[x_k, x_{k+1}]`` (a correlated noise's measurement ``ys (B, ·, m)`` of the step
    included), and the model index of ``ys[:, 0]``: the run's start convention (1: the first
    measurement after a prediction) plus ``first``, the run step ``ys[:, 0]`` is (a window)."""
    off = (0 if flt.start == "update" else 1) + first
    return flt._cross.smooth_predict(flt._predict_cross, ys, off), off


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
