"""Unscented Kalman filter (discrete time), scaled sigma points of van der Merwe.

Sigma points ``χ_0 = m``, ``χ_{±i} = m ± (√((n+λ) P))_i`` (columns of the lower Cholesky factor),
``λ = α² (n + κ) − n``; mean weights ``W_0 = λ/(n+λ)``, covariance weight
``W_0^c = W_0 + 1 − α² + β``, others ``1/(2(n+λ))``.

Predict: ``m⁻ = Σ W_i f(χ_i)``, ``P⁻ = Σ W^c_i (f(χ_i) − m⁻)(·)ᵀ + Σ W_i G(χ_i) Q G(χ_i)ᵀ``
(the expected noise covariance over the sigma points; equals ``G Q Gᵀ`` for constant G).
Update: sigma points redrawn from ``(m⁻, P⁻)``, ``ŷ = Σ W_i h(χ_i)``, ``S = Σ W^c_i (h_i − ŷ)(·)ᵀ + R``,
``C = Σ W^c_i (χ_i − m⁻)(h_i − ŷ)ᵀ``, then :func:`~nlfilter.filters.linalg.gaussian_update`.

Non-additive process noise ``x[k+1] = f(x[k], w[k])`` (``DiscreteModel(..., noise=[w...])``):
``UKF(model)`` predicts over augmented sigma points of ``(x, w)`` (``augmented``; Julier &
Uhlmann 1997, Wan & van der Merwe 2000).

The UKF is the skeleton of :mod:`nlfilter.filters.gaussian` with the
:class:`~nlfilter.filters.rules.Unscented` rule; :class:`ContinuousDiscreteUKF` its
continuous-discrete version (SDE dynamics, discrete measurements).
"""

from __future__ import annotations

import numpy as np

from .. import _validate as V
from ..angles import angles_of, near, wrap_components
from .base import DiscreteFilter, GaussianState  # noqa: F401  (GaussianState: the doctests)
from .gaussian import ContinuousDiscreteGaussianFilter, GaussianFilter
from .linalg import gaussian_update, poison
from .rules import Unscented


class UKF(GaussianFilter):
    """Unscented Kalman filter (batched): the :class:`~nlfilter.filters.gaussian.GaussianFilter`
    skeleton with the :class:`~nlfilter.filters.rules.Unscented` rule. ``alpha, beta, kappa``:
    scaling of the sigma points (module docstring).

    ``augmented``: the prediction over sigma points of the augmented state ``(x, w)`` (Julier &
    Uhlmann 1997; Wan & van der Merwe 2000, the augmented UKF): ``N((m, 0), diag(P, Q))`` in
    dimension ``n + r`` (λ, weights and ``kappa`` of that dimension), propagated through
    ``x⁺ = f(x, w)``; then ``m⁻ = Σ W_i f(χ_i)``, ``P⁻ = Σ W^c_i (f(χ_i) − m⁻)(·)ᵀ`` (no added noise
    term) and, for the smoother, ``Cov[x, x⁺]`` from the x-part of the points. A non-additive
    measurement noise (``meas_noise=``, ``y = h(x, v)``) is augmented the same way in the update:
    points of ``N((m⁻, 0), diag(P⁻, R))``, ``ŷ = Σ W_i h(χ_i)``, ``S = Σ W^c_i (h_i − ŷ)(·)ᵀ`` (no
    added R), ``C = Σ W^c_i (χ^x_i − m⁻)(h_i − ŷ)ᵀ``; an additive one keeps the n-point update
    with R. ``None`` (default): each of the prediction and the update is augmented exactly when
    its noise is non-additive (``DiscreteModel(..., noise=[w...])``, ``meas_noise=[v...]``);
    ``True`` also augments the prediction of additive process noise (``f(x) + G(x) w``); on a
    linear model every choice is the Kalman filter. ``augmented`` (attribute): whether either is."""

    name = "ukf"
    compiled = True  # its steps are the family's (backend="numba"; augmented sigma points: refused)
    source = "Julier & Uhlmann 1997; van der Merwe 2004 (scaled sigma points); Wan & van der Merwe 2000 (augmented)"
    structures = ("state-dependent R", "time-varying R", "cross noise", "non-additive noise",
                  "non-additive measurement noise", "angles")

    def __init__(self, model, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 start: str | None = None, augmented: bool | None = None):
        DiscreteFilter.__init__(self, model, start=start)
        alpha = float(V.positive("alpha", alpha))
        beta = float(V.positive("beta", beta, strict=False))
        kappa = V.real("kappa", kappa)
        if model.n + kappa <= 0:
            raise ValueError(f"kappa: expected n + kappa > 0 (n = {model.n}), got {kappa!r}")
        add_f, add_h = getattr(model, "additive", True), getattr(model, "additive_measurement", True)
        if augmented is not None and not isinstance(augmented, (bool, np.bool_)):
            raise TypeError(f"augmented: expected True, False or None, got {augmented!r}")
        if augmented is not None and not augmented and not (add_f and add_h):
            raise ValueError("augmented: the model's noise enters f or h non-additively (noise=, meas_noise=); "
                             "expected True or None (augmented sigma points), got False")
        if augmented and getattr(model, "cross_noise", None) is not None:
            raise ValueError("augmented: augmented sigma points with correlated noise (cross_noise) are not "
                             "supported; expected False (the decorrelated prediction)")
        # the prediction is augmented when asked or when f is non-additive; the update when h is
        self._aug_predict = bool(augmented) if augmented is not None else not add_f
        self.augmented = self._aug_predict or not add_h
        self._set_rule(Unscented(alpha, beta, float(kappa)))
        self.alpha, self.beta, self.kappa = self.rule.alpha, self.rule.beta, self.rule.kappa

    def _predict(self, state, k, cross: bool = False):
        """With ``augmented``: the prediction over the sigma points of ``(x, w)`` (class docstring)."""
        if not self._aug_predict:
            return super()._predict(state, k, cross=cross)
        md = self.model
        n = md.n

        def f(Z, t):  # x⁺ = f(x, w) on augmented points Z = (x, w)
            return md.f_aug(Z, t) if not getattr(md, "additive", True) else md.transition(Z[..., :n], Z[..., n:], t)

        # the filter's own rule on (x, w): its n + κ > 0 holds in any larger dimension
        ang = angles_of(md).states  # angular states: circular mean over the augmented points (nlfilter.angles)
        mo = self.rule.moments(_augmented(state, md.Q), f, self._time(k), cross=cross, **({"angles": ang} if ang else {}))
        new = GaussianState(mo.mean, mo.cov)
        new = new if mo.bad is None else poison(new, mo.bad)
        return (new, mo.cross[..., :n, :]) if cross else new

    def _condition(self, state, y, t, R=None):
        """A non-additive measurement noise: the update over the sigma points of ``(x, v)`` (class
        docstring); otherwise the skeleton's."""
        md = self.model
        if getattr(md, "additive_measurement", True) or R is not None:
            return super()._condition(state, y, t, R=R)
        ang = angles_of(md)
        mo = self.rule.moments(_augmented(state, md.R), md.h_aug, t, **({"angles": ang.measurements} if ang else {}))
        yhat = near(mo.mean, y, ang.measurements)  # angles: the wrapped innovation
        new = gaussian_update(state, y, yhat, mo.cov, mo.cross[..., :md.n, :])  # S = Cov[h(x, v)], C = Cov[x, h]
        return GaussianState(wrap_components(new.mean, ang.states), new.cov), mo.bad, (yhat, mo.cov)


def _augmented(state, C) -> GaussianState:
    """The Gaussian of ``(x, noise)``: ``N((m, 0), diag(P, C))`` for a belief ``N(m, P)``."""
    m, P = state[0], state[1]
    n, p, batch = m.shape[-1], C.shape[-1], m.shape[:-1]
    Pa = np.zeros((*batch, n + p, n + p))
    Pa[..., :n, :n] = P
    Pa[..., n:, n:] = C
    return GaussianState(np.concatenate([m, np.zeros((*batch, p))], axis=-1), Pa)


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
                 scheme: str = "rk4", substeps: int = 1, start: str | None = None, t0: float | None = None):
        if getattr(model, "kind", None) == "sde" and (not np.isfinite(kappa) or model.n + kappa <= 0):
            raise ValueError(f"kappa: expected n + kappa > 0 (n = {model.n}), got {kappa!r}")
        super().__init__(model, dt, Unscented(alpha, beta, kappa), scheme=scheme, substeps=substeps,
                         start=start, t0=t0)
        self.alpha, self.beta, self.kappa = self.rule.alpha, self.rule.beta, self.rule.kappa
