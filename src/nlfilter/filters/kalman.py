"""Linear Kalman filter (discrete) and Kalman–Bucy filter (continuous), with their Riccati
steady states (seed 000 eqs. 1.33-1.36 for the discrete filter).

A model is linear when ``f`` and ``h`` are affine in the state and ``G`` is constant
(``model.is_linear``); the matrices ``F = f_x``, ``H = h_x`` and offsets ``f(0)``, ``h(0)`` are
read from the model at each step (so time-varying linear models work).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from ..angles import angles_of, near, wrap_components
from .base import ContinuousFilter, DiscreteFilter, GaussianState
from .diffuse import kalman_steps
from .diffuse_prior import DiffusePrior
from .fading import FadingMemory
from .linalg import gaussian_update, innovation_info
from .ekf import ContinuousEKF
from .skeleton import CrossNoise
from .smoothing import backward_steps, rts


def _require_linear(model, who):
    if not getattr(model, "is_linear", False):
        raise ValueError(f"model: {who} needs a linear model (f, h affine in the state, G constant); "
                         f"got {model!r}; use EKF, UKF or a second-order filter")


class KalmanFilter(DiffusePrior, DiscreteFilter, FadingMemory):
    """Discrete Kalman filter on a linear :class:`~nlfilter.models.DiscreteModel` (batched, Joseph-form update).

    Correlated noise ``E[w_k v_kᵀ] = S`` (``cross_noise``; :class:`~nlfilter.filters.skeleton.CrossNoise`):
    the prediction ``m⁻ = F m + b + G K_w (y_k − H m − d)``, ``P⁻ = F̃ P F̃ᵀ + G (Q − K_w Sᵀ) Gᵀ``,
    ``F̃ = F − G K_w H``, ``K_w = S R⁻¹`` (Anderson & Moore 1979, §5.5), exact.

    ``fading_memory(alpha)``: ``P⁻ = α² F P Fᵀ + G Q Gᵀ`` (:mod:`~nlfilter.filters.fading`;
    filterpy's ``KalmanFilter.alpha``).

    Noise given per step (``R`` ``(T, m, m)`` / ``(B, T, m, m)``, ``Q`` ``(T, r, r)`` /
    ``(B, T, r, r)``, or written with parameters given as arrays over time;
    :mod:`nlfilter.models`, "Noise given per step"): the step ``k``'s covariances enter the
    recursion (seed 000 eqs. 1.33-1.36 with ``Q_k``, ``R_k``)::

        m⁻_{k+1} = F_k m_k + b_k,        P⁻_{k+1} = F_k P_k F_kᵀ + G_k Q_k G_kᵀ
        S_k = H_k P⁻_k H_kᵀ + R_k,       K_k = P⁻_k H_kᵀ S_k⁻¹
        m_k = m⁻_k + K_k (y_k − H_k m⁻_k − d_k),   P_k = (I − K_k H_k) P⁻_k (I − K_k H_k)ᵀ + K_k R_k K_kᵀ
        log p(y_k | y_{<k}) = log N(y_k; H_k m⁻_k + d_k, S_k)

    (per-path arrays: each path its own ``R_k``, ``Q_k``); the RTS smoother runs on the same
    predictions."""

    name = "kf"
    family = "gaussian"
    source = "seed 000 eqs. 1.33-1.36 (Kalman 1960)"
    needs = ("linear",)
    structures = ("cross noise", "time-varying R", "angles")
    compiled = True  # backend="numba": its matrices as data (compiled.kalman_loop); cross noise runs here
    compiled_kind = "kalman"
    diffuse_prior = True  # run(), smooth(): P0 with inf entries is a diffuse prior (diffuse_prior.DiffusePrior)

    def __init__(self, model, *, start: str | None = None):
        super().__init__(model, start=start)
        _require_linear(model, "KalmanFilter")
        self._const = getattr(model, "time_invariant", False)  # else F, b, H, d, GQGᵀ read at every step
        if self._const:
            self._mats = self._matrices(0)
        self._cross = CrossNoise(model)

    def _diffuse_steps(self):
        """The diffuse prior's steps (:class:`~nlfilter.filters.diffuse_prior.DiffusePrior`): the model's matrices."""
        return kalman_steps(self)

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        return self._cross.unmeasured(super().init(m0, P0, batch, initial=initial, rng=rng))

    def _matrices(self, k):
        md = self.model
        z = np.zeros(md.n)
        if getattr(md, "_per_path_G", False):  # G Q_k Gᵀ per path: at the batch's states (_gqg)
            GQG = None
        else:
            G = md.G(z, k)
            GQG = G @ md.Q @ G.T
        return md.f_x(z, k), md.f(z, k), md.h_x(z, k), md.h(z, k), GQG

    def _gqg(self, GQG, m, k):
        """``G Q_k Gᵀ``: the step's matrix, or per path (a per-path Q given per step) at the means ``m``."""
        return self.model.GQGT(m, k) if GQG is None else GQG

    def predict(self, state, k):
        state = self._inflate(state)  # fading memory: from α² P (fading.py)
        if self._cross.S is None:
            F, b, _, _, GQG = self._mats if self._const else self._matrices(k)
            m, P = state
            GQG = self._gqg(GQG, m, k)
            return GaussianState(wrap_components(m @ F.T + b, angles_of(self.model).states), F @ P @ F.T + GQG)
        return self._predict_cross(state, k)[0]

    def update(self, state, y, k):
        return self._cross.carry(self._update(state, y, k)[0], y)

    smoother = "rts"

    def _predict_cross(self, state, k):
        """The prediction and ``Cov[x_k, x_{k+1}] = P F̃ᵀ`` (``F̃ = F`` without correlated noise)."""
        F, b, H, d, GQG = self._mats if self._const else self._matrices(k)
        state = self._inflate(state)  # fading memory: from α² P, D = P F̃ᵀ (fading.py)
        m, P = state[0], state[1]
        GQG = self._gqg(GQG, m, k)
        dec = self._cross.decorrelation(state, k)
        if dec is None:
            mean = wrap_components(m @ F.T + b, angles_of(self.model).states)  # angles: wrapped (nlfilter.angles)
            return self._cross.unmeasured(GaussianState(mean, F @ P @ F.T + GQG)), self._deflate(P @ F.T)
        D, e, sub = dec
        Ft = F - D @ H  # F̃ = F − G K_w H
        mean = np.einsum("...ij,...j->...i", Ft, m) + b + np.einsum("...ij,...j->...i", D, e - d)
        cov = Ft @ P @ np.swapaxes(Ft, -1, -2) + GQG - sub
        mean = wrap_components(mean, angles_of(self.model).states)
        return (self._cross.unmeasured(GaussianState(mean, 0.5 * (cov + np.swapaxes(cov, -1, -2)))),
                self._deflate(P @ np.swapaxes(Ft, -1, -2)))

    def _smooth(self, est, beliefs, ys, t0):
        """The Rauch–Tung–Striebel smoother (Rauch, Tung & Striebel 1965; :func:`~nlfilter.filters.smoothing.rts`)."""
        ms, Ps, lag = rts(est.means, est.covs, *backward_steps(self, ys), angles=angles_of(self.model).states)
        return ms, Ps, {"lag_one_cov": lag}

    likelihood = "prediction-error"

    def _update(self, state, y, k):
        _, _, H, d, _ = self._mats if self._const else self._matrices(k)
        m, P = state[0], state[1]
        state = GaussianState(m, P)
        md = self.model
        R = md.R if md.R_constant else md.R_of(m, k)  # R_k given per step (the structure "time-varying R")
        C = P @ H.T
        S = H @ C + R
        ang = angles_of(md)
        yhat = near(m @ H.T + d, y, ang.measurements)  # angles: the wrapped innovation (nlfilter.angles)
        new = gaussian_update(state, y, yhat, S, C, H=np.broadcast_to(H, (*m.shape[:-1], *H.shape)), R=R)
        return GaussianState(wrap_components(new.mean, ang.states), new.cov), yhat, S

    def _update_info(self, state, y, k):
        """The update and the step's log N(y; H m⁻ + d, H P⁻ Hᵀ + R) (prediction-error decomposition)."""
        new, yhat, S = self._update(state, y, k)
        return self._cross.carry(new, y), None, innovation_info(y, yhat, S)


def steady_state(model, k: int = 0):
    """Steady-state predicted and filtered error covariances ``(P_pred, P_filt)`` of the
    discrete Kalman filter, from ``scipy.linalg.solve_discrete_are`` (time-invariant model)."""
    _require_linear(model, "steady_state")
    z = np.zeros(model.n)
    F, H, G = model.f_x(z, k), model.h_x(z, k), model.G(z, k)
    P = sla.solve_discrete_are(F.T, H.T, G @ model.Q @ G.T, model.R)
    S = H @ P @ H.T + model.R
    K = P @ H.T @ np.linalg.inv(S)
    Pf = P - K @ S @ K.T
    return 0.5 * (P + P.T), 0.5 * (Pf + Pf.T)


def steady_state_continuous(model, t: float = 0.0):
    """Steady-state error covariance of the Kalman–Bucy filter (``solve_continuous_are``)."""
    _require_linear(model, "steady_state_continuous")
    z = np.zeros(model.n)
    F, H, G = model.f_x(z, t), model.h_x(z, t), model.G(z, t)
    P = sla.solve_continuous_are(F.T, H.T, G @ model.Q @ G.T, model.R)
    return 0.5 * (P + P.T)


class KalmanBucy(ContinuousEKF):
    """Kalman–Bucy filter on a linear :class:`~nlfilter.models.SDEModel` (the continuous EKF is exact there)."""

    name = "kf"
    source = "Kalman & Bucy 1961 (seed 004 eqs. 35-37, linear)"
    needs = ("linear",)

    def __init__(self, model, dt, *, scheme="rk4", substeps=1):
        _require_linear(model, "KalmanBucy")
        super().__init__(model, dt, scheme=scheme, substeps=substeps)


__all__ = ["KalmanFilter", "KalmanBucy", "steady_state", "steady_state_continuous", "ContinuousFilter"]
