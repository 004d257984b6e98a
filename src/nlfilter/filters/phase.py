"""Phase tracking (seed 001 ch. 4): phase-lock loop, linear quadrature filter, tensor filter, and
an optimal reference by a grid filter on the circle.

Problem (001 eqs. 4.1-4.6, 4.11-4.14): θ is a Brownian motion of intensity ``q``; the baseband
measurement is ``dz = (sin θ, cos θ) dt + dn``, ``E dn dnᵀ = 2 r I dt``. In rectangular
coordinates ``x = (sin θ, cos θ)`` the problem is bilinear (:class:`~nlfilter.bilinear.PhaseModel`,
built by :func:`~nlfilter.bilinear.phase_model`) and the state lives on the unit circle.
``P_θℓ = √(2 r q)`` (001 eq. 4.9) is the noise-to-signal parameter; every steady-state quantity
depends on ``q`` and ``r`` only through it.

Every filter here is a continuous-time :class:`~nlfilter.filters.base.Filter` on a
:class:`~nlfilter.bilinear.PhaseModel`: ``run(ys, m0, P0)`` with ``ys`` the increments
``dz (..., T, 2)`` on a grid of step ``dt``. ``Estimates.means`` estimate ``x = (sin θ, cos θ)``
``(..., T, 2)``; the phase estimate ``θ̂ (..., T)`` is ``Estimates.extras["theta"]`` (``atan2`` of
the estimate of x — the output map of each filter — except for the PLL, whose θ̂ is its own
unwrapped loop phase). The prior is that of x: ``m0`` the mean of ``(sin θ0, cos θ0)``, ``P0``
its covariance (each filter says how it uses them). A NaN component of an increment is missing:
it contributes no innovation (the grid filter: a flat likelihood for it).
"""

from __future__ import annotations

from types import MappingProxyType
from typing import NamedTuple

import numpy as np
from scipy.special import i0e, i1e

from .. import _validate as V
from ..bilinear import PhaseModel, phase_model
from ..sde_step import END_POINT, HELD
from .base import Estimates, Filter, gaussian_prior, ode_step
from .bilinear import TensorFilter, _SteadyLinearRecursion
from .pointmass import circle_points, moments, normalize

X0_CIRCLE = np.diag([0.5, 0.5, 1.0])  # E[z zᵀ] of z = (sin θ, cos θ, 1), θ uniform: fixes the conserved |x|²


def wrap(a):
    """Angles wrapped to ``(−π, π]``."""
    return np.pi - np.mod(np.pi - np.asarray(a), 2 * np.pi)


def circle_moment(mon) -> float:
    """``E[x1^a x2^b]`` for ``x = (sin θ, cos θ)``, θ uniform: ``(a−1)!!(b−1)!!/(a+b)!!`` for even a, b.

    >>> circle_moment((2, 0)), circle_moment((2, 2)), circle_moment((1, 1))
    (0.5, 0.125, 0.0)
    """
    a, b = int(mon[0]), int(mon[1])
    if a % 2 or b % 2:
        return 0.0
    df = lambda k: float(np.prod(np.arange(k, 0, -2, dtype=float))) if k > 0 else 1.0  # noqa: E731
    return df(a - 1) * df(b - 1) / df(a + b)


def qr_from_P(P: float, q: float = 1.0):
    """``(q, r)`` with ``√(2 r q) = P`` (001 eq. 4.9)."""
    V.positive("P", P)
    V.positive("q", q)
    return q, P * P / (2 * q)


def lqf_gain(q: float, r: float) -> float:
    """Steady gain of the linear quadrature filter, 001 eq. 4.18: ``√(rq(rq+1))/(2r) − q/2``."""
    return float(np.sqrt(r * q * (r * q + 1)) / (2 * r) - q / 2)


def pll_gain(q: float, r: float) -> float:
    """PLL gain minimizing the linearized phase MSE, 001 eq. 4.8: ``√(q / 2r)``."""
    return float(np.sqrt(q / (2 * r)))


def _phase_model(model):
    if not isinstance(model, PhaseModel):
        raise TypeError(f"model: expected a PhaseModel (nlfilter.bilinear.phase_model(q, r)), got {type(model).__name__}")
    return model


def _with_theta(est: Estimates) -> Estimates:
    """The output map of the quadrature filters: ``θ̂ = atan2(x̂₁, x̂₂)`` into ``extras["theta"]``."""
    theta = np.arctan2(est.means[..., 0], est.means[..., 1])
    return est._replace(extras=MappingProxyType({**est.extras, "theta": theta}))


class PhaseEstimate(NamedTuple):
    """Belief of the PLL: the loop phase ``theta (B,)`` (unwrapped)."""

    theta: np.ndarray


class PLL(Filter):
    """Classical phase-lock loop (001 eqs. 4.8-4.10): ``dθ̂ = K dz_I`` with the in-phase
    measurement ``dz_I = cos θ̂ dz₁ − sin θ̂ dz₂`` (= sin(θ − θ̂) dt + noise, 001 eq. 4.6) and
    ``K = √(q/2r)``. Integrated by RK4 (or Euler) with ``dz/dt`` held constant over a step
    (001 §4.3, after Eterno).

    Prior: ``θ̂0 = atan2(m0₁, m0₂)`` (the direction of the prior mean of x = (sin θ, cos θ); per
    path allowed; ``m0 = 0`` gives θ̂0 = 0); ``P0`` is checked but not used. ``means`` are
    ``(sin θ̂, cos θ̂)``, ``covs`` NaN (the loop carries no covariance), ``extras["theta"]`` the
    unwrapped loop phase θ̂. A missing component of ``dz`` drops its term of ``dz_I``. Its gain is
    fixed, but not on the off-line-gain runner of :mod:`.offline`: the loop's innovation
    ``cos θ̂ dz₁ − sin θ̂ dz₂`` is nonlinear in the estimate (no affine map ``θ̂ ↦ Φ θ̂ + Γ dz``).

    >>> pll = PLL(phase_model(1.0, 0.5), 0.01)
    >>> float(pll.run(np.zeros((1, 3, 2)), [0.0, 1.0], np.eye(2)).extras["theta"][0, -1])
    0.0
    """

    covariance = "none"

    name = "pll"
    family = "off-line gains"
    source = "seed 001 §4.1, eqs. 4.6-4.10"
    accepts = ("phase",)
    time = "continuous"
    measurement_convention = HELD

    def __init__(self, model: PhaseModel, dt: float, *, scheme: str = "rk4", K: float | None = None):
        self.model = _phase_model(model)
        self.q, self.r = model.q, model.r
        self.dt = float(V.positive("dt", dt))
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        self.K = pll_gain(self.q, self.r) if K is None else float(V.positive("K", K))

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        g = super().init(m0, P0, batch, initial=initial, rng=rng)
        return PhaseEstimate(np.arctan2(g.mean[:, 0], g.mean[:, 1]))

    def step(self, belief, dy, t):
        h, K = self.dt, self.K
        if np.isnan(dy).any():
            dy = np.where(np.isnan(dy), 0.0, dy)  # a missing component: no term in dz_I
        z1, z2 = dy[..., 0] / h, dy[..., 1] / h
        f = lambda th, s: K * (np.cos(th) * z1 - np.sin(th) * z2)  # noqa: E731
        return PhaseEstimate(ode_step(f, belief.theta, t, h, scheme=self.scheme))

    def summary(self, belief):
        th = belief.theta
        return np.stack([np.sin(th), np.cos(th)], axis=-1), None

    def extras(self, belief):
        return {"theta": belief.theta}


class LinearQuadratureFilter(_SteadyLinearRecursion):
    """Linear quadrature filter (Gustafson-Speyer; 001 eqs. 4.17-4.19): the optimal linear filter
    of the bilinear phase model in steady state, ``θ̂ = atan2(x̂₁, x̂₂)`` (the output map). The gain
    is computed by :class:`~nlfilter.filters.bilinear.OptimalLinearFilter` from eq. 2.54 (equal to
    eq. 4.18). Prior: ``x̂0 = m0`` (per path allowed; ``m0 = 0``: no phase information); ``P0``
    checked only (steady gains from t = 0). ``covs``: the steady error covariance of x̂ (a path
    with a missing component: that of the recursion it ran, :mod:`.offline`). The recursion is the
    off-line-gain runner's (steady schedule, ``dy/dt`` held); ``atan2`` is its output map."""

    name = "lqf"
    source = "seed 001 §4.2, eqs. 4.17-4.19 (2.31-2.54)"
    accepts = ("phase",)

    def __init__(self, model: PhaseModel, dt: float, *, scheme: str = "rk4"):
        self._linear(_phase_model(model), dt, scheme, X0_CIRCLE)
        self.q, self.r = model.q, model.r

    @property
    def state_dim(self) -> int:
        return 2

    def output(self, est):
        return _with_theta(est)


class PhaseTensorFilter(TensorFilter):
    """Tensor filter for phase tracking (001 §4.2-4.3): LQF estimates post-processed by
    ``α x̂ᵢ + β x̂ᵢ³`` (odd powers up to ``degree``) with gains from the exact steady-state
    moments of ``(x, x̂)`` on the circle (the conservation laws ``E|x|^{2k} = 1`` imposed), then
    ``θ̂ = atan2(x̃₁, x̃₂)`` (001 eq. 4.31; the output map). Belief, prior and missing data as
    :class:`~nlfilter.filters.bilinear.TensorFilter` (``x̂0 = m0``)."""

    name = "phase-tensor"
    source = "seed 001 §4.2-4.3, eqs. 4.20-4.31"
    accepts = ("phase",)

    def __init__(self, model: PhaseModel, dt: float, *, degree: int = 3, scheme: str = "rk4"):
        super().__init__(_phase_model(model), dt, targets=[0, 1], degree=degree, initial=circle_moment,
                         X0=X0_CIRCLE, scheme=scheme)
        self.q, self.r = model.q, model.r

    def fits(self):
        return self.fit()

    def output(self, est):
        return _with_theta(est)


def post_processor(P: float, *, degree: int = 3, q: float = 1.0):
    """Off-line cubic (or higher odd) post-processor of x₁ = sin θ at ``P_θℓ = P``
    (001 Figs. 4.3-4.4): returns the :class:`~nlfilter.filters.bilinear.PostProcessorFit`
    (``gains`` = (α, β, ...), ``mse``, ``mse_linear``, ``reduction`` in percent).

    >>> fit = post_processor(0.129)
    >>> round(fit.reduction, 1)          # 001 §4.3: "reduced the mean square error by over 9%"
    9.2
    """
    q, r = qr_from_P(P, q)
    tf = TensorFilter(phase_model(q, r), 1.0, targets=[0], degree=degree, initial=circle_moment,
                      X0=np.diag([0.5, 0.5, 1.0]))
    return tf.fit()[0]


class CircleDensity(NamedTuple):
    """Belief of :class:`CircleGridFilter`: weights ``p (B, size)`` on the grid of the circle."""

    p: np.ndarray


def _von_mises_concentration(rho):
    """``κ`` with ``I₁(κ)/I₀(κ) = ρ`` (bisection, vectorized), 0 where ρ = 0."""
    rho = np.asarray(rho, float)
    lo = np.zeros_like(rho)
    hi = np.full_like(rho, 1.0) + 2.0 / np.maximum(1.0 - rho, 1e-300)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        big = i1e(mid) / i0e(mid) > rho
        hi, lo = np.where(big, mid, hi), np.where(big, lo, mid)
    return np.where(rho > 0, 0.5 * (lo + hi), 0.0)


class CircleGridFilter(Filter):
    """Optimal (Bayes) phase filter on a grid of ``size`` points on the circle: the exact heat
    semigroup of the Brownian phase in Fourier space (``p̂_k ← p̂_k e^{−q k² dt / 2}``), then the
    Kallianpur-Striebel likelihood of the increment, ``exp(h(θ)ᵀ dz / 2r)`` with
    ``h = (sin θ, cos θ)`` (``|h|² = 1`` cancels in the normalisation; a missing component of
    ``dz``: a flat likelihood for it). Estimates: ``means`` ``E[sin θ], E[cos θ]`` (optimal for
    x), ``covs`` their posterior covariance on the grid, ``extras["theta"]`` ``θ̂ = arg E[e^{iθ}]``
    (optimal for E[1 − cos ε]; the output map).

    Prior: ``m0 = P0 = None`` (default) the uniform law; ``m0`` the mean of x = (sin θ0, cos θ0)
    (``|m0| < 1``, per path allowed): the von Mises law with that mean (direction
    ``atan2(m0₁, m0₂)``, mean resultant length ``|m0|``; ``P0`` is checked but does not enter, the
    von Mises law fixing the second moments); or ``initial``: weights on the grid, ``(size,)`` or
    per path ``(..., size)``, non-negative with a positive sum.

    >>> g = CircleGridFilter(phase_model(1.0, 0.5), 0.01, size=64)
    >>> est = g.run(np.zeros((1, 2, 2)))
    >>> np.abs(np.round(est.means[0, -1], 12)).tolist()          # uniform prior, no information
    [0.0, 0.0]
    """

    blas_threads = 1  # small dense products per step: one BLAS thread (base.Filter.blas_threads)
    name = "circle-grid"
    family = "reference"
    source = "seed 001 ch. 4 (optimal filter of Table 4.1; eqs. 4.11-4.14)"
    accepts = ("phase",)
    time = "continuous"
    measurement_convention = END_POINT  # the exact diffusion on the circle (FFT), then h at the end point

    def __init__(self, model: PhaseModel, dt: float, *, size: int = 256):
        self.model = _phase_model(model)
        self.q, self.r = model.q, model.r
        self.dt = float(V.positive("dt", dt))
        self.size = int(V.positive("size", size, integer=True))
        self.theta = circle_points(self.size)
        self._sc = np.sin(self.theta), np.cos(self.theta)
        self._X = np.stack(self._sc, axis=-1)  # the points (sin θ, cos θ) of x
        k = np.fft.rfftfreq(self.size, d=1.0 / self.size)
        self._decay = np.exp(-0.5 * self.q * k ** 2 * self.dt)

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        B = int(np.prod(batch))
        if initial is not None:
            if m0 is not None or P0 is not None:
                raise ValueError("initial: give the prior either as grid weights (initial) or as m0, P0, not both")
            arr = V.finite("initial", V.as_float_array("initial", initial))
            try:
                p = np.broadcast_to(arr, (*batch, self.size)).reshape(B, self.size).copy()
            except ValueError:
                raise ValueError(f"initial: expected weights (..., {self.size}) broadcasting to the batch {batch} "
                                 f"of ys, got shape {arr.shape}") from None
            if np.any(p < 0) or np.any(~(p.sum(axis=-1) > 0)):
                raise ValueError("initial: expected non-negative weights with a positive sum on every path")
            return CircleDensity(normalize(p))
        if m0 is None and P0 is None:
            return CircleDensity(np.full((B, self.size), 1.0 / self.size))
        g = gaussian_prior(m0, P0, 2, batch, who=type(self).__name__)
        rho = np.hypot(g.mean[:, 0], g.mean[:, 1])
        if np.any(rho >= 1):
            raise ValueError(f"m0: the mean of (sin θ0, cos θ0) lies inside the unit circle (|m0| < 1); got |m0| = "
                             f"{float(rho.max()):.6g}")
        kappa = _von_mises_concentration(rho)
        mu = np.arctan2(g.mean[:, 0], g.mean[:, 1])
        w = np.exp(kappa[:, None] * (np.cos(self.theta[None, :] - mu[:, None]) - 1.0))
        return CircleDensity(normalize(w))

    def step(self, belief, dy, t):
        s, c = self._sc
        p = np.fft.irfft(np.fft.rfft(belief.p, axis=-1) * self._decay, n=self.size, axis=-1)
        p = np.maximum(p, 0.0)
        if np.isnan(dy).any():
            dy = np.where(np.isnan(dy), 0.0, dy)  # a missing component: flat likelihood
        a = (dy[..., 0, None] * s + dy[..., 1, None] * c) / (2 * self.r)
        return CircleDensity(normalize(p * np.exp(a - a.max(axis=-1, keepdims=True))))

    def summary(self, belief):
        return moments(belief.p, self._X)

    def output(self, est):
        return _with_theta(est)


__all__ = ["PLL", "LinearQuadratureFilter", "PhaseTensorFilter", "CircleGridFilter", "PhaseEstimate",
           "CircleDensity", "post_processor", "circle_moment", "qr_from_P", "lqf_gain", "pll_gain",
           "wrap", "phase_model"]
