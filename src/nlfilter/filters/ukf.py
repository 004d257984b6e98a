"""Unscented Kalman filter (discrete time), scaled sigma points of van der Merwe.

Sigma points ``χ_0 = m``, ``χ_{±i} = m ± (√((n+λ) P))_i`` (columns of the lower Cholesky factor),
``λ = α² (n + κ) − n``; mean weights ``W_0 = λ/(n+λ)``, covariance weight
``W_0^c = W_0 + 1 − α² + β``, others ``1/(2(n+λ))``.

Predict: ``m⁻ = Σ W_i f(χ_i)``, ``P⁻ = Σ W^c_i (f(χ_i) − m⁻)(·)ᵀ + Σ W_i G(χ_i) Q G(χ_i)ᵀ``
(the expected noise covariance over the sigma points; equals ``G Q Gᵀ`` for constant G).
Update: sigma points redrawn from ``(m⁻, P⁻)``, ``ŷ = Σ W_i h(χ_i)``, ``S = Σ W^c_i (h_i − ŷ)(·)ᵀ + R``,
``C = Σ W^c_i (χ_i − m⁻)(h_i − ŷ)ᵀ``, then :func:`~nlfilter.filters.base.gaussian_update`.

The UKF is the skeleton of :mod:`nlfilter.filters.gaussian` with the
:class:`~nlfilter.filters.rules.Unscented` rule; :class:`ContinuousDiscreteUKF` its
continuous-discrete version (SDE dynamics, discrete measurements).
"""

from __future__ import annotations

import numpy as np

from .. import _validate as V
from .base import DiscreteFilter, GaussianState  # noqa: F401  (GaussianState: the doctests)
from .gaussian import ContinuousDiscreteGaussianFilter, GaussianFilter
from .rules import Unscented, sigma_points


class UKF(GaussianFilter):
    """Unscented Kalman filter (batched): the :class:`~nlfilter.filters.gaussian.GaussianFilter`
    skeleton with the :class:`~nlfilter.filters.rules.Unscented` rule. ``alpha, beta, kappa``:
    scaling of the sigma points (module docstring)."""

    name = "ukf"
    source = "Julier & Uhlmann 1997; van der Merwe 2004 (scaled sigma points)"

    def __init__(self, model, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 start: str = "update"):
        DiscreteFilter.__init__(self, model, start=start)
        alpha = float(V.positive("alpha", alpha))
        beta = float(V.positive("beta", beta, strict=False))
        if not np.isfinite(kappa) or model.n + kappa <= 0:
            raise ValueError(f"kappa: expected n + kappa > 0 (n = {model.n}), got {kappa!r}")
        self._set_rule(Unscented(alpha, beta, float(kappa)))
        self.alpha, self.beta, self.kappa = self.rule.alpha, self.rule.beta, self.rule.kappa

    def _points(self, state):
        return sigma_points(state.mean, state.cov, self.alpha, self.beta, self.kappa)


class ContinuousDiscreteUKF(ContinuousDiscreteGaussianFilter):
    """Continuous-discrete unscented Kalman filter (Särkkä 2007, IEEE TAC 52(9) 1631-1641):
    between measurements ``dm/dt = E[f]``, ``dP/dt = Cov[x, f] + Cov[f, x] + E[G Q Gᵀ]``
    with the expectations over the sigma points of ``(m, P)`` at every stage of the integrator;
    the UKF update at the measurements ``y_k = h(x(t_k)) + v_k``.

    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x], Q=2.0, R=1.0)
    >>> s = ContinuousDiscreteUKF(model, 0.1, substeps=4).predict(GaussianState(np.array([1.0]), np.array([[0.5]])), 0)
    >>> round(float(s.mean[0]), 6), round(float(s.cov[0, 0]), 6)   # linear: the exact moments (RK4)
    (0.904837, 0.590635)
    """

    name = "cd-ukf"
    source = ("Särkkä 2007, On unscented Kalman filtering for state estimation of continuous-time nonlinear "
              "systems, IEEE TAC 52(9)")

    def __init__(self, model, dt: float, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 scheme: str = "rk4", substeps: int = 1, start: str = "update", t0: float = 0.0):
        if getattr(model, "kind", None) == "sde" and (not np.isfinite(kappa) or model.n + kappa <= 0):
            raise ValueError(f"kappa: expected n + kappa > 0 (n = {model.n}), got {kappa!r}")
        super().__init__(model, dt, Unscented(alpha, beta, kappa), scheme=scheme, substeps=substeps,
                         start=start, t0=t0)
        self.alpha, self.beta, self.kappa = self.rule.alpha, self.rule.beta, self.rule.kappa
