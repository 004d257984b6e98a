"""The compiled code cached on disk: a generated module's source written once to a folder of its
own, named by the hash of everything it is made of, imported from there, and numba's machine code
for its cached functions (``cache=True``) kept beside it — so that a second process (a rerun, a
Dask worker, a CI job) loads the loop instead of compiling it.

Where: ``$NLFILTER_CACHE``, else the folder ``compiled`` beside the results store's default file
(``$XDG_CACHE_HOME/nlfilter/compiled``, ``~/.cache`` when ``XDG_CACHE_HOME`` is unset). An entry is
``<root>/<tag>-<key>/``: ``module.py`` (the generated source, never rewritten), numba's
``__pycache__/`` and ``sealed.json``. The key is the SHA-256 of the source (the model's generated
functions, the rule's kernels, the loop, the dimensions compiled in — all text in the module) and
of the Python, NumPy, numba, llvmlite and nlfilter versions: change the model, the code or a
version, and it is another entry.

Never trusted: ``module.py`` is compared with the source it must hold (a damaged or foreign file is
written again, which also makes numba's index stale: numba keys it by the file's time stamp and
size); after numba has written its files (the first run), :func:`seal` records their SHA-256 in
``sealed.json``; an entry whose numba files do not match their seal (truncated, damaged, written by
a process that did not finish) loses them and is compiled again. numba does not check its own
files (a truncated index or data file raises from deep inside the dispatcher), hence the seal.
A process that may write numba's files into an unsealed entry says so in ``owner.json`` (its pid
and host); while that process lives (on another host: for an hour), another process finding the
entry unsealed leaves it alone and compiles in memory instead of deleting files being written.
A folder that cannot be written leaves the disk cache off for the process, with one warning:
the loop is then compiled in memory, as without a cache.
"""

from __future__ import annotations

import functools
import glob
import hashlib
import importlib.util
import json
import os
import platform
import shutil
import socket
import sys
import time
import tempfile
import warnings
from pathlib import Path

__all__ = ["cache_root", "load_source", "seal", "versions", "ready", "holds_tag", "ready_by_tag"]

_MODULES: dict = {}  # key -> module (this process)
_OFF: dict = {}  # root -> why the disk cache is off there
_SEALED: set = set()  # the entries this process found or made sealed (seal asks the disk once)


def cache_root() -> Path:
    """``$NLFILTER_CACHE``, else ``$XDG_CACHE_HOME/nlfilter/compiled`` (default ``~/.cache``)."""
    from ..._paths import home

    env = os.environ.get("NLFILTER_CACHE")
    return Path(env).expanduser() if env else home() / "compiled"


@functools.lru_cache(maxsize=1)
def versions() -> str:
    """The versions an entry's machine code depends on, besides its source."""
    from importlib.metadata import PackageNotFoundError, version

    import numpy

    from ... import __version__

    def of(name):  # read from the installed metadata: numba need not be imported to look an entry up
        try:
            return version(name)
        except PackageNotFoundError:  # pragma: no cover - numba is a core dependency
            return "absent"
    return (f"python {platform.python_implementation()} {sys.version.split()[0]} {platform.machine()}; numpy "
            f"{numpy.__version__}; numba {of('numba')}; llvmlite {of('llvmlite')}; nlfilter {__version__}")


def _key(text: str) -> str:
    return hashlib.sha256((versions() + "\n" + text).encode()).hexdigest()[:32]


def _write_atomic(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def _digests(entry: Path) -> dict:
    pyc = entry / "__pycache__"
    if not pyc.is_dir():
        return {}
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(pyc.iterdir()) if p.suffix in (".nbi", ".nbc")}


def _trusted(entry: Path) -> bool:
    """Whether numba's files in ``entry`` are those :func:`seal` recorded (no files: trivially)."""
    found = _digests(entry)
    if not found:
        return True
    try:
        sealed = json.loads((entry / "sealed.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(sealed, dict) and sealed == found


#: how long an unsealed entry's owner on another host is taken to be alive (no pid to ask there)
OWNER_SECONDS = 3600.0


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. PermissionError: it exists, owned by someone else
        return True
    return True


def _busy(entry: Path) -> bool:
    """Whether another living process claimed ``entry`` (:func:`_claim`) and may still be writing
    numba's files there."""
    try:
        owner = json.loads((entry / "owner.json").read_text())
        pid, host, since = int(owner["pid"]), str(owner["host"]), float(owner["time"])
    except (OSError, ValueError, KeyError, TypeError):
        return False
    if host != socket.gethostname():
        return time.time() - since < OWNER_SECONDS
    return pid != os.getpid() and _alive(pid)


def _claim(entry: Path) -> None:
    _write_atomic(entry / "owner.json", json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                                    "time": time.time()}).encode())


def _in_memory(text: str, name: str):
    """The module compiled without the disk (numba cannot cache code that is not in a file)."""
    module = type(sys)(name)
    exec(compile(text.replace("cache=True", "cache=False"), f"<{name}>", "exec"), module.__dict__)  # noqa: S102
    return module


def load_source(text: str, tag: str):
    """The module whose source is ``text`` (its functions jitted with ``cache=True`` where their
    machine code should be kept), imported from its cache entry; ``tag`` names the entry's folder.
    The same module object for the same text within a process. Returns ``(module, entry)``; entry
    None where the disk cache is off."""
    key = _key(text)
    if key in _MODULES:
        return _MODULES[key]
    name = f"nlfilter_compiled_{tag.replace('-', '_')}_{key}"
    root = cache_root()
    entry = root / f"{tag}-{key}"
    module = None
    if str(root) not in _OFF:
        try:
            entry.mkdir(parents=True, exist_ok=True)
            src = entry / "module.py"
            data = text.encode()
            try:
                same = src.read_bytes() == data
            except OSError:
                same = False
            if not same or not _trusted(entry):
                if _busy(entry):  # another process is writing it: leave it, compile in memory
                    module = _in_memory(text, name)
                    _MODULES[key] = (module, None)
                    return module, None
                shutil.rmtree(entry / "__pycache__", ignore_errors=True)  # numba's files go, and their seal
                (entry / "sealed.json").unlink(missing_ok=True)
                _SEALED.discard(entry)
            if not same:  # new, damaged or foreign: written again (numba's index would be stale)
                _write_atomic(src, data)
            if not (entry / "sealed.json").exists():  # numba may write here: say who, until sealed
                _claim(entry)
            probe = entry / f".probe-{os.getpid()}"  # numba writes beside the source: it must be writable
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            _OFF[str(root)] = str(exc)
            warnings.warn(f"nlfilter: the compiled-code cache {str(root)!r} cannot be written ({exc}); compiling in "
                          "memory in this process (set NLFILTER_CACHE to a writable folder)", RuntimeWarning, stacklevel=3)
        else:
            spec = importlib.util.spec_from_file_location(name, src)
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module  # numba finds a cached function's globals through its module
            spec.loader.exec_module(module)
    if module is None:
        module, entry = _in_memory(text, name), None
    _MODULES[key] = (module, entry)
    return module, entry


def ready(text: str, tag: str) -> str | None:
    """Where the module of ``text`` is ready without compiling: ``"process"`` (imported in this
    process), ``"disk"`` (a sealed entry holding this source), or None (it would be compiled).
    Imports nothing: the automatic backend asks before deciding to load numba."""
    key = _key(text)
    if key in _MODULES:
        return "process"
    entry = cache_root() / f"{tag}-{key}"
    try:
        ok = (entry / "module.py").read_bytes() == text.encode() and (entry / "sealed.json").is_file()
    except OSError:
        return None
    return "disk" if ok and _trusted(entry) else None


def holds_tag(tag: str) -> bool:
    """Whether the disk cache holds a sealed entry of ``tag`` at all (a listing of the folder, no
    source): where it holds none (a fresh installation, a kind or shape never run), :func:`ready`
    of any source of that tag is None, and the automatic backend asks no loop's text to know it (a
    specialized loop's text takes 0.1-0.6 s to write)."""
    try:
        return any(p.parent.name[len(tag) + 1:].isalnum() for p in cache_root().glob(f"{glob.escape(tag)}-*/sealed.json"))
    except OSError:
        return False


def ready_by_tag(tag: str, make) -> str | None:
    """:func:`ready` of the source ``make()`` returns (``(text, tag)``), written only where the cache
    holds an entry of ``tag`` at all (:func:`holds_tag`); None otherwise. (Not ``"process"`` for a
    module compiled in memory: the callers ask their process first.)"""
    return ready(*make()) if holds_tag(tag) else None


def seal(entry) -> None:
    """Record the SHA-256 of numba's files in ``entry`` (after a run compiled or loaded them), once
    (a process asks the disk once per entry: :data:`_SEALED`)."""
    if entry is None or entry in _SEALED:
        return
    if (entry / "sealed.json").exists():
        _SEALED.add(entry)
        return
    found = _digests(entry)
    if found:
        try:
            _write_atomic(entry / "sealed.json", json.dumps(found, indent=0, sort_keys=True).encode())
            (entry / "owner.json").unlink(missing_ok=True)
            _SEALED.add(entry)
        except OSError:  # pragma: no cover - a folder that became unwritable: the entry stays unsealed
            pass
