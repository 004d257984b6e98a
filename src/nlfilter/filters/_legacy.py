"""Legacy run bookkeeping for the filters that still write their own time loop (being moved onto
:meth:`nlfilter.filters.base.Filter.run`); removed when the last one has moved."""

from __future__ import annotations

import numpy as np

from .. import _validate as V
from ..errors import DivergenceError
from .beliefs import GaussianState
from .linalg import _all_ok, bad_paths


def _prepare(name_ys, ys, m0, P0, n, m):
    ys = V.as_float_array(name_ys, ys, ndim_min=2, shape_tail=(None, m))
    V.finite(name_ys, ys, allow_nan=True)
    m0 = V.as_float_array("m0", m0, shape_tail=(n,)) if np.ndim(m0) else np.full(n, float(m0))
    V.finite("m0", m0)
    P0 = V.covariance("P0", P0, n, batch=True)
    batch = ys.shape[:-2]
    try:
        mean = np.broadcast_to(m0, (*batch, n)).copy()
        cov = np.broadcast_to(P0, (*batch, n, n)).copy()
    except ValueError:
        raise ValueError(f"m0/P0: shapes {m0.shape}, {P0.shape} do not broadcast to the batch "
                         f"{batch} of {name_ys}") from None
    return ys, GaussianState(mean, cov), batch


class _Runner:
    """Shared bookkeeping of ``run``: output arrays, divergence checks, marking."""

    def __init__(self, batch, T, n, on_divergence, name):
        self.on = V.choice("on_divergence", on_divergence, {"raise", "mark"})
        self.means = np.empty((T, *batch, n))  # time-major while filling (contiguous writes)
        self.covs = np.empty((T, *batch, n, n))
        self.diverged = np.zeros(batch, dtype=bool)
        self.step = np.full(batch, -1)
        self.any_diverged = False
        self.name = name

    def record(self, k, state, reset: GaussianState, *, write: bool = True) -> GaussianState:
        """Check step ``k``'s state (raise or mark), write it unless ``write`` is False, and
        return it with diverged paths reset to ``reset``."""
        if not self.any_diverged and _all_ok(state.mean, state.cov):  # the common case
            if write:
                self.means[k] = state.mean
                self.covs[k] = state.cov
            return state
        bad = bad_paths(state.mean, state.cov)
        bad &= ~self.diverged
        if bad.any():
            if self.on == "raise":
                idx = np.flatnonzero(bad.ravel())
                raise DivergenceError(
                    f"{self.name}: covariance lost positive definiteness or a value became non-finite "
                    f"at step {k} on {idx.size} path(s), first {idx[:5].tolist()}; pass "
                    "on_divergence='mark' to record such paths and go on", step=k, paths=idx,
                    what="covariance")
            self.diverged |= bad
            self.step[bad] = k
            self.any_diverged = True
        # diverged paths restart from a harmless state; their outputs are NaN (flagged)
        d = self.diverged
        state = GaussianState(np.where(d[..., None], reset.mean, state.mean),
                              np.where(d[..., None, None], reset.cov, state.cov))
        if write:
            self.means[k] = np.where(d[..., None], np.nan, state.mean)
            self.covs[k] = np.where(d[..., None, None], np.nan, state.cov)
        return state

    def result(self):
        from .base import Estimates
        return Estimates(np.ascontiguousarray(np.moveaxis(self.means, 0, -2)),
                         np.ascontiguousarray(np.moveaxis(self.covs, 0, -3)), self.diverged, self.step)


