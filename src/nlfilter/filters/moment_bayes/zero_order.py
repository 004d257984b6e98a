"""Zero-order problem (000 Chapter III): ``z_k = x_k + v_k``, x i.i.d. on ``[x_min, x_max]``.

Given ``z``, ``x`` lies in ``(l, u) = (max(x_min, z - c), min(x_max, z + c))`` (000 eqs. 3.8-3.11),
the likelihood is constant there (eq. 3.3), so the conditional mean is a ratio of integrals of the
prior (eq. 3.5). With the prior replaced by its degree-N least-squares polynomial
(:mod:`nlfilter.moments.densities`) the estimate is (eq. 3.7)::

    x_hat = int_l^u x f_N(x) dx / int_l^u f_N(x) dx

computed exactly in the Legendre basis. When the denominator is below ``eps`` or ``x_hat`` leaves
``(l, u)`` the estimate falls back to the midpoint ``(l + u)/2`` (eq. 3.16, Fig. 7 steps 9-13).

Adaptive mode (000 eqs. 2.27-2.29, 3.12-3.15, flow chart Fig. 7): the sample moments of ``z``
(eq. 2.27) give moments of ``x`` through the binomial relation with the known moments of ``v``
(eq. 3.14); they are blended with the initial guess of weight ``n0`` (eq. 3.15) and refreshed every
``window`` samples (000: 20). At step k the flow chart first accumulates ``z_k`` (step 4),
refreshes if due (steps 5-6) and then estimates ``x_k`` (steps 7-13); ``update`` keeps that order.
The learner's running sums are per path in the belief; a missing measurement is not learnt from.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np

from ... import _validate as V
from ...moments.densities import (LegendreDensity, difference_moments, is_moment_sequence,
                                  legendre_antiderivative, legendre_values, pdf_batched_1d, series_times_x,
                                  uniform_moments)
from ...bounded import ZeroOrderModel
from ._moment_base import (MomentFilter, MomentFilterWarning, check_invalid_moments, check_N, keep_missing, observed,
                      sample_moments, warn_refresh_failures)


class ZeroOrderBelief(NamedTuple):
    """Per path: ``mean (B, 1)`` the estimate of x_k; ``fallback``/``invalid (B,)`` flags;
    ``moments (B, N)`` the moments of x in use (adaptive; per-path known ones; else ``(B, 0)``),
    ``valid (B,)`` whether they are a moment sequence, ``coef (B, N+1)`` the Legendre coefficients
    of their polynomial prior (``(B, 0)`` with the known moments) and ``coef_x (B, N+2)`` the series of
    x times it (refreshed with ``coef``; ``(B, 0)`` with the known moments); the learner's power sums
    ``acc (B, N)`` (completed windows) and ``part (B, N)`` (current window), ``count (B,)``
    samples learnt; ``refreshed``/``refresh_failed (B,)`` the flags of this step's refresh
    (:data:`~nlfilter.filters.moment_bayes.INVALID_MOMENTS`)."""

    mean: np.ndarray
    fallback: np.ndarray
    invalid: np.ndarray
    moments: np.ndarray
    valid: np.ndarray
    coef: np.ndarray
    coef_x: np.ndarray
    acc: np.ndarray
    part: np.ndarray
    count: np.ndarray
    refreshed: np.ndarray
    refresh_failed: np.ndarray


def _interval(z, x_min, x_max, c, outside):
    # 000 eqs. 3.8-3.9: ends of the support of x | z for x in (x_min, x_max), v in (-c, c)
    l = np.maximum(x_min, z - c)
    u = np.minimum(x_max, z + c)
    bad = ~(u >= l)
    if np.any(bad):
        if outside == "raise":
            idx = np.argwhere(bad)[0]
            raise ValueError(f"ys: measurement {float(np.asarray(z)[tuple(idx)])!r} at index {tuple(int(i) for i in idx)} "
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

    Returns
    -------
    x_hat, fallback : arrays shaped like ``z``

    >>> from nlfilter.moments.densities import LegendreDensity, uniform_moments
    >>> d = LegendreDensity.from_moments(uniform_moments(4))
    >>> zero_order_estimate(np.array([0.5, -1.2]), d)[0].tolist()   # J = 0: z/2 (eq. 3.26)
    [0.25, -0.6]
    """
    z = np.asarray(z, dtype=float)
    l, u = _interval(z, x_min, x_max, noise_halfwidth, outside)
    a, c = density.alpha, density.center
    return _estimate_on(l, u, density.coef, series_times_x(density.coef, a, c), a, c, eps)[:2]


def _estimate_on(l, u, s0, s1, alpha, center, eps):
    """Eq. 3.7 on ``(l, u)`` with the series ``s0`` of the prior and ``s1`` of ``x`` times it: both
    ends and both integrals from one table of Legendre values (000 Fig. 7 steps 8-13, eq. 3.16).
    Returns ``(x_hat, fallback, l, u)``."""
    t = np.clip(alpha * (np.stack([l, u]) - center), -1.0, 1.0)
    P = legendre_values(t, s1.shape[-1])
    F0, F1 = legendre_antiderivative(s0, t, values=P), legendre_antiderivative(s1, t, values=P)
    de = F0[1] - F0[0]  # 000 Fig. 7 step 8
    nu = F1[1] - F1[0]  # step 10
    with np.errstate(divide="ignore", invalid="ignore"):
        xh = nu / de  # 000 eq. 3.7 (the common factor 1/2 of eq. 3.3 cancels)
    fb = ~(de >= eps) | ~((xh > l) & (xh < u))  # steps 9 and 12
    return np.where(fb, 0.5 * (l + u), xh), fb, l, u  # eq. 3.16


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


def _from_model(flt, model, N, support, noise_halfwidth, moments, adaptive):
    """The constructor's two forms: ``(ZeroOrderModel, N)`` — support (−1, 1), the noise half-width
    and (known-moment mode, ``moments=None``) the exact moments of x from the model — or the raw
    ``(N, support=..., noise_halfwidth=...)``. Returns ``(model, N, support, noise_halfwidth, moments)``."""
    if isinstance(model, ZeroOrderModel):
        if N is None:
            raise TypeError("N: expected the highest moment used, (model, N), got None")
        for name, v in (("support", support), ("noise_halfwidth", noise_halfwidth)):
            if v is not None:
                raise ValueError(f"{name}: given by the model ({model!r}); expected None, got {v!r}")
        if model.beta != 0 and not isinstance(flt, ScaledNoiseZeroOrderFilter):
            raise ValueError(f"model: beta = {model.beta} is the non-additive problem; use ScaledNoiseZeroOrderFilter")
        if moments is None and not adaptive:
            i = np.arange(1, int(N) + 1) if isinstance(N, (int, np.integer)) else None
            if i is not None:  # x ~ (J+1)/2 x^J on (−1, 1): E x^i = (J+1)/(J+1+i), i even; 0 odd
                moments = np.where(i % 2 == 0, (model.J + 1) / (model.J + 1 + i), 0.0)
        return model, N, (-1.0, 1.0), model.noise_halfwidth, moments
    if N is not None:
        raise TypeError(f"N: given twice (the raw form is ({type(flt).__name__}(N, ...)), got N={N!r}")
    return None, model, ((-1.0, 1.0) if support is None else support), \
        (1.0 if noise_halfwidth is None else noise_halfwidth), moments


class ZeroOrderMomentFilter(MomentFilter):
    """Method-of-moments estimator for ``z = x + v`` (000 Chapter III, Fig. 7).

    ``run(ys)`` with ``ys (..., T, 1)`` returns :class:`~nlfilter.filters.estimates.Estimates`: ``means``
    the estimates of x_k, ``covs`` NaN (documented: the estimator carries no posterior second
    moment), ``extras["fallback"]`` (True where eq. 3.16 was used), ``extras["invalid"]`` (True where
    the moments in use failed the moment-sequence test) and, adaptive, ``extras["moments"] (..., T, N)``
    the moments of x in use at each step and the refresh flags ``refreshed``/``refresh_failed
    (..., T)``. A missing measurement: the estimate is the prior mean of x (the first moment in
    use), nothing is learnt.

    Parameters
    ----------
    N : int
        Highest moment used (degree of the polynomial prior), 1 <= N <= 40.
    support : (x_min, x_max)
        Known bounds of x (000 assumption 2).
    noise_halfwidth : float
        ``c`` in ``v ~ U(-c, c)`` (000 assumption 3: c = 1).
    moments : array (N,) or None
        Known moments of x (non-adaptive mode). Exactly one of ``moments`` / ``adaptive`` is used.
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
        Impossible measurements (``|z - x| > c`` for every admissible x): raise ``ValueError``
        naming ``ys``, or clip ``z`` to the nearest possible value.
    invalid_moments : {"warn", "keep", "ignore"}
        When the moments in use are not a moment sequence on the support (too high an N for the
        data): "warn" uses eq. 3.16 while they are in use and issues one
        :class:`~nlfilter.filters.moment_bayes.MomentFilterWarning` per run; "keep" rejects a refresh that learns such moments
        (the previous ones stay; impossible known or initial moments: as "warn") and warns;
        "ignore" uses the polynomial anyway (000's own algorithm, guarded only by ``eps``). The
        same meaning in every seed-000 filter: :data:`~nlfilter.filters.moment_bayes.INVALID_MOMENTS`.
    """

    name = "zero-order-moment"
    source = "seed 000 eqs. 2.27-2.29, 3.3-3.16, Fig. 7"
    needs = ("bounded support of x", "uniform measurement noise")

    accepts = ("zero-order",)

    def __init__(self, model, N: int | None = None, *, support=None, noise_halfwidth: float | None = None,
                 moments=None, adaptive: bool = False, initial_moments=None, n0: float = 100.0,
                 window: int = 20, eps: float = 1e-6, outside: str = "raise", invalid_moments: str = "warn"):
        model, N, support, noise_halfwidth, moments = _from_model(self, model, N, support, noise_halfwidth,
                                                                  moments, adaptive)
        self.N = check_N(N)
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
        self.invalid_moments = check_invalid_moments(invalid_moments)
        self._powers = np.arange(1, self.N + 1)
        self._density = None if self.moments is None or self.moments.ndim > 1 else self.density()
        # what a step needs and the data do not change: the scaling t = alpha (x - center) of the
        # support and, with known moments, the series of the prior and of x times it
        self._alpha, self._center = 2.0 / (x_max - x_min), 0.5 * (x_max + x_min)
        if self._density is not None:
            self._s0 = self._density.coef
            self._s1 = series_times_x(self._s0, self._alpha, self._center)

    @property
    def state_dim(self) -> int:
        return 1

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
        d = self._density if moments is None and self._density is not None else self.density(moments)
        return zero_order_estimate(z, d, x_min=self.x_min, x_max=self.x_max,
                                   noise_halfwidth=self.c, eps=self.eps, outside=self.outside)

    def recover_moments(self, mz_hat, n_s):
        """Moments of x from sample moments of z after ``n_s`` samples (eqs. 3.14-3.15)."""
        n_s = np.asarray(n_s, dtype=float)[..., None]
        mx_hat = difference_moments(sample_moments(mz_hat, 1.0), self.mv)  # 000 eq. 3.14
        w0 = self.n0 / (n_s + self.n0)
        return w0 * self.initial_moments + (1.0 - w0) * mx_hat  # 000 eq. 3.15

    def _learning_data(self, z):
        """With ``outside="clip"`` the learner accumulates the clipped measurements (every
        possible one), as the estimates use them, so that an impossible outlier cannot overflow
        the sample moments; else ``z`` (an impossible one raises)."""
        return np.clip(z, self.x_min - self.c, self.x_max + self.c) if self.outside == "clip" else z

    # -- the protocol --------------------------------------------------------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None):
        self._no_prior(m0, P0, initial)
        B = math.prod(batch)
        if self.adaptive:
            m = np.broadcast_to(self.initial_moments, (*batch, self.N)).reshape(B, self.N).copy()
        elif self.moments.ndim > 1:  # per-path known moments
            try:
                m = np.broadcast_to(self.moments, (*batch, self.N)).reshape(B, self.N).copy()
            except ValueError:
                raise ValueError(f"moments: per-path moments of shape {self.moments.shape} do not broadcast to "
                                 f"the batch {tuple(batch)} of ys") from None
        else:
            m = np.zeros((B, 0))
        valid = np.broadcast_to(is_moment_sequence(self.moments if m.shape[1] == 0 else m, self.x_min, self.x_max),
                                (B,)).copy()
        zero = np.zeros((B, self.N))
        mean = self._prior_mean(m, B)
        coef = self.density(m).coef.copy() if m.shape[1] else np.zeros((B, 0))
        coef_x = series_times_x(coef, self._alpha, self._center) if m.shape[1] else np.zeros((B, 0))
        no = np.zeros(B, bool)
        return ZeroOrderBelief(mean, no, ~valid, m, valid, coef, coef_x, zero, zero.copy(), np.zeros(B, int),
                               no.copy(), no.copy())

    def _prior_mean(self, m, B):
        mom = m if m.shape[1] else np.broadcast_to(self.moments, (B, self.N))
        return mom[:, :1].copy()

    def predict(self, belief, k):
        """x_{k+1} is independent of x_k: the belief is the prior of x (mean: the first moment in use)."""
        B = belief.mean.shape[0]
        no = np.zeros(B, bool)
        return belief._replace(mean=self._prior_mean(belief.moments, B), fallback=no, refreshed=no,
                               refresh_failed=no)

    def update(self, belief, y, k):
        z, obs = observed(y)
        if not obs.all():
            z = np.where(obs, z, 0.5 * (self.x_min + self.x_max))  # a possible value on missing paths
        m, valid, coef, coef_x = belief.moments, belief.valid, belief.coef, belief.coef_x
        acc, part, count = belief.acc, belief.part, belief.count
        due = failed = np.zeros(z.shape[0], bool)
        if self.adaptive:  # 000 Fig. 7 steps 4-6: accumulate, refresh if due, then estimate
            part = part + self._learning_data(z)[:, None] ** self._powers
            if not obs.all():
                part = np.where(obs[:, None], part, belief.part)
            count = count + obs
            due = obs & (count % self.window == 0)
            if due.any():
                acc = np.where(due[:, None], acc + part, acc)
                part = np.where(due[:, None], 0.0, part)
                new = self.recover_moments(acc / np.maximum(count, 1)[:, None], count)  # eqs. 2.27, 3.14, 3.15
                m_prev, valid_prev = m, valid
                m = np.where(due[:, None], new, m)
                valid = np.where(due, is_moment_sequence(m, self.x_min, self.x_max), valid)
                failed = due & ~valid
                take = due & valid if self.invalid_moments == "keep" else due  # "keep": reject impossible ones
                if self.invalid_moments == "keep":
                    m, valid = np.where(take[:, None], m, m_prev), np.where(take, valid, valid_prev)
                new = self.density(m).coef
                coef = np.where(take[:, None], new, coef)
                coef_x = np.where(take[:, None], series_times_x(new, self._alpha, self._center), coef_x)
        xh, fb, lu = self._estimate(z, coef, coef_x)
        if self.invalid_moments != "ignore":
            l, u = lu
            xh = np.where(valid, xh, 0.5 * (l + u))
            fb = fb | ~valid
        new = ZeroOrderBelief(xh[:, None], fb, ~valid, m, valid, coef, coef_x, acc, part, count, due, failed)
        return keep_missing(obs, new, belief)

    def _estimate(self, z, coef, coef_x):
        """``(x_hat, fallback, (l, u))`` of one step (a subclass may give None for ``(l, u)`` with
        ``invalid_moments="ignore"``): the series precomputed with the known moments, else the
        belief's ``coef``, ``coef_x``."""
        l, u = _interval(z, self.x_min, self.x_max, self.c, self.outside)
        known = not coef.shape[1]
        xh, fb, l, u = _estimate_on(l, u, self._s0 if known else coef, self._s1 if known else coef_x,
                                    self._alpha, self._center, self.eps)
        return xh, fb, (l, u)

    def summary(self, belief):
        return belief.mean, None

    def extras(self, belief):
        out = {"fallback": belief.fallback, "invalid": belief.invalid}
        if self.adaptive:
            out.update(moments=belief.moments, refreshed=belief.refreshed, refresh_failed=belief.refresh_failed)
        return out

    def output(self, est):
        if self.invalid_moments == "ignore":
            return est
        if self.adaptive and "refresh_failed" in est.extras and est.extras["refresh_failed"].any():
            used = ("eq. 3.16 used while they were in use" if self.invalid_moments == "warn"
                    else "the moments in use before kept")
            warn_refresh_failures(self, est, "x", (self.x_min, self.x_max), used)
        elif "invalid" in est.extras and est.extras["invalid"].any():
            n = int(np.sum(est.extras["invalid"]))
            warnings.warn(f"moments: {n} estimate(s) used moments that no law on [{self.x_min}, {self.x_max}] "
                          f"has (N = {self.N} too high for the data); eq. 3.16 used there",
                          MomentFilterWarning, stacklevel=3)
        return est


class ScaledNoiseZeroOrderFilter(ZeroOrderMomentFilter):
    """Method-of-moments estimator for the non-additive measurement ``z = x + (1 + beta x) v``
    (000 eq. 1.2 form ``z = h(x, v)``; a state-dependent noise scale), ``v ~ U(-c, c)``, ``|beta| < 1/|x|max``.

    For fixed x, ``v = (z - x)/(1 + beta x)`` (eq. 1.10) and the likelihood is
    ``f_v(v) / (1 + beta x) = 1/(2c (1 + beta x))`` (eq. 1.11) on
    ``(l, u) = (max(x_min, (z - c)/(1 + beta c)), min(x_max, (z + c)/(1 - beta c)))``, so eq. 3.5 becomes
    ``x_hat = int x f(x)/(1 + beta x) / int f(x)/(1 + beta x)`` over (l, u), f the polynomial prior
    (Gauss–Legendre with ``nodes`` points: the integrand is smooth on (l, u)). Fallback: eq. 3.16.
    Impossible measurements are clipped to the possible range ``[min (x − (1 + beta x) c), max (x + (1 +
    beta x) c)]`` over the support (an outlier's estimate is then a bound of the support, and the
    learner's sample moments cannot overflow). ``invalid_moments`` as in :class:`ZeroOrderMomentFilter`
    (default "warn"; until this option the filter used impossible moments silently and reported
    ``extras["invalid"]`` as always False).

    Adaptive moments: ``E[z^i] = sum_j C(i,j) E[x^{i-j} (1 + beta x)^j] m_v^(j)`` is triangular in
    the moments of x (the analogue of eq. 3.13) and is solved sequentially (analogue of eq. 3.14).
    Outputs as :class:`ZeroOrderMomentFilter`.
    """

    name = "scaled-noise-zero-order-moment"
    source = "seed 000 eqs. 1.2, 1.10-1.11, 3.5, 3.16 (non-additive form)"

    def __init__(self, model, beta: float | None = None, *, N: int | None = None, support=None,
                 noise_halfwidth: float | None = None, moments=None, adaptive: bool = False,
                 initial_moments=None, n0: float = 100.0, window: int = 20, eps: float = 1e-6, nodes: int = 48,
                 invalid_moments: str = "warn"):
        if isinstance(model, ZeroOrderModel):  # (model, N): beta is the model's
            if beta is not None and N is not None:
                raise TypeError(f"beta: the model gives beta = {model.beta}; expected (model, N), got beta={beta!r}")
            N, beta = (beta if N is None else N), model.beta
        elif N is not None:
            raise TypeError(f"N: given twice (the raw form is ScaledNoiseZeroOrderFilter(N, beta)), got N={N!r}")
        elif beta is None:
            raise TypeError("beta: expected the noise-scale coefficient of z = x + (1 + beta x) v, got None")
        super().__init__(model, N if isinstance(model, ZeroOrderModel) else None, support=support,
                         noise_halfwidth=noise_halfwidth, moments=moments,
                         adaptive=adaptive, initial_moments=initial_moments, n0=n0,
                         window=window, eps=eps, outside="clip", invalid_moments=invalid_moments)
        self.beta = float(beta)
        if not np.all(1 + self.beta * np.array([self.x_min, self.x_max]) > 0):
            raise ValueError(f"beta: expected 1 + beta x > 0 on the support {support}, got beta = {beta!r}")
        self._t, self._w = np.polynomial.legendre.leggauss(int(V.positive("nodes", nodes, integer=True)))
        # triangular map: m_z = T @ (1, m_x) built from the expansion of (x + (1 + beta x) v)^i
        N = self.N
        mv = np.r_[1.0, self.mv]
        T = np.zeros((N + 1, N + 1))
        T[0, 0] = 1.0
        for i in range(1, N + 1):
            for j in range(i + 1):
                # x^{i-j} (1 + beta x)^j = sum_k C(j,k) beta^k x^{i-j+k}
                for k in range(j + 1):
                    T[i, i - j + k] += math.comb(i, j) * mv[j] * math.comb(j, k) * self.beta ** k
        self._T = T
        ends = np.array([self.x_min, self.x_max])  # z is monotone in v (1 + beta x > 0): corners
        self._z_range = (float(np.min(ends - (1 + self.beta * ends) * self.c)),
                         float(np.max(ends + (1 + self.beta * ends) * self.c)))

    @property
    def base(self):  # the additive filter's options (kept for callers of the former composition)
        return self

    def interval(self, z):
        c = self.c
        z = np.clip(z, *self._z_range)  # an impossible measurement: the nearest possible one
        l = np.maximum(self.x_min, (z - c) / (1 + self.beta * c))
        u = np.minimum(self.x_max, (z + c) / (1 - self.beta * c))
        return l, np.maximum(u, l)

    def estimate(self, z, moments=None, *, chunk: int = 4096):
        """``(x_hat, fallback)``; known moments are processed in chunks of ``chunk`` measurements
        (memory: chunk x nodes x (N+1) floats)."""
        z = np.asarray(z, dtype=float)
        if moments is None and z.size > chunk:
            flat = z.reshape(-1)
            parts = [self._estimate_sn(flat[i:i + chunk]) for i in range(0, flat.size, chunk)]
            return (np.concatenate([p[0] for p in parts]).reshape(z.shape),
                    np.concatenate([p[1] for p in parts]).reshape(z.shape))
        return self._estimate_sn(z, moments)

    def _estimate(self, z, coef, coef_x):
        lu = self.interval(z) if self.invalid_moments != "ignore" else None
        if not coef.shape[1]:
            return (*self.estimate(z), lu)
        return (*self._estimate_sn(z, density=LegendreDensity(coef, self.x_min, self.x_max)), lu)

    def _estimate_sn(self, z, moments=None, density=None):
        d = density if density is not None else (
            self._density if moments is None and self._density is not None else self.density(moments))
        l, u = self.interval(z)
        x = 0.5 * (l + u)[..., None] + 0.5 * (u - l)[..., None] * self._t
        wq = 0.5 * (u - l)[..., None] * self._w
        f = d.pdf(x) if d.coef.ndim == 1 else pdf_batched_1d(d, x)
        g = wq * f / (1 + self.beta * x)
        de, nu = g.sum(-1), (g * x).sum(-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            xh = nu / de
        fb = ~(de >= self.eps) | ~((xh > l) & (xh < u))
        return np.where(fb, 0.5 * (l + u), xh), fb

    def recover_moments(self, mz_hat, n_s):
        rhs = np.concatenate([np.ones((*mz_hat.shape[:-1], 1)), mz_hat], axis=-1)
        mx = np.linalg.solve(self._T, rhs[..., None])[..., 0][..., 1:]
        w0 = self.n0 / (np.asarray(n_s, dtype=float)[..., None] + self.n0)
        return w0 * self.initial_moments + (1 - w0) * mx

    def _learning_data(self, z):
        return np.clip(z, *self._z_range)  # 000's flow chart: the measurements (every possible one as it is)

