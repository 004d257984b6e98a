"""The results store: one SQLite file (standard library :mod:`sqlite3`) that keeps every finished
Monte Carlo block and every finished run, so that an interrupted or crashed run resumes where it
stopped and past results can be listed, shown and exported (``nlfilter results``).

Two tables:

``blocks``
    One row per finished Monte Carlo block (:mod:`nlfilter.montecarlo`): the per-path arrays a
    block function returned (``numpy.savez`` bytes), under the block's ``key`` — a SHA-256 of what
    fixes its numbers: the experiment, the task label, the effective parameters (JSON), the seed,
    the block size, the nlfilter version and a fingerprint of the package's source files (so a
    code change never reuses a stale block) — and its path range ``[start, stop)``. Each block is
    committed in its own transaction as it finishes: a killed process leaves every finished block
    and no partial one.
``runs``
    One row per experiment run started through the command line: experiment, effective
    parameters, seed, runs, quick flag, version, code fingerprint, status (``running``, ``done``,
    ``interrupted``, ``failed``), start and finish times, wall seconds, the command, and, when
    done, the result's JSON (:meth:`nlfilter.results.Result.to_dict`).

The file knows it is a store: SQLite's ``PRAGMA application_id`` holds :data:`APPLICATION_ID` and
``PRAGMA user_version`` the schema version :data:`SCHEMA_VERSION`. A new or empty file is
initialised (in one transaction); a store made before the mark (exactly these two tables) is
marked; any other file — another program's database, one with other tables, a newer schema, not
SQLite at all — is refused with one line naming it, read only and left unchanged. A block whose
bytes are damaged is recomputed (with a warning), never served.

The default file is ``$NLFILTER_STORE``, else ``$XDG_CACHE_HOME/nlfilter/results.sqlite`` (``~/.cache``
when ``XDG_CACHE_HOME`` is unset). Several processes may share one file (SQLite's locking, WAL
journal); only the process that runs an experiment writes, never a Dask worker.

>>> import tempfile, os, numpy as np
>>> path = os.path.join(tempfile.mkdtemp(), "r.sqlite")
>>> with ResultsStore(path) as st:
...     key = block_key(experiment="demo", task="sim", params={"T": 1.0}, seed=0, block=4)
...     st.put_block(key, 0, 4, {"m2": np.arange(4.0)}, experiment="demo", task="sim", seconds=0.1)
...     st.get_block(key, 0, 4)["m2"].tolist()
[0.0, 1.0, 2.0, 3.0]
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import sqlite3
import time
import warnings
from datetime import datetime, timezone
from pathlib import Path

_SCHEMA = """
CREATE TABLE IF NOT EXISTS blocks (
    key TEXT NOT NULL, start INTEGER NOT NULL, stop INTEGER NOT NULL,
    experiment TEXT, task TEXT, seconds REAL, created TEXT, data BLOB NOT NULL,
    PRIMARY KEY (key, start, stop));
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT, experiment TEXT NOT NULL, params TEXT, seed INTEGER,
    runs INTEGER, quick INTEGER, version TEXT, code TEXT, status TEXT NOT NULL, started TEXT,
    finished TEXT, seconds REAL, command TEXT, result TEXT);
"""
STATUSES = ("running", "done", "interrupted", "failed")
APPLICATION_ID = 0x6E6C6672  #: "nlfr" in SQLite's header (PRAGMA application_id): the file is an nlfilter store
SCHEMA_VERSION = 1  #: PRAGMA user_version: this module's schema (_SCHEMA)
_TABLES = {"blocks": ["key", "start", "stop", "experiment", "task", "seconds", "created", "data"],
           "runs": ["id", "experiment", "params", "seed", "runs", "quick", "version", "code", "status", "started",
                    "finished", "seconds", "command", "result"]}


def _recognise(path: Path) -> str:
    """What the file at ``path`` is, read without changing it (``immutable``: no lock, no journal
    files created beside it): ``"ours"`` (an nlfilter store of this schema), ``"new"`` (absent or an
    empty database), ``"unmarked"`` (exactly nlfilter's tables, made before the store marked its
    files), or a description of a file that is not ours."""
    if not path.exists() or path.stat().st_size == 0:
        return "new"
    db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro&immutable=1", uri=True)
    try:
        return _state(db)
    finally:
        db.close()


def _state(db) -> str:
    """:func:`_recognise` of the database open as ``db``."""
    app, version = (db.execute(f"PRAGMA {p}").fetchone()[0] for p in ("application_id", "user_version"))
    tables = {name: [c[1] for c in db.execute(f"PRAGMA table_info('{name}')")]
              for (name,) in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    tables.pop("sqlite_sequence", None)  # SQLite's own (AUTOINCREMENT)
    if app == APPLICATION_ID:
        if version > SCHEMA_VERSION:
            return f"schema version {version}, made by a newer nlfilter than this one ({SCHEMA_VERSION})"
        return "ours"
    if app != 0:
        return f"application id {app:#x}, another program's"
    if not tables:
        return "new"
    if tables == _TABLES:
        return "unmarked"
    return f"tables {sorted(tables)}"


def _initialise(db, where: str) -> None:
    """Create the schema and mark the file (one transaction: a concurrent opener sees all or none)."""
    db.execute("BEGIN IMMEDIATE")
    try:
        state = _state(db)  # again, live and under the write lock: another process may have done it
        if state == "ours":
            db.execute("ROLLBACK")
            return
        if state not in ("new", "unmarked"):
            raise ValueError(f"store: {where!r} is not an nlfilter results store ({state}); expected an nlfilter "
                             "store or a new file (nothing was changed)")
        for statement in filter(str.strip, _SCHEMA.split(";")):
            db.execute(statement)
        db.execute(f"PRAGMA application_id={APPLICATION_ID}")
        db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        db.execute("COMMIT")
    except BaseException:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise


class _Guarded:
    """The connection, its errors as one-line ``ValueError``s naming the file (a file damaged after
    it was opened: ``database disk image is malformed``)."""

    def __init__(self, db, where: str):
        self._db, self._where = db, where

    def execute(self, sql: str, args=()):
        try:
            return self._db.execute(sql, args)
        except sqlite3.OperationalError as exc:
            raise ValueError(f"store {self._where!r}: {exc}") from None
        except sqlite3.DatabaseError as exc:
            raise ValueError(f"store {self._where!r}: the file is damaged ({exc}); expected a readable nlfilter "
                             "store (move it away to start a new one)") from None

    def close(self) -> None:
        self._db.close()


def default_path() -> Path:
    """``$NLFILTER_STORE``, else ``$XDG_CACHE_HOME/nlfilter/results.sqlite`` (default ``~/.cache``)."""
    from ._paths import home

    env = os.environ.get("NLFILTER_STORE")
    return Path(env).expanduser() if env else home() / "results.sqlite"


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 (first 16 hex digits) of the package's ``.py`` files, their paths and contents: any
    change to the code gives a new fingerprint, so the store never serves a block computed by
    other code."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


def _canon(obj) -> str:
    from .results import _default, _encode
    return json.dumps(_encode(obj), sort_keys=True, default=_default, separators=(",", ":"))


def block_key(*, experiment: str, task: str, params: dict, seed: int, block: int) -> str:
    """The key of a Monte Carlo task's blocks: SHA-256 of the experiment id, the task label, the
    effective parameters, the seed, the block size, the nlfilter version and :func:`code_fingerprint`."""
    from . import __version__
    ident = {"experiment": experiment, "task": task, "params": params, "seed": seed, "block": block,
             "version": __version__, "code": code_fingerprint()}
    return hashlib.sha256(_canon(ident).encode()).hexdigest()


def _pack(arrays: dict) -> bytes:
    import numpy as np  # here, not at the top: `nlfilter results list` needs no NumPy

    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def _unpack(data: bytes) -> dict:
    import numpy as np

    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


class ResultsStore:
    """The SQLite results store at ``path`` (created with its folder on first use); see the module
    docstring. Use as a context manager or call ``close()``."""

    def __init__(self, path=None):
        self.path = Path(default_path() if path is None else path).expanduser()
        if self.path.exists() and self.path.is_dir():
            raise ValueError(f"store: {str(self.path)!r} is a folder; expected the path of an SQLite file")
        where = str(self.path)
        try:
            state = _recognise(self.path)  # read-only: a file that is not ours is left untouched
            if state not in ("ours", "new", "unmarked"):
                raise ValueError(f"store: {where!r} is not an nlfilter results store ({state}); expected an "
                                 "nlfilter store or a new file (nothing was changed)")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            db = sqlite3.connect(where, timeout=60.0, isolation_level=None)
            if state != "ours":
                _initialise(db, where)
            db.execute("PRAGMA journal_mode=WAL")
        except (OSError, sqlite3.Error) as exc:
            raise ValueError(f"store: cannot open {where!r} as an SQLite results store ({exc})") from None
        self._db = _Guarded(db, where)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._db.close()

    # -- Monte Carlo blocks ------------------------------------------------------------------------
    def get_block(self, key: str, start: int, stop: int) -> dict | None:
        """The arrays of block ``[start, stop)`` under ``key``, or None if it has not finished."""
        row = self._db.execute("SELECT data FROM blocks WHERE key=? AND start=? AND stop=?",
                               (key, start, stop)).fetchone()
        if row is None:
            return None
        try:
            return _unpack(row[0])
        except Exception as exc:  # noqa: BLE001 - a damaged block (any reader error) is recomputed
            warnings.warn(f"store {str(self.path)!r}: the block [{start}, {stop}) of {key[:12]} is damaged "
                          f"({type(exc).__name__}: {exc}); recomputing it", RuntimeWarning, stacklevel=2)
            return None

    def put_block(self, key: str, start: int, stop: int, arrays: dict, *, experiment: str = "",
                  task: str = "", seconds: float | None = None) -> None:
        """Commit one finished block (its own transaction)."""
        self._db.execute("INSERT OR REPLACE INTO blocks VALUES (?,?,?,?,?,?,?,?)",
                         (key, start, stop, experiment, task, seconds, _now(), _pack(arrays)))

    def count_blocks(self, experiment: str | None = None) -> int:
        if experiment is None:
            return self._db.execute("SELECT COUNT(*) FROM blocks").fetchone()[0]
        return self._db.execute("SELECT COUNT(*) FROM blocks WHERE experiment=?", (experiment,)).fetchone()[0]

    # -- runs --------------------------------------------------------------------------------------
    def start_run(self, experiment: str, *, params: dict, seed, runs, quick: bool, command: str | None) -> int:
        from . import __version__
        if seed is not None and not (isinstance(seed, int) and 0 <= seed < 2**63):
            raise ValueError(f"seed: got {seed!r}; expected None or an integer from 0 to 2**63 - 1 (kept as an "
                             "SQLite INTEGER)")
        cur = self._db.execute(
            "INSERT INTO runs (experiment, params, seed, runs, quick, version, code, status, started, command) "
            "VALUES (?,?,?,?,?,?,?,?,?,?)",
            (experiment, _canon(params), seed, runs, int(bool(quick)), __version__, code_fingerprint(),
             "running", _now(), command))
        self._t0 = getattr(self, "_t0", {})
        self._t0[cur.lastrowid] = time.perf_counter()
        return cur.lastrowid

    def finish_run(self, run_id: int, status: str, result=None) -> None:
        if status not in STATUSES:
            raise ValueError(f"status: expected one of {STATUSES}, got {status!r}")
        t0 = getattr(self, "_t0", {}).pop(run_id, None)
        secs = None if t0 is None else time.perf_counter() - t0
        text = None if result is None else json.dumps(result.to_dict(), allow_nan=False, ensure_ascii=False)
        self._db.execute("UPDATE runs SET status=?, finished=?, seconds=?, result=? WHERE id=?",
                         (status, _now(), secs, text, run_id))

    def find_done(self, experiment: str, *, params: dict, seed, runs, quick: bool):
        """The latest finished run of ``experiment`` with these settings and this code, as a
        :class:`~nlfilter.results.Result`, or None."""
        from . import __version__
        from .results import Result
        row = self._db.execute(
            "SELECT result FROM runs WHERE experiment=? AND params=? AND seed IS ? AND runs IS ? AND quick=? "
            "AND version=? AND code=? AND status='done' ORDER BY id DESC LIMIT 1",
            (experiment, _canon(params), seed, runs, int(bool(quick)), __version__, code_fingerprint())).fetchone()
        if row is None:
            return None
        try:
            return Result.from_json(json.loads(row[0]))
        except Exception as exc:  # noqa: BLE001 - a damaged result is run again
            warnings.warn(f"store {str(self.path)!r}: the stored result of {experiment} is damaged "
                          f"({type(exc).__name__}: {exc}); running it again", RuntimeWarning, stacklevel=2)
            return None

    def runs(self, experiment: str | None = None) -> list[dict]:
        """Every run (latest first) as a dict of the ``runs`` columns (``result`` left out)."""
        cols = ["id", "experiment", "params", "seed", "runs", "quick", "version", "code", "status", "started",
                "finished", "seconds", "command"]
        sql = f"SELECT {', '.join(cols)} FROM runs"
        args: tuple = ()
        if experiment is not None:
            sql += " WHERE experiment=?"
            args = (experiment,)
        return [dict(zip(cols, r)) for r in self._db.execute(sql + " ORDER BY id DESC", args)]

    def run(self, run_id: int) -> dict:
        """One run's columns plus its ``result`` (a Result, or None when not done)."""
        from .results import Result
        hits = [r for r in self.runs() if r["id"] == run_id]
        if not hits:
            ids = [r["id"] for r in self.runs()][:10]
            raise ValueError(f"run id {run_id}: not in the store {str(self.path)!r}; expected one of "
                             f"{ids or 'none (the store is empty)'}")
        text = self._db.execute("SELECT result FROM runs WHERE id=?", (run_id,)).fetchone()[0]
        try:
            result = None if text is None else Result.from_json(json.loads(text))
        except Exception as exc:  # noqa: BLE001 - any reader error: the run's stored table is damaged
            raise ValueError(f"run id {run_id}: its stored result in {str(self.path)!r} is damaged "
                             f"({type(exc).__name__}: {exc}); expected a readable result") from None
        return {**hits[0], "result": result}
