"""Unscented Kalman filter (discrete time), scaled sigma points of van der Merwe.

Sigma points ``χ_0 = m``, ``χ_{±i} = m ± (√((n+λ) P))_i`` (columns of the lower Cholesky factor),
``λ = α² (n + κ) − n``; mean weights ``W_0 = λ/(n+λ)``, covariance weight
``W_0^c = W_0 + 1 − α² + β``, others ``1/(2(n+λ))``.

Predict: ``m⁻ = Σ W_i f(χ_i)``, ``P⁻ = Σ W^c_i (f(χ_i) − m⁻)(·)ᵀ + Σ W_i G(χ_i) Q G(χ_i)ᵀ``
(the expected noise covariance over the sigma points; equals ``G Q Gᵀ`` for constant G).
Update: sigma points redrawn from ``(m⁻, P⁻)``, ``ŷ = Σ W_i h(χ_i)``, ``S = Σ W^c_i (h_i − ŷ)(·)ᵀ + R``,
``C = Σ W^c_i (χ_i − m⁻)(h_i − ŷ)ᵀ``, then :func:`~nlfilter.filters.base.gaussian_update`.
"""

from __future__ import annotations

import numpy as np

from .. import _validate as V
from .base import DiscreteFilter, GaussianState, gaussian_update, poison, sqrt_psd


def sigma_points(m, P, alpha, beta, kappa):
    """Sigma points ``(..., 2n+1, n)``, weights ``(Wm, Wc)`` of shape ``(2n+1,)``, and the paths
    ``(...)`` whose covariance is not PSD (their points are drawn from the identity and must be
    discarded: the UKF poisons them so that ``run`` raises or marks them). The square root is the
    Cholesky factor, or the eigen root where P is only semi-definite (:func:`sqrt_psd`)."""
    n = m.shape[-1]
    lam = alpha**2 * (n + kappa) - n
    L, bad = sqrt_psd((n + lam) * P)
    Lt = np.swapaxes(L, -1, -2)  # rows = columns of L
    X = np.concatenate([m[..., None, :], m[..., None, :] + Lt, m[..., None, :] - Lt], axis=-2)
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + 1 - alpha**2 + beta
    return X, Wm, Wc, bad


class UKF(DiscreteFilter):
    """Unscented Kalman filter (batched). ``alpha, beta, kappa``: scaling of the sigma points."""

    name = "ukf"

    def __init__(self, model, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 start: str = "update"):
        super().__init__(model, start=start)
        self.alpha = float(V.positive("alpha", alpha))
        self.beta = float(V.positive("beta", beta, strict=False))
        if not np.isfinite(kappa) or model.n + kappa <= 0:
            raise ValueError(f"kappa: expected n + kappa > 0 (n = {model.n}), got {kappa!r}")
        self.kappa = float(kappa)

    def _points(self, state):
        return sigma_points(state.mean, state.cov, self.alpha, self.beta, self.kappa)

    def predict(self, state, k):
        md = self.model
        X, Wm, Wc, bad = self._points(state)
        FX = md.f(X, k)
        m = np.einsum("i,...ij->...j", Wm, FX)
        D = FX - m[..., None, :]
        P = np.einsum("i,...ia,...ib->...ab", Wc, D, D)
        if md.G_constant:
            P = P + md.GQGT(state.mean, k)
        else:
            P = P + np.einsum("i,...iab->...ab", Wm, md.GQGT(X, k))
        return poison(GaussianState(m, P), bad)

    def update(self, state, y, k):
        md = self.model
        X, Wm, Wc, bad = self._points(state)
        HX = md.h(X, k)
        yp = np.einsum("i,...ij->...j", Wm, HX)
        Dy = HX - yp[..., None, :]
        Dx = X - state.mean[..., None, :]
        S = np.einsum("i,...ia,...ib->...ab", Wc, Dy, Dy) + md.R
        C = np.einsum("i,...ia,...ib->...ab", Wc, Dx, Dy)
        return poison(gaussian_update(state, y, yp, S, C), bad)
