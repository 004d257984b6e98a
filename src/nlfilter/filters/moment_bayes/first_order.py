"""First-order problem (derived here; 000 Chapter IV is only outlined in its abstract).

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
   posterior mean. Fallback (the analogue of eq. 3.16): if the normaliser is below ``eps`` or
   the mean leaves the interval, the posterior is taken uniform on the interval.
4. *Adaptation* (the analogue of eqs. 2.27-2.29 and 3.14-3.15): in steady state
   ``x = sum_j h^j w_{k-1-j}``, so the cumulants obey ``kappa_i(x) = kappa_i(w) / (1 - h^i)``.
   Sample moments of ``z`` give moments of ``x`` (eq. 3.14), hence cumulants of ``x``, hence
   those of ``w``: ``kappa_i(w) = (1 - h^i) kappa_i(x)``; blended with the initial guess of weight
   ``n0`` and refreshed every ``window`` samples. As in 000's Fig. 7 a refresh at step k comes
   before the estimate of step k: the prediction into step k is then redone with the new input
   moments (the belief keeps the moments of ``h x_{k-1}`` for that).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ...moments.densities import (LegendreDensity, affine_moments, cumulants_to_moments, moments_to_cumulants,
                                  sum_moments)
from ._moment_base import BOX_AND_LEARNER, REFRESH, MomentFilter, configure_input, keep_missing, observed


IntervalBelief = NamedTuple("IntervalBelief", [("m", np.ndarray), *BOX_AND_LEARNER, ("hm", np.ndarray), *REFRESH])
IntervalBelief.__doc__ = """Per path: posterior moments ``m (B, N)`` of x_k and support ``[lo, hi] (B,)``, the
    ``fallback (B,)`` flag, the input moments in use ``mw (B, N)``, the learner's power sums
    ``acc (B, N)`` and sample count ``count (B,)``, the moments ``hm (B, N)`` of ``h x_{k-1}``,
    ``predicted (B,)`` (whether ``m`` is a prediction from them, to redo after a refresh) and the
    flags ``refreshed``/``refresh_failed (B,)`` of this step's refresh (:data:`~nlfilter.filters.moment_bayes.INVALID_MOMENTS`)."""


def _raw_model(model, args, kind):
    """``(model, rest)``: a :class:`~nlfilter.bounded.BoundedNoiseModel` as the first argument,
    or the raw parameters (h, w_bound / A, b, c, w_bound) turned into one."""
    from ...bounded import BoundedNoiseModel
    if isinstance(model, BoundedNoiseModel):
        return model, args
    if kind == 1:
        h, (w_bound, *rest) = model, args
        if isinstance(h, bool) or not isinstance(h, (int, float, np.floating)) or not abs(h) < 1:
            raise ValueError(f"h: expected a real number with |h| < 1 (000 eq. 2.4), got {h!r}")
        return BoundedNoiseModel.first_order(h, w_bound), rest
    A, (b, c, w_bound, *rest) = model, args
    return BoundedNoiseModel(A, b, c, w_bound), rest


class FirstOrderMomentFilter(MomentFilter):
    """Moment Bayesian filter for ``x_{k+1} = h x_k + w_k``, ``z_k = x_k + v_k`` (000 eqs. 2.4-2.5).

    ``FirstOrderMomentFilter(model, N, ...)`` with a first-order
    :class:`~nlfilter.bounded.BoundedNoiseModel` (or the raw ``(h, w_bound, N, ...)``). See the
    module docstring for the derivation. The filter is exact except for the projection of each
    predicted density onto degree-N polynomials (on the reachable interval).

    ``run(ys)``, ``ys (..., T, 1)``: ``means`` the posterior means, ``covs`` the posterior variance
    ``m_2 - m_1^2`` (clipped at 0), NaN when N = 1 (no second moment is carried: no covariance
    exists, which is not a divergence); ``extras``: ``fallback (..., T)`` (uniform fallback used),
    ``lower``/``upper (..., T, 1)`` the posterior's interval and, adaptive, ``w_moments (..., T, N)``
    the input moments in use and the refresh flags ``refreshed``/``refresh_failed (..., T)``. A
    missing measurement: predict only, nothing learnt.

    Parameters
    ----------
    model : BoundedNoiseModel (n = 1, ``|h| < 1``); its ``w_bound`` and ``noise_halfwidth`` are used
    N : int
        Number of moments carried (degree of the polynomial densities).
    w_moments : array (N,) or None
        Known moments of w; or ``adaptive=True`` to learn them (initial guess ``initial_w_moments``,
        default uniform on the bound, weight ``n0``, refreshed every ``window`` samples).
    eps : float
        Posterior normaliser below which the uniform fallback is used.
    outside : {"raise", "clip"}
        A measurement inconsistent with the reachable interval: raise ``ValueError`` naming ``ys``,
        or clip to the nearest consistent value (posterior = the nearest end point).
    invalid_moments : {"warn", "keep", "ignore"}
        A refresh that learns input moments no law on ``[-w_b, w_b]`` has: use the uniform law's
        instead and warn, keep the previous ones and warn, or use them silently (000's algorithm);
        see :data:`~nlfilter.filters.moment_bayes.INVALID_MOMENTS`. Default "warn" (until
        this option the filter used them silently).

    Notes
    -----
    Step convention: ``ys[..., 0, :]`` measures ``x_0``, whose prior is the stationary law implied by
    the (known or initially guessed) input moments on the stationary interval ``|x| <= w_b/(1-|h|)``.

    Examples
    --------
    >>> import numpy as np
    >>> from nlfilter.bounded import BoundedNoiseModel; from nlfilter.moments.densities import uniform_moments
    >>> f = FirstOrderMomentFilter(BoundedNoiseModel.first_order(0.5, 1.0), 4, w_moments=uniform_moments(4))
    >>> r = f.run(np.array([[0.3], [-0.2], [0.9]]))
    >>> r.means.shape, bool(np.all(np.abs(r.means) <= 2.0))
    ((3, 1), True)
    """

    name = "first-order-moment"
    source = "seed 000 eqs. 1.9, 1.13, 2.4-2.5, 2.27-2.29, 3.3, 3.13-3.16 (first-order form derived here)"
    n = 1

    def __init__(self, model, *args, w_moments=None, adaptive: bool = False,
                 initial_w_moments=None, n0: float = 100.0, window: int = 20, noise_halfwidth: float | None = None,
                 eps: float = 1e-9, outside: str = "raise", invalid_moments: str = "warn"):
        model, rest = _raw_model(model, args, 1)
        if model.n != 1:
            raise ValueError(f"model: expected a first-order model (n = 1), got n = {model.n}")
        if len(rest) != 1:
            raise TypeError(f"N: expected FirstOrderMomentFilter(model, N, ...), got {len(rest)} positional N")
        h = model.h
        if not abs(h) < 1 or model.b[0] != 1.0 or model.c[0] != 1.0:
            raise ValueError(f"model: expected x' = h x + w, z = x + v with |h| < 1, got A={model.A.tolist()}, "
                             f"b={model.b.tolist()}, c={model.c.tolist()}")
        self.model = model
        self.h = h
        configure_input(self, model.w_bound, rest[0], w_moments, adaptive, initial_w_moments, n0, window,
                        model.noise_halfwidth if noise_halfwidth is None else noise_halfwidth, eps, outside,
                        invalid_moments)
        self.bound = self.wb / (1.0 - abs(self.h))  # stationary reachable set |x| <= w_b/(1-|h|)
        self.S = 1.0 / (1.0 - self.h ** np.arange(1, self.N + 1))  # sum_j h^{ij} = 1/(1 - h^i)
        self.z_bound = self.bound + self.c  # largest possible |z|
        self._powers = np.arange(1, self.N + 1)

    # -- building blocks (all batched) ------------------------------------------------------
    def stationary_moments(self, mw):
        """Moments of the stationary x: ``kappa_i(x) = kappa_i(w) / (1 - h^i)``."""
        return cumulants_to_moments(moments_to_cumulants(mw) * self.S)

    def predict_moments(self, m, l, u, mw):
        """Moments and reachable interval of ``h x + w`` (exact; binomial expansion, eq. 3.13)."""
        mp = sum_moments(affine_moments(m, self.h, 0.0), mw)
        lp, up = self._predict_interval(l, u)
        return mp, lp, up

    def _predict_interval(self, l, u):
        a, b = self.h * l, self.h * u
        lp = np.maximum(np.minimum(a, b) - self.wb, -self.bound)
        up = np.minimum(np.maximum(a, b) + self.wb, self.bound)
        return lp, up

    def update_moments(self, m, l, u, z):
        """Posterior moments and interval given ``z`` (uniform likelihood, eq. 3.3; fallback 3.16)."""
        lo = np.maximum(l, z - self.c)
        hi = np.minimum(u, z + self.c)
        width_tol = 1e-12 * (1.0 + self.bound)
        bad = hi < lo - width_tol
        if np.any(bad):
            if self.outside == "raise":
                i = tuple(int(j) for j in np.argwhere(bad)[0])
                raise ValueError(f"ys: measurement {float(np.asarray(z)[i] if np.ndim(z) else z)!r} (path {i}) "
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

    # -- the protocol --------------------------------------------------------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None):
        self._no_prior(m0, P0, initial)
        B = math.prod(batch)
        mw = np.broadcast_to(self.w_moments if not self.adaptive else self.initial_w_moments, (*batch, self.N))
        mw = mw.reshape(B, self.N).copy()
        m = self.stationary_moments(mw)
        no = np.zeros(B, bool)
        return IntervalBelief(m, np.full(B, -self.bound), np.full(B, self.bound), no, mw,
                              np.zeros((B, self.N)), np.zeros(B, int), np.zeros_like(m), no.copy(), no.copy(),
                              no.copy())

    def predict(self, belief, k):
        hm = affine_moments(belief.m, self.h, 0.0)
        lp, up = self._predict_interval(belief.lo, belief.hi)
        B = belief.m.shape[0]
        no = np.zeros(B, bool)
        return belief._replace(m=sum_moments(hm, belief.mw), lo=lp, hi=up, fallback=no, hm=hm,
                               predicted=np.ones(B, bool), refreshed=no, refresh_failed=no)

    def update(self, belief, y, k):
        z, obs = observed(y)
        z = np.where(obs, z, 0.5 * (belief.lo + belief.hi))  # a consistent value on missing paths
        m = belief.m
        mw, acc, count, redo, refreshed, failed = self._refresh_input(belief, z, obs)
        if redo is not None:
            m = np.where(redo[:, None], sum_moments(belief.hm, mw), m)
        post, lo, hi, fb = self.update_moments(m, belief.lo, belief.hi, z)
        new = IntervalBelief(post, lo, hi, fb, mw, acc, count, belief.hm, np.zeros_like(belief.predicted),
                             refreshed, failed)
        return keep_missing(obs, new, belief._replace(m=m, mw=mw, acc=acc, count=count))

    def summary(self, belief):
        m = belief.m
        cov = np.maximum(m[:, 1] - m[:, 0] ** 2, 0.0)[:, None, None] if self.N >= 2 else None
        return m[:, :1], cov

    def extras(self, belief):
        return {"fallback": belief.fallback, "lower": belief.lo[:, None], "upper": belief.hi[:, None],
                **self._learner_extras(belief)}
