"""The experiment registry (:data:`nlfilter.experiments.EXPERIMENTS`) is the one place an experiment is
stated, and it is read without importing any experiment (issue 28, item 5): ``nlfilter list`` and
``import nlfilter`` load neither SymPy, SciPy, numba nor matplotlib, nor the filters (``nlfilter
results list`` not even NumPy). The mechanism is tested (which modules a fresh process imported,
from ``-X importtime``), not the time it takes (~0.15 s of CPU against ~3.5 s before)."""

from __future__ import annotations

import inspect
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

from nlfilter import experiments

# what the cheap paths must not load: the heavy dependencies (SymPy, SciPy, numba, matplotlib: seconds
# of CPU between them) and nlfilter's filters and experiment modules, which import them
HEAVY = ("sympy", "scipy", "numba", "matplotlib", "nlfilter.filters")
SRC = str(Path(experiments.__file__).resolve().parents[2])


def _imported(args: list[str]) -> tuple[set[str], str]:
    """The modules a fresh ``python -X importtime ARGS`` imports (every module of the process is
    printed once, when first imported) and its standard output."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([SRC, os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-X", "importtime", *args], capture_output=True, text=True, env=env,
                         check=True, timeout=60)
    mods = {line.rpartition("|")[2].strip() for line in out.stderr.splitlines() if line.startswith("import time:")}
    assert "nlfilter" in mods, out.stderr[-500:]  # the listing is what we think it is
    return mods, out.stdout


def _heavy(mods: set[str]) -> set[str]:
    return {m for m in mods if m in HEAVY or m.startswith(tuple(h + "." for h in HEAVY))
            or (m.startswith("nlfilter.experiments.") and m != "nlfilter.experiments")}


@pytest.mark.parametrize("args", [["-c", "import nlfilter"], ["-m", "nlfilter.cli", "list"],
                                  ["-m", "nlfilter.cli", "list", "--params"]], ids=" ".join)
def test_cheap_paths_import_nothing_heavy(args):
    mods, out = _imported(args)
    assert not _heavy(mods), sorted(_heavy(mods))
    if "list" in args:  # and it printed the registry, every experiment on its line
        assert [line.split("\t")[0] for line in out.splitlines() if not line.startswith(" ")] == \
            list(experiments.registry())


def test_results_list_imports_nothing_heavy(tmp_path):
    from nlfilter.store import ResultsStore

    path = tmp_path / "r.sqlite"
    with ResultsStore(path) as st:
        st.finish_run(st.start_run("demo", params={}, seed=0, runs=1, quick=True, command="demo"), "failed")
    mods, out = _imported(["-m", "nlfilter.cli", "results", "list", "--store", str(path)])
    assert not _heavy(mods) and "numpy" not in mods, sorted(_heavy(mods))
    assert "demo" in out


def test_the_check_sees_an_import():
    """The listing holds what a process imports, NumPy here (so the test above can fail), and the check
    names the heavy modules of a listing."""
    mods, _ = _imported(["-c", "import nlfilter, numpy"])
    assert {"numpy", "numpy.linalg"} <= mods and not _heavy(mods)
    assert _heavy({"nlfilter", "nlfilter.experiments", "nlfilter.experiments.oh_shin", "nlfilter.filters.ekf",
                   "numpy", "sympyx"}) == {"nlfilter.experiments.oh_shin", "nlfilter.filters.ekf"}


def test_every_module_registered_and_every_entry_found():
    """Each module of the package (but the ``_`` helpers) holds a registered experiment; each entry's
    ``"module:function"`` names a function of this package that takes what :meth:`Experiment.run`
    passes."""
    modules = {f"{experiments.__name__}.{m.name}" for m in pkgutil.iter_modules(experiments.__path__)
               if not m.name.startswith("_")}
    reg = experiments.registry()
    assert {e.target.partition(":")[0] for e in reg.values()} == modules
    assert list(reg) == sorted(reg)  # nlfilter list prints them by id
    for eid, exp in reg.items():
        fn = exp.func
        assert callable(fn) and fn.__module__ == exp.target.partition(":")[0], eid
        inspect.signature(fn).bind(dict(exp.params), quick=True, runs=None, seed=0, progress=False)


def test_moment_laws_are_the_registered_choices():
    from nlfilter.experiments.moment_systems import LAWS

    for eid in ("moment-first-order", "moment-second-order"):
        exp = experiments.get(eid)
        assert exp.ranges["laws"] == tuple(LAWS) and exp.params["laws"] == list(LAWS), eid


def test_entries_are_checked_when_stated():
    def entry(id, ranges=None):
        return experiments.Experiment(id, "t", "s", {"a": 1}, "nlfilter.experiments.linear_gaussian:run",
                                      ranges or {})

    with pytest.raises(ValueError, match="'x' registered twice"):
        experiments._index(entry("x"), entry("y"), entry("x"))
    with pytest.raises(ValueError, match=r"ranges of 'x': \['b'\] are not parameters"):
        entry("x", {"b": ">0"})
    with pytest.raises(ValueError, match="experiment 'nope': unknown; expected one of"):
        experiments.get("nope")
