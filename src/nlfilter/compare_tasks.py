"""The tasks of a comparison (:func:`nlfilter.comparison.compare`): every filter, and every rung of
the reference, runs as tasks — one per filter and ``block`` of paths — on an executor
(:mod:`nlfilter.montecarlo`), and, inside a :func:`~nlfilter.montecarlo.session` with a results
store (``nlfilter compare`` opens one), every finished task is committed to the store as a block,
keyed by what fixes its numbers (:func:`nlfilter.store.block_key`: the comparison's inputs, the
filter's settings, the data it reads, its random stream, the path range, the block size, the
version and the code). An interrupted comparison rerun with the same settings reads its finished
tasks back and computes only the others; the numbers are the same, bitwise, because each block is
its own batch with single-threaded BLAS wherever it runs.

Progress bars name what runs: ``filters: 7 × 200 paths``, ``reference: particle 2000 × 200 paths``,
``check: particle 8000 × 64 paths`` (one bar per group of tasks, and with one task per run the
steps of that run under the same label).
"""

from __future__ import annotations

import hashlib

import numpy as np

from .errors import DivergenceError
from .filters.base import Estimates
from .compare_filters import _lifted_prior, _run_rng, filter_ident

_NUMERIC = "biufc"


def _pack(e: Estimates) -> dict | None:
    """The arrays of an Estimates for the store, or None when an extra is not a numeric array."""
    out = {"means": e.means, "covs": e.covs, "diverged": e.diverged, "diverged_step": e.diverged_step}
    for k, v in dict(e.extras).items():
        a = np.asarray(v)
        if a.dtype.kind not in _NUMERIC + "?":
            return None
        out[f"extra:{k}"] = a
    return out


def _unpack(d: dict) -> Estimates:
    extras = {k[len("extra:"):]: v for k, v in d.items() if k.startswith("extra:")}
    return Estimates(d["means"], d["covs"], d["diverged"].astype(bool), d["diverged_step"], extras)


def _digest(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def _filter_task(job):
    """A task of :func:`compare`: ``(method, filter, ys, prior, keywords)`` -> its Estimates, or
    the exception it raised (returned, so that the other tasks run on and the caller decides).
    BLAS runs single-threaded, here as on a Dask worker (:func:`nlfilter.montecarlo._compute`):
    a block's numbers do not depend on where it ran."""
    from threadpoolctl import threadpool_limits

    go, flt, ys, args, kw = job
    with threadpool_limits(limits=1, user_api="blas"):
        try:
            return getattr(flt, go)(ys, *args, **kw)
        except Exception as exc:  # noqa: BLE001 - handed to the caller, which raises or records it
            return exc


class Tasks:
    """Runs filters on (some of) a comparison's data as tasks on the executor ``ex``; with a
    session store, finished tasks are kept and read back (module docstring).

    ``ident``: the comparison's inputs that fix every task's numbers besides the filter and its
    data (the prior, the stream root, ``on_divergence``), JSON-able, for the blocks' keys."""

    def __init__(self, ex, sess, *, root, block, chunk, on_divergence, progress, given, model, m0, P0, ident):
        self.ex, self.sess, self.root, self.block, self.chunk = ex, sess, root, block, chunk
        self.on_divergence, self.progress, self.given, self.model = on_divergence, progress, given, model
        self.m0, self.P0, self.ident = m0, P0, ident
        self.reused = 0
        self.computed = 0

    @property
    def store(self):
        return None if self.sess is None else self.sess.store

    def jobs_of(self, name, flt, ys, key, smooth, bar):
        """The tasks of one filter on ``ys``: one per block of paths (its own random stream keyed
        by ``key or name``, per path: the same draws for any block), with its prior; and their
        path ranges."""
        go = "smooth" if smooth else "run"
        B = ys.shape[0]
        size = B if self.block is None else self.block
        if getattr(flt, "own_prior", False):  # it starts from a prior of its own
            args = ()
        elif self.given is not self.model and getattr(flt, "model", None) is self.given:  # a bilinear model's filter
            args = _lifted_prior(self.given, self.m0, self.P0)[:2]
        else:
            args = (self.m0, self.P0)
        out, ranges = [], []
        for lo in range(0, B, size):
            hi = min(lo + size, B)
            kw = {"on_divergence": self.on_divergence}
            if getattr(flt, "random", False):
                kw["rng"] = _run_rng(self.root, key or name, range(lo, hi))
            if self.chunk is not None:
                kw["chunk"] = self.chunk
            if bar and size == B and self.ex.name == "local":  # the steps of a run in this process
                kw["progress"] = bar if isinstance(bar, str) else True
            out.append((go, flt, ys[lo:hi], args, kw))
            ranges.append((lo, hi))
        return out, ranges

    def _key(self, name, flt, ys, key, smooth, size):
        """The store key of one filter's tasks on ``ys`` (None: no store, or the comparison did
        not state its inputs)."""
        if self.store is None or self.ident is None:
            return None
        from .store import block_key
        ident = {**self.ident, "filter": filter_ident(flt), "stream": key or name, "go": "smooth" if smooth else "run",
                 "ys": _digest(ys), "shape": list(ys.shape)}
        return block_key(experiment=self.sess.experiment, task=f"{name}/{key or name}", params=ident,
                         seed=self.sess.seed, block=size)

    def execute(self, groups, desc, keep=True):
        """Run the groups ``(name, flt, ys, key, smooth, bar)`` on the executor, all their tasks
        at once; per group its Estimates (blocks concatenated in path order; a bilinear filter's
        read at the base state's coordinates) or the exception of its first failed block, noted
        with the filter's name. ``keep``: read and write finished tasks in the session's store."""
        from tqdm.auto import tqdm

        jobs, owner, where = [], [], []
        for g, group in enumerate(groups):
            js, ranges = self.jobs_of(*group)
            name, flt, ys, key, smooth, _ = group
            k = self._key(name, flt, ys, key, smooth, self.block or ys.shape[0]) if keep else None
            jobs += js
            owner += [g] * len(js)
            where += [(k, lo, hi) for lo, hi in ranges]
        done = [None] * len(jobs)
        for i, (k, lo, hi) in enumerate(where):
            if k is not None:
                got = self.store.get_block(k, lo, hi)
                if got is not None:
                    done[i] = _unpack(got)
        todo = [i for i in range(len(jobs)) if done[i] is None]
        self.reused += len(jobs) - len(todo)
        with tqdm(total=len(jobs), initial=len(jobs) - len(todo), disable=not self.progress or len(jobs) < 2,
                  desc=desc, unit="task", leave=False) as pbar:
            for j, res_ in self.ex.map_unordered(_filter_task, [jobs[i] for i in todo]):
                i = todo[j]
                done[i] = res_
                k, lo, hi = where[i]
                if k is not None and isinstance(res_, Estimates):
                    arrays = _pack(res_)
                    if arrays is not None:
                        self.store.put_block(k, lo, hi, arrays, experiment=self.sess.experiment, task=desc)
                pbar.update(1)
        self.computed += len(todo)
        if self.sess is not None:  # an experiment's run: its meta["execution"] counts these blocks too
            self.sess.computed += len(todo)
            self.sess.reused += len(jobs) - len(todo)
        out = []
        for g, (name, flt, ys, key, smooth, bar) in enumerate(groups):
            parts = [done[i] for i in range(len(jobs)) if owner[i] == g]
            exc = next((p for p in parts if isinstance(p, BaseException)), None)
            if exc is not None:
                if isinstance(exc, (DivergenceError, np.linalg.LinAlgError, FloatingPointError, OverflowError)):
                    exc.add_note(f"compare: while {'smoothing with' if smooth else 'running'} filter {name!r} "
                                 f"({type(flt).__name__})")
                out.append(exc)
                continue
            e = parts[0] if len(parts) == 1 else Estimates.concatenate(parts)
            if (self.given is not self.model and getattr(flt, "model", None) is self.given
                    and not getattr(flt, "own_prior", False)):
                cols = _lifted_prior(self.given, self.m0, self.P0)[2]
                if e.means.shape[-1] != len(cols):  # the whole lifted state: read the base coordinates
                    e = Estimates(e.means[..., cols], e.covs[..., cols, :][..., :, cols], e.diverged,
                                  e.diverged_step, e.extras)
            out.append(e)
        return out

    def run(self, name, flt, ys, key=None, bar=False, smooth=False, desc=None, keep=True):
        """One filter's estimates on ``ys`` (:meth:`execute`); a failure is raised."""
        (e,) = self.execute([(name, flt, ys, key, smooth, bar)], desc or name, keep=keep)
        if isinstance(e, BaseException):
            raise e
        return e
