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
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

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


def default_path() -> Path:
    """``$NLFILTER_STORE``, else ``$XDG_CACHE_HOME/nlfilter/results.sqlite`` (default ``~/.cache``)."""
    env = os.environ.get("NLFILTER_STORE")
    if env:
        return Path(env).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(cache) / "nlfilter" / "results.sqlite"


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
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def _unpack(data: bytes) -> dict:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


class ResultsStore:
    """The SQLite results store at ``path`` (created with its folder on first use); see the module
    docstring. Use as a context manager or call :meth:`close`."""

    def __init__(self, path=None):
        self.path = Path(default_path() if path is None else path).expanduser()
        if self.path.exists() and self.path.is_dir():
            raise ValueError(f"store: {str(self.path)!r} is a folder; expected the path of an SQLite file")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(str(self.path), timeout=60.0, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.executescript(_SCHEMA)
        except (OSError, sqlite3.DatabaseError) as exc:
            raise ValueError(f"store: cannot open {str(self.path)!r} as an SQLite results store ({exc})") from None

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
        return None if row is None else _unpack(row[0])

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
        return None if row is None else Result.from_json(json.loads(row[0]))

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
        return {**hits[0], "result": None if text is None else Result.from_json(json.loads(text))}
