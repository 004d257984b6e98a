"""The bookkeeping of :meth:`~nlfilter.filters.base.Filter.run`: the output arrays, the divergence
check after every step (raise or mark: divergence as data), the restart of marked paths, a
log-likelihood term that is not finite treated as a divergence with its reason; and the input side,
each step's measurements as a contiguous row (:class:`Rows`)."""

from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

from ..errors import DivergenceError
from .estimates import Estimates
from .linalg import _all_ok, bad_paths


def loglik_divergence(name: str, k: int, idx) -> DivergenceError:
    """The error of a run whose log-likelihood term is not finite at step ``k`` on the paths
    ``idx`` (``what="loglik"``): a term ``−½[eᵀS⁻¹e + log det S + m log 2π]`` that overflows a
    double (a measurement ~1e200 away from its prediction: the true value, about −1e400, has no
    float) or is NaN (a non-finite or singular S). ``on_divergence="mark"`` records such paths
    instead (``diverged``, ``diverged_step``, ``extras["loglik_failed"]``)."""
    return DivergenceError(
        f"{name}: the log-likelihood term is not finite (−inf or NaN: the measurement is too far from its "
        f"predicted law for a double, or its predicted covariance is singular) at step {k} on {len(idx)} path(s), "
        f"first {list(map(int, idx[:5]))}; pass on_divergence='mark' to record such paths "
        "(extras['loglik_failed']) and go on", step=k, paths=idx, what="loglik")


#: a batch's outputs are written through a time-major buffer of at most this many steps and bytes
CHUNK_STEPS, CHUNK_BYTES = 64, 1 << 21


class Rows:
    """The measurements of step ``k`` of a batch ``yf (B, T, m)``, ``rows[k]``: ``yf[:, k]`` with its
    values, each a contiguous ``(B, m)`` (for a batch, a row of a time-major copy of the next block
    of steps, made when a step outside the last block is asked for: a path-major column read step
    by step strides over the whole data, each path on a page of its own). Each block is a new
    array, never written again: a row a belief keeps (correlated noise carries ``y_k``) stays as it
    was."""

    def __init__(self, yf):
        B, T, m = yf.shape
        self.yf, self.T, self.k0, self.block = yf, T, 0, None
        self.size = min(CHUNK_STEPS, max(1, CHUNK_BYTES // (8 * B * m))) if B > 1 and T > 1 and m else 0

    @staticmethod
    def of(yf):
        """The rows of ``yf``: :class:`Rows`, or where they need no copy (one path, one step, no
        component) ``yf`` time-major, a view: ``[k]`` is ``yf[:, k]`` itself, without a Python call."""
        rows = Rows(yf)
        return rows if rows.size else yf.swapaxes(0, 1)

    def __getitem__(self, k):
        if not self.size:
            return self.yf[:, k]
        i = k - self.k0
        if self.block is None or not 0 <= i < len(self.block):
            self.k0, i = k, 0
            self.block = np.ascontiguousarray(self.yf[:, k:k + self.size].swapaxes(0, 1))
        return self.block[i]


class Recorder:
    """Bookkeeping of :meth:`~nlfilter.filters.base.Filter.run`: output arrays (path-major ``(B, T, ...)`` while filling,
    the layout of the result: no transposing copy at the end), the divergence check after each
    step (raise or mark), the restart of marked paths."""

    def __init__(self, flt, B, T, on_divergence, keep: bool = False):
        self.flt, self.B, self.T = flt, B, T
        self.beliefs = [] if keep else None  # every step's belief, for a smoother's backward pass
        self.on = on_divergence
        self.means = self.covs = None
        self.extras = {}
        self.diverged = np.zeros(B, dtype=bool)
        self.step = np.full(B, -1)
        self.any_diverged = False
        self._chunk, self._buffers, self._k0, self._spare = 1, {}, 0, {}  # the time-major buffers of a batch (_put)
        self._summary, self._extras = flt.summary, flt.extras  # (looked up once)

    def _store(self, k, mean, cov, belief, d=None, info=None):
        if self.means is None:
            n = mean.shape[-1]
            self.means = np.empty((self.B, self.T, n))
            self.covs = np.empty((self.B, self.T, n, n))
            self._chunk = min(CHUNK_STEPS, CHUNK_BYTES // (8 * self.B * (n + n * n))) if self.B > 1 else 1
        bufs = self._buffers
        if d is None and bufs and cov is not None:  # a batch's step inside a chunk: straight into its buffers
            bufs["means"][0][k - self._k0] = mean
            bufs["covs"][0][k - self._k0] = cov
        elif d is None and self._chunk <= 1 and cov is not None:  # (one path: _put's writes, in place)
            self.means[:, k] = mean
            self.covs[:, k] = cov
        elif d is None:
            self._put(k, "means", self.means, mean)
            self._put(k, "covs", self.covs, np.nan if cov is None else cov)
        else:
            self._put(k, "means", self.means, np.where(d[:, None], np.nan, mean))
            self._put(k, "covs", self.covs, np.nan if cov is None else np.where(d[:, None, None], np.nan, cov))
        ex = self._extras(belief)
        if info is not None:
            ex = {**(ex or {}), **info}
        if ex:
            for name, v in ex.items():
                v = np.asarray(v)
                if d is not None and v.dtype.kind == "f":
                    v = np.where(d.reshape(-1, *(1,) * (v.ndim - 1)), np.nan, v)
                if name not in self.extras:
                    self.extras[name] = np.empty((v.shape[0], self.T, *v.shape[1:]), v.dtype)
                self._put(k, name, self.extras[name], v)
        if self._buffers and (k + 1 - self._k0 == self._chunk or k == self.T - 1):
            self._flush(k)

    def _put(self, k, name, out, v):
        """Step ``k`` of the output ``out (B, T, ...)``: written in place, or, for a batch of paths, into a
        time-major buffer of ``_chunk`` steps (contiguous writes) copied into ``out`` by :meth:`_flush`
        (a path-major column written step by step strides over the whole output: twice the time)."""
        if self._chunk <= 1:
            out[:, k] = v
            return
        buf = self._buffers.get(name)
        if buf is None:  # the chunk's buffer: one array per output for the whole run
            arr = self._spare.get(name)
            if arr is None:
                arr = self._spare[name] = np.empty((self._chunk, *out.shape[:1], *out.shape[2:]), out.dtype)
            buf = self._buffers[name] = (arr, out, k)
        buf[0][k - self._k0] = v

    def _flush(self, k):
        """The buffered steps ``_k0..k`` into the outputs."""
        for buf, out, first in self._buffers.values():
            out[:, first:k + 1] = buf[first - self._k0:k + 1 - self._k0].swapaxes(0, 1)
        self._buffers = {}
        self._k0 = k + 1

    def check(self, k, belief, bad, start):
        """:meth:`record` without writing (the check after a prediction): the belief, with the
        diverged paths restarted from ``start``."""
        if bad is None and not self.any_diverged:
            mean, cov = self._summary(belief)
            if _all_ok(mean, cov) if cov is not None else math.isfinite(np.add.reduce(mean, axis=None)):
                return belief
        return self.record(k, belief, bad, start, write=False)

    def record(self, k, belief, bad, start, *, write: bool = True, info=None):
        """Check step ``k``'s belief (raise or mark), write its summary (and the step's likelihood
        ``info``, a dict of per-path arrays) unless ``write`` is False, and return it with the
        diverged paths restarted from ``start``. A path whose log-likelihood term ``info["loglik"]``
        is not finite diverges too (:func:`loglik_divergence`; marked: ``extras["loglik_failed"]``
        is True at that step)."""
        mean, cov = self._summary(belief)
        ll_bad = None
        if info is not None:
            if not math.isfinite(np.add.reduce(info["loglik"], axis=None)):
                ll_bad = ~np.isfinite(info["loglik"])
            info = {**info, "loglik_failed": np.zeros(self.B, bool)}
        if bad is None and ll_bad is None and not self.any_diverged and (
                _all_ok(mean, cov) if cov is not None else math.isfinite(np.add.reduce(mean, axis=None))):
            if write:
                self._store(k, mean, cov, belief, info=info)
                if self.beliefs is not None:
                    self.beliefs.append(belief)
            return belief
        now = bad_paths(mean, cov) if cov is not None else ~np.all(np.isfinite(mean), axis=-1)
        if bad is not None:
            now = now | bad
        now &= ~self.diverged
        if ll_bad is not None:  # only the likelihood failed on these paths: say so
            info["loglik_failed"] = failed = ll_bad & ~now & ~self.diverged
            if failed.any() and self.on == "raise" and not now.any():
                raise loglik_divergence(self.flt.name, k, np.flatnonzero(failed))
            now |= failed
        if now.any():
            if self.on == "raise":
                idx = np.flatnonzero(now)
                why = self.flt._divergence_reason(belief, now)
                if why is not None:  # the filter says what failed (e.g. the grid filter: left the grid)
                    text, what, idx = why
                    raise DivergenceError(f"{self.flt.name}: {text} at step {k} on {idx.size} path(s), first "
                                          f"{idx[:5].tolist()}; pass on_divergence='mark' to record such paths "
                                          "and go on", step=k, paths=idx, what=what)
                raise DivergenceError(
                    f"{self.flt.name}: covariance lost positive definiteness or a value became non-finite "
                    f"at step {k} on {idx.size} path(s), first {idx[:5].tolist()}; pass "
                    "on_divergence='mark' to record such paths and go on", step=k, paths=idx, what="covariance")
            self.diverged |= now
            self.step[now] = k
            self.any_diverged = True
        belief = self.flt.reset(belief, self.diverged, start)  # restart harmlessly; outputs NaN (flagged)
        if write:
            self._store(k, mean, cov, belief, self.diverged, info)
            if self.beliefs is not None:
                self.beliefs.append(belief)
        return belief

    def result(self, batch) -> Estimates:
        def out(a):  # (B, T, ...) -> (*batch, T, ...), a view
            return a.reshape(*batch, *a.shape[1:])
        if self.means is None:  # T = 0
            n = self.flt.state_dim
            self.means, self.covs = np.empty((self.B, 0, n)), np.empty((self.B, 0, n, n))
        extras = MappingProxyType({k: out(v) for k, v in self.extras.items()})
        return Estimates(out(self.means), out(self.covs), self.diverged.reshape(batch), self.step.reshape(batch), extras)


def _blas_limit(threads):
    """A context limiting the BLAS library to ``threads`` threads (threadpoolctl) for a run; a no-op for None."""
    if threads is None:
        import contextlib
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits
    return threadpool_limits(limits=threads, user_api="blas")
