"""Phase tracking (seed 001 ch. 4): phase-lock loop, linear quadrature filter, tensor filter, and
an optimal reference by a grid filter on the circle.

Problem (001 eqs. 4.1-4.6, 4.11-4.14): θ is a Brownian motion of intensity ``q``; the baseband
measurement is ``dz = (sin θ, cos θ) dt + dn``, ``E dn dnᵀ = 2 r I dt``. In rectangular
coordinates ``x = (sin θ, cos θ)`` the problem is bilinear (:func:`~nlfilter.bilinear.phase_model`)
and the state lives on the unit circle. ``P_θℓ = √(2 r q)`` (001 eq. 4.9) is the noise-to-signal
parameter; every steady-state quantity depends on ``q`` and ``r`` only through it.

All filters take the increments ``dzs (..., T, 2)`` on a grid of step ``dt`` and return phase
estimates ``(..., T)`` (and, where they have them, estimates of x).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _validate as V
from ..bilinear import phase_model
from .base import screen_outputs, screened
from .bilinear import OptimalLinearFilter, TensorFilter


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


class PhaseEstimates(NamedTuple):
    """``theta (..., T)`` phase estimates; ``x (..., T, 2)`` estimates of (sin θ, cos θ) or None."""

    theta: np.ndarray
    x: np.ndarray | None


def _check(dzs):
    dzs = V.as_float_array("dzs", dzs, ndim_min=2, shape_tail=(None, 2))
    V.finite("dzs", dzs)
    return dzs


def _per_path(name, value, batch, tail=()):
    """``value`` checked (finite) and broadcast to ``(*batch, *tail)`` (a copy)."""
    arr = V.finite(name, V.as_float_array(name, value))
    try:
        return np.broadcast_to(arr, (*batch, *tail)).copy()
    except ValueError:
        want = "an array (..., " + ", ".join(map(str, tail)) + ")" if tail else "a scalar or an array"
        raise ValueError(f"{name}: expected {want} broadcasting to the batch {batch} of dzs, "
                         f"got shape {arr.shape}") from None


class PLL:
    """Classical phase-lock loop (001 eqs. 4.8-4.10): ``dθ̂ = K dz_I`` with the in-phase
    measurement ``dz_I = cos θ̂ dz₁ − sin θ̂ dz₂`` (= sin(θ − θ̂) dt + noise, 001 eq. 4.6) and
    ``K = √(q/2r)``. Integrated by RK4 (or Euler) with ``dz/dt`` held constant over a step
    (001 §4.3, after Eterno).

    >>> pll = PLL(1.0, 0.5, 0.01)
    >>> float(pll.run(np.zeros((1, 3, 2)), theta0=0.0).theta[0, -1])
    0.0
    """

    name = "pll"

    def __init__(self, q: float, r: float, dt: float, *, scheme: str = "rk4", K: float | None = None):
        self.q, self.r = float(V.positive("q", q)), float(V.positive("r", r))
        self.dt = float(V.positive("dt", dt))
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        self.K = pll_gain(q, r) if K is None else float(V.positive("K", K))

    @screened
    def run(self, dzs, theta0=0.0) -> PhaseEstimates:
        """Phase estimates for increments ``dzs (..., T, 2)`` from ``theta0`` (scalar or per path);
        :class:`~nlfilter.errors.DivergenceError` if an estimate becomes non-finite."""
        dzs = _check(dzs)
        th = _per_path("theta0", theta0, dzs.shape[:-2])
        out = np.empty(dzs.shape[:-1])
        h, K = self.dt, self.K
        for k in range(dzs.shape[-2]):
            z1, z2 = dzs[..., k, 0] / h, dzs[..., k, 1] / h
            f = lambda t: K * (np.cos(t) * z1 - np.sin(t) * z2)  # noqa: E731
            if self.scheme == "euler":
                th = th + h * f(th)
            else:
                k1 = f(th)
                k2 = f(th + h / 2 * k1)
                k3 = f(th + h / 2 * k2)
                k4 = f(th + h * k3)
                th = th + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            out[..., k] = th
        screen_outputs(self.name, out[..., None])  # a huge increment overflows θ̂: raise, never NaN
        return PhaseEstimates(out, None)


class LinearQuadratureFilter:
    """Linear quadrature filter (Gustafson-Speyer; 001 eqs. 4.17-4.19): the optimal linear filter
    of the bilinear phase model in steady state, ``θ̂ = atan2(x̂₁, x̂₂)``. The gain is computed by
    :class:`~nlfilter.filters.bilinear.OptimalLinearFilter` from eq. 2.54 (equal to eq. 4.18)."""

    name = "lqf"

    def __init__(self, q: float, r: float, dt: float, *, scheme: str = "rk4"):
        self.q, self.r = float(V.positive("q", q)), float(V.positive("r", r))
        self.model = phase_model(q, r)
        self.linear = OptimalLinearFilter(self.model, dt, gains="steady", scheme=scheme,
                                          X0=np.diag([0.5, 0.5, 1.0]))
        self.dt = self.linear.dt

    def run(self, dzs, m0=(0.0, 0.0)) -> PhaseEstimates:
        dzs = _check(dzs)
        est = self.linear.run(dzs, np.asarray(m0, float), 0.5 * np.eye(2))
        x = est.means
        return PhaseEstimates(np.arctan2(x[..., 0], x[..., 1]), x)


class PhaseTensorFilter:
    """Tensor filter for phase tracking (001 §4.2-4.3): LQF estimates post-processed by
    ``α x̂ᵢ + β x̂ᵢ³`` (odd powers up to ``degree``) with gains from the exact steady-state
    moments of ``(x, x̂)`` on the circle (the conservation laws ``E|x|^{2k} = 1`` imposed), then
    ``θ̂ = atan2(x̃₁, x̃₂)`` (001 eq. 4.31)."""

    name = "tensor"

    def __init__(self, q: float, r: float, dt: float, *, degree: int = 3, scheme: str = "rk4"):
        self.q, self.r = float(V.positive("q", q)), float(V.positive("r", r))
        self.model = phase_model(q, r)
        self.tensor = TensorFilter(self.model, dt, targets=[0, 1], degree=degree, initial=circle_moment,
                                   X0=np.diag([0.5, 0.5, 1.0]), scheme=scheme)
        self.dt = float(dt)

    def fits(self):
        return self.tensor.fit()

    def run(self, dzs, m0=(0.0, 0.0)) -> PhaseEstimates:
        dzs = _check(dzs)
        est = self.tensor.run(dzs, np.asarray(m0, float), 0.5 * np.eye(2))
        x = est.means
        return PhaseEstimates(np.arctan2(x[..., 0], x[..., 1]), x)


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


class CircleGridFilter:
    """Optimal (Bayes) phase filter on a grid of ``size`` points on the circle: the exact heat
    semigroup of the Brownian phase in Fourier space (``p̂_k ← p̂_k e^{−q k² dt / 2}``), then the
    Kallianpur-Striebel likelihood of the increment, ``exp(h(θ)ᵀ dz / 2r)`` with
    ``h = (sin θ, cos θ)`` (``|h|² = 1`` cancels in the normalisation). Estimates:
    ``E[sin θ], E[cos θ]`` (optimal for x) and ``θ̂ = arg E[e^{iθ}]`` (optimal for E[1 − cos ε]).

    >>> g = CircleGridFilter(1.0, 0.5, 0.01, size=64)
    >>> est = g.run(np.zeros((1, 2, 2)))
    >>> np.abs(np.round(est.x[0, -1], 12)).tolist()          # uniform prior, no information
    [0.0, 0.0]
    """

    name = "optimal"

    def __init__(self, q: float, r: float, dt: float, *, size: int = 256):
        self.q, self.r = float(V.positive("q", q)), float(V.positive("r", r))
        self.dt = float(V.positive("dt", dt))
        self.size = int(V.positive("size", size, integer=True))
        self.theta = 2 * np.pi * np.arange(self.size) / self.size
        k = np.fft.rfftfreq(self.size, d=1.0 / self.size)
        self._decay = np.exp(-0.5 * self.q * k ** 2 * self.dt)

    @screened
    def run(self, dzs, p0=None) -> PhaseEstimates:
        """Filter ``dzs (..., T, 2)`` from the prior ``p0`` on the grid (``(..., size)``, non-negative;
        default uniform); :class:`~nlfilter.errors.DivergenceError` if an estimate becomes non-finite."""
        dzs = _check(dzs)
        batch, T = dzs.shape[:-2], dzs.shape[-2]
        if p0 is None:
            p = np.full((*batch, self.size), 1.0 / self.size)
        else:
            p = _per_path("p0", p0, batch, (self.size,))
            if np.any(p < 0) or np.any(~(p.sum(axis=-1) > 0)):
                raise ValueError("p0: expected non-negative weights with a positive sum on every path")
            p = p / p.sum(axis=-1, keepdims=True)
        s, c = np.sin(self.theta), np.cos(self.theta)
        xs = np.empty((*batch, T, 2))
        for k in range(T):
            p = np.fft.irfft(np.fft.rfft(p, axis=-1) * self._decay, n=self.size, axis=-1)
            p = np.maximum(p, 0.0)
            a = (dzs[..., k, 0, None] * s + dzs[..., k, 1, None] * c) / (2 * self.r)
            w = p * np.exp(a - a.max(axis=-1, keepdims=True))
            p = w / w.sum(axis=-1, keepdims=True)
            xs[..., k, 0] = p @ s
            xs[..., k, 1] = p @ c
        screen_outputs(self.name, xs)  # an overflowing likelihood: raise, never NaN
        return PhaseEstimates(np.arctan2(xs[..., 0], xs[..., 1]), xs)


def simulate_phase(q: float, r: float, dt: float, steps: int, paths: int, rng, *, substeps: int = 4,
                   theta0=None):
    """Phase paths ``theta (paths, steps)`` at ``t_k = k dt`` and baseband increments
    ``dzs (paths, steps, 2)``: θ exact Brownian increments on ``substeps`` sub-intervals,
    ``∫ (sin θ, cos θ) dt`` by the trapezoidal rule, ``dn ~ N(0, 2 r dt I)`` (001 eq. 4.14)."""
    h = dt / substeps
    th = rng.uniform(-np.pi, np.pi, size=paths) if theta0 is None else np.broadcast_to(theta0, (paths,)).astype(float)
    thetas = np.empty((paths, steps))
    dzs = np.empty((paths, steps, 2))
    sq = np.sqrt(q * h)
    sn = np.sqrt(2 * r * dt)
    for k in range(steps):
        acc1 = np.zeros(paths)
        acc2 = np.zeros(paths)
        for _ in range(substeps):
            tn = th + sq * rng.standard_normal(paths)
            acc1 += 0.5 * h * (np.sin(th) + np.sin(tn))
            acc2 += 0.5 * h * (np.cos(th) + np.cos(tn))
            th = tn
        thetas[:, k] = th
        dzs[:, k, 0] = acc1 + sn * rng.standard_normal(paths)
        dzs[:, k, 1] = acc2 + sn * rng.standard_normal(paths)
    return thetas, dzs


__all__ = ["PLL", "LinearQuadratureFilter", "PhaseTensorFilter", "CircleGridFilter", "PhaseEstimates",
           "post_processor", "circle_moment", "qr_from_P", "lqf_gain", "pll_gain", "simulate_phase", "wrap"]
