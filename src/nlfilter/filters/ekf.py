"""Extended Kalman filters, discrete and continuous time.

Discrete (``x[k+1] = f + G w``, ``y = h + v``)::

    predict:  m⁻ = f(m),  P⁻ = F P Fᵀ + G Q Gᵀ,            F = f_x(m), G = G(m)
    update:   S = H P Hᵀ + R,  K = P Hᵀ S⁻¹,  m⁺ = m + K (y − h(m)),
              P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ  (Joseph),    H = h_x(m)

Continuous (Itô SDE, measurement increments ``dy``; seed 004 eqs. 35-37 without the second-order
terms)::

    dm = f dt + K (dy − h dt),  K = P Hᵀ R⁻¹
    dP/dt = F P + P Fᵀ + G Q Gᵀ − P Hᵀ R⁻¹ H P

integrated between increments by Euler or RK4 with ``dy/dt`` held constant over the step.
"""

from __future__ import annotations

import numpy as np

from .base import ContinuousFilter, DiscreteFilter, GaussianState, gaussian_update, mm


class EKF(DiscreteFilter):
    """Extended Kalman filter for a :class:`~nlfilter.models.DiscreteModel` (batched).

    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0)
    >>> est = EKF(model).run(np.array([[[1.0], [0.5]]]), m0=[0.0], P0=[[1.0]])
    >>> est.means.shape, round(float(est.means[0, 0, 0]), 6)
    ((1, 2, 1), 0.5)
    """

    name = "ekf"

    def __init__(self, model, *, start: str = "update"):
        super().__init__(model, start=start)
        model.require("f", "f_x", "h", "h_x", "G", by="EKF")

    def predict(self, state, k):
        m, P = state
        md = self.model
        F = md.f_x(m, k)
        cov = mm(mm(F, P), np.swapaxes(F, -1, -2)) + md.GQGT(m, k)
        return GaussianState(md.f(m, k), cov)

    def update(self, state, y, k):
        m, P = state
        md = self.model
        H = md.h_x(m, k)
        C = mm(P, np.swapaxes(H, -1, -2))
        S = mm(H, C) + md.R
        return gaussian_update(state, y, md.h(m, k), S, C, H=H, R=md.R)


class ContinuousEKF(ContinuousFilter):
    """Continuous-time EKF (Kalman–Bucy on the linearization) for an :class:`SDEModel`.

    Parameters
    ----------
    model : SDEModel
    dt : float — the measurement step of the increments ``dy``
    scheme : ``"rk4"`` (default) or ``"euler"`` — integration of the mean/covariance ODE
    substeps : int — integration steps per measurement step
    """

    name = "ekf"

    def __init__(self, model, dt, *, scheme="rk4", substeps=1):
        super().__init__(model, dt, scheme=scheme, substeps=substeps)
        model.require("f", "f_x", "h", "h_x", "G", by="ContinuousEKF")
        self._Rinv = np.linalg.inv(model.R)

    def step(self, state, dy, t):
        md, Rinv = self.model, self._Rinv
        obs = ~np.isnan(dy)
        z = np.where(obs, dy, 0.0) / self.dt

        def rhs(m, P, z, s):
            F = md.f_x(m, s)
            H = md.h_x(m, s) * obs[..., :, None]  # missing components do not update
            PHt = P @ np.swapaxes(H, -1, -2)
            K = PHt @ Rinv
            dm = md.f(m, s) + np.einsum("...ij,...j->...i", K, z - md.h(m, s) * obs)
            FP = F @ P
            dP = FP + np.swapaxes(FP, -1, -2) + md.GQGT(m, s) - K @ np.swapaxes(PHt, -1, -2)
            return dm, dP

        return self.integrate(rhs, state, z, t)
