"""Lossless results: provenance, the parameters that ran, unique rows, the JSON round trip."""

import json
import math

import numpy as np
import pytest

from nlfilter import __version__, cli
from nlfilter.experiments import registry
from nlfilter.results import Result, Row

# the parameter of each experiment's Result.params that holds the simulated horizon (int, or
# {case: int}); the simulators' calls are recorded by the quick run (tests/conftest.py)
HORIZON = {"cubic-sensor": "steps", "cubic-sensor-closures": "steps", "linear-gaussian": "steps",
           "moment-first-order": "T", "moment-second-order": "T", "oh-shin": "steps",
           "phase-tracking": "steps", "second-order": "problem_steps", "zero-order": None,
           "zero-order-adaptive": "n_max", "zero-order-robustness": "n", "smoothing": "steps",
           "square-root": "problem_steps"}
# and the one that holds the simulated paths: "paths", but zero-order's Table 1 check draws its
# "paths" i.i.d. samples as sample_paths paths of samples_per_path samples (per-path streams)
PATHS = {"zero-order": "sample_paths"}
HORIZON["zero-order"] = "samples_per_path"


@pytest.fixture
def quick_runs(quick_reproduction):
    """One quick run per experiment, ``{id: (Result, [(steps, paths) of each simulation])}``: those
    of ``nlfilter reproduce all --quick`` (tests/conftest.py), shared with tests/test_report.py."""
    return quick_reproduction.runs


def _values(v):
    return set(v.values()) if isinstance(v, dict) else {v}


def test_registry_covered():
    assert set(HORIZON) == set(registry())


def test_json_round_trip_every_experiment(quick_runs, tmp_path):
    for eid, (res, _) in quick_runs.items():
        path = tmp_path / f"{eid}.json"
        res.to_json(path)
        back = Result.from_json(path)
        assert back == res, eid
        assert back.to_dict() == json.loads(path.read_text()), eid
        assert back.notes == res.notes and back.notes, eid
        assert back.series == {}  # figures' arrays are not in the JSON


def test_meta_records_what_ran(quick_runs):
    for eid, (res, _) in quick_runs.items():
        m = res.meta
        assert (m["experiment"], m["seed"], m["runs"], m["quick"], m["given"]) == (eid, 0, None, True, {}), eid
        assert m["paths"] == res.params["paths"], eid
        assert m["nlfilter"] == __version__ and m["numpy"] == np.__version__ and m["timestamp"].endswith("+00:00")


def test_params_are_the_shapes_simulated(quick_runs):
    """Recorded paths and horizon = the (steps, paths) every simulator call of the quick run got."""
    for eid, (res, calls) in quick_runs.items():
        assert calls, eid
        assert {p for _, p in calls} == _values(res.params[PATHS.get(eid, "paths")]), eid
        key = HORIZON[eid]
        assert {s for s, _ in calls} == (_values(res.params[key]) if key else {1}), eid


def test_quick_params_differ_from_defaults_where_quick_overrides(quick_runs):
    """The declared parameters a quick run changes are exactly those its code overrides."""
    changed = {eid: {k for k, v in exp.params.items() if quick_runs[eid][0].params[k] != v}
               for eid, exp in registry().items()}
    assert changed == {
        "cubic-sensor": {"T", "burn"}, "cubic-sensor-closures": {"t_end", "burn_in", "grid_size"},
        "linear-gaussian": {"steps", "grid", "particles"}, "moment-first-order": {"T", "skip", "grid"},
        "moment-second-order": {"T", "skip", "particles"}, "oh-shin": {"grid_size"},
        "phase-tracking": {"time_constants", "discard", "grid", "sweep"},
        "second-order": {"grid_size", "fb_particles", "fb_pf_runs"}, "zero-order": set(),
        "zero-order-adaptive": {"n_max"}, "zero-order-robustness": {"n"}, "smoothing": {"steps", "particles"},
        "square-root": {"long_steps"}}
    cubic = quick_runs["cubic-sensor"][0].params
    assert (cubic["T"], cubic["burn"], cubic["paths"]) == (5.0, 2.5, 64)  # not the defaults T = 60, burn = 5


def test_rows_unique_in_every_experiment(quick_runs):
    for eid, (res, _) in quick_runs.items():
        keys = [r.key() for r in res.rows]
        assert len(keys) == len(set(keys)), eid
    pt = quick_runs["phase-tracking"][0]
    off = pt.get("tensor", "mse_x1", P=0.129, method="off-line")
    mc = pt.get("tensor", "mse_x1", P=0.129, method="monte carlo")
    assert off.stderr is None and mc.stderr is not None


def test_add_refuses_a_duplicate_key():
    res = Result("t", "t", "s", {})
    res.add("kf", "mse", 1.0, P=0.1)
    res.add("kf", "mse", 1.0, P=0.2)
    with pytest.raises(ValueError, match=r"\('kf', 'mse', \{'P': 0.1\}\)"):
        res.add("kf", "mse", 2.0, P=0.1)


def test_non_finite_round_trip_exact(tmp_path):
    res = Result("t", "t", "s", {"tol": math.inf, "x": [math.nan, 1.0]}, notes=["a note"], meta={"seed": None})
    res.add("a", "v", math.nan, stderr=math.inf, paper=-math.inf)
    res.add("b", "v", 0.1 + 0.2, stderr=None, paper=None, k=np.int64(3))
    path = tmp_path / "r.json"
    res.to_json(path)  # allow_nan=False: would raise on a bare NaN
    d = json.loads(path.read_text())
    assert d["rows"][0]["value"] == "nan" and d["rows"][0]["stderr"] == "inf" and d["rows"][0]["paper"] == "-inf"
    back = Result.from_json(path)
    a, b = back.rows
    assert math.isnan(a.value) and a.stderr == math.inf and a.paper == -math.inf
    assert b.value == 0.1 + 0.2 and b.stderr is None and b.params == {"k": 3}
    assert back.params["tol"] == math.inf and math.isnan(back.params["x"][0])
    assert back.rows == res.rows and back.notes == ["a note"] and back.meta == {"seed": None}


def test_from_json_rejects_what_is_not_a_result():
    with pytest.raises(ValueError, match="missing"):
        Result.from_json({"experiment": "x"})
    with pytest.raises(ValueError, match="number"):
        Row.from_dict({"filter": "f", "quantity": "q", "value": "oops"})


def test_cli_json_has_provenance(tmp_path, capsys):
    path = tmp_path / "lg.json"
    argv = ["reproduce", "linear-gaussian", "--quick", "--runs", "5", "--seed", "2", "--no-progress",
            "--param", "steps=20", "--json", str(path)]
    assert cli.main(argv) == 0
    d = json.loads(path.read_text())
    m = d["meta"]
    assert (m["experiment"], m["seed"], m["runs"], m["paths"], m["quick"]) == ("linear-gaussian", 2, 5, 5, True)
    assert m["given"] == {"steps": 20} and m["command"] == "nlfilter " + " ".join(argv)
    assert d["params"]["steps"] == 20 and d["params"]["paths"] == 5
    assert d["notes"] and "5 paths" in d["notes"][0]
    assert Result.from_json(path).to_dict() == d
