"""Fuzz of the command line (issue 15, item 7): a table of bad invocations of every subcommand
beside tests/test_cli_params.py's sweep of every ``--param``. Each is ``clean`` when it exits 2
with at most three lines on stderr and no traceback, leaves no output file, and did not run
the experiment."""

from __future__ import annotations

import contextlib
import io

import pytest

from nlfilter import cli

MODEL = "examples/models/cubic-sensor.toml"
_PENDULUM = (__import__("pathlib").Path(__file__).parents[2] / "examples" / "models" / "pendulum.toml").read_text()


def _invocations(tmp):
    d = tmp / "exists-as-dir"
    d.mkdir()
    f = tmp / "exists-as-file"
    f.write_text("x")
    bad_toml = tmp / "bad.toml"
    bad_toml.write_text("[model\nname = 1\n")
    empty_toml = tmp / "empty.toml"
    empty_toml.write_text("")
    acos = tmp / "acos.toml"  # issue 26: a SymPy TypeError and an OverflowError reached the command line
    acos.write_text(_PENDULUM.replace("Q = [[0.001]]", 'Q = [["acos(2)"]]'))
    digits = tmp / "digits.toml"
    digits.write_text(_PENDULUM.replace("g = 9.81", "g = 1" + "0" * 400))
    tower = tmp / "tower.toml"
    tower.write_text(_PENDULUM.replace('"sin(theta)"', '"9**9**9"'))
    store = tmp / "st.sqlite"
    from nlfilter.store import ResultsStore
    ResultsStore(store).close()
    foreign = tmp / "other.sqlite"
    import sqlite3
    with sqlite3.connect(foreign) as db:
        db.execute("CREATE TABLE notes (x)")
    q = ["reproduce", "cubic-sensor", "--quick", "--no-progress", "--no-store"]
    c = ["compare", MODEL, "--no-progress", "--paths", "4", "--steps", "3"]
    return [
        ("no command", []),
        ("unknown command", ["frobnicate"]),
        ("unknown experiment", ["reproduce", "no-such-experiment", "--quick"]),
        ("runs 0", q + ["--runs", "0"]),
        ("runs -1", q + ["--runs", "-1"]),
        ("runs abc", q + ["--runs", "abc"]),
        ("runs 2.5", q + ["--runs", "2.5"]),
        ("runs 10^12", q + ["--runs", "1000000000000"]),
        ("seed -1", q + ["--seed", "-1"]),
        ("seed abc", q + ["--seed", "abc"]),
        ("chunk 0", q + ["--chunk", "0"]),
        ("chunk -3", q + ["--chunk", "-3"]),
        ("param without =", q + ["--param", "q"]),
        ("unknown param", q + ["--param", "nosuch=1"]),
        ("json into a missing folder", q + ["--json", str(tmp / "missing" / "x.json")]),
        ("json empty path", q + ["--json", ""]),
        ("json is a folder", q + ["--json", str(d)]),
        ("plot with a bad suffix", q + ["--plot", str(tmp / "fig.xyz")]),
        ("plot is a folder", q + ["--plot", str(d)]),
        ("report is a file", q[:1] + ["all", "--quick", "--no-progress", "--no-store", "--report", str(f)]),
        ("store is a folder", q[:-1] + ["--store", str(d)]),
        ("executor unknown", q + ["--executor", "cloud"]),
        ("workers 0", q + ["--executor", "dask", "--workers", "0"]),
        ("workers without dask", q + ["--workers", "2"]),
        ("compare missing file", ["compare", str(tmp / "nope.toml")]),
        ("compare malformed toml", ["compare", str(bad_toml)]),
        ("compare empty toml", ["compare", str(empty_toml)]),
        ("compare a folder", ["compare", str(d)]),
        ("compare paths 0", c + ["--paths", "0"]),
        ("compare steps -1", c + ["--steps", "-1"]),
        ("compare unknown filter", c + ["--filters", "no-such-filter"]),
        ("compare empty filter list", c + ["--filters", ""]),
        ("compare block -1", c + ["--block", "-1"]),
        ("compare json bad suffix", c + ["--json", str(tmp / "x.txt")]),
        ("results show missing run", ["results", "show", "999999", "--store", str(tmp / "s.sqlite")]),
        ("results show abc", ["results", "show", "abc", "--store", str(tmp / "s.sqlite")]),
        ("results export no format", ["results", "export", "--store", str(tmp / "s.sqlite")]),
        ("results export into a missing folder", ["results", "export", "--csv", str(tmp / "missing" / "x.csv"),
                                                  "--store", str(tmp / "s.sqlite")]),
        ("results store is a folder", ["results", "list", "--store", str(d)]),
        ("list unknown flag", ["list", "--bogus"]),
        ("compare acos(2) in Q", ["compare", str(acos), "--no-progress"]),
        ("compare a 400-digit parameter", ["compare", str(digits), "--no-progress"]),
        ("compare 9**9**9", ["compare", str(tower), "--no-progress"]),
        ("seed 2**70", q + ["--seed", str(2**70)]),
        ("seed 2**70 with a store", q[:-1] + ["--store", str(store), "--seed", str(2**70)]),
        ("results export csv empty path", ["results", "export", "--csv", "", "--store", str(store)]),
        ("results export json under the proc folder", ["results", "export", "--json", "/proc/nlfilter-x.json", "--store",
                                             str(store)]),
        ("results list on another program's database", ["results", "list", "--store", str(foreign)]),
    ]


def _run(argv):
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = cli.main(argv)
        except SystemExit as exc:  # argparse's own errors
            code = exc.code
        except BaseException as exc:  # noqa: BLE001 - an escaping exception is what we count
            return "raised", f"{type(exc).__name__}: {exc}", ""
    return code, err.getvalue(), out.getvalue()


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("cli-fuzz")


def _labels():
    import pathlib
    import tempfile
    with tempfile.TemporaryDirectory() as t:
        return [label for label, _ in _invocations(pathlib.Path(t))]


@pytest.mark.parametrize("label", _labels())
def test_bad_invocation_exits_2_with_one_short_message(fuzz, tmp, label, monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).parents[2])
    sub = tmp / label.replace(" ", "-")
    sub.mkdir()
    argv = dict(_invocations(sub))[label]
    before = set(p for p in sub.rglob("*"))
    code, err, _ = _run(argv)
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    written = set(p for p in sub.rglob("*")) - before
    clean = code == 2 and 1 <= len(lines) <= 3 and "Traceback" not in err and not written
    fuzz.count("command line", "clean" if clean else "unclean", clean, label=f"{label}: exit {code}, {err[:300]!r}")
    assert clean, (label, code, err[-2000:], written)
