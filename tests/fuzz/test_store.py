"""Fuzz of the results store (issue 26): ``ResultsStore`` and ``nlfilter results list`` pointed at
files that are not nlfilter stores — another program's SQLite database, one with an application
id, a newer schema, text, an empty file, a truncated and a byte-corrupted store — and a store
whose blocks and results are damaged, then two processes initialising and writing one new file at
once. A foreign file must be refused ``named`` (a one-line ``ValueError`` naming the path) and
left byte-for-byte unchanged; a damaged block is recomputed (``handled``), never served."""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import sqlite3
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from nlfilter import cli
from nlfilter.store import APPLICATION_ID, ResultsStore, block_key

ROOT = Path(__file__).resolve().parents[2]


def _store(path):
    with ResultsStore(path) as st:
        key = block_key(experiment="e", task="t", params={}, seed=0, block=2)
        for start in range(0, 8, 2):
            st.put_block(key, start, start + 2, {"a": np.arange(start, start + 2.0)}, experiment="e")
    return key


def _sql(path, *statements):
    with contextlib.closing(sqlite3.connect(path)) as db:
        for sql in statements:
            db.execute(sql)
        db.commit()
    return path


def _foreign(tmp):
    """label -> a file that is not a usable nlfilter store."""
    files = {}
    files["another program's tables"] = _sql(tmp / "other-app.sqlite", "CREATE TABLE contacts (name TEXT, phone TEXT)",
                                             "INSERT INTO contacts VALUES ('a', '1')")
    files["another application id"] = _sql(tmp / "app-id.sqlite", "PRAGMA application_id = 1179603016")  # no tables
    _store(tmp / "extra-table.sqlite")
    files["nlfilter's tables and another"] = _sql(tmp / "extra-table.sqlite", "PRAGMA application_id = 0",
                                                  "CREATE TABLE mine (x)")
    _store(tmp / "newer.sqlite")
    files["a newer schema"] = _sql(tmp / "newer.sqlite", "PRAGMA user_version = 99")
    p = tmp / "text.sqlite"
    p.write_text("name,phone\na,1\n" * 200)
    files["a text file"] = p
    p = tmp / "truncated.sqlite"
    _store(tmp / "whole.sqlite")
    _sql(tmp / "whole.sqlite", "PRAGMA wal_checkpoint(TRUNCATE)")  # fold the WAL into the file
    p.write_bytes((tmp / "whole.sqlite").read_bytes()[:150])
    files["a truncated store"] = p
    p = tmp / "scrambled.sqlite"
    data = bytearray((tmp / "whole.sqlite").read_bytes())
    data[16:24] = b"\xff" * 8  # the header's page size and format bytes
    p.write_bytes(bytes(data))
    files["a corrupted header"] = p
    return files


@pytest.fixture(scope="module")
def foreign(tmp_path_factory):
    return _foreign(tmp_path_factory.mktemp("store-fuzz"))


LABELS = ["another program's tables", "another application id", "nlfilter's tables and another", "a newer schema",
          "a text file", "a truncated store", "a corrupted header"]


@pytest.mark.parametrize("label", LABELS)
def test_foreign_file_is_refused_by_name_and_left_unchanged(fuzz, foreign, label):
    path = foreign[label]
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    siblings = sorted(os.listdir(path.parent))
    fuzz.check("results store", lambda: ResultsStore(path), [str(path), repr(str(path))], label=label)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = cli.main(["results", "list", "--store", str(path)])
    lines = err.getvalue().strip().splitlines()
    clean = code == 2 and len(lines) == 1 and str(path) in lines[0] and "Traceback" not in err.getvalue()
    fuzz.count("results store", "clean" if clean else "unclean", clean, label=f"results list on {label}: {lines}")
    assert clean, (code, err.getvalue())
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before, "the file was changed"
    assert sorted(os.listdir(path.parent)) == siblings, "files appeared beside it"


def test_damaged_blocks_are_recomputed_and_damaged_results_named(fuzz, tmp_path):
    path = tmp_path / "s.sqlite"
    key = _store(path)
    with contextlib.closing(sqlite3.connect(path)) as db:
        db.execute("UPDATE blocks SET data = ? WHERE start = 0", (b"PK\x03\x04 not a zip",))
        db.execute("UPDATE blocks SET data = substr(data, 1, 40) WHERE start = 2")  # truncated npz
        db.execute("INSERT INTO runs (experiment, status, result) VALUES ('e', 'done', '{\"rows\": [')")
        db.commit()
    with ResultsStore(path) as st:
        for start in (0, 2):
            def get(start=start):
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    got = st.get_block(key, start, start + 2)
                assert got is None and any("damaged" in str(w.message) for w in caught)
                return None
            fuzz.check("results store", get, ["damaged"], bad=False, label=f"damaged block [{start}, {start + 2})")
        assert st.get_block(key, 4, 6)["a"].tolist() == [4.0, 5.0]  # the intact ones are served
        run = st.runs()[0]["id"]
        fuzz.check("results store", lambda: st.run(run), [f"run id {run}"], label="damaged result")


_WRITER = """
import sys, numpy as np
from nlfilter.store import ResultsStore, block_key
with ResultsStore(sys.argv[1]) as st:
    key = block_key(experiment="c", task=sys.argv[2], params={}, seed=0, block=1)
    for i in range(40):
        st.put_block(key, i, i + 1, {"a": np.full(1, float(i))}, experiment="c", task=sys.argv[2])
    rid = st.start_run("c", params={}, seed=0, runs=None, quick=True, command=sys.argv[2])
    st.finish_run(rid, "interrupted")
"""


def test_two_writers_initialise_and_fill_one_new_file(fuzz, tmp_path):
    path = tmp_path / "shared.sqlite"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))}
    procs = [subprocess.Popen([sys.executable, "-c", _WRITER, str(path), name], env=env, stderr=subprocess.PIPE,
                              text=True) for name in ("one", "two")]
    errs = [p.communicate(timeout=120)[1] for p in procs]
    ok = all(p.returncode == 0 for p in procs) and not any(e.strip() for e in errs)
    with ResultsStore(path) as st:
        ok = ok and st.count_blocks("c") == 80 and sorted(r["command"] for r in st.runs("c")) == ["one", "two"]
    with contextlib.closing(sqlite3.connect(path)) as db:
        ok = ok and db.execute("PRAGMA application_id").fetchone()[0] == APPLICATION_ID
    fuzz.count("results store", "handled" if ok else "unclean", ok, label=f"two writers: {errs}")
    assert ok, errs
