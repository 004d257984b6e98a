"""The adaptive method-of-moments Bayesian filter for bounded, non-Gaussian noise (seed 000).

Zero-order problem (000 Chapter III)
-----------------------------------
``z_k = x_k + v_k`` with ``x_k`` i.i.d. on ``[x_min, x_max]`` (density unknown except through its
moments) and ``v_k ~ U(-c, c)`` (000 uses c = 1).  Given ``z``, ``x`` lies in
``(l, u) = (max(x_min, z - c), min(x_max, z + c))`` (000 eqs. 3.8-3.11), the likelihood is
constant there (eq. 3.3), so the conditional mean is a ratio of integrals of the prior (eq. 3.5).
With the prior replaced by its degree-N least-squares polynomial (:mod:`nlfilter.moments.densities`)
the estimate is (eq. 3.7)::

    x_hat = int_l^u x f_N(x) dx / int_l^u f_N(x) dx

computed exactly in the Legendre basis.  When the denominator is below ``eps`` or ``x_hat`` leaves
``(l, u)`` the estimate falls back to the midpoint ``(l + u)/2`` (eq. 3.16, Fig. 7 steps 9-13).

Adaptive mode (000 eqs. 2.27-2.29, 3.12-3.15, flow chart Fig. 7): the sample moments of ``z``
(eq. 2.27) give moments of ``x`` through the binomial relation with the known moments of ``v``
(eq. 3.14); they are blended with the initial guess of weight ``n0`` (eq. 3.15) and refreshed every
``window`` samples (000: 20).  At step k the flow chart first accumulates ``z_k`` (step 4),
refreshes if due (steps 5-6) and then estimates ``x_k`` (steps 7-13); we keep that order.

First-order problem (derived here; 000 Chapter IV is only outlined in its abstract)
---------------------------------------------------------------------------------
``x_{k+1} = h x_k + w_k``, ``z_k = x_k + v_k`` (000 eqs. 2.4-2.5), ``|w| <= w_b``, ``v ~ U(-c, c)``.
The filter carries the posterior of ``x_k`` as its moments ``m_1..m_N`` and its support
``[l_k, u_k]`` (Schweppe's reachable set, an interval here):

1. *Predict* (eq. 1.13 with the linear map): the moments of ``h x_k + w_k`` follow exactly from
   those of ``x_k`` and ``w_k`` by the binomial expansion (eq. 3.13 applied to ``h x`` and ``w``);
   the reachable interval is ``h [l_k, u_k] + [-w_b, w_b]``.
2. The predicted density is the degree-N Legendre polynomial with those moments on that interval.
3. *Update* (eq. 1.9, uniform likelihood as in eq. 3.3): the posterior support is the predicted
   interval intersected with ``[z - c, z + c]``; posterior moments are ratios of exact integrals
   of the polynomial over it (the same integrals as eq. 3.7, for powers 0..N); the estimate is the
   posterior mean.  Fallback (the analogue of eq. 3.16): if the normaliser is below ``eps`` or
   the mean leaves the interval, the posterior is taken uniform on the interval.
4. *Adaptation* (the analogue of eqs. 2.27-2.29 and 3.14-3.15): in steady state
   ``x = sum_j h^j w_{k-1-j}``, so the cumulants obey ``kappa_i(x) = kappa_i(w) / (1 - h^i)``.
   Sample moments of ``z`` give moments of ``x`` (eq. 3.14), hence cumulants of ``x``, hence
   those of ``w``: ``kappa_i(w) = (1 - h^i) kappa_i(x)``; blended with the initial guess of weight
   ``n0`` and refreshed every ``window`` samples.

Second-order problem (000 eqs. 2.6-2.8) — :class:`SecondOrderMomentFilter`
--------------------------------------------------------------------------
``x_{k+1} = A x_k + b w_k`` (2-vector), ``z_k = c.x_k + v_k``.  The same four steps in 2-D:

1. mixed moments ``E[x0^i x1^j]`` (total order <= N) propagate exactly through the linear map by
   a multinomial expansion (:func:`moment_map_tensor`, eq. 3.13 in two dimensions);
2. the reachable set (Schweppe) is bounded by a convex *template polygon*
   ``{x : d_j.x <= beta_j}`` over fixed directions ``d_j`` (evenly spaced, plus ``+-c``): its
   prediction is the exact support function of ``A P (+) b [-w_b, w_b]`` on those directions,
   ``beta_j' = max_{v in P} d_j.(A v) + w_b |d_j.b|`` (``bounding="box"`` keeps only the axes);
3. the predicted density is the tensor Legendre polynomial of total degree N on the polygon's
   bounding box, restricted to the polygon;
4. the update integrates it exactly over the polygon cut by the slab ``|z - c.x| <= c_v``
   (fan of triangles, collapsed Gauss–Legendre rules exact for degree 2N) — posterior moments,
   mean, fallback to the uniform law on the cut polygon as in 1-D, and also when the posterior
   covariance is not positive semi-definite (the degree-N polynomial is negative over much of the
   cut, as on a loose bounding box: its "moments" are no law's);
5. adaptation uses ``kappa_i(w) = kappa_i(y) / sum_j (c^T A^j b)^i`` with ``y = c.x``.

All filters here return a :class:`MomentRun`; ``MomentRun.to_estimates()`` gives the common
:class:`~nlfilter.filters.base.Estimates` (posterior means and covariances) of the filter protocol.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np

from .. import _validate as V
from ..moments.densities import (LegendreDensity, LegendreDensity2D, cumulants_to_moments, difference_moments,
                                 is_moment_sequence, moments_to_cumulants, sum_moments,
                                 uniform_moments)
from .base import screened

__all__ = ["ZeroOrderMomentFilter", "ZeroOrderRun", "zero_order_estimate", "power_density_estimate",
           "FirstOrderMomentFilter", "MomentRun", "BoundedGridFilter1D", "impulse_power_sums",
           "SecondOrderMomentFilter", "linear_map_moments", "bootstrap_particle_means",
           "ScaledNoiseZeroOrderFilter",
           "MomentFilterWarning"]


class MomentFilterWarning(UserWarning):
    """The moments in use cannot be those of a law on the support (N too high for the data)."""


class ZeroOrderRun(NamedTuple):
    """Output of :meth:`ZeroOrderMomentFilter.run`.

    estimates : (..., T) estimates of x_k
    fallback : (..., T) bool, True where eq. 3.16 was used
    moments : (..., U, N) moments of x in use after each refresh (U refreshes; empty if not adaptive)
    invalid : (..., T) bool, True where the moments in use failed the moment-sequence test
    """

    estimates: np.ndarray
    fallback: np.ndarray
    moments: np.ndarray
    invalid: np.ndarray


def _interval(z, x_min, x_max, c, outside):
    # 000 eqs. 3.8-3.9: ends of the support of x | z for x in (x_min, x_max), v in (-c, c)
    l = np.maximum(x_min, z - c)
    u = np.minimum(x_max, z + c)
    bad = ~(u >= l)
    if np.any(bad):
        if outside == "raise":
            idx = np.argwhere(bad)[0]
            raise ValueError(f"zs: measurement {float(np.asarray(z)[tuple(idx)])!r} at index {tuple(int(i) for i in idx)} "
                             f"is impossible: expected x_min - c <= z <= x_max + c = "
                             f"[{x_min - c}, {x_max + c}] (|z - x| <= {c} for some admissible x)")
        # documented fallback "clip": treat z as the nearest possible measurement
        zc = np.clip(z, x_min - c, x_max + c)
        l = np.maximum(x_min, zc - c)
        u = np.minimum(x_max, zc + c)
    return l, u


def zero_order_estimate(z, density: LegendreDensity, *, x_min=-1.0, x_max=1.0, noise_halfwidth=1.0,
                        eps=1e-6, outside="raise"):
    """Estimate ``E[x | z]`` with the polynomial prior (000 eq. 3.7) and the fallback (eq. 3.16).

    Parameters
    ----------
    z : array (...)
    density : LegendreDensity with batch shape broadcastable to ``z`` (its interval = ``[x_min, x_max]``)
    Returns ``(x_hat, fallback)``, both shaped like ``z``.

    >>> from nlfilter.moments.densities import LegendreDensity, uniform_moments
    >>> d = LegendreDensity.from_moments(uniform_moments(4))
    >>> zero_order_estimate(np.array([0.5, -1.2]), d)[0].tolist()   # J = 0: z/2 (eq. 3.26)
    [0.25, -0.6]
    """
    z = np.asarray(z, dtype=float)
    l, u = _interval(z, x_min, x_max, noise_halfwidth, outside)
    de = density.integral(l, u, 0)  # 000 Fig. 7 step 8
    nu = density.integral(l, u, 1)  # step 10
    with np.errstate(divide="ignore", invalid="ignore"):
        xh = nu / de  # 000 eq. 3.7 (the common factor 1/2 of eq. 3.3 cancels)
    fb = ~(de >= eps) | ~((xh > l) & (xh < u))  # steps 9 and 12
    return np.where(fb, 0.5 * (l + u), xh), fb  # eq. 3.16


def power_density_estimate(z, J: int):
    """Optimal estimate for ``f(x) = (J+1)/2 x^J`` on (-1, 1), ``v ~ U(-1, 1)`` (000 eq. 3.20).

    ``x_op = (J+1)/(J+2) (u^{J+2} - l^{J+2}) / (u^{J+1} - l^{J+1})`` with (l, u) of eq. 3.19.
    """
    z = np.asarray(z, dtype=float)
    l = np.maximum(-1.0, z - 1.0)
    u = np.minimum(1.0, z + 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (J + 1) / (J + 2) * (u ** (J + 2) - l ** (J + 2)) / (u ** (J + 1) - l ** (J + 1))
    return np.where(u - l > 0, x, 0.5 * (l + u))


class ZeroOrderMomentFilter:
    """Method-of-moments estimator for ``z = x + v`` (000 Chapter III, Fig. 7).

    Parameters
    ----------
    N : int
        Highest moment used (degree of the polynomial prior), 1 <= N <= 40.
    support : (x_min, x_max)
        Known bounds of x (000 assumption 2).
    noise_halfwidth : float
        ``c`` in ``v ~ U(-c, c)`` (000 assumption 3: c = 1).
    moments : array (N,) or None
        Known moments of x (non-adaptive mode).  Exactly one of ``moments`` / ``adaptive`` is used.
    adaptive : bool
        Learn the moments of x from the data (eqs. 2.27-2.29, 3.14-3.15).
    initial_moments : array (N,) or None
        Initial guess (default: x uniform on the support, as in 000's Fig. 10 runs).
    n0 : float
        Weight of the initial guess in equivalent samples (eq. 3.15; 000 uses 100).
    window : int
        Refresh the moments every ``window`` samples (000: 20).
    eps : float
        Threshold on the denominator of eq. 3.7 below which eq. 3.16 is used (000's ε; not printed).
    outside : {"raise", "clip"}
        Impossible measurements (``|z - x| > c`` for every admissible x): raise ``ValueError``, or
        clip ``z`` to the nearest possible value.
    invalid_moments : {"warn", "ignore"}
        When the moments in use are not a moment sequence on the support (too high an N for the
        data): "warn" issues a :class:`MomentFilterWarning` and uses eq. 3.16 while they are
        invalid; "ignore" uses the polynomial anyway (000's own algorithm, guarded only by ``eps``).
    """

    def __init__(self, N: int, *, support=(-1.0, 1.0), noise_halfwidth: float = 1.0, moments=None,
                 adaptive: bool = False, initial_moments=None, n0: float = 100.0, window: int = 20,
                 eps: float = 1e-6, outside: str = "raise", invalid_moments: str = "warn"):
        V.positive("N", N, integer=True)
        if N > 40:
            raise ValueError(f"N: expected at most 40, got {N}")
        self.N = int(N)
        try:
            x_min, x_max = (float(s) for s in support)
        except (TypeError, ValueError):
            raise TypeError(f"support: expected a pair (x_min, x_max), got {support!r}") from None
        if not x_max > x_min:
            raise ValueError(f"support: expected x_min < x_max, got {support!r}")
        self.x_min, self.x_max = x_min, x_max
        self.c = float(V.positive("noise_halfwidth", noise_halfwidth))
        self.mv = uniform_moments(self.N, -self.c, self.c)
        self.adaptive = bool(adaptive)
        if not self.adaptive:
            if moments is None:
                raise ValueError("moments: expected the N known moments of x (or adaptive=True), got None")
            self.moments = self._check_moments("moments", moments)
        else:
            if moments is not None:
                raise ValueError("moments: expected None when adaptive=True (give initial_moments instead)")
            self.moments = None
        self.initial_moments = (uniform_moments(self.N, x_min, x_max) if initial_moments is None
                                else self._check_moments("initial_moments", initial_moments))
        self.n0 = float(V.positive("n0", n0, strict=False))
        self.window = int(V.positive("window", window, integer=True))
        self.eps = float(V.positive("eps", eps, strict=False))
        self.outside = V.choice("outside", outside, {"raise", "clip"})
        self.invalid_moments = V.choice("invalid_moments", invalid_moments, {"warn", "ignore"})

    def _check_moments(self, name, m):
        m = V.as_float_array(name, m, shape_tail=(self.N,))
        V.finite(name, m)
        return m

    def density(self, moments=None) -> LegendreDensity:
        """The polynomial prior of degree N from ``moments`` (default: the known ones)."""
        m = self.moments if moments is None else moments
        return LegendreDensity.from_moments(m, self.x_min, self.x_max)

    def estimate(self, z, moments=None):
        """``(x_hat, fallback)`` for measurements ``z`` (...) with the given or known moments."""
        return zero_order_estimate(z, self.density(moments), x_min=self.x_min, x_max=self.x_max,
                                   noise_halfwidth=self.c, eps=self.eps, outside=self.outside)

    def recover_moments(self, mz_hat, n_s):
        """Moments of x from sample moments of z after ``n_s`` samples (eqs. 3.14-3.15)."""
        mx_hat = difference_moments(mz_hat, self.mv)  # 000 eq. 3.14
        w0 = self.n0 / (n_s + self.n0)
        return w0 * self.initial_moments + (1.0 - w0) * mx_hat  # 000 eq. 3.15

    def run(self, zs) -> ZeroOrderRun:
        """Filter a batch of sequences ``zs`` (..., T) (000 Fig. 7)."""
        zs = V.as_float_array("zs", zs, ndim_min=1)
        V.finite("zs", zs)
        batch, T = zs.shape[:-1], zs.shape[-1]
        if not self.adaptive:
            valid = bool(is_moment_sequence(self.moments, self.x_min, self.x_max))
            if not valid and self.invalid_moments == "warn":
                warnings.warn(f"moments: not the moments of a law on [{self.x_min}, {self.x_max}] "
                              f"(N = {self.N}); using eq. 3.16", MomentFilterWarning, stacklevel=2)
                l, u = _interval(zs, self.x_min, self.x_max, self.c, self.outside)
                return ZeroOrderRun(0.5 * (l + u), np.ones(zs.shape, bool), np.zeros((*batch, 0, self.N)),
                                    np.ones(zs.shape, bool))
            xh, fb = self.estimate(zs, self.moments[..., None, :] if self.moments.ndim > 1 else None)
            return ZeroOrderRun(xh, fb, np.zeros((*batch, 0, self.N)), np.full(zs.shape, not valid))
        est = np.empty(zs.shape)
        fb = np.empty(zs.shape, bool)
        inv = np.zeros(zs.shape, bool)
        hist = []
        m = np.broadcast_to(self.initial_moments, (*batch, self.N))
        powers = np.arange(1, self.N + 1)
        acc = np.zeros((*batch, self.N))  # 000 eq. 2.28
        zl = _learning_data(self, zs, self.x_min - self.c, self.x_max + self.c)
        W = self.window
        n_bad = 0
        # Steps with 1-based index k = W, 2W, ... refresh before estimating (Fig. 7 steps 4-6).
        refresh = list(range(W - 1, T, W))
        bounds = sorted(set([0] + refresh + [T]))
        prev = 0
        for a, b in zip(bounds[:-1], bounds[1:]):
            if a in refresh:
                acc = acc + np.sum(zl[..., prev:a + 1, None] ** powers, axis=-2)
                prev = n_s = a + 1
                m = self.recover_moments(acc / n_s, n_s)  # eqs. 2.27, 3.14, 3.15
                hist.append(m)
            valid = is_moment_sequence(m, self.x_min, self.x_max)
            xh, f = self.estimate(zs[..., a:b], m[..., None, :])
            if self.invalid_moments == "warn":
                l, u = _interval(zs[..., a:b], self.x_min, self.x_max, self.c, self.outside)
                xh = np.where(valid[..., None], xh, 0.5 * (l + u))
                f = f | ~valid[..., None]
            n_bad += int(np.sum(~valid))
            est[..., a:b], fb[..., a:b], inv[..., a:b] = xh, f, ~valid[..., None]
        if n_bad and self.invalid_moments == "warn":
            warnings.warn(f"moments: {n_bad} refresh window(s) gave moments that no law on "
                          f"[{self.x_min}, {self.x_max}] has (N = {self.N} too high for the data); "
                          f"eq. 3.16 used there", MomentFilterWarning, stacklevel=2)
        H = np.stack(hist, axis=-2) if hist else np.zeros((*batch, 0, self.N))
        return ZeroOrderRun(est, fb, H, inv)


# ====================================================================== first-order system

class MomentRun(NamedTuple):
    """Output of the dynamic moment filters.

    estimates : (..., T, n) posterior means
    fallback : (..., T) bool, True where the uniform fallback (analogue of eq. 3.16) was used
    lower, upper : (..., T, n) the posterior's bounding interval / box (Schweppe's reachable set
        intersected with the measurement's)
    w_moments : (..., U, N) input moments in use after each refresh (adaptive mode; else U = 0)
    covs : (..., T, n, n) posterior covariances; NaN when N < 2 (the second moments are not
        carried: no covariance exists, which is not a divergence)
    """

    estimates: np.ndarray
    fallback: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    w_moments: np.ndarray
    covs: np.ndarray | None = None

    def to_estimates(self):
        """The filter protocol's :class:`~nlfilter.filters.base.Estimates` (no divergence possible:
        every step is finite by construction, fallbacks are flagged in ``fallback``)."""
        from .base import Estimates
        batch = self.estimates.shape[:-2]
        return Estimates(self.estimates, self.covs, np.zeros(batch, bool), np.full(batch, -1))


def impulse_power_sums(g, N: int) -> np.ndarray:
    """``S_i = sum_j g_j^i`` for i = 1..N from impulse-response coefficients ``g`` (1-D array).

    With ``y = sum_j g_j w_{k-j}`` and i.i.d. ``w``: ``kappa_i(y) = kappa_i(w) S_i`` (cumulants add
    over independent terms and scale by ``g^i``) — the dynamic counterpart of eq. 3.13.
    """
    g = np.asarray(g, dtype=float)
    return np.array([np.sum(g ** i) for i in range(1, N + 1)])


class _AdaptiveInput:
    """Learns the moments of the input ``w`` from measured data (analogue of 000 eqs. 2.27-2.29,
    3.14-3.15): sample moments of z -> moments of y = z - v (eq. 3.14) -> cumulants of y ->
    cumulants of w (divide by S_i) -> moments of w, blended with the initial guess (eq. 3.15)."""

    def __init__(self, N, S, mv, initial, n0, window):
        self.N, self.S, self.mv, self.initial, self.n0, self.window = N, S, mv, initial, n0, window

    def moments(self, acc, n_s):
        my = difference_moments(acc / n_s, self.mv)  # 000 eq. 3.14
        kw = moments_to_cumulants(my) / self.S
        mw_hat = cumulants_to_moments(kw)
        w0 = self.n0 / (n_s + self.n0)
        return w0 * self.initial + (1.0 - w0) * mw_hat  # 000 eq. 3.15


def _check_N(N):
    V.positive("N", N, integer=True)
    if N > 40:
        raise ValueError(f"N: expected at most 40, got {N}")
    return int(N)


def _configure_input(flt, w_bound, N, w_moments, adaptive, initial_w_moments, n0, window,
                     noise_halfwidth, eps, outside):
    """Checks and stores the options shared by the first- and second-order filters: input bound,
    order N, known or adaptive input moments (000 eqs. 2.27-2.29), measurement half-width."""
    flt.wb = float(V.positive("w_bound", w_bound))
    flt.N = _check_N(N)
    flt.c = float(V.positive("noise_halfwidth", noise_halfwidth))
    flt.mv = uniform_moments(flt.N, -flt.c, flt.c)
    flt.eps = float(V.positive("eps", eps, strict=False))
    flt.outside = V.choice("outside", outside, {"raise", "clip"})
    flt.adaptive = bool(adaptive)
    if flt.adaptive == (w_moments is not None):
        raise ValueError("w_moments: expected the N known input moments, or None with adaptive=True; "
                         f"got w_moments={'None' if w_moments is None else 'an array'}, adaptive={adaptive}")
    chk = lambda name, m: V.finite(name, V.as_float_array(name, m, shape_tail=(flt.N,)))  # noqa: E731
    flt.w_moments = None if w_moments is None else chk("w_moments", w_moments)
    flt.initial_w_moments = (uniform_moments(flt.N, -flt.wb, flt.wb) if initial_w_moments is None
                             else chk("initial_w_moments", initial_w_moments))
    flt.n0 = float(V.positive("n0", n0, strict=False))
    flt.window = int(V.positive("window", window, integer=True))


def _learning_data(flt, zs, lo, hi):
    """The measurements the adaptive learner accumulates: with ``outside="clip"`` the clipped ones
    (``[lo, hi]``: every possible measurement), as the estimates use them, so that an impossible
    outlier cannot overflow the sample moments; else ``zs`` (an impossible one raises)."""
    return np.clip(zs, lo, hi) if flt.outside == "clip" else zs


def _start_run(flt, zs):
    """Checked ``zs (..., T)``, the batch shape, T, the input moments to start from (known, or
    the initial guess of the adaptive estimator) over the batch, the adaptive learner and the
    measurements it learns from (:func:`_learning_data`; ``flt.z_bound``: largest possible |z|)."""
    zs = V.as_float_array("zs", zs, ndim_min=1)
    V.finite("zs", zs)
    batch, T = zs.shape[:-1], zs.shape[-1]
    mw = np.broadcast_to(flt.w_moments if not flt.adaptive else flt.initial_w_moments, (*batch, flt.N))
    learner = _AdaptiveInput(flt.N, flt.S, flt.mv, flt.initial_w_moments, flt.n0, flt.window)
    return zs, batch, T, mw, learner, _learning_data(flt, zs, -flt.z_bound, flt.z_bound)


class FirstOrderMomentFilter:
    """Moment Bayesian filter for ``x_{k+1} = h x_k + w_k``, ``z_k = x_k + v_k`` (000 eqs. 2.4-2.5).

    See the module docstring for the derivation.  The filter is exact except for the projection
    of each predicted density onto degree-N polynomials (on the reachable interval).

    Parameters
    ----------
    h : float, |h| < 1
    w_bound : float
        Known bound ``|w| <= w_bound`` (000 assumption 2).
    N : int
        Number of moments carried (degree of the polynomial densities).
    w_moments : array (N,) or None
        Known moments of w; or ``adaptive=True`` to learn them (initial guess ``initial_w_moments``,
        default uniform on the bound, weight ``n0``, refreshed every ``window`` samples).
    noise_halfwidth : float
        ``c`` in ``v ~ U(-c, c)``.
    eps : float
        Posterior normaliser below which the uniform fallback is used.
    outside : {"raise", "clip"}
        A measurement inconsistent with the reachable interval: raise ``ValueError`` naming it, or
        clip to the nearest consistent value (posterior = the nearest end point).

    Step convention: ``zs[..., 0]`` measures ``x_0``, whose prior is the stationary law implied by
    the (known or initially guessed) input moments on the stationary interval ``|x| <= w_b/(1-|h|)``.

    >>> import numpy as np
    >>> f = FirstOrderMomentFilter(0.5, 1.0, 4, w_moments=uniform_moments(4))
    >>> r = f.run(np.array([0.3, -0.2, 0.9]))
    >>> r.estimates.shape, bool(np.all(np.abs(r.estimates) <= 2.0))
    ((3, 1), True)
    """

    n = 1

    def __init__(self, h: float, w_bound: float, N: int, *, w_moments=None, adaptive: bool = False,
                 initial_w_moments=None, n0: float = 100.0, window: int = 20, noise_halfwidth: float = 1.0,
                 eps: float = 1e-9, outside: str = "raise"):
        if isinstance(h, bool) or not isinstance(h, (int, float, np.floating)) or not abs(h) < 1:
            raise ValueError(f"h: expected a real number with |h| < 1 (000 eq. 2.4), got {h!r}")
        self.h = float(h)
        _configure_input(self, w_bound, N, w_moments, adaptive, initial_w_moments, n0, window,
                         noise_halfwidth, eps, outside)
        self.bound = self.wb / (1.0 - abs(self.h))  # stationary reachable set |x| <= w_b/(1-|h|)
        self.S = 1.0 / (1.0 - self.h ** np.arange(1, self.N + 1))  # sum_j h^{ij} = 1/(1 - h^i)
        self.z_bound = self.bound + self.c  # largest possible |z|

    # -- building blocks (all batched) ------------------------------------------------------
    def stationary_moments(self, mw):
        """Moments of the stationary x: ``kappa_i(x) = kappa_i(w) / (1 - h^i)``."""
        return cumulants_to_moments(moments_to_cumulants(mw) * self.S)

    def predict(self, m, l, u, mw):
        """Moments and reachable interval of ``h x + w`` (exact; binomial expansion, eq. 3.13)."""
        from ..moments.densities import affine_moments
        mp = sum_moments(affine_moments(m, self.h, 0.0), mw)
        a, b = self.h * l, self.h * u
        lp = np.maximum(np.minimum(a, b) - self.wb, -self.bound)
        up = np.minimum(np.maximum(a, b) + self.wb, self.bound)
        return mp, lp, up

    def update(self, m, l, u, z):
        """Posterior moments and interval given ``z`` (uniform likelihood, eq. 3.3; fallback 3.16)."""
        lo = np.maximum(l, z - self.c)
        hi = np.minimum(u, z + self.c)
        width_tol = 1e-12 * (1.0 + self.bound)
        bad = hi < lo - width_tol
        if np.any(bad):
            if self.outside == "raise":
                i = tuple(int(j) for j in np.argwhere(bad)[0])
                raise ValueError(f"zs: measurement {float(np.asarray(z)[i] if np.ndim(z) else z)!r} (path {i}) "
                                 f"is inconsistent with the reachable interval "
                                 f"[{float(np.asarray(l)[i] if np.ndim(l) else l)}, "
                                 f"{float(np.asarray(u)[i] if np.ndim(u) else u)}] and |v| <= {self.c}")
            edge = np.where(z - self.c > u, u, l)
            lo = np.where(bad, edge, lo)
            hi = np.where(bad, edge, hi)
        point = hi - lo <= width_tol
        hi_s = np.where(point, lo + 1.0, hi)  # dummy width for degenerate intervals
        d = LegendreDensity.from_moments(m, l, np.maximum(u, l + width_tol))
        I = d.integrals(lo, hi_s, range(0, self.N + 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            post = I[..., 1:] / I[..., :1]
        mean = post[..., 0]
        fb = ~(I[..., 0] >= self.eps) | ~((mean > lo) & (mean < hi)) | ~np.all(np.isfinite(post), axis=-1)
        # fallback: uniform on the posterior interval (the analogue of eq. 3.16)
        k = np.arange(1, self.N + 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            uni = (hi_s[..., None] ** (k + 1) - lo[..., None] ** (k + 1)) / ((k + 1) * (hi_s - lo)[..., None])
        pt = lo[..., None] ** k
        post = np.where(point[..., None], pt, np.where(fb[..., None], uni, post))
        return post, lo, hi, fb & ~point

    @screened
    def run(self, zs) -> MomentRun:
        """Filter a batch of measurement sequences ``zs`` (..., T)."""
        zs, batch, T, mw, learner, zl = _start_run(self, zs)
        est = np.empty((*batch, T, 1))
        lower = np.empty((*batch, T, 1))
        upper = np.empty((*batch, T, 1))
        fbs = np.empty((*batch, T), bool)
        covs = np.empty((*batch, T, 1, 1))
        hist = []
        acc = np.zeros((*batch, self.N))
        powers = np.arange(1, self.N + 1)
        m = self.stationary_moments(mw)
        l = np.full(batch, -self.bound)
        u = np.full(batch, self.bound)
        for k in range(T):
            z = zs[..., k]
            if self.adaptive:
                acc = acc + zl[..., k, None] ** powers
                if (k + 1) % self.window == 0:  # refresh before estimating, as Fig. 7
                    mw = learner.moments(acc, k + 1)
                    hist.append(mw)
            if k > 0:
                m, l, u = self.predict(m, l, u, mw)
            m, l, u, fb = self.update(m, l, u, z)
            est[..., k, 0], lower[..., k, 0], upper[..., k, 0], fbs[..., k] = m[..., 0], l, u, fb
            covs[..., k, 0, 0] = np.maximum(m[..., 1] - m[..., 0] ** 2, 0.0) if self.N >= 2 else np.nan
        H = np.stack(hist, axis=-2) if hist else np.zeros((*batch, 0, self.N))
        return MomentRun(est, fbs, lower, upper, H, covs)


# ====================================================================== grid optimum (1-D)

class BoundedGridFilter1D:
    """Point-mass (grid) optimum for ``x_{k+1} = h x_k + w_k``, ``z_k = x_k + v_k`` with bounded
    ``w`` (known law, a frozen ``scipy.stats`` distribution with a CDF) and ``v ~ U(-c, c)``.

    The grid covers the stationary reachable interval ``|x| <= w_b/(1-|h|)`` with ``G`` cells;
    the transition matrix holds the exact probability that ``h x_i + w`` falls in cell j (CDF
    differences: no smoothing of the discontinuous input densities), the likelihood is the exact
    fraction of each cell inside ``[z - c, z + c]``.  The prior of ``x_0`` is the grid's stationary
    law.  Error: O(cell width) in the state, far below the filters' errors at G = 400.
    """

    def __init__(self, h, w_law, w_bound, *, G: int = 400, noise_halfwidth: float = 1.0):
        self.h = float(h)
        self.c = float(V.positive("noise_halfwidth", noise_halfwidth))
        self.G = int(V.positive("G", G, integer=True))
        B = float(w_bound) / (1.0 - abs(self.h))
        self.edges = np.linspace(-B, B, self.G + 1)
        self.x = 0.5 * (self.edges[1:] + self.edges[:-1])
        # T[i, j] = P(h x_i + w in cell j)
        hi = self.edges[None, 1:] - self.h * self.x[:, None]
        lo = self.edges[None, :-1] - self.h * self.x[:, None]
        Tm = w_law.cdf(hi) - w_law.cdf(lo)
        self.T = Tm / Tm.sum(axis=1, keepdims=True)
        p = np.full(self.G, 1.0 / self.G)
        for _ in range(500):
            p = p @ self.T
        self.p0 = p

    def likelihood(self, z):
        a = np.maximum(self.edges[:-1], z[..., None] - self.c)
        b = np.minimum(self.edges[1:], z[..., None] + self.c)
        return np.clip(b - a, 0.0, None)

    def run(self, zs):
        """Posterior means ``(..., T, 1)`` for ``zs`` (..., T)."""
        zs = np.asarray(zs, dtype=float)
        batch, T = zs.shape[:-1], zs.shape[-1]
        p = np.broadcast_to(self.p0, (*batch, self.G)).copy()
        out = np.empty((*batch, T, 1))
        for k in range(T):
            if k > 0:
                p = p @ self.T
            p = p * self.likelihood(zs[..., k])
            s = p.sum(axis=-1, keepdims=True)
            if np.any(~(s > 0)):
                raise ValueError(f"zs: measurement at step {k} impossible under the grid model")
            p = p / s
            out[..., k, 0] = p @ self.x
        return out


# ====================================================================== second-order system

def _monomial_index(N):
    """Exponent pairs (i, j) with i + j <= N, and a mask on the (N+1, N+1) array."""
    mask = np.add.outer(np.arange(N + 1), np.arange(N + 1)) <= N
    return mask


def moment_map_tensor(A, b, N: int) -> np.ndarray:
    """``C[i, j, p, q, r]``: ``E[y0^i y1^j] = sum C[i,j,p,q,r] E[x0^p x1^q] E[w^r]`` for ``y = A x + b w``.

    Built once per filter (multinomial expansion of ``(A00 x0 + A01 x1 + b0 w)^i (A10 x0 + A11 x1 + b1 w)^j``).
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)

    def powers(a0, a1, bw):
        out = [np.zeros((N + 1, N + 1, N + 1))]
        out[0][0, 0, 0] = 1.0
        for _ in range(N):
            prev = out[-1]
            nxt = np.zeros_like(prev)
            nxt[1:, :, :] += a0 * prev[:-1, :, :]
            nxt[:, 1:, :] += a1 * prev[:, :-1, :]
            nxt[:, :, 1:] += bw * prev[:, :, :-1]
            out.append(nxt)
        return out

    P0 = powers(A[0, 0], A[0, 1], b[0])
    P1 = powers(A[1, 0], A[1, 1], b[1])
    C = np.zeros((N + 1,) * 5)
    for i in range(N + 1):
        for j in range(N + 1 - i):
            a, c = P0[i], P1[j]
            for p, q, r in zip(*np.nonzero(a)):
                sub = c[: N + 1 - p, : N + 1 - q, : N + 1 - r]
                C[i, j, p:p + sub.shape[0], q:q + sub.shape[1], r:r + sub.shape[2]] += a[p, q, r] * sub
    return C


def linear_map_moments(M, A, b, mw, C=None) -> np.ndarray:
    """Mixed moments of ``A x + b w`` (x independent of the scalar w), total order <= N.

    ``M[..., i, j] = E[x0^i x1^j]`` (M[0,0] = 1), ``A`` (2, 2), ``b`` (2,), ``mw`` (..., N) moments of w.
    Exact (eq. 3.13 in two dimensions).  ``C`` = :func:`moment_map_tensor` if precomputed.
    """
    M = np.asarray(M, dtype=float)
    N = M.shape[-1] - 1
    C = moment_map_tensor(A, b, N) if C is None else C
    mw = np.concatenate([np.ones((*np.shape(mw)[:-1], 1)), np.asarray(mw, dtype=float)], axis=-1)
    return np.einsum("ijpqr,...pq,...r->...ij", C, M, mw)


class SecondOrderMomentFilter:
    """Moment Bayesian filter for ``x_{k+1} = A x_k + b w_k``, ``z_k = c.x_k + v_k`` (000 eqs. 2.6-2.8).

    000 writes the second-order system in modal form ``A = diag(h1, h2)``, ``b = c = (d1, d2)``
    (eqs. 2.6-2.7 as the OCR reads them); any stable 2x2 ``A`` works here.  See the module
    docstring for the derivation: mixed moments of total order <= N propagate exactly
    (:func:`linear_map_moments`), the reachable set is bounded by a box (interval arithmetic),
    the predicted density is the tensor Legendre polynomial of total degree N on the box, and the
    posterior moments are exact integrals over the box cut by the measurement slab.

    >>> import numpy as np
    >>> f = SecondOrderMomentFilter(np.diag([0.6, -0.5]), [1.0, 1.0], [1.0, 1.0], 1.0, 2,
    ...                             w_moments=uniform_moments(2))
    >>> f.run(np.array([0.3, -0.2, 0.9])).estimates.shape
    (3, 2)
    """

    n = 2

    def __init__(self, A, b, c, w_bound: float, N: int, *, w_moments=None, adaptive: bool = False,
                 initial_w_moments=None, n0: float = 100.0, window: int = 20, noise_halfwidth: float = 1.0,
                 eps: float = 1e-9, outside: str = "raise", bounding: str = "polygon", directions: int = 16):
        self.bounding = V.choice("bounding", bounding, {"box", "polygon"})
        self.A = V.as_float_array("A", A, ndim=2)
        if self.A.shape != (2, 2):
            raise ValueError(f"A: expected shape (2, 2), got {self.A.shape}")
        if not np.max(np.abs(np.linalg.eigvals(self.A))) < 1:
            raise ValueError(f"A: expected a stable matrix (spectral radius < 1), got {self.A.tolist()}")
        self.b = V.as_float_array("b", b, shape_tail=(2,))
        self.cv = V.as_float_array("c", c, shape_tail=(2,))
        if self.cv[1] == 0:
            raise ValueError("c: expected c[1] != 0 (swap the states otherwise)")
        _configure_input(self, w_bound, N, w_moments, adaptive, initial_w_moments, n0, window,
                         noise_halfwidth, eps, outside)
        # stationary bounding box and impulse response g_j = c^T A^j b
        Ab = [self.b]
        for _ in range(50000):
            Ab.append(self.A @ Ab[-1])
            if np.max(np.abs(Ab[-1])) < 1e-17:
                break
        Ab = np.array(Ab)
        self.bound = self.wb * np.sum(np.abs(Ab), axis=0)
        self.S = impulse_power_sums(Ab @ self.cv, self.N)
        self.z_bound = self.wb * float(np.sum(np.abs(Ab @ self.cv))) + self.c  # largest possible |z|
        self._K = self.N + 2  # Gauss-Legendre nodes per direction: exact for the degree-2N integrands
        self._gl = np.polynomial.legendre.leggauss(self._K)
        self._mask = _monomial_index(self.N)
        self._C = moment_map_tensor(self.A, self.b, self.N)
        # template directions for the polygon bound: evenly spaced, plus the measurement's +-c
        m = int(V.positive("directions", directions, integer=True))
        ang = 2 * np.pi * np.arange(m) / m
        cn = self.cv / np.linalg.norm(self.cv)
        self.D = np.concatenate([np.stack([np.cos(ang), np.sin(ang)], axis=-1), cn[None], -cn[None]])
        self.beta_stat = self.wb * np.sum(np.abs(Ab @ self.D.T), axis=0)  # support of the stationary set
        self._DAb = np.abs(self.D @ self.b) * self.wb
        tt, ww = np.polynomial.legendre.leggauss(self.N + 2)
        self._tri = (0.5 * (tt + 1), 0.5 * ww)

    # -- building blocks --------------------------------------------------------------------
    def stationary(self, mw, steps: int | None = None):
        """Stationary mixed moments and box, by iterating the exact prediction from x = 0
        (``steps`` default: until the spectral radius^steps < 1e-15)."""
        if steps is None:
            rho = float(np.max(np.abs(np.linalg.eigvals(self.A))))
            steps = 1 if rho == 0 else int(min(50000, np.ceil(np.log(1e-15) / np.log(rho)) + 1))
        M = np.zeros((*np.shape(mw)[:-1], self.N + 1, self.N + 1))
        M[..., 0, 0] = 1.0
        for _ in range(steps):
            M = linear_map_moments(M, self.A, self.b, mw, self._C)
        return M, np.broadcast_to(-self.bound, (*M.shape[:-2], 2)), np.broadcast_to(self.bound, (*M.shape[:-2], 2))

    def predict(self, M, lo, hi, mw):
        Mp = linear_map_moments(M, self.A, self.b, mw, self._C)
        Al = self.A * lo[..., None, :]
        Ah = self.A * hi[..., None, :]
        bw = np.abs(self.b) * self.wb
        lp = np.maximum(np.sum(np.minimum(Al, Ah), axis=-1) - bw, -self.bound)
        hp = np.minimum(np.sum(np.maximum(Al, Ah), axis=-1) + bw, self.bound)
        return Mp, lp, hp

    def _slab_nodes(self, lo, hi, s_lo, s_hi):
        """Quadrature nodes/weights on {box} ∩ {s_lo <= c.x <= s_hi}: returns x (..., Q, 2), w (..., Q),
        and the polygon's candidate vertices (..., V, 2) with a validity mask."""
        c0, c1 = self.cv
        corners = np.stack([c0 * lo[..., 0] + c1 * lo[..., 1], c0 * lo[..., 0] + c1 * hi[..., 1],
                            c0 * hi[..., 0] + c1 * lo[..., 1], c0 * hi[..., 0] + c1 * hi[..., 1]], axis=-1)
        a = np.maximum(s_lo, corners.min(axis=-1))
        bnd = np.minimum(s_hi, corners.max(axis=-1))
        bps = np.sort(np.concatenate([corners, a[..., None], bnd[..., None]], axis=-1), axis=-1)
        bps = np.clip(bps, a[..., None], np.maximum(a, bnd)[..., None])  # (..., 6)
        t, w = self._gl
        sa, sb = bps[..., :-1, None], bps[..., 1:, None]  # (..., 5, 1)
        s = 0.5 * (sa + sb) + 0.5 * (sb - sa) * t  # (..., 5, K)
        ws = 0.5 * (sb - sa) * w

        def x0_range(s):
            e1 = s - c1 * lo[..., None, None, 1]
            e2 = s - c1 * hi[..., None, None, 1]
            if c0 != 0:
                r1, r2 = e1 / c0, e2 / c0
                l0 = np.maximum(lo[..., None, None, 0], np.minimum(r1, r2))
                u0 = np.minimum(hi[..., None, None, 0], np.maximum(r1, r2))
            else:
                l0 = np.broadcast_to(lo[..., None, None, 0], s.shape)
                u0 = np.broadcast_to(hi[..., None, None, 0], s.shape)
            return l0, np.maximum(u0, l0)

        l0, u0 = x0_range(s)  # (..., 5, K)
        x0 = 0.5 * (l0 + u0)[..., None] + 0.5 * (u0 - l0)[..., None] * t  # (..., 5, K, K)
        wx = 0.5 * (u0 - l0)[..., None] * w
        x1 = (s[..., None] - c0 * x0) / c1
        W = (ws[..., None] * wx) / abs(c1)
        shp = W.shape[:-3] + (-1,)
        X = np.stack([x0.reshape(shp), x1.reshape(shp)], axis=-1)
        # polygon vertices: the x0-range ends at every breakpoint
        vb = bps[..., None, :]
        vl0, vu0 = x0_range(vb)
        vl0, vu0 = vl0[..., 0, :], vu0[..., 0, :]
        vx0 = np.concatenate([vl0, vu0], axis=-1)
        vs = np.concatenate([bps, bps], axis=-1)
        verts = np.stack([vx0, (vs - c0 * vx0) / c1], axis=-1)
        return X, W.reshape(shp), verts, bnd >= a

    def update(self, M, lo, hi, z):
        z = np.asarray(z, dtype=float)
        X, W, verts, ok = self._slab_nodes(lo, hi, z - self.c, z + self.c)
        if np.any(~ok):
            if self.outside == "raise":
                i = tuple(int(j) for j in np.argwhere(~ok)[0])
                raise ValueError(f"zs: measurement {float(z[i] if z.ndim else z)!r} (path {i}) is inconsistent "
                                 f"with the reachable box and |v| <= {self.c}")
            # clip: use the nearest reachable value of c.x as the measurement
            c0, c1 = self.cv
            corners = np.stack([c0 * lo[..., 0] + c1 * lo[..., 1], c0 * hi[..., 0] + c1 * hi[..., 1],
                                c0 * lo[..., 0] + c1 * hi[..., 1], c0 * hi[..., 0] + c1 * lo[..., 1]], axis=-1)
            zc = np.clip(z, corners.min(-1) - self.c, corners.max(-1) + self.c)
            X, W, verts, ok = self._slab_nodes(lo, hi, zc - self.c, zc + self.c)
        d = LegendreDensity2D.from_moments(M, lo, hi)
        p = d.pdf(X) if X.ndim == 2 else _pdf_batched(d, X)
        N = self.N
        e = np.arange(N + 1)
        P0 = X[..., 0, None] ** e  # (..., Q, N+1)
        P1 = X[..., 1, None] ** e
        I = np.einsum("...q,...qi,...qj->...ij", W * p, P0, P1)
        U = np.einsum("...q,...qi,...qj->...ij", W, P0, P1)  # uniform on the polygon (fallback)
        with np.errstate(divide="ignore", invalid="ignore"):
            post = I / I[..., :1, :1]
            uni = U / U[..., :1, :1]
        # new bounding box of the polygon box ∩ slab
        nlo = np.min(verts, axis=-2)
        nhi = np.max(verts, axis=-2)
        mean = np.stack([post[..., 1, 0], post[..., 0, 1]], axis=-1)
        fb = (~(I[..., 0, 0] >= self.eps) | ~np.all((mean >= nlo) & (mean <= nhi), axis=-1)
              | ~np.all(np.isfinite(post[..., self._mask]), axis=-1) | _not_psd(post))
        area = U[..., 0, 0]
        tiny = ~(area > 1e-14 * np.prod(self.bound))
        post = np.where(fb[..., None, None], uni, post)
        # a degenerate polygon (zero area): point mass at the centre of its vertices
        cen = 0.5 * (nlo + nhi)
        pt = cen[..., 0, None, None] ** e[:, None] * cen[..., 1, None, None] ** e[None, :]
        post = np.where(tiny[..., None, None], pt, post)
        post = np.where(self._mask, post, 0.0)
        width = np.maximum(nhi - nlo, 1e-9 * (1 + self.bound))
        nhi = nlo + width
        return post, nlo, nhi, fb & ~tiny

    # -- polygon (template) bound ------------------------------------------------------------
    def _polygon(self, beta):
        """Vertices of {x : D x <= beta} (clipping the stationary box), (..., P, 2), CCW."""
        B = self.bound
        box = np.array([[-B[0], -B[1]], [B[0], -B[1]], [B[0], B[1]], [-B[0], B[1]]])
        P = np.broadcast_to(box, (*beta.shape[:-1], 4, 2))
        for j in range(self.D.shape[0]):
            P = _clip_halfplane(P, self.D[j], beta[..., j])
            if P.shape[-2] > 8:
                P = _trim_polygon(P)
        return _trim_polygon(P)

    def predict_polygon(self, M, verts, mw):
        """Exact moments of A x + b w; template bound: support of A P (+) b [-w_b, w_b] on D."""
        Mp = linear_map_moments(M, self.A, self.b, mw, self._C)
        AV = verts @ self.A.T
        beta = np.max(np.einsum("jk,...pk->...pj", self.D, AV), axis=-2) + self._DAb
        beta = np.minimum(beta, self.beta_stat)
        P = self._polygon(beta)
        return Mp, P

    def update_polygon(self, M, verts, z):
        z = np.asarray(z, dtype=float)
        cn = self.cv / np.linalg.norm(self.cv)
        scale = 1.0 / np.linalg.norm(self.cv)
        lo_b = np.min(verts, axis=-2)
        hi_b = np.max(verts, axis=-2)
        Q = _clip_halfplane(verts, cn, (z + self.c) * scale)
        Q = _trim_polygon(_clip_halfplane(Q, -cn, -(z - self.c) * scale))
        X, W = _polygon_quadrature(Q, *self._tri)
        area = W.sum(-1)
        tiny = ~(area > 1e-12 * np.prod(self.bound))
        if np.any(tiny):
            # measurement (nearly) inconsistent with the reachable polygon
            proj = np.einsum("k,...pk->...p", self.cv, verts)
            gap = np.maximum(proj.min(-1) - (z + self.c), (z - self.c) - proj.max(-1))
            bad = gap > 1e-9 * (1 + np.max(self.bound))
            if np.any(bad) and self.outside == "raise":
                i = tuple(int(j) for j in np.argwhere(bad)[0])
                raise ValueError(f"zs: measurement {float(z[i] if z.ndim else z)!r} (path {i}) is inconsistent "
                                 f"with the reachable polygon and |v| <= {self.c}")
        d = LegendreDensity2D.from_moments(M, lo_b, np.maximum(hi_b, lo_b + 1e-12))
        p = _pdf_batched(d, X) if X.ndim > 2 else d.pdf(X)
        e = np.arange(self.N + 1)
        P0 = X[..., 0, None] ** e
        P1 = X[..., 1, None] ** e
        I = np.einsum("...q,...qi,...qj->...ij", W * p, P0, P1)
        U = np.einsum("...q,...qi,...qj->...ij", W, P0, P1)
        with np.errstate(divide="ignore", invalid="ignore"):
            post = I / I[..., :1, :1]
            uni = U / U[..., :1, :1]
        nlo, nhi = np.min(Q, axis=-2), np.max(Q, axis=-2)
        mean = np.stack([post[..., 1, 0], post[..., 0, 1]], axis=-1)
        fb = (~(I[..., 0, 0] >= self.eps) | ~np.all((mean >= nlo) & (mean <= nhi), axis=-1)
              | ~np.all(np.isfinite(post[..., self._mask]), axis=-1) | _not_psd(post))
        post = np.where(fb[..., None, None], uni, post)
        # degenerate / inconsistent (clip mode): point mass at the polygon point nearest the slab
        proj = np.einsum("k,...pk->...p", self.cv, verts)
        near = np.take_along_axis(verts, np.argmin(np.abs(proj - z[..., None]), axis=-1)[..., None, None], axis=-2)[..., 0, :]
        pt = near[..., 0, None, None] ** e[:, None] * near[..., 1, None, None] ** e[None, :]
        post = np.where(tiny[..., None, None], pt, post)
        Q = np.where(tiny[..., None, None], near[..., None, :], Q)
        post = np.where(self._mask, post, 0.0)
        return post, Q, np.min(Q, axis=-2), np.max(Q, axis=-2), fb & ~tiny

    @screened
    def run(self, zs) -> MomentRun:
        """Filter a batch of measurement sequences ``zs`` (..., T)."""
        zs, batch, T, mw, learner, zl = _start_run(self, zs)
        M, lo, hi = self.stationary(self.w_moments if not self.adaptive else self.initial_w_moments)
        M = np.broadcast_to(M, (*batch, self.N + 1, self.N + 1))
        lo = np.broadcast_to(lo, (*batch, 2))
        hi = np.broadcast_to(hi, (*batch, 2))
        verts = self._polygon(np.broadcast_to(self.beta_stat, (*batch, self.D.shape[0])))
        est = np.empty((*batch, T, 2))
        lower = np.empty((*batch, T, 2))
        upper = np.empty((*batch, T, 2))
        fbs = np.empty((*batch, T), bool)
        covs = np.full((*batch, T, 2, 2), np.nan)
        hist = []
        acc = np.zeros((*batch, self.N))
        powers = np.arange(1, self.N + 1)
        for k in range(T):
            z = zs[..., k]
            if self.adaptive:
                acc = acc + zl[..., k, None] ** powers
                if (k + 1) % self.window == 0:
                    mw = learner.moments(acc, k + 1)
                    hist.append(mw)
            if self.bounding == "box":
                if k > 0:
                    M, lo, hi = self.predict(M, lo, hi, mw)
                M, lo, hi, fb = self.update(M, lo, hi, z)
            else:
                if k > 0:
                    M, verts = self.predict_polygon(M, verts, mw)
                M, verts, lo, hi, fb = self.update_polygon(M, verts, z)
            est[..., k, 0], est[..., k, 1] = M[..., 1, 0], M[..., 0, 1]
            lower[..., k, :], upper[..., k, :], fbs[..., k] = lo, hi, fb
            if self.N >= 2:
                c01 = M[..., 1, 1] - M[..., 1, 0] * M[..., 0, 1]
                covs[..., k, 0, 0] = M[..., 2, 0] - M[..., 1, 0] ** 2
                covs[..., k, 1, 1] = M[..., 0, 2] - M[..., 0, 1] ** 2
                covs[..., k, 0, 1] = covs[..., k, 1, 0] = c01
        H = np.stack(hist, axis=-2) if hist else np.zeros((*batch, 0, self.N))
        return MomentRun(est, fbs, lower, upper, H, covs)


def _not_psd(post):
    """Boolean ``(...)``: mixed moments ``post (..., N+1, N+1)`` (N ≥ 2) whose covariance is not
    positive semi-definite (False for N < 2: no second moments)."""
    if post.shape[-1] < 3:
        return np.zeros(post.shape[:-2], bool)
    m0, m1 = post[..., 1, 0], post[..., 0, 1]
    v0, v1 = post[..., 2, 0] - m0 * m0, post[..., 0, 2] - m1 * m1
    c = post[..., 1, 1] - m0 * m1
    return ~((v0 >= 0) & (v1 >= 0) & (v0 * v1 >= c * c))


def _clip_halfplane(P, d, beta):
    """Sutherland–Hodgman: the convex polygon P (..., V, 2) cut by {x : d.x <= beta}; (..., V+1, 2).

    Output keeps a fixed capacity: kept vertices first (in order), padded with copies of the last
    one (zero-length edges, harmless for the quadrature and the support function).  An empty
    result collapses to the vertex of P nearest the half-plane.
    """
    beta = np.asarray(beta, dtype=float)
    s = np.einsum("k,...pk->...p", d, P) - beta[..., None]
    Pn = np.roll(P, -1, axis=-2)
    sn = np.roll(s, -1, axis=-1)
    inside = s <= 0
    cross = (s <= 0) != (sn <= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(cross, s / (s - sn), 0.0)
    X = P + t[..., None] * (Pn - P)
    cand = np.stack([P, X], axis=-2).reshape(*P.shape[:-2], 2 * P.shape[-2], 2)
    keep = np.stack([inside, cross], axis=-1).reshape(*s.shape[:-1], 2 * s.shape[-1])
    cap = P.shape[-2] + 1
    order = np.argsort(~keep, axis=-1, kind="stable")[..., :cap]
    out = np.take_along_axis(cand, order[..., None], axis=-2)
    n = keep.sum(-1)
    last = np.take_along_axis(out, np.clip(n - 1, 0, cap - 1)[..., None, None], axis=-2)
    idx = np.arange(cap)
    out = np.where((idx < n[..., None])[..., None], out, last)
    empty = n == 0
    if np.any(empty):
        nearest = np.take_along_axis(P, np.argmin(s, axis=-1)[..., None, None], axis=-2)
        out = np.where(empty[..., None, None], nearest, out)
    return out


def _trim_polygon(P, tol=1e-13):
    """Drop repeated consecutive vertices (padding) and cut the capacity to the largest count."""
    d = np.linalg.norm(P - np.roll(P, 1, axis=-2), axis=-1)
    scale = 1.0 + np.max(np.abs(P), axis=(-2, -1))
    keep = d > tol * scale[..., None]
    keep[..., 0] |= ~keep.any(-1)
    n = keep.sum(-1)
    cap = max(int(n.max()), 3)
    order = np.argsort(~keep, axis=-1, kind="stable")[..., :cap]
    out = np.take_along_axis(P, order[..., None], axis=-2)
    last = np.take_along_axis(out, np.clip(n - 1, 0, cap - 1)[..., None, None], axis=-2)
    return np.where((np.arange(cap) < n[..., None])[..., None], out, last)


def _polygon_quadrature(P, t, w):
    """Nodes (..., Q, 2) and weights (..., Q) on the convex polygon P (fan of triangles from P[0];
    collapsed Gauss–Legendre on each: exact for polynomials of degree <= 2 len(t) - 2)."""
    v0 = P[..., :1, :]
    a = P[..., 1:-1, :] - v0
    b = P[..., 2:, :] - v0
    area2 = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # signed, (..., V-2)
    S, Tt = np.meshgrid(t, t, indexing="ij")
    Ws = np.outer(w, w) * S  # Jacobian s (collapsed square)
    S, Tt, Ws = S.ravel(), Tt.ravel(), Ws.ravel()
    X = v0[..., None, :] + S[:, None] * ((1 - Tt)[:, None] * a[..., None, :] + Tt[:, None] * b[..., None, :])
    W = np.abs(area2)[..., None] * Ws
    shp = X.shape[:-3] + (-1,)
    return X.reshape(*shp, 2), W.reshape(shp)


def _pdf_batched(d, X):
    """``d.pdf`` at points X (..., Q, 2) for a batch of densities of shape (...)."""
    t = d.alpha[..., None, :] * (X - d.center[..., None, :])
    from ..moments.densities import legendre_values
    P0 = legendre_values(t[..., 0], d.degree)
    P1 = legendre_values(t[..., 1], d.degree)
    val = np.prod(d.alpha, axis=-1)[..., None] * np.einsum("...ij,...qi,...qj->...q", d.coef, P0, P1)
    return val


# ====================================================================== particle optimum (2-D)

def bootstrap_particle_means(rng, zs, A, b, c, w_sampler, x0_sampler, *, particles: int = 4000,
                             noise_halfwidth: float = 1.0):
    """Bootstrap particle filter for the bounded second-order system (the near-optimal reference).

    Uniform likelihood ``1{|z - c.x| <= c_v}`` (000 eq. 3.3), systematic resampling every step.
    ``w_sampler(rng, shape)`` draws inputs, ``x0_sampler(rng, shape)`` draws ``x_0`` (..., 2).
    Returns posterior means (R, T, 2).
    """
    zs = np.asarray(zs, dtype=float)
    R, T = zs.shape
    P = int(particles)
    x = x0_sampler(rng, (R, P))
    A = np.asarray(A, float)
    b = np.asarray(b, float)
    c = np.asarray(c, float)
    out = np.empty((R, T, 2))
    ar = np.arange(P)
    for k in range(T):
        if k > 0:
            x = x @ A.T + w_sampler(rng, (R, P))[..., None] * b
        lik = (np.abs(zs[:, k, None] - x @ c) <= noise_halfwidth).astype(float)
        s = lik.sum(axis=1)
        if np.any(s == 0):  # every particle excluded: keep the nearest ones (rare, logged by caller)
            dist = np.abs(zs[:, k, None] - x @ c)
            lik = np.where(s[:, None] == 0, (dist <= dist.min(axis=1, keepdims=True) + 1e-9), lik)
            s = lik.sum(axis=1)
        wts = lik / s[:, None]
        out[:, k] = np.einsum("rp,rpi->ri", wts, x)
        cdf = np.cumsum(wts, axis=1)
        cdf[:, -1] = 1.0
        u = (rng.random((R, 1)) + ar) / P
        idx = np.minimum(np.array([np.searchsorted(cdf[r], u[r]) for r in range(R)]), P - 1)
        x = np.take_along_axis(x, idx[..., None], axis=1)
    return out


# ====================================================================== non-additive zero-order

class ScaledNoiseZeroOrderFilter:
    """Method-of-moments estimator for the non-additive measurement ``z = x + (1 + beta x) v``
    (000 eq. 1.2 form ``z = h(x, v)``; a state-dependent noise scale), ``v ~ U(-c, c)``, ``|beta| < 1/|x|max``.

    For fixed x, ``v = (z - x)/(1 + beta x)`` (eq. 1.10) and the likelihood is
    ``f_v(v) / (1 + beta x) = 1/(2c (1 + beta x))`` (eq. 1.11) on
    ``(l, u) = (max(x_min, (z - c)/(1 + beta c)), min(x_max, (z + c)/(1 - beta c)))``, so eq. 3.5 becomes
    ``x_hat = int x f(x)/(1 + beta x) / int f(x)/(1 + beta x)`` over (l, u), f the polynomial prior
    (Gauss–Legendre with ``nodes`` points: the integrand is smooth on (l, u)).  Fallback: eq. 3.16.

    Adaptive moments: ``E[z^i] = sum_j C(i,j) E[x^{i-j} (1 + beta x)^j] m_v^(j)`` is triangular in
    the moments of x (the analogue of eq. 3.13) and is solved sequentially (analogue of eq. 3.14).
    """

    def __init__(self, N: int, beta: float, *, support=(-1.0, 1.0), noise_halfwidth: float = 1.0,
                 moments=None, adaptive: bool = False, initial_moments=None, n0: float = 100.0,
                 window: int = 20, eps: float = 1e-6, nodes: int = 48):
        self.base = ZeroOrderMomentFilter(N, support=support, noise_halfwidth=noise_halfwidth, moments=moments,
                                          adaptive=adaptive, initial_moments=initial_moments, n0=n0,
                                          window=window, eps=eps, outside="clip", invalid_moments="ignore")
        self.beta = float(beta)
        b = self.base
        if not np.all(1 + self.beta * np.array([b.x_min, b.x_max]) > 0):
            raise ValueError(f"beta: expected 1 + beta x > 0 on the support {support}, got beta = {beta!r}")
        self.N = b.N
        self._t, self._w = np.polynomial.legendre.leggauss(int(V.positive("nodes", nodes, integer=True)))
        # triangular map: m_z = T @ (1, m_x) built from the expansion of (x + (1 + beta x) v)^i
        N = self.N
        mv = np.r_[1.0, b.mv]
        T = np.zeros((N + 1, N + 1))
        T[0, 0] = 1.0
        for i in range(1, N + 1):
            for j in range(i + 1):
                # x^{i-j} (1 + beta x)^j = sum_k C(j,k) beta^k x^{i-j+k}
                for k in range(j + 1):
                    T[i, i - j + k] += math.comb(i, j) * mv[j] * math.comb(j, k) * self.beta ** k
        self._T = T

    def interval(self, z):
        b, c = self.base, self.base.c
        l = np.maximum(b.x_min, (z - c) / (1 + self.beta * c))
        u = np.minimum(b.x_max, (z + c) / (1 - self.beta * c))
        return l, np.maximum(u, l)

    def estimate(self, z, moments=None, *, chunk: int = 4096):
        """``(x_hat, fallback)``; known moments are processed in chunks of ``chunk`` measurements
        (memory: chunk x nodes x (N+1) floats)."""
        z = np.asarray(z, dtype=float)
        if moments is None and z.size > chunk:
            flat = z.reshape(-1)
            parts = [self._estimate(flat[i:i + chunk]) for i in range(0, flat.size, chunk)]
            return (np.concatenate([p[0] for p in parts]).reshape(z.shape),
                    np.concatenate([p[1] for p in parts]).reshape(z.shape))
        return self._estimate(z, moments)

    def _estimate(self, z, moments=None):
        d = self.base.density(moments)
        l, u = self.interval(z)
        x = 0.5 * (l + u)[..., None] + 0.5 * (u - l)[..., None] * self._t
        wq = 0.5 * (u - l)[..., None] * self._w
        f = d.pdf(x) if d.coef.ndim == 1 else _pdf1(d, x)
        g = wq * f / (1 + self.beta * x)
        de, nu = g.sum(-1), (g * x).sum(-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            xh = nu / de
        fb = ~(de >= self.base.eps) | ~((xh > l) & (xh < u))
        return np.where(fb, 0.5 * (l + u), xh), fb

    def recover_moments(self, mz_hat, n_s):
        rhs = np.concatenate([np.ones((*mz_hat.shape[:-1], 1)), mz_hat], axis=-1)
        mx = np.linalg.solve(self._T, rhs[..., None])[..., 0][..., 1:]
        w0 = self.base.n0 / (n_s + self.base.n0)
        return w0 * self.base.initial_moments + (1 - w0) * mx

    def run(self, zs) -> ZeroOrderRun:
        zs = V.as_float_array("zs", zs, ndim_min=1)
        V.finite("zs", zs)
        b = self.base
        batch, T = zs.shape[:-1], zs.shape[-1]
        if not b.adaptive:
            xh, fb = self.estimate(zs)
            return ZeroOrderRun(xh, fb, np.zeros((*batch, 0, self.N)), np.zeros(zs.shape, bool))
        est = np.empty(zs.shape)
        fbs = np.empty(zs.shape, bool)
        m = np.broadcast_to(b.initial_moments, (*batch, self.N))
        acc = np.zeros((*batch, self.N))
        powers = np.arange(1, self.N + 1)
        refresh = list(range(b.window - 1, T, b.window))
        bounds = sorted(set([0] + refresh + [T]))
        prev, hist = 0, []
        for a, e in zip(bounds[:-1], bounds[1:]):
            if a in refresh:
                acc = acc + np.sum(zs[..., prev:a + 1, None] ** powers, axis=-2)
                prev = a + 1
                m = self.recover_moments(acc / prev, prev)
                hist.append(m)
            est[..., a:e], fbs[..., a:e] = self.estimate(zs[..., a:e], m[..., None, :])
        H = np.stack(hist, axis=-2) if hist else np.zeros((*batch, 0, self.N))
        return ZeroOrderRun(est, fbs, H, np.zeros(zs.shape, bool))


def _pdf1(d, x):
    """Batched 1-D density values: d has batch shape (..., 1) or (...), x (..., Q)."""
    t = d.alpha[..., None] * (x - d.center[..., None])
    from ..moments.densities import legendre_values
    P = legendre_values(t, d.degree)
    coef = d.coef
    return d.alpha[..., None] * np.einsum("...i,...qi->...q", coef, P)
