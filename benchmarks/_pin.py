"""One pinning for every benchmark, and one way to write its JSON (issue 28, item 7).

Import this module **first**, before NumPy, SciPy, numba or jax (``import _pin`` at the top of a
script in ``benchmarks/``): at import it pins every side of a side-by-side run alike, one core and
one thread,

* the thread counts of OpenMP, OpenBLAS, MKL, Accelerate, numexpr and numba
  (``OMP_NUM_THREADS`` … ``NUMBA_NUM_THREADS`` = 1, set before those libraries load), then BLAS
  and OpenMP again through threadpoolctl (in case a library was loaded already);
* XLA (jax, dynamax): ``XLA_FLAGS`` gets ``--xla_cpu_multi_thread_eigen=false
  intra_op_parallelism_threads=1``, ``JAX_PLATFORMS=cpu``;
* the process to one core (``os.sched_setaffinity``; threads started later inherit it): the core
  of ``NLFILTER_BENCH_CORE`` if set, else the one core the process already has (``taskset -c 1
  python ...``), else the last core allowed;
* nlfilter's compile cache (``NLFILTER_CACHE``) to a fresh empty directory, so that "compile
  included" means a cold compile; ``NLFILTER_BENCH_CACHE=keep`` keeps the user's cache.

``NLFILTER_BENCH_PIN=0`` (set before the import) skips the thread and core pinning — for the one
benchmark that measures the thread count itself (``bench_grid.py``) — and records that it did.

:func:`environment` says what was pinned and where the run happened (machine, load before and
after, versions, the commit of the nlfilter tree imported); :func:`write` stores it with the
results, one entry per ``label`` in the JSON file, keeping the other labels (a file written before
this module, without ``"runs"``, is kept as the run ``"before-issue-28"``). :func:`best_of`,
:func:`first_and_best` and :func:`side_by_side` are the timing and row helpers the scripts share.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
                    "NUMEXPR_NUM_THREADS", "NUMBA_NUM_THREADS")
XLA_ONE_THREAD = ("--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1")
WATCHED = ("numpy", "scipy", "numba", "jax", "jaxlib", "nlfilter", "statsmodels")

_T0 = time.time()
_LOAD0 = os.getloadavg()


def _src_digest():
    """The SHA-256 of the ``.py`` files of the nlfilter package this process (and its children,
    with the same environment) imports, found without importing it; None where it is not found."""
    import hashlib
    import importlib.util

    spec = importlib.util.find_spec("nlfilter")
    if spec is None or not spec.submodule_search_locations:
        return None
    root = next(iter(spec.submodule_search_locations))
    digest = hashlib.sha256()
    for folder, dirs, files in sorted(os.walk(root)):
        dirs.sort()
        for name in sorted(files):
            if name.endswith(".py"):
                path = os.path.join(folder, name)
                digest.update(os.path.relpath(path, root).encode())
                with open(path, "rb") as fh:
                    digest.update(fh.read())
    return digest.hexdigest()[:16]


#: at import: a run whose imported sources change before it writes (an edit, a checkout, a merge in
#: the tree it imports: its processes would run different code) is flagged by :func:`environment`
_SRC0 = _src_digest()
_LATE = sorted(m for m in WATCHED if m in sys.modules)  # loaded before the pinning: their pools may be wider
PINNED = os.environ.get("NLFILTER_BENCH_PIN", "1") != "0"
CORE = None
_limits = None

if PINNED:
    for _v in THREAD_VARIABLES:
        os.environ[_v] = "1"
    _flags = os.environ.get("XLA_FLAGS", "").split()
    os.environ["XLA_FLAGS"] = " ".join(_flags + [f for f in XLA_ONE_THREAD if f not in _flags])
    os.environ["JAX_PLATFORMS"] = "cpu"
    _allowed = sorted(os.sched_getaffinity(0))
    if os.environ.get("NLFILTER_BENCH_CORE"):
        CORE = int(os.environ["NLFILTER_BENCH_CORE"])
    else:
        CORE = _allowed[-1]
    os.sched_setaffinity(0, {CORE})
    try:  # a peer's own environment may lack threadpoolctl: the variables above then do it alone
        from threadpoolctl import threadpool_limits

        _limits = threadpool_limits(limits=1)  # kept: the limits hold for the whole process
    except ImportError:
        pass
if _LATE:
    print(f"_pin: imported after {', '.join(_LATE)}: import benchmarks/_pin.py first", file=sys.stderr)

if os.environ.get("NLFILTER_BENCH_CACHE", "") != "keep":
    import tempfile

    _CACHE = tempfile.TemporaryDirectory(prefix="nlfilter-bench-cache-")  # removed at exit
    os.environ["NLFILTER_CACHE"] = _CACHE.name


def best_of(fn, repeat: int):
    """``(best seconds of repeat calls of fn(), the last output)``."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def first_and_best(fn, repeat: int):
    """The first call of ``fn()`` (a compile, a cache load or nothing: whatever the side pays
    before its first result) and then the best of ``repeat - 1`` more (at least one).

    Returns ``{"first": s, "best": s, "compile": first - best, "included": first, "first_cpu": s,
    "best_cpu": s}`` and the output. "compile" is the side's compile (or cache load) apart;
    "included" the time to the first result; the ``_cpu`` keys are the process's CPU seconds of the
    first call and the least of the others (a shared core inflates wall time, not CPU time).
    """
    t, c = time.perf_counter(), time.process_time()
    fn()
    first, first_cpu = time.perf_counter() - t, time.process_time() - c
    best, best_cpu, out = float("inf"), float("inf"), None
    for _ in range(max(repeat - 1, 1)):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        best, best_cpu = min(best, time.perf_counter() - t), min(best_cpu, time.process_time() - c)
    return {"first": first, "best": best, "compile": max(first - best, 0.0), "included": first,
            "first_cpu": first_cpu, "best_cpu": best_cpu}, out


def default_calls(call, repeat: int):
    """The default call (``call()``: ``run`` with no ``backend=``) repeated as a process repeating a
    job does, up to ``repeat`` times: the automatic rule moves a later call to the compiled loop once
    the NumPy loop's time repays its load or compile. Stops early once three calls after the first
    ran a compiled loop (the steady state: the first calls of a fresh process also pay the first touch
    of their output arrays' memory, 7 s of one call at n = 16 where the kernel compacts memory for
    huge pages). Returns ``(timing, output)``: the timing as
    :func:`first_and_best` (its best over the later calls: the steady state), plus ``calls`` (each
    call's wall and CPU seconds and backend: ``Filter.backend_for`` spied on), ``best_backend`` (the
    best later call's) and ``to_steady`` (wall and CPU seconds of the calls before the first of the
    steady state's backend: what the process paid to get there, NumPy calls and a compile or load)."""
    from nlfilter.filters.base import Filter  # (on the class: an attribute of the filter's own is refused)

    ask, chose = Filter.backend_for, []

    def spy(self, *a, **k):
        r = ask(self, *a, **k)
        chose.append((str(r[0]), str(r[1])))
        return r

    calls, out = [], None
    Filter.backend_for = spy
    try:
        for i in range(max(repeat, 2)):  # (at least a first call and a later one)
            del chose[:]
            t, c = time.perf_counter(), time.process_time()
            out = call()
            calls.append({"wall": time.perf_counter() - t, "cpu": time.process_time() - c,
                          "backend": chose[0][0] if chose else None, "why": chose[0][1] if chose else None})
            if i >= 3 and all(x["backend"] not in (None, "numpy") for x in calls[-3:]):
                break
    finally:
        Filter.backend_for = ask
    later = calls[1:]
    best = min(later, key=lambda x: x["wall"])
    at = next((i for i, x in enumerate(calls) if x["backend"] == best["backend"] and i > 0), len(calls))
    timing = {"first": calls[0]["wall"], "best": best["wall"], "compile": max(calls[0]["wall"] - best["wall"], 0.0),
              "included": calls[0]["wall"], "first_cpu": calls[0]["cpu"], "best_cpu": min(x["cpu"] for x in later),
              "calls": calls, "best_backend": best["backend"],
              "to_steady": {"wall": sum(x["wall"] for x in calls[:at]), "cpu": sum(x["cpu"] for x in calls[:at]),
                            "calls": at}}
    return timing, out


def side_by_side(ours: str, peer: str, ours_value: float, peer_value: float, unit: str, **extra) -> dict:
    """One row naming both sides: ``peer_over_ours`` > 1 means ours is faster."""
    return {"ours": ours, "peer": peer, "unit": unit, "ours_value": ours_value, "peer_value": peer_value,
            "peer_over_ours": peer_value / ours_value if ours_value else None, **extra}


def default_backend():
    """The ``backend`` of ``Filter.run`` when the call names none (the "default call"), or None
    where the imported nlfilter has no backend argument."""
    import inspect

    from nlfilter.filters import EKF  # in every version of the package (its run is the family's)

    for cls in EKF.__mro__:  # the run that names it: a mixin's run (DiffusePrior's) passes **kw on to it
        run = cls.__dict__.get("run")
        p = None if run is None else inspect.signature(run).parameters.get("backend")
        if p is not None:
            return p.default
    return None


def _git(path, *args):
    try:
        return subprocess.run(["git", "-C", str(path), *args], capture_output=True, text=True, timeout=20,
                              check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None


def commit_of(path) -> dict:
    """The git commit of the tree holding ``path`` and whether its ``src/`` differs from it."""
    path = os.path.dirname(os.path.abspath(path))
    head = _git(path, "rev-parse", "HEAD")
    root = _git(path, "rev-parse", "--show-toplevel")
    dirty = _git(path, "status", "--porcelain", "--", os.path.join(root, "src")) if root else None
    return {"tree": root, "commit": head, "src_modified": bool(dirty) if dirty is not None else None}


def _version(dist):
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def _cpu_model():
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine()


def _thp() -> dict:
    """The kernel's transparent huge page settings (NumPy advises huge pages for large arrays: where
    the kernel compacts memory to find them, a fresh process's first touch of a large array is slow)."""
    out = {}
    for name in ("enabled", "defrag"):
        try:
            with open(f"/sys/kernel/mm/transparent_hugepage/{name}") as fh:
                out[name] = fh.read().strip()
        except OSError:
            out[name] = None
    return out


def pinning() -> dict:
    """What was pinned: the core, the thread variables, XLA's flags and the thread pools loaded."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        threadpool_info = list
    return {"pinned": PINNED, "core": CORE, "affinity": sorted(os.sched_getaffinity(0)),
            "threads": {v: os.environ.get(v) for v in THREAD_VARIABLES}, "XLA_FLAGS": os.environ.get("XLA_FLAGS"),
            "thread_pools": [{k: i.get(k) for k in ("user_api", "internal_api", "num_threads", "version")}
                             for i in threadpool_info()],
            "imported_before_pin": _LATE, "NUMPY_MADVISE_HUGEPAGE": os.environ.get("NUMPY_MADVISE_HUGEPAGE"),
            "transparent_hugepage": _thp(),
            "nlfilter_cache": "kept (the user's)" if os.environ.get("NLFILTER_BENCH_CACHE") == "keep"
            else "a fresh empty directory (cold)"}


def environment() -> dict:
    """Pinning, machine, load (1/5/15-minute averages at import and now, ``uptime``), versions and
    the commit of the nlfilter tree imported."""
    import platform

    import nlfilter

    uptime = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip() or None
    versions = {"python": platform.python_version()}
    for dist in ("numpy", "scipy", "sympy", "numba", "llvmlite", "jax", "jaxlib", "dynamax", "filterpy",
                 "statsmodels", "threadpoolctl"):
        versions[dist] = _version(dist)
    return {"pinning": pinning(),
            "machine": {"platform": platform.platform(), "cpu": _cpu_model(), "cores": os.cpu_count()},
            "load": {"at_start": list(_LOAD0), "at_end": list(os.getloadavg()), "uptime_at_end": uptime,
                     "note": "1/5/15-minute load averages; the machine's cores are shared with other jobs"},
            "wall_seconds": time.time() - _T0, "versions": versions,
            "nlfilter": {"file": os.path.dirname(nlfilter.__file__), **commit_of(nlfilter.__file__),
                         "sources_at_start": _SRC0, "sources_changed_during_run": _src_digest() != _SRC0},
            "benchmarks": commit_of(__file__), "argv": sys.argv}


def write(path, label: str, payload: dict, benchmark: str | None = None) -> dict:
    """Store ``payload`` with :func:`environment` as the run ``label`` of the JSON file ``path``
    (other labels kept) and print where; returns the run written."""
    import json
    import pathlib

    out = pathlib.Path(path)
    res = json.loads(out.read_text()) if out.exists() else {}
    if res and "runs" not in res:
        res = {"runs": {"before-issue-28": res}}
    run = {**payload, "environment": environment()}
    if run["environment"]["nlfilter"]["sources_changed_during_run"]:
        print(f"warning: nlfilter's sources ({run['environment']['nlfilter']['file']}) changed during the run: its "
              "processes may have run different code (recorded as sources_changed_during_run)", file=sys.stderr)
    if benchmark:
        res["benchmark"] = benchmark
    res.setdefault("runs", {})[label] = run
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2, ensure_ascii=False, default=float) + "\n")
    print(f"wrote {out} (run {label!r})")
    return run
