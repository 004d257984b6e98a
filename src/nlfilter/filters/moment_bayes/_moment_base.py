"""What the seed-000 moment filters share: option checks, the pure adaptive-input learner (its
running statistics live in the belief, per path), the missing-data helper, and what every
adaptive filter does with impossible learnt moments (:data:`INVALID_MOMENTS`, the refresh report
and its warning)."""

from __future__ import annotations

import warnings

import numpy as np

from ... import _validate as V
from ...moments.densities import (cumulants_to_moments, difference_moments, is_moment_sequence,
                                  moments_to_cumulants, uniform_moments)
from ..base import Filter
from ..beliefs import where_paths


class MomentFilterWarning(UserWarning):
    """The moments in use cannot be those of a law on the support (N too high for the data)."""


#: What an adaptive filter does when a refresh learns moments that no law on the bound has (the
#: moment-space test :func:`~nlfilter.moments.densities.is_moment_sequence`), the same in every
#: seed-000 filter:
#:
#: * ``"warn"`` — the impossible moments are not used: in their place the filter uses the uniform
#:   law on the bound (the zero-order filter: eq. 3.16, the midpoint of the interval of x given z,
#:   which is the estimate under that law) until a refresh learns possible ones; one
#:   :class:`MomentFilterWarning` per run gives the refresh failure rate and what to change.
#: * ``"keep"`` — the refresh is rejected: the moments in use before it (the last possible ones,
#:   at first the initial guess) stay; warns as ``"warn"``.
#: * ``"ignore"`` — the impossible moments are used as learnt (000's algorithm, guarded only by
#:   the fallback of eq. 3.16 and its analogues); no warning.
#:
#: Whatever the choice, ``Estimates.extras`` has ``refreshed (..., T)`` (a refresh at that step)
#: and ``refresh_failed (..., T)`` (it learnt impossible moments): per path, their sums over the
#: time axis are the refresh count and the failed-refresh count.
INVALID_MOMENTS = ("warn", "keep", "ignore")

#: the fields the beliefs of the first- and second-order filters share, in their order: the
#: support box, the fallback flag, the input moments in use and the learner's power sums and count
#: (``BOX_AND_LEARNER``), then whether the belief is a prediction and the flags of this step's
#: refresh (``REFRESH``)
BOX_AND_LEARNER = tuple((f, np.ndarray) for f in ("lo", "hi", "fallback", "mw", "acc", "count"))
REFRESH = tuple((f, np.ndarray) for f in ("predicted", "refreshed", "refresh_failed"))


def check_invalid_moments(value) -> str:
    return V.choice("invalid_moments", value, set(INVALID_MOMENTS))


def refresh_failure_rate(est) -> np.ndarray:
    """Per path ``(...)``: the fraction of the adaptive learner's refreshes that learnt impossible
    moments (``extras["refresh_failed"]`` over ``extras["refreshed"]``; 0 where no refresh ran)."""
    if "refreshed" not in est.extras:
        if est.means.shape[-2] == 0:  # no step, no refresh
            return np.zeros(est.means.shape[:-2])
        raise ValueError("est: expected the Estimates of an adaptive seed-000 filter (extras 'refreshed', "
                         f"'refresh_failed'), got extras {sorted(est.extras)}")
    n = np.sum(est.extras["refreshed"], axis=-1)
    return np.sum(est.extras["refresh_failed"], axis=-1) / np.maximum(n, 1)


def warn_refresh_failures(flt, est, what: str, support, used: str) -> None:
    """One :class:`MomentFilterWarning` for the run ``est`` of the adaptive filter ``flt`` if any
    refresh learnt impossible moments: the filter, the failure rate, what was done and what to
    change (lower N; more samples per refresh, ``window``, or a heavier initial guess, ``n0``)."""
    bad = int(np.sum(est.extras.get("refresh_failed", 0)))
    if not bad:
        return
    n = int(np.sum(est.extras["refreshed"]))
    warnings.warn(f"{flt.name}: {bad} of {n} refreshes ({100 * bad / n:.1f} %) learnt moments of {what} that no "
                  f"law on [{support[0]:g}, {support[1]:g}] has (N = {flt.N} too high for the data); {used}. "
                  f"Lower N, or raise window (now {flt.window}) or n0 (now {flt.n0:g}).",
                  MomentFilterWarning, stacklevel=4)


def impulse_power_sums(g, N: int) -> np.ndarray:
    """``S_i = sum_j g_j^i`` for i = 1..N from impulse-response coefficients ``g`` (1-D array).

    With ``y = sum_j g_j w_{k-j}`` and i.i.d. ``w``: ``kappa_i(y) = kappa_i(w) S_i`` (cumulants add
    over independent terms and scale by ``g^i``) — the dynamic counterpart of eq. 3.13.
    """
    g = np.asarray(g, dtype=float)
    return np.array([np.sum(g ** i) for i in range(1, N + 1)])


def input_moments(N, S, mv, initial, n0, acc, n_s):
    """Moments of the input ``w`` learnt from data (analogue of 000 eqs. 2.27-2.29, 3.14-3.15):
    sample moments ``acc / n_s`` of z -> moments of y = z - v (eq. 3.14) -> cumulants of y ->
    cumulants of w (divide by S_i) -> moments of w, blended with the initial guess (eq. 3.15).
    ``n_s`` is per path (``(B,)``) or a number."""
    n_s = np.asarray(n_s, dtype=float)[..., None]
    my = difference_moments(sample_moments(acc, n_s), mv)  # 000 eq. 3.14
    kw = moments_to_cumulants(my) / S
    mw_hat = cumulants_to_moments(kw)
    w0 = n0 / (n_s + n0)
    return w0 * initial + (1.0 - w0) * mw_hat  # 000 eq. 3.15


def sample_moments(acc, n_s) -> np.ndarray:
    """The sample moments ``acc / n_s`` of the measurements the adaptive learner accumulated,
    refused naming ``ys`` when their powers overflowed (a measurement of magnitude ~1e300 that no
    bounded state and noise explain: ``outside="clip"`` clips such measurements instead)."""
    m = acc / n_s
    if not np.all(np.isfinite(m)):
        raise ValueError("ys: the powers of the measurements overflowed the learnt sample moments (a measurement "
                         "no bounded state and noise explain); expected measurements within the model's bounds, "
                         "or pass outside='clip'")
    return m


def check_N(N):
    V.positive("N", N, integer=True)
    if N > 40:
        raise ValueError(f"N: expected at most 40, got {N}")
    return int(N)


def configure_input(flt, w_bound, N, w_moments, adaptive, initial_w_moments, n0, window,
                    noise_halfwidth, eps, outside, invalid_moments):
    """Checks and stores the options shared by the first- and second-order filters: input bound,
    order N, known or adaptive input moments (000 eqs. 2.27-2.29), measurement half-width, what
    to do with impossible learnt input moments (:data:`INVALID_MOMENTS`)."""
    flt.wb = float(V.positive("w_bound", w_bound))
    flt.N = check_N(N)
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
    flt.invalid_moments = check_invalid_moments(invalid_moments)
    flt.uniform_w_moments = uniform_moments(flt.N, -flt.wb, flt.wb)


def observed(y):
    """``(z (B,), obs (B,))``: the scalar measurement of each path and whether it is observed."""
    z = np.asarray(y, dtype=float)[..., 0]
    return z, ~np.isnan(z)


def keep_missing(obs, new, old):
    """The updated belief on the observed paths, the predicted one (unchanged) on the others."""
    return new if obs.all() else where_paths(obs, new, old)


class MomentFilter(Filter):
    """Base of the seed-000 filters: a :class:`~nlfilter.bounded.BoundedNoiseModel` (``kind =
    "bounded"``), scalar measurements ``ys (..., T, 1)``; the prior is the filter's own (the
    stationary law implied by the input moments, or the known/learnt law of x), so ``m0``/``P0``
    must be None."""

    family = "method-of-moments"
    accepts = ("bounded",)
    needs = ("linear dynamics", "bounded input", "uniform measurement noise")
    time = "discrete"
    own_prior = True

    @property
    def data_dim(self) -> int:
        return 1

    def _no_prior(self, m0, P0, initial):
        for name, v in (("m0", m0), ("P0", P0), ("initial", initial)):
            if v is not None:
                raise ValueError(f"{name}: {type(self).__name__} starts from its own prior (the law implied "
                                 f"by the input moments on the reachable set); expected None, got {v!r}")

    def _learn(self, acc, count, zl, obs):
        """Accumulate ``zl`` into the power sums of the observed paths (000 eq. 2.28); returns the
        new ``(acc, count, due)`` with ``due`` the paths whose window is complete (refresh)."""
        acc = np.where(obs[:, None], acc + zl[:, None] ** self._powers, acc)
        count = count + obs
        return acc, count, obs & (count % self.window == 0)

    def _refresh_input(self, belief, z, obs):
        """The adaptive input step of 000's Fig. 7, before x_k is estimated: learn ``z_k`` (clipped
        with ``outside="clip"``) and refresh the input moments of the paths whose window is complete;
        refreshed moments that no law on ``[-w_b, w_b]`` has are handled as ``invalid_moments`` says.
        Returns ``(mw, acc, count, redo, refreshed, failed)``: ``redo`` the paths whose prediction
        into step k must be redone with the refreshed moments (None when there are none),
        ``refreshed``/``failed (B,)`` the paths refreshed now and those whose refresh was impossible."""
        mw, acc, count = belief.mw, belief.acc, belief.count
        none = np.zeros(mw.shape[0], bool)
        if not self.adaptive:
            return mw, acc, count, None, none, none
        zl = np.clip(z, -self.z_bound, self.z_bound) if self.outside == "clip" else z
        acc, count, due = self._learn(acc, count, zl, obs)
        if not due.any():
            return mw, acc, count, None, none, none
        new = input_moments(self.N, self.S, self.mv, self.initial_w_moments, self.n0, acc, np.maximum(count, 1))
        ok = is_moment_sequence(new, -self.wb, self.wb)
        if self.invalid_moments != "ignore" and not ok.all():
            new = np.where(ok[:, None], new, self.uniform_w_moments if self.invalid_moments == "warn" else mw)
        mw = np.where(due[:, None], new, mw)
        redo = due & belief.predicted
        return mw, acc, count, (redo if redo.any() else None), due, due & ~ok

    def _learner_extras(self, belief):
        """The adaptive learner's per-step outputs: the input moments in use and the refresh flags."""
        if not self.adaptive:
            return {}
        return {"w_moments": belief.mw, "refreshed": belief.refreshed, "refresh_failed": belief.refresh_failed}

    def output(self, est):
        if self.adaptive and self.invalid_moments != "ignore":
            used = ("the uniform law on the bound used in their place" if self.invalid_moments == "warn"
                    else "the moments in use before kept")
            warn_refresh_failures(self, est, "the input w", (-self.wb, self.wb), used)
        return est
