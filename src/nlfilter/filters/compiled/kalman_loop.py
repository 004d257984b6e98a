"""The linear Kalman filter on the compiled loop (``KalmanFilter.run(..., backend="numba")``):
the loop template (:func:`.loops.steps_`) with a predict and an update kernel that read the
model's matrices as data, not as generated code.

A linear model's step is ``x_{k+1} = F_k x_k + b_k + G_k w_k``, ``y_k = H_k x_k + d_k + v_k``
(seed 000 eqs. 1.33-1.36): the kernels take ``F, b, H, d`` and ``N = G Q Gᵀ`` as arrays over time
``(T_mat, ...)`` (one entry when the model is time-invariant, else one per time ``0..T-1+offset``,
evaluated in NumPy by :meth:`~nlfilter.filters.kalman.KalmanFilter._matrices`, as the NumPy loop
does at each step). The loop is therefore compiled once per process for every linear model — no
code is generated per model, and a :meth:`~nlfilter.models.Model.with_params` copy (e.g. each
evaluation of :func:`nlfilter.fit`) only recomputes the matrices.

The update is the one of every Gaussian rule (:func:`~.step_kernels.condition_`: the observed
components, Joseph form, the log-likelihood of the prediction-error decomposition); the
divergence test after each step is :func:`~.path_linalg.psd_check_`, as the NumPy loop's
recorder. The kernels are sources with the uniform signature of :mod:`.rule_kernels` (whose
``KERNELS_BY_KIND["kalman"]`` lists them), compiled by :func:`.build.steps`; their globals are the
kernels of :mod:`.path_linalg` and :mod:`.step_kernels` only.
"""

from __future__ import annotations

import inspect

import numpy as np

from .kernels import Kernel
from .path_linalg import psd_check
from .step_kernels import condition, meas_cov, predict_cov, work

__all__ = ["SOURCES", "SCALAR_SOURCES", "SCALAR", "KALMAN_KEY", "alloc_kalman", "predict_kalman_", "update_kalman_",
           "matrices", "scalar_parameters"]


def alloc_kalman(n, mdim, r=0, N=0):
    """The work arrays of the Kalman kernels."""
    mp, FP, W, L, ev = np.empty(n), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty(n)
    C, S, Ht, yhat = np.empty((n, mdim)), np.empty((mdim, mdim)), np.empty((n, mdim)), np.empty(mdim)
    return (mp, FP, W, L, ev, C, S, Ht, yhat, work(n, mdim), np.empty((1, 1, 1)))


def predict_kalman_(m, P, t, p, Q, GQG0, G_const, tol, ks, ws, n, mdim):
    """``m⁻ = F m + b``, ``P⁻ = F P Fᵀ + G Q Gᵀ`` (seed 000 eq. 1.33) with the matrices of time
    ``t`` (entry 0 of a time-invariant model's)."""
    Fs, bs, Hs, ds, Ns = ks
    mp, FP, W, L, ev, C, S, Ht, yhat, w, M0 = ws
    k = int(t) if Fs.shape[0] > 1 else 0
    F, b, N = Fs[k], bs[k], Ns[k]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += F[i, j] * m[j]
        mp[i] = s + b[i]
    predict_cov(F, P, N, P, FP, W, n)  # F P Fᵀ + G Q Gᵀ
    for i in range(n):
        m[i] = mp[i]
    return psd_check(m, P, n, tol, W, L, ev)


def update_kalman_(m, P, y, t, p, R, tol, want, l1, i1, c1, ks, ws, n, mdim):
    """``ŷ = H m + d``, ``C = P Hᵀ``, ``S = H C + R``; the Joseph-form update (seed 000 eqs.
    1.34-1.36) with the matrices of time ``t``."""
    Fs, bs, Hs, ds, Ns = ks
    mp, FP, W, L, ev, C, S, Ht, yhat, w, M0 = ws
    k = int(t) if Hs.shape[0] > 1 else 0
    H, d = Hs[k], ds[k]
    for a in range(mdim):
        s = 0.0
        for j in range(n):
            s += H[a, j] * m[j]
        yhat[a] = s + d[a]
    meas_cov(P, H, R, Ht, C, S, n, mdim)  # C = P Hᵀ, S = H C + R
    ok = condition(m, P, y, yhat, S, C, H, R, True, M0, False, False, n, mdim, w, want, l1, i1, c1)
    return ok and psd_check(m, P, n, tol, W, L, ev)


def scalar_f_(x, t, p):
    """``F_k x + b_k`` of a scalar model, ``p`` the rows ``(F, b, H, d, √N)`` of :func:`scalar_parameters`."""
    i = 5 * int(t) if p.shape[0] > 5 else 0
    return p[i] * x + p[i + 1]


def scalar_fx_(x, t, p):
    """``F_k``."""
    i = 5 * int(t) if p.shape[0] > 5 else 0
    return p[i]


def scalar_h_(x, t, p):
    """``H_k x + d_k``."""
    i = 5 * int(t) if p.shape[0] > 5 else 0
    return p[i + 2] * x + p[i + 3]


def scalar_hx_(x, t, p):
    """``H_k``."""
    i = 5 * int(t) if p.shape[0] > 5 else 0
    return p[i + 2]


def scalar_G_(x, t, p):
    """``√N_k`` (``G Q Gᵀ = N_k`` with ``Q = 1``: the time-varying case)."""
    i = 5 * int(t) if p.shape[0] > 5 else 0
    return p[i + 4]


#: the Python sources of this module's kernels (compiled by :func:`.build.steps` into the template)
SOURCES = (predict_kalman_, update_kalman_)
#: the scalar model functions of the EKF's scalar batch loop (:func:`.loops.steps_scalar_`) on a
#: linear model with one state and one measurement: the matrices read from ``p`` (the loop binds them)
SCALAR_SOURCES = (scalar_f_, scalar_fx_, scalar_h_, scalar_hx_, scalar_G_)
#: those as sources, by the names of :func:`.kernels.scalar_kernels`
SCALAR = {name: Kernel(fn.__name__, inspect.getsource(fn), True)
          for name, fn in zip(("f", "fx", "h", "hx", "G"), SCALAR_SOURCES)}


def scalar_parameters(ks):
    """``(p, Q, GQG0, G_const)`` of the scalar batch loop from the matrices ``ks`` of :func:`matrices`
    (``n = m = 1``): ``p`` the rows ``(F, b, H, d, √N)`` per time; a time-invariant model's ``N``
    enters exactly as ``GQG0``, a time-varying one's as ``G = √N_k``, ``Q = 1``."""
    F, b, H, d, N = (a.reshape(a.shape[0]) for a in ks)
    p = np.ascontiguousarray(np.stack([F, b, H, d, np.sqrt(np.maximum(N, 0.0))], axis=1).reshape(-1))
    const = F.shape[0] == 1
    return p, np.ones((1, 1)), N.reshape(-1, 1, 1)[0].copy() if const else np.zeros((1, 1)), const


def matrices(flt, times: int):
    """``(F, b, H, d, N)`` of ``flt`` (a :class:`~nlfilter.filters.kalman.KalmanFilter`) as
    C-contiguous arrays over time: one entry for a time-invariant model, else ``times`` entries
    (times ``0..times-1``); None when a matrix is not one per time (parameters per path)."""
    n, mdim = flt.model.n, flt.model.m
    shapes = ((n, n), (n,), (mdim, n), (mdim,), (n, n))
    at = [flt._mats] if flt._const else [flt._matrices(k) for k in range(max(times, 1))]
    if any(np.shape(a) != s for mats in at for a, s in zip(mats, shapes)):
        return None
    return tuple(np.ascontiguousarray(np.array([mats[i] for mats in at], dtype=float)) for i in range(5))


#: the key of the Kalman loop in the compiled store (:data:`.kernels.KERNELS`): one loop for every model
KALMAN_KEY = predict_kalman_
