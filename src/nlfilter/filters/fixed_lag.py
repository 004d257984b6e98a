"""The fixed-lag smoother: ``E[x_k | y_0..y_{k+L}]`` and its covariance, online, for every
discrete Gaussian filter, keeping only the last ``L + 1`` filtered beliefs (memory O(L), work
O(L) per step).

After the filter has taken in ``y_j`` it holds the filtered moments of steps ``j − L..j``; the
Rauch–Tung–Striebel backward pass over that window (:func:`~nlfilter.filters.smoothing.rts`,
through the filter's rule) gives the smoothed belief of step ``j − L`` given ``y_0..y_j``. The
backward pass at step ``i`` reads only the filtered moments of steps ``i..j``, so this is *exactly*
the fixed-interval smoother of the data ``y_0..y_j`` at step ``j − L`` (Särkkä 2013, *Bayesian
Filtering and Smoothing*, §8.6 fixed-lag smoothing by a sliding RTS window; Moore 1973 for the
augmented-state form it equals on a linear model). The last ``L`` steps, once the data end, are
the fixed-interval smoother's.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .. import _validate as V
from ..angles import angles_of
from ..errors import DivergenceError
from .beliefs import GaussianState
from .estimates import Estimates
from .smoothing import backward_steps, rts

__all__ = ["fixed_lag", "fixed_lag_steps"]


def _check(flt, lag):
    if getattr(flt, "smoother", None) != "rts" or not hasattr(flt, "_predict_cross"):
        raise TypeError(f"flt: the fixed-lag smoother runs a discrete-time Gaussian filter's RTS backward pass over "
                        f"a window (KF, EKF, UKF, CKF, GHKF, IEKF, SLF, the second-order filters); got "
                        f"{type(flt).__name__}")
    return V.positive("lag", lag, integer=True)


def fixed_lag_steps(flt, ys, m0, P0, lag: int):
    """Yield ``(k, GaussianState)``: the belief of step ``k`` given ``y_0..y_{k+lag}`` (module
    docstring), as soon as ``y_{k+lag}`` has come in; after the last measurement, the remaining
    steps given all of it. ``ys``: an iterable of measurements ``(B, m)`` (NaN where missing),
    read one at a time (a stream), or an array ``(B, T, m)``; ``m0``, ``P0`` as
    :meth:`~nlfilter.filters.base.Filter.run` for ``B`` paths. A path whose filtered or smoothed
    belief is not finite raises :class:`~nlfilter.errors.DivergenceError`."""
    lag = _check(flt, lag)
    start = 0 if flt.start == "update" else 1
    means, covs, window = deque(maxlen=lag + 1), deque(maxlen=lag + 1), deque(maxlen=lag + 1)
    belief, j = None, -1
    for j, y in enumerate(ys):
        y = np.asarray(y, dtype=float)
        if y.ndim != 2 or y.shape[-1] != flt.model.m:
            raise ValueError(f"ys: expected measurements of shape (paths, {flt.model.m}) one step at a time, "
                             f"got {y.shape} at step {j}")
        if belief is None:
            belief = flt.init(m0, P0, (y.shape[0],))
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # a failure is caught below
            if j > 0 or start:
                belief = flt.predict(belief, j + start - 1)
            if not np.isnan(y).all():
                belief = flt.update(belief, y, j + start)
        m, P = flt.summary(belief)
        _finite(m, P, j, "filtered")
        means.append(m)
        covs.append(P)
        window.append(y)
        if j >= lag:
            yield j - lag, _smoothed(flt, means, covs, window, j - lag)[0]
    if belief is None:
        return
    first = max(0, j - lag + 1)
    for i, state in enumerate(_smoothed(flt, list(means)[-(j + 1 - first):], list(covs)[-(j + 1 - first):],
                                        list(window)[-(j + 1 - first):], first)):
        yield first + i, state


def _smoothed(flt, means, covs, window, first):
    """The RTS pass over the window's filtered moments (steps ``first..``): the smoothed beliefs."""
    ms, Ps = np.stack(means, axis=1), np.stack(covs, axis=1)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        sm, sP, _ = rts(ms, Ps, *backward_steps(flt, np.stack(window, axis=1), first), angles=angles_of(flt.model).states)
    _finite(sm, sP, first, "smoothed")
    return [GaussianState(sm[:, i], sP[:, i]) for i in range(sm.shape[1])]


def _finite(m, P, k, what):
    bad = ~(np.all(np.isfinite(m.reshape(m.shape[0], -1)), axis=1) & np.all(np.isfinite(P.reshape(P.shape[0], -1)), axis=1))
    if bad.any():
        idx = np.flatnonzero(bad)
        raise DivergenceError(f"fixed_lag: the {what} belief is not finite at step {k} on {idx.size} path(s), first "
                              f"{idx[:5].tolist()}", step=k, paths=idx, what="smoother" if what == "smoothed" else "mean")


def fixed_lag(flt, ys, m0, P0, lag: int) -> Estimates:
    """The fixed-lag estimates of every step: ``means[..., k, :] = E[x_k | y_0..y_{min(k+lag, T−1)}]``
    (and ``covs``), by :func:`fixed_lag_steps` over ``ys (..., T, m)``.

    >>> import numpy as np, sympy as sp; from nlfilter import DiscreteModel; from nlfilter.filters import KalmanFilter
    >>> x = sp.Symbol("x"); kf = KalmanFilter(DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.5, R=1.0))
    >>> ys = np.array([[[0.3], [1.0], [0.2], [-0.4]]])
    >>> lag1, full = fixed_lag(kf, ys, 0.0, 1.0, lag=1), kf.smooth(ys, 0.0, 1.0)
    >>> bool(np.allclose(lag1.means[0, -2:], full.means[0, -2:], rtol=1e-12))   # the last lag + 1 steps: all the data
    True
    """
    ys = flt.check_data(ys)
    batch, T, m = ys.shape[:-2], ys.shape[-2], ys.shape[-1]
    B = int(np.prod(batch, dtype=int))
    yf = ys.reshape(B, T, m)
    n = flt.state_dim
    means, covs = np.full((B, T, n), np.nan), np.full((B, T, n, n), np.nan)
    for k, state in fixed_lag_steps(flt, (yf[:, k] for k in range(T)), m0, P0, lag):
        means[:, k], covs[:, k] = state.mean, state.cov
    return Estimates(means.reshape(*batch, T, n), covs.reshape(*batch, T, n, n), np.zeros(batch, bool),
                     np.full(batch, -1), {})
