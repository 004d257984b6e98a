"""The block-structured Monte Carlo (nlfilter.montecarlo) and the results store (nlfilter.store):
identical numbers for any executor, worker count and chunk; an interrupted run resumes without
recomputing its finished blocks; Ctrl-C on the command line exits 130 with one line and leaves
the store consistent; ``nlfilter results list | show | export``.

"Identical" here is bitwise: every block is computed as its own batch from per-path streams, so
who computes it (this process, a Dask worker) and how blocks are grouped into tasks (the chunk)
cannot change its arithmetic. The JSON compared is the whole result file except ``meta``'s
timestamp and ``meta["execution"]``, which record how the run was computed by design."""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pytest

from nlfilter import cli, montecarlo
from nlfilter.experiments import get
from nlfilter.experiments import cubic_sensor as cs
from nlfilter.experiments import moment_systems as ms
from nlfilter.store import ResultsStore

# the quick second-order moment system on one input law and one N: 5 paths = blocks of 2, 2 and 1,
# ~1 s a run (phase tracking, used before, runs ~5 s of Monte Carlo and, once per process, ~10 s
# off-line: how blocks are computed, grouped, sent to Dask workers and resumed is the experiment's
# business only through its block function)
EXP = "moment-second-order"
PARAMS = {"laws": ["uniform"], "N": [2], "particles": 200, "T": 30, "skip": 10, "block": 2}


def _json(res) -> str:
    d = res.to_dict()
    d["meta"].pop("timestamp")
    d["meta"].pop("execution")
    return json.dumps(d, sort_keys=True)


@pytest.fixture(scope="module")
def reference():
    return get(EXP).run(PARAMS, quick=True, runs=5, seed=1)


@pytest.fixture(scope="module")
def scheduler():
    """The address of one 2-worker LocalCluster for this module's Dask tests, started by the
    executor as a run starts its own (single-threaded worker processes, their stderr quiet): each
    LocalCluster costs its processes' start-up and imports (~3 s of CPU a worker), so the tests share
    one; how a run starts and closes a cluster of its own is tested once (``workers=1``)."""
    pytest.importorskip("dask.distributed")
    ex = montecarlo.DaskExecutor(workers=2)
    try:
        yield ex._cluster.scheduler_address
    finally:
        ex.close()


def test_chunks_give_identical_json(reference):
    exp = get(EXP)
    for chunk in (1, 3, 4, 100):
        assert _json(exp.run(PARAMS, quick=True, runs=5, seed=1, chunk=chunk)) == _json(reference), chunk


def test_dask_workers_give_identical_json(reference, scheduler):
    exp = get(EXP)
    for workers, chunk, address in ((1, None, None), (None, None, scheduler), (None, 4, scheduler)):
        res = exp.run(PARAMS, quick=True, runs=5, seed=1, executor="dask", workers=workers, chunk=chunk,
                      scheduler=address)
        assert res.meta["execution"]["executor"] == "dask" and res.meta["execution"]["workers"] == (workers or 2)
        assert res.meta["execution"]["blocks_computed"] == 3
        assert _json(res) == _json(reference), (workers, chunk)


def _crash_at(monkeypatch, module, name, n):
    """Replace the block function ``module.name`` by one that records the rows it is called on
    and "crashes" the process (KeyboardInterrupt, as Ctrl-C would) at its ``n``-th call, once."""
    real, calls, armed = getattr(module, name), [], [True]

    def flaky(rows, **kw):
        calls.append(rows)
        if len(calls) == n and armed[0]:
            armed[0] = False
            raise KeyboardInterrupt
        return real(rows, **kw)

    monkeypatch.setattr(module, name, flaky)
    return calls


def test_interrupted_run_resumes_only_unfinished_blocks(tmp_path, monkeypatch, reference):
    calls = _crash_at(monkeypatch, ms, "_second_order_block", 3)
    exp = get(EXP)
    with ResultsStore(tmp_path / "s.sqlite") as st:
        with pytest.raises(KeyboardInterrupt):
            exp.run(PARAMS, quick=True, runs=5, seed=1, store=st)
        assert st.count_blocks(EXP) == 2
        calls.clear()
        res = exp.run(PARAMS, quick=True, runs=5, seed=1, store=st)
        assert [(r.start, r.stop) for r in calls] == [(4, 5)]  # only the unfinished block
        assert (res.meta["execution"]["blocks_reused"], res.meta["execution"]["blocks_computed"]) == (2, 1)
        assert _json(res) == _json(reference)
        calls.clear()  # a larger run reuses the blocks it shares (the same path ranges)
        more = exp.run(PARAMS, quick=True, runs=6, seed=1, store=st)
        assert [(r.start, r.stop) for r in calls] == [(4, 6)]
        assert more.params["paths"] == 6
        calls.clear()  # another seed, another key: nothing reused
        exp.run(PARAMS, quick=True, runs=2, seed=2, store=st)
        assert [(r.start, r.stop) for r in calls] == [(0, 2)]


# quick cubic sensor, one (q, r): 5 paths = blocks of 2, 2 and 1; a step dt of 0.1 (50 steps of the
# quick T = 5, not the automatic ~1400): how blocks resume does not depend on the step
CUBIC = {"q": [2.0], "r": [1.0], "block": 2, "dt": 0.1}


def test_cubic_sensor_resumes_only_unfinished_blocks(tmp_path, monkeypatch):
    exp = get("cubic-sensor")
    reference = exp.run(CUBIC, quick=True, runs=5, seed=1)
    calls = _crash_at(monkeypatch, cs, "_cubic_block", 2)
    with ResultsStore(tmp_path / "s.sqlite") as st:
        with pytest.raises(KeyboardInterrupt):
            exp.run(CUBIC, quick=True, runs=5, seed=1, store=st)
        assert st.count_blocks("cubic-sensor") == 1
        calls.clear()
        res = exp.run(CUBIC, quick=True, runs=5, seed=1, store=st)
        assert [(r.start, r.stop) for r in calls] == [(2, 4), (4, 5)]  # only the unfinished blocks
        assert (res.meta["execution"]["blocks_reused"], res.meta["execution"]["blocks_computed"]) == (1, 2)
        assert _json(res) == _json(reference)
        assert any(r.quantity == "diverged_fraction" for r in res.rows)  # the per-path flags came back too


def test_montecarlo_checks_block_functions(tmp_path):
    with pytest.raises(TypeError, match="dict of per-path arrays"):
        montecarlo.montecarlo("t", lambda rows: [1.0], 3, block=2)
    with pytest.raises(ValueError, match="leading axis of 2"):
        montecarlo.montecarlo("t", lambda rows: {"a": np.zeros(7)}, 3, block=2)
    with pytest.raises(ValueError, match="block: expected a positive integer"):
        montecarlo.montecarlo("t", lambda rows: {"a": np.zeros(len(rows))}, 3, block=0)
    with ResultsStore(tmp_path / "s.sqlite") as st, montecarlo.session(store=st, experiment="x"):
        with pytest.raises(ValueError, match="ident"):
            montecarlo.montecarlo("t", lambda rows: {"a": np.zeros(len(rows))}, 3)
    with pytest.raises(ValueError, match="executor"):
        with montecarlo.session(executor="spark"):
            pass
    with pytest.raises(ValueError, match="store.*folder"):
        ResultsStore(tmp_path)


def _default_sigint():  # a shell's background job starts with SIGINT ignored; Python then
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # installs no KeyboardInterrupt handler: restore it


def _cli(*args, **kw):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [os.path.join(os.path.dirname(__file__), "..", "src"),
                                                                     os.environ.get("PYTHONPATH")]))}
    return subprocess.Popen([sys.executable, "-m", "nlfilter.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, preexec_fn=_default_sigint, **kw)


def test_ctrl_c_exits_130_and_the_rerun_resumes(tmp_path):
    store = tmp_path / "s.sqlite"
    out = tmp_path / "out.json"
    # blocks of one path, ~1 s each after ~2 s of start-up (the quick linear-Gaussian run: its grid
    # and particle references; phase-tracking, used before, spends ~12 s off-line in each of the
    # three processes): the interrupt lands after 2 blocks with 4 to go
    runs = 6
    args = ["reproduce", "linear-gaussian", "--quick", "--runs", str(runs), "--seed", "4", "--param", "block=1",
            "--no-progress", "--store", str(store), "--json", str(out)]
    p = _cli(*args)
    deadline = time.time() + 120
    blocks = 0
    while time.time() < deadline and p.poll() is None:  # wait for the first finished block
        time.sleep(0.2)
        if store.exists():
            try:
                with sqlite3.connect(store) as db:
                    blocks = db.execute("SELECT COUNT(*) FROM blocks").fetchone()[0]
            except sqlite3.OperationalError:  # the schema is not there yet
                blocks = 0
            if blocks >= 2:
                break
    assert p.poll() is None, "the run ended before it could be interrupted"
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 130, stderr
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr, stderr
    assert "interrupted" in stderr and str(store) in stderr
    assert not out.exists()  # no partial JSON
    with ResultsStore(store) as st:
        kept = st.count_blocks("linear-gaussian")
        assert 2 <= kept < runs
        assert st.runs()[0]["status"] == "interrupted"
    p = _cli(*args)
    stdout, stderr = p.communicate(timeout=300)
    assert p.returncode == 0, stderr
    assert f"reused {kept} finished Monte Carlo block(s)" in stderr
    resumed = json.loads(out.read_text())
    assert resumed["meta"]["execution"]["blocks_computed"] == runs - kept
    # the uninterrupted run, in a process of its own too (the off-line rows' last bit may depend on
    # the process's BLAS thread count, which the Monte Carlo blocks pin to 1)
    fresh_out = tmp_path / "fresh.json"
    p = _cli(*[a if a != str(out) else str(fresh_out) for a in args if a not in ("--store", str(store))], "--no-store")
    assert p.communicate(timeout=300)[0] and p.returncode == 0
    fresh = json.loads(fresh_out.read_text())
    assert resumed["rows"] == fresh["rows"] and resumed["notes"] == fresh["notes"]
    assert fresh["meta"]["execution"]["blocks_computed"] == runs and fresh["meta"]["execution"]["store"] is None


def test_results_list_show_export(tmp_path, capsys):
    store = str(tmp_path / "s.sqlite")
    base = ["reproduce", "linear-gaussian", "--quick", "--runs", "4", "--param", "steps=20", "--no-progress",
            "--store", store]
    assert cli.main(base) == 0
    assert cli.main(base + ["--seed", "3"]) == 0
    capsys.readouterr()
    assert cli.main(["results", "list", "--store", store]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].split("\t")[:3] == ["run", "experiment", "status"]
    assert [ln.split("\t")[:4] for ln in lines[1:]] == [["2", "linear-gaussian", "done", "3"],
                                                        ["1", "linear-gaussian", "done", "0"]]
    assert cli.main(["results", "show", "1", "--store", store]) == 0
    shown = capsys.readouterr().out
    assert "run 1: linear-gaussian (done" in shown and "riccati" in shown
    csv_path, json_path = tmp_path / "rows.csv", tmp_path / "all.json"
    assert cli.main(["results", "export", "1", "2", "--csv", str(csv_path), "--store", store]) == 0
    import csv
    rows = list(csv.DictReader(csv_path.open()))
    with ResultsStore(store) as st:
        r1, r2 = st.run(1)["result"], st.run(2)["result"]
    assert len(rows) == len(r1.rows) + len(r2.rows)
    first = rows[0]
    assert first["run"] == "1" and first["experiment"] == "linear-gaussian"
    assert float(first["value"]) == r1.rows[0].value
    assert cli.main(["results", "export", "--json", str(json_path), "--store", store]) == 0  # latest per experiment
    data = json.loads(json_path.read_text())
    assert [d["run"] for d in data] == [2] and data[0]["rows"] == r2.to_dict()["rows"]
    capsys.readouterr()
    for argv in (["results", "show", "99", "--store", store], ["results", "list", "--store", str(tmp_path / "none.sqlite")],
                 ["results", "export", "--csv", str(tmp_path / "no" / "x.csv"), "--store", store]):
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("nlfilter: error:"), err


def test_output_paths_are_checked_before_the_run(tmp_path, capsys, monkeypatch):
    from nlfilter import experiments
    monkeypatch.setattr(experiments.Experiment, "run", lambda *a, **k: pytest.fail("the run started"))
    for opt, path in (("--json", str(tmp_path / "missing" / "a.json")), ("--json", ""), ("--plot", str(tmp_path / "fig.xyz")),
                      ("--plot", str(tmp_path))):
        assert cli.main(["reproduce", "phase-tracking", opt, path, "--no-progress"]) == 2  # refused up front
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and opt in err[0], err
    monkeypatch.undo()
    assert cli.main(["reproduce", "linear-gaussian", "--quick", "--workers", "2"]) == 2
    assert "--executor dask" in capsys.readouterr().err


def _own_block(rows, *, flt, model):
    """A user's block function: simulate the paths ``rows`` of ``model`` and reduce each to the
    filter's mean squared error (per-path streams: the same path numbers in any block)."""
    from nlfilter.simulate import simulate
    sim = simulate(model, 30, paths=rows, rng=11, m0=0.5, P0=0.1)
    est = flt.run(sim.ys, [0.5], [[0.1]])
    return {"mse": ((est.means - sim.xs) ** 2).mean(axis=(1, 2))}


def test_a_users_filter_sweep_runs_on_dask(scheduler):
    """Filters built from a SymPy model pickle to Dask workers (the model's lazily generated
    functions travel without their weak back-reference) and give the local numbers bitwise."""
    import functools

    import cloudpickle
    import sympy as sp

    from nlfilter import DiscreteModel
    from nlfilter.filters import REGISTRY

    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[0.9 * x + 0.1 * sp.sin(x)], h=[x ** 3], Q=0.1, R=0.5)
    names = ("ekf", "ukf", "second-order")
    for name in names:  # pickles before and after first use
        flt = REGISTRY[name].for_model(md)
        cloudpickle.loads(cloudpickle.dumps(flt))
        flt.run(np.zeros((1, 3, 1)), [0.5], [[0.1]])
        cloudpickle.loads(cloudpickle.dumps(flt))
    local = {n: montecarlo.montecarlo(n, functools.partial(_own_block, flt=REGISTRY[n].for_model(md), model=md), 7,
                                      block=3)["mse"] for n in names}
    with montecarlo.session(executor="dask", scheduler=scheduler, chunk=3):
        remote = {n: montecarlo.montecarlo(n, functools.partial(_own_block, flt=REGISTRY[n].for_model(md), model=md),
                                           7, block=3)["mse"] for n in names}
    for n in names:
        assert local[n].shape == (7,) and np.array_equal(local[n], remote[n]), n


def _compare_json(res) -> str:
    d = res.to_dict()
    d["meta"].pop("timestamp")
    d["meta"].pop("execution")
    for r in d["params"]["reference"]["rungs"]:  # the certificate records its own wall time
        r.pop("seconds", None)
    d["params"]["reference"].pop("seconds", None)
    d["notes"] = [re.sub(r", [0-9.]+ s\)", ")", n) for n in d["notes"]]  # and its note
    return json.dumps(d, sort_keys=True)


def test_compare_runs_on_dask_with_identical_json(scheduler):
    """``compare`` on a 2-worker LocalCluster — its filters and the reference's rungs as tasks, one
    per filter and block of paths — writes the JSON of the local run, bitwise; and a block split
    of the paths changes no number beyond the last bits of a batch's arithmetic."""
    import sympy as sp

    from nlfilter import DiscreteModel
    from nlfilter.comparison import compare

    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[0.9 * x + 0.2 * sp.sin(x)], h=[x ** 2 / 4 + x], Q=0.1, R=0.3)
    kw = dict(paths=24, m0=0.5, P0=0.2, rng=3, block=8)
    from nlfilter.filters import EKF, UKF, ParticleFilter
    filters = {"ekf": EKF(md), "ukf": UKF(md), "pf": ParticleFilter(md, 300)}  # one that draws
    local = compare(md, filters, 20, executor="local", **kw)
    remote = compare(md, filters, 20, executor="dask", scheduler=scheduler, **kw)
    assert remote.meta["execution"]["executor"] == "dask" and remote.meta["execution"]["workers"] == 2
    assert local.params["block"] == 8 and local.params["reference"]["kind"] == "grid"
    assert _compare_json(remote) == _compare_json(local)
    one = compare(md, filters, 20, **dict(kw, block=None))  # all paths as one batch
    for r in local.rows:
        o = one.get(r.filter, r.quantity, **r.params)
        assert o.value == pytest.approx(r.value, rel=1e-12, abs=1e-15), (r.filter, r.quantity)
