"""Extended Kalman filters, discrete and continuous time.

Discrete (``x[k+1] = f + G w``, ``y = h + v``)::

    predict:  m⁻ = f(m),  P⁻ = F P Fᵀ + G Q Gᵀ,            F = f_x(m), G = G(m)
    update:   S = H P Hᵀ + R,  K = P Hᵀ S⁻¹,  m⁺ = m + K (y − h(m)),
              P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ  (Joseph),    H = h_x(m)

Continuous (Itô SDE, measurement increments ``dy``; seed 004 eqs. 35-37 without the second-order
terms)::

    dm = f dt + K (dy − h dt),  K = P Hᵀ R⁻¹
    dP/dt = F P + P Fᵀ + G Q Gᵀ − P Hᵀ R⁻¹ H P

one step per increment: the ``dt`` terms integrated by Euler or RK4, then ``K dy`` added with the
gain at the start of the step (the Itô reading; with Euler this is Euler–Maruyama).
"""

from __future__ import annotations

import numpy as np

from .base import ContinuousFilter, DiscreteFilter, GaussianState, gaussian_update, mm, observed_precision


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
        """Itô step: the ``dt`` terms integrated by ``scheme``, the innovation ``K dy`` added with
        the gain at the start of the step. (Holding ``dy/dt`` constant inside RK4 stages would
        converge to the Stratonovich reading whenever the gain depends on the state.)"""
        md = self.model
        obs = ~np.isnan(dy)
        dy0 = np.where(obs, dy, 0.0)
        Rinv = observed_precision(md.R, self._Rinv, obs)  # missing components do not update

        def gain(m, P, s):
            H = md.h_x(m, s) * obs[..., :, None]
            PHt = mm(P, np.swapaxes(H, -1, -2))
            return mm(PHt, Rinv), PHt

        def rhs(m, P, z, s):
            K, PHt = gain(m, P, s)
            dm = md.f(m, s) - np.einsum("...ij,...j->...i", K, md.h(m, s) * obs)
            FP = mm(md.f_x(m, s), P)
            dP = FP + np.swapaxes(FP, -1, -2) + md.GQGT(m, s) - mm(K, np.swapaxes(PHt, -1, -2))
            return dm, dP

        K0, _ = gain(state.mean, state.cov, t)
        new = self.integrate(rhs, state, None, t)
        return GaussianState(new.mean + np.einsum("...ij,...j->...i", K0, dy0), new.cov)
