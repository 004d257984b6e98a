"""Monte Carlo in blocks: computed on any executor, kept in the results store, resumed after a crash.

An experiment states its Monte Carlo as a *block function* ``fn(rows) -> {name: array}``: for the
paths ``rows = range(a, b)`` it simulates, filters and reduces each path to a few numbers
(arrays whose leading axis is ``len(rows)``). With per-path streams (:mod:`nlfilter.streams`) the
numbers of path ``p`` depend on the seed and ``p`` only. :func:`montecarlo` splits the paths into
blocks of a fixed size ``block`` (part of the result's identity), computes every block on its own
— as its own batch, so its floating-point arithmetic is the same whoever computes it — and
concatenates the blocks' arrays in path order. Hence the numbers are identical, bitwise, for

* any **executor**: ``"local"`` (this process) or ``"dask"`` (a ``dask.distributed`` cluster,
  :class:`DaskExecutor`; a ``LocalCluster`` when no scheduler address is given);
* any number of **workers**;
* any **chunk** (paths per task, :func:`nlfilter.evaluate.chunk`, CLI ``--chunk``): a task is a
  run of consecutive blocks, each still computed as its own batch; the chunk only sets how much
  work one task carries (and the memory it needs).

With a results store (:class:`nlfilter.store.ResultsStore`), every finished block is committed
as soon as its task returns, keyed by :func:`nlfilter.store.block_key` (experiment, task, the
inputs ``ident`` of the block function, seed, block size, version, code fingerprint): a rerun of
an interrupted or crashed run recomputes only the blocks that had not finished.

:func:`session` sets the executor, the store and the progress bar for the code inside it
(:meth:`nlfilter.experiments.Experiment.run` opens one); :func:`montecarlo` outside any session
computes locally with no store.

>>> import numpy as np
>>> from nlfilter import streams
>>> def fn(rows):  # one normal per path, from the path's own stream
...     return {"z": np.array([np.random.default_rng(streams.child(streams.root(7), p)).normal() for p in rows])}
>>> a = montecarlo("demo", fn, 10, block=4)["z"]
>>> with session(chunk=8):
...     b = montecarlo("demo", fn, 10, block=4)["z"]
>>> a.shape, bool((a == b).all())
((10,), True)
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from . import _validate as V

BLOCK = 32  # default paths per block
MAX_BLOCKS = 10**6  # blocks one Monte Carlo task may have


@dataclass
class Session:
    """What :func:`montecarlo` runs on: the executor, the store (or None), the experiment id
    (part of the blocks' keys), the seed, the chunk, the progress flag, and counters of the blocks
    computed and reused."""

    executor: object
    store: object = None
    experiment: str = ""
    seed: int | None = 0
    chunk: int | None = None
    progress: bool = False
    computed: int = 0
    reused: int = 0
    tasks: list = field(default_factory=list)

    def execution(self) -> dict:
        """For ``Result.meta["execution"]``: how the run was computed (never what it computed)."""
        ex = self.executor
        return {"executor": ex.name, "workers": getattr(ex, "workers", 1), "chunk": self.chunk,
                "store": None if self.store is None else str(self.store.path),
                "blocks_computed": self.computed, "blocks_reused": self.reused}


_SESSION: contextvars.ContextVar = contextvars.ContextVar("montecarlo_session", default=None)


def current() -> Session | None:
    """The open :class:`Session`, or None."""
    return _SESSION.get()


class LocalExecutor:
    """Run the tasks one after another in this process."""

    name = "local"
    workers = 1

    def map_unordered(self, func, items):
        for i, item in enumerate(items):
            yield i, func(item)

    def close(self):
        pass


def _stderr_to_devnull():
    """Point file descriptor 2 at /dev/null (processes started meanwhile inherit it); returns a
    duplicate of the old one to restore, or None if stderr is not a file descriptor here."""
    try:
        saved = os.dup(2)
    except OSError:  # pragma: no cover - no fd 2
        return None
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    os.close(devnull)
    return saved


class DaskExecutor:
    """Run the tasks on a ``dask.distributed`` cluster: the scheduler at ``address``, or a
    ``LocalCluster`` of ``workers`` single-threaded worker processes (default 2) started here and
    closed by ``close()``. Needs the optional extra ``pip install "nlfilter[dask]"``."""

    name = "dask"

    def __init__(self, address: str | None = None, workers: int | None = None):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:  # pragma: no cover - the extra is installed in the test environment
            raise ValueError('executor: "dask" needs dask.distributed; install it with pip install "nlfilter[dask]"') from None
        if workers is not None:
            V.positive("workers", workers, integer=True)
        if address is not None and workers is not None:
            raise ValueError(f"workers: the cluster at {address!r} has its own workers; expected workers=None "
                             f"with a scheduler address, got {workers}")
        self._cluster = None
        if address is None:
            environ = dict(os.environ)  # distributed sets OMP/MKL/OPENBLAS_NUM_THREADS=1, PYTHONHASHSEED ... here
            # the processes started here (workers, multiprocessing's resource tracker) write their stderr to
            # /dev/null: a terminal's Ctrl-C reaches the whole process group, and each would print its own
            # KeyboardInterrupt traceback; this process reports the interrupt (and a task's error, which
            # comes back through its future) in one line
            saved = _stderr_to_devnull()
            try:
                self._cluster = LocalCluster(n_workers=workers or 2, threads_per_worker=1, processes=True,
                                             dashboard_address=":0")
                self.client = Client(self._cluster)
            finally:  # for its workers; this process (and what it starts) keeps its own environment
                os.environ.clear()
                os.environ.update(environ)
                if saved is not None:
                    os.dup2(saved, 2)
                    os.close(saved)
        else:
            try:
                self.client = Client(address, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise ValueError(f"scheduler: cannot connect to {address!r} ({exc})") from None
        self.workers = len(self.client.scheduler_info().get("workers", {})) or (workers or 0)

    def map_unordered(self, func, items):
        from dask.distributed import as_completed
        futures = {self.client.submit(func, item, pure=False): i for i, item in enumerate(items)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        finally:
            for fut in futures:
                fut.cancel()

    def close(self):
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(executor=None, *, scheduler: str | None = None, workers: int | None = None):
    """An executor from its name (``"local"``, ``"dask"``; None: local) or an executor object."""
    if executor is None or executor == "local":
        if scheduler is not None or workers not in (None, 1):
            raise ValueError("executor: --scheduler and --workers need executor 'dask'; got the local executor")
        return LocalExecutor()
    if executor == "dask":
        return DaskExecutor(scheduler, workers)
    if hasattr(executor, "map_unordered"):
        return executor
    raise ValueError(f"executor: expected 'local', 'dask' or an executor object, got {executor!r}")


@contextlib.contextmanager
def session(*, executor=None, store=None, experiment: str = "", seed: int | None = 0, chunk: int | None = None,
            progress: bool = False, scheduler: str | None = None, workers: int | None = None):
    """Open a :class:`Session` for the block: :func:`montecarlo` inside it runs on ``executor``
    (see :func:`make_executor`; one made here is closed at the end) and keeps its blocks in
    ``store`` (a :class:`~nlfilter.store.ResultsStore`, or None)."""
    if chunk is not None:
        V.positive("chunk", chunk, integer=True)
    ex = make_executor(executor, scheduler=scheduler, workers=workers)
    owned = ex is not executor
    sess = Session(ex, store, experiment, seed, chunk, progress)
    token = _SESSION.set(sess)
    try:
        yield sess
    finally:
        _SESSION.reset(token)
        if owned:
            ex.close()


def _compute(job):
    """A task: the blocks ``ranges`` of ``fn``, each as its own batch -> [(arrays, seconds)].

    BLAS runs single-threaded here, in this process as on a Dask worker: a multithreaded BLAS may
    round a reduction differently with its thread count, and a block's numbers must not depend
    on where it ran (the executors parallelize over blocks instead)."""
    from threadpoolctl import threadpool_limits

    fn, ranges = job
    out = []
    with threadpool_limits(limits=1, user_api="blas"):
        for rows in ranges:
            t0 = time.perf_counter()
            arrays = fn(rows)
            out.append((arrays, time.perf_counter() - t0))
    return out


def _check(task, rows, arrays):
    if not isinstance(arrays, dict) or not arrays:
        raise TypeError(f"{task}: the block function must return a non-empty dict of per-path arrays, "
                        f"got {type(arrays).__name__}")
    out = {}
    for k, v in arrays.items():
        a = np.asarray(v)
        if a.ndim == 0 or a.shape[0] != len(rows):
            raise ValueError(f"{task}: block array {k!r} has shape {a.shape}; expected a leading axis of "
                             f"{len(rows)} (one entry per path of rows {rows.start}..{rows.stop - 1})")
        out[k] = a
    return out


def montecarlo(task: str, fn, paths: int, *, block: int = BLOCK, ident: dict | None = None,
               desc: str | None = None) -> dict:
    """The per-path arrays of ``fn`` over ``paths`` paths, computed in blocks of ``block`` paths.

    Parameters
    ----------
    task : label of the Monte Carlo task within the experiment (part of the blocks' key)
    fn : ``fn(rows: range) -> {name: array}``, each array with leading axis ``len(rows)``; a pure
        function of ``rows`` and of the inputs named in ``ident`` (on a Dask cluster it is pickled
        to the workers: a module-level function or a ``functools.partial`` of one)
    paths : number of Monte Carlo paths
    block : paths per block — the unit of computation and of storage; the numbers do not depend on
        the executor, the workers or the chunk, but the last bit may depend on ``block``
    ident : the inputs that fix ``fn``'s numbers (JSON-serialisable), for the blocks' key in the
        store (:func:`nlfilter.store.block_key`); required when a store is in use
    desc : progress-bar label (default ``task``)

    Returns
    -------
    dict name -> array with leading axis ``paths``, in path order.
    """
    V.positive("paths", paths, integer=True)
    V.positive("block", block, integer=True)
    if -(-paths // block) > MAX_BLOCKS:
        raise ValueError(f"paths: {paths:,} paths in blocks of {block:,} make {-(-paths // block):,} blocks; "
                         f"expected at most {MAX_BLOCKS:,} blocks (raise block)")
    sess = current() or Session(LocalExecutor())
    ranges = [range(a, min(a + block, paths)) for a in range(0, paths, block)]
    done: dict[int, dict] = {}
    key = None
    if sess.store is not None:
        if ident is None:
            raise ValueError(f"ident: the task {task!r} runs with a results store; expected the dict of its "
                             "block function's inputs (the blocks' key), got None")
        from .store import block_key
        key = block_key(experiment=sess.experiment, task=task, params=ident, seed=sess.seed, block=block)
        for i, rows in enumerate(ranges):
            got = sess.store.get_block(key, rows.start, rows.stop)
            if got is not None:
                done[i] = got
        sess.reused += len(done)
    todo = [i for i in range(len(ranges)) if i not in done]
    per_task = max(1, (sess.chunk or block) // block)
    groups = [todo[j:j + per_task] for j in range(0, len(todo), per_task)]
    jobs = [(fn, [ranges[i] for i in g]) for g in groups]
    bar = tqdm(total=len(ranges), initial=len(done), disable=not sess.progress, desc=desc or task, unit="block")
    try:
        for gi, out in sess.executor.map_unordered(_compute, jobs):
            for i, (arrays, secs) in zip(groups[gi], out):
                arrays = _check(task, ranges[i], arrays)
                if key is not None:
                    sess.store.put_block(key, ranges[i].start, ranges[i].stop, arrays,
                                         experiment=sess.experiment, task=task, seconds=secs)
                done[i] = arrays
                sess.computed += 1
                bar.update(1)
    finally:
        bar.close()
    names = list(done[0])
    for i in range(1, len(ranges)):
        if list(done[i]) != names:
            raise ValueError(f"{task}: blocks 0 and {i} returned different arrays ({names} vs {list(done[i])}); "
                             "expected the same names from every block")
    return {k: np.concatenate([done[i][k] for i in range(len(ranges))]) for k in names}
