"""The default call with a **warm** disk cache, as a second process meets it (issue 28, "fast by
default": a rerun, the model's compiled loop already on disk from an earlier process).

:func:`warm_default` runs one job (a filter made by a factory of a benchmark script, on the data
given) twice, each in a new Python process pinned as the caller (:mod:`_pin`: the same core, one
thread; ``NLFILTER_BENCH_CACHE=keep``, so both use the caller's ``NLFILTER_CACHE`` folder):

1. the **fill**: one call with ``backend="numba"``, which compiles the job's loop and writes it
   (and its seal) to the disk cache;
2. the **timed** process: fresh (nothing compiled or loaded in it, numba not imported), it times
   the default call (``run`` with no ``backend=``) with :func:`_pin.first_and_best`: its first call
   pays whatever the default call pays there (numba's import, the cached loop's load: its
   "compile"), and records what the automatic rule chose and why (``backend_for`` as the run asked
   it) and the process's CPU seconds.

The same with ``backend="numba"`` (the column ``numba-fresh``): what the default call would pay
where it took the cached loop at once. A fresh process also pays the first touch of its output
arrays' memory: where NumPy advises huge pages for large arrays and the kernel compacts memory to
find them (``transparent_hugepage/defrag`` ``madvise``, as on the machine of the runs
``warm-cache*``), that took 2-3.5 s of CPU for the EKF's 410 MB at n = 16, against 0.2 s with
``NUMPY_MADVISE_HUGEPAGE=0`` (the runs ``warm-cache-nohugepage`` and ``warm-cache-calls``; the
environment records it).

Run as a script, this module is that child process (``python _warm.py '<job json>'``).
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread, as the caller)

import importlib  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import pathlib  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import numpy as np  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
_FILLED: dict = {}  # job -> the filling process's report
CACHE_NOTE = ("warm disk cache: the job's loop compiled and written to NLFILTER_CACHE by another process "
              "(backend='numba'); the call timed in a fresh process (nothing compiled or loaded in it, numba not "
              "imported): its first call's extra is numba's import and the loop's load (and the first touch of "
              "its memory)")

SHAPE_NOTE = ("shape-warm disk cache: another model of the job's shape run by another process with "
              "backend='numba-shared' (the model-free loop of the shape on disk, not the job's model); the call "
              "timed in a fresh process: its first call's extra is numba's import, the loop's load and the "
              "compile of the model's own functions")


def _child(factory: str, args: list, ys, m0, P0, repeat: int, backend: str | None) -> dict:
    """Run the job in a new process; returns its report (with the means as an array)."""
    with tempfile.TemporaryDirectory(prefix="nlfilter-bench-job-") as tmp:
        np.savez(pathlib.Path(tmp) / "job.npz", ys=ys, m0=np.asarray(m0, float), P0=np.asarray(P0, float))
        job = {"factory": factory, "args": args, "repeat": repeat, "backend": backend, "dir": tmp}
        env = {**os.environ, "NLFILTER_BENCH_CACHE": "keep"}  # NLFILTER_CACHE: the caller's (_pin's folder)
        if _pin.CORE is not None:
            env["NLFILTER_BENCH_CORE"] = str(_pin.CORE)
        t = time.perf_counter()
        subprocess.run([sys.executable, str(HERE / "_warm.py"), json.dumps(job)], env=env, check=True, cwd=HERE)
        wall = time.perf_counter() - t
        out = json.loads((pathlib.Path(tmp) / "out.json").read_text())
        out["means"] = np.load(pathlib.Path(tmp) / "means.npy")
    out["process_wall_seconds"] = wall
    return out


def warm_default(factory: str, args: list, ys, m0, P0, repeat: int, backend: str | None = None, fill=None):
    """The default call (``backend`` None; else the run with that ``backend``) of ``factory(*args)``
    (``"module:function"`` in ``benchmarks/``) on ``ys`` with the job's loop on disk beforehand (see
    the module). Returns ``(timing, estimates, notes)`` as a column of
    :func:`_peers.nlfilter_sides`: the timing of :func:`_pin.first_and_best` plus ``backend`` and
    ``why`` (the rule's choice at the first call), ``calls`` (each call's wall and CPU seconds and
    backend: the automatic rule may move to the cached loop at a later call), ``fill`` (the filling
    process's compile, wall and CPU seconds) and the timed process's CPU seconds and page faults;
    the estimates carry ``means``. ``fill``: ``(backend, args)`` of the filling process (default
    ``("numba", args)``: the job itself; ``("numba-shared", other args)``: another model of the
    job's shape on the model-free loop, ``--cache shape``)."""
    fill_backend, fill_args = fill or ("numba", args)
    job = (factory, json.dumps(fill_args), fill_backend, ys.shape)
    if job not in _FILLED:  # (once per job: a second column finds it filled)
        _FILLED[job] = _child(factory, fill_args, ys, m0, P0, 1, fill_backend)
    fill = _FILLED[job]
    out = _child(factory, args, ys, m0, P0, repeat, backend)
    timing = {**out["timing"], "backend": out["backend"], "why": out["why"],
              "cache": "warm" if fill_backend == "numba" else "shape",
              "numba_imported_at_start": out["numba_imported_at_start"],
              "process_cpu_seconds": out["process_cpu_seconds"],
              "minor_page_faults": out["minor_page_faults"], "calls": out["calls"],
              "fill": {"first": fill["timing"]["first"], "first_cpu": fill["timing"]["first_cpu"],
                       "unsealed_entries": fill["unsealed"]}}
    notes = [CACHE_NOTE if fill_backend == "numba" else SHAPE_NOTE]
    if fill["unsealed"]:
        notes.append(f"{factory}{tuple(args)}: the filling process left {fill['unsealed']} entries unsealed")
    return timing, SimpleNamespace(means=out["means"]), notes


def _unsealed_entries() -> int:
    """Entries of the disk cache holding numba's files without their seal."""
    from nlfilter.filters.compiled.cache import cache_root

    root = cache_root()
    return sum(1 for p in root.glob("*/__pycache__") if not (p.parent / "sealed.json").exists())


def _entry_state(flt, B: int) -> dict:
    """The disk-cache entry of the model's own loop that the default call asked about (after the
    calls: asked before, its text would be made outside the first call's time): whether it exists,
    holds the loop's source, is sealed and trusted (numba's files those the seal records) and ready."""
    from nlfilter.filters.compiled import build, cache

    kind, fns, scalar, dims, _ = build.loop_of(flt, B)
    text, tag = build.text_of(kind, fns, scalar, dims)
    entry = cache.cache_root() / f"{tag}-{cache._key(text)}"
    src = entry / "module.py"
    return {"tag": tag, "dims": repr(dims), "exists": entry.is_dir(),
            "source_matches": src.is_file() and src.read_bytes() == text.encode(),
            "sealed": (entry / "sealed.json").is_file(), "trusted": entry.is_dir() and cache._trusted(entry),
            "ready": cache.ready(text, tag)}


def _main(job: dict) -> None:
    numba_at_start = "numba" in sys.modules
    sys.path.insert(0, str(HERE))
    module, name = job["factory"].split(":")
    flt = getattr(importlib.import_module(module), name)(*job["args"])
    data = np.load(pathlib.Path(job["dir"]) / "job.npz")
    ys, m0, P0 = data["ys"], data["m0"], data["P0"]
    if job["backend"] is None:  # the default call, repeated as a process repeating the job (_pin.default_calls)
        timing, est = _pin.default_calls(lambda: flt.run(ys, m0, P0), job["repeat"])
        calls = timing.pop("calls")
        backend, why = calls[0]["backend"], calls[0]["why"]
    else:
        calls = []  # each call's (wall, CPU) seconds: the first apart, then the best, as _pin.first_and_best
        for _ in range(max(job["repeat"], 1)):
            t, c = time.perf_counter(), time.process_time()
            est = flt.run(ys, m0, P0, backend=job["backend"])
            calls.append({"wall": time.perf_counter() - t, "cpu": time.process_time() - c, "backend": job["backend"]})
        timing = {"first": calls[0]["wall"], "first_cpu": calls[0]["cpu"]}
        if len(calls) > 1:
            best, best_cpu = min(x["wall"] for x in calls[1:]), min(x["cpu"] for x in calls[1:])
            timing.update(best=best, best_cpu=best_cpu, compile=max(calls[0]["wall"] - best, 0.0),
                          included=calls[0]["wall"])
        backend, why = job["backend"], None
    if job["backend"] is None:
        try:
            timing["loop_entry"] = _entry_state(flt, ys.shape[0])
        except Exception as exc:  # noqa: BLE001 - a filter the compiled loop does not take: no entry to name
            timing["loop_entry"] = {"error": f"{type(exc).__name__}: {exc}"}
    ru = resource.getrusage(resource.RUSAGE_SELF)
    np.save(pathlib.Path(job["dir"]) / "means.npy", est.means)
    out = {"timing": timing, "calls": calls, "backend": backend, "why": why, "numba_imported_at_start": numba_at_start,
           "process_cpu_seconds": ru.ru_utime + ru.ru_stime, "unsealed": _unsealed_entries(),
           "minor_page_faults": ru.ru_minflt}
    (pathlib.Path(job["dir"]) / "out.json").write_text(json.dumps(out))


if __name__ == "__main__":
    _main(json.loads(sys.argv[1]))
