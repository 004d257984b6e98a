import collections
import json
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import sympy as sp

from nlfilter.models import DiscreteModel


@pytest.fixture
def nonlinear3():
    """A random-ish nonlinear 3-state model with state-dependent G, used across tests."""
    x1, x2, x3 = sp.symbols("x1 x2 x3")
    f = [x1 + 0.1 * x2, 0.95 * x2 - 0.1 * sp.sin(x1) + 0.02 * x3**2, 0.9 * x3 + 0.05 * x1 * x2]
    h = [x1**2 / 4 + x3, sp.atan(x2) + 0.3 * x1]
    G = [[1, 0], [0.1 * x1, 1], [0, 0.5 + 0.1 * x3**2]]
    return DiscreteModel([x1, x2, x3], f, h, G, Q=np.diag([0.02, 0.05]), R=np.diag([0.1, 0.2]))


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _check_figure(result, tmp_path, expect: dict, paper=()):
    """Draw ``result`` and check its panels: exactly the panels of ``expect`` (name -> labels each
    must draw), finite arrays of matching lengths, x increasing, bands ordered, and the paper's
    values present in the panels named in ``paper``. Returns the PNG path."""
    import struct

    from nlfilter.plots import plot_result

    assert set(result.series) == set(expect)
    for name, panel in result.series.items():
        if panel.get("kind", "line") == "bar":
            k = len(panel["categories"])
            assert k >= 1 and set(expect[name]) <= set(panel["bars"])
            for label, y in panel["bars"].items():
                assert len(y) == k and np.all(np.isfinite(y)), (name, label)
            for label, e in panel.get("errors", {}).items():
                assert len(e) == k and np.all(np.asarray(e) >= 0), (name, label)
            has_paper = any(v is not None for vals in panel.get("paper", {}).values() for v in vals)
        else:
            x = np.asarray(panel["x"], dtype=float)
            assert x.ndim == 1 and x.size >= 2 and np.all(np.isfinite(x)) and np.all(np.diff(x) > 0), name
            assert set(expect[name]) <= set(panel["lines"]), (name, set(panel["lines"]))
            for label, y in panel["lines"].items():
                y = np.asarray(y, dtype=float)
                assert y.shape == x.shape and np.all(np.isfinite(y)), (name, label)
            for label, (lo, hi) in panel.get("bands", {}).items():
                assert np.shape(lo) == x.shape and np.all(np.asarray(lo) <= np.asarray(hi)), (name, label)
            has_paper = bool(panel.get("paper"))
            for px, py in panel.get("paper", {}).values():
                assert np.all(np.isfinite(py)) and (px is None or np.size(px) == np.size(py))
        assert has_paper == (name in paper), name
        assert panel.get("ylabel"), name
    path = tmp_path / f"{result.experiment}.png"
    plot_result(result, path)
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    w, h = struct.unpack(">II", data[16:24])  # IHDR: width, height
    assert 600 <= w <= 3000 and 300 <= h <= 2000
    assert 15_000 < len(data) < 600_000
    return path


@pytest.fixture
def check_figure(tmp_path):
    """``check_figure(result, expect, paper=())``: see :func:`_check_figure`."""
    return lambda result, expect, paper=(): _check_figure(result, tmp_path, expect, paper)


@pytest.fixture(scope="session", autouse=True)
def _post_processor_computed_once(tmp_path_factory):
    """``phase-tracking``'s off-line part, the post-processor fits of Figs. 4.3-4.4 (about 12 s of
    the 14 s of a quick run: the quintic fits at small ``P``), computed once per test run.

    The fit is a deterministic function of ``(P, degree, q)`` (exact steady-state moments, no
    random numbers), so a repeated call returns what the first one computed: the same object in
    a process, its pickle (the same numbers, bit for bit) in another xdist worker of the run;
    the many quick runs of the experiment in the tests (chunks and resume in
    experiments/test_chunks, test_results, test_report) then cost only their Monte Carlo. Only the
    experiment's module is patched: tests of ``post_processor`` itself (tests/filters) call the
    function."""
    import pickle

    from nlfilter.experiments import phase_tracking

    real, fits = phase_tracking.post_processor, {}
    base = tmp_path_factory.getbasetemp()
    shared = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "post-processor-fits"
    shared.mkdir(exist_ok=True)

    def once(P, *, degree=3, q=1.0):
        key = (float(P), int(degree), float(q))
        if key not in fits:
            path = shared / f"{key[0]!r}-{key[1]}-{key[2]!r}.pickle"
            try:
                fits[key] = pickle.loads(path.read_bytes())
            except (OSError, pickle.UnpicklingError, EOFError):
                fits[key] = real(P, degree=degree, q=q)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_bytes(pickle.dumps(fits[key]))
                os.replace(tmp, path)  # whole or absent for another worker
        return fits[key]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(phase_tracking, "post_processor", once)
        yield


class QuickReproduction(NamedTuple):
    """What :func:`quick_reproduction` ran: the report folder, the command's arguments, and
    ``runs``: ``{experiment id: (Result, [(steps, paths) of every simulation it made])}``."""

    folder: Path
    argv: list
    runs: dict


#: the simulators the experiments call (under the names their modules import them)
_SIMULATORS = ("simulate", "simulate_ou", "simulate_phase", "simulate_continuous_discrete")


def _recording(func, calls):
    import inspect
    sig = inspect.signature(func)

    def wrapper(*args, **kwargs):
        b = sig.bind(*args, **kwargs)
        b.apply_defaults()
        paths = b.arguments["paths"]  # an int, or the range of path indices of one chunk
        calls.append((int(b.arguments["steps"]), len(paths) if isinstance(paths, range) else int(paths)))
        return func(*args, **kwargs)
    return wrapper


@pytest.fixture(scope="session")
def quick_reproduction(tmp_path_factory):
    """``nlfilter reproduce all --quick --report DIR`` (every experiment's quick run, ~1.5 min of
    CPU), run once per test process for tests/test_report.py (the report, its resume) and
    tests/test_results.py (the Results themselves, recorded as each experiment returned it, with
    the ``(steps, paths)`` of every simulation it made). The schedule below sends the modules that
    use it to one worker."""
    import importlib

    from nlfilter import cli, experiments
    from nlfilter.bounded import BoundedNoiseModel, ZeroOrderModel

    simulate_module = importlib.import_module("nlfilter.simulate")
    comparison_module = importlib.import_module("nlfilter.comparison")
    runs, real_run = {}, experiments.Experiment.run

    def recorded(exp, *args, **kwargs):
        calls = []
        module = importlib.import_module(exp.func.__module__)
        with pytest.MonkeyPatch.context() as mp:
            for mod in (module, comparison_module):  # an experiment may simulate through compare
                for name in _SIMULATORS:
                    if hasattr(mod, name) and getattr(mod, name) is getattr(simulate_module, name):
                        mp.setattr(mod, name, _recording(getattr(simulate_module, name), calls))
            for cls in (BoundedNoiseModel, ZeroOrderModel):
                mp.setattr(cls, "simulate", _recording(cls.simulate, calls))
            res = real_run(exp, *args, **kwargs)
        runs[exp.id] = (res, calls)
        return res

    folder = tmp_path_factory.mktemp("report")
    argv = ["reproduce", "all", "--quick", "--no-progress", "--report", str(folder / "out"),
            "--store", str(folder / "store.sqlite")]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(experiments.Experiment, "run", recorded)
        assert cli.main(argv) == 0
    assert set(runs) == set(experiments.registry())
    return QuickReproduction(folder / "out", argv, runs)


@pytest.fixture(autouse=True)
def _private_store(tmp_path, monkeypatch):
    """The command line's results store goes to a temporary file, never the user's cache."""
    monkeypatch.setenv("NLFILTER_STORE", str(tmp_path / "results.sqlite"))


# -- the fuzz suite's table (tests/fuzz): counted per area, gathered from every xdist worker ---------
FUZZ_OUTCOMES = ("named", "handled", "clean", "unnamed", "accepted", "silent nan", "raw", "hang", "unclean")


def _fuzz_table():
    return {"counts": collections.defaultdict(collections.Counter), "failures": []}


def pytest_configure(config):
    config.fuzz_table = _fuzz_table()
    # the compiled loops' disk cache: one folder for the whole run, the xdist workers included (they
    # inherit the controller's environment), so a loop one worker compiled is loaded by the others;
    # never the user's cache, and removed at the end (pytest_unconfigure)
    if "NLFILTER_CACHE" not in os.environ and not hasattr(config, "workerinput"):
        import tempfile
        config.compiled_cache = os.environ["NLFILTER_CACHE"] = tempfile.mkdtemp(prefix="nlfilter-test-compiled-")


def pytest_unconfigure(config):
    where = getattr(config, "compiled_cache", None)
    if where is not None:
        import shutil
        shutil.rmtree(where, ignore_errors=True)
        os.environ.pop("NLFILTER_CACHE", None)


def pytest_sessionfinish(session):
    """An xdist worker sends its part of the table to the controller."""
    out = getattr(session.config, "workeroutput", None)
    table = getattr(session.config, "fuzz_table", None)
    if out is not None and table is not None:
        out["fuzz_table"] = json.dumps({"counts": {a: dict(c) for a, c in table["counts"].items()},
                                        "failures": table["failures"]})


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """The controller adds a finished worker's part of the table (pytest-xdist's hook)."""
    part = getattr(node, "workeroutput", {}).get("fuzz_table")
    if part:
        part, table = json.loads(part), node.config.fuzz_table
        for area, counts in part["counts"].items():
            table["counts"][area].update(counts)
        table["failures"].extend(part["failures"])


def pytest_terminal_summary(terminalreporter, config):
    """The fuzz suite's table (issue 15): one row per area, one column per outcome;
    ``NLFILTER_FUZZ_JSON`` also writes it as JSON."""
    counts, failures = config.fuzz_table["counts"], config.fuzz_table["failures"]
    if not counts or hasattr(config, "workerinput"):
        return
    tr = terminalreporter
    tr.section("fuzz suite: outcomes per area")
    cols = [o for o in FUZZ_OUTCOMES if any(c[o] for c in counts.values())]
    tr.write_line(f"{'area':<30}{'cases':>7}" + "".join(f"{c:>12}" for c in cols))
    for area in sorted(counts):
        c = counts[area]
        tr.write_line(f"{area:<30}{sum(c.values()):>7}" + "".join(f"{c[o]:>12}" for o in cols))
    for line in failures[:40]:
        tr.write_line("  " + line)
    path = os.environ.get("NLFILTER_FUZZ_JSON")
    if path:
        Path(path).write_text(json.dumps({"counts": {a: dict(c) for a, c in counts.items()},
                                          "failures": failures}, indent=1, sort_keys=True))


# -- the xdist schedule (README: ``python -m pytest -n auto``) ------------------------------------
_MODULE_FIXTURE = ('@pytest.fixture(scope="module")', "@pytest.fixture(scope='module')")
#: session fixtures of minutes of CPU: the modules that use one are one unit of work (one worker)
_SESSION_FIXTURES = ("quick_reproduction",)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """pytest-xdist's default schedule (``load``) deals consecutive tests to whichever worker is
    free, so a module whose tests share a module-scoped fixture (a quick run of an experiment, a
    Monte Carlo reference: up to a minute of CPU) computes it once on each worker that gets one of
    its tests — near the end of the run, where xdist sends tests in small chunks, on both. Here
    such a module is one unit of work for one worker (xdist's ``loadscope`` units), the modules
    that use one of the costly session fixtures (:data:`_SESSION_FIXTURES`) together one unit, and
    every other test its own unit; units of several tests are sent first (xdist orders units by their
    number of tests), so the long shared fixtures run at the start, not in the last minute
    while the other worker idles. Any other ``--dist`` (``loadfile``, ``worksteal`` ...) is xdist's."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    root, shared, shared_text = Path(str(config.rootpath)), {}, {}

    def shares_a_module_fixture(module: str) -> bool:
        if module not in shared:
            try:
                text = (root / module).read_text(encoding="utf-8")
            except OSError:
                text = ""
            shared[module] = any(f in text for f in _MODULE_FIXTURE)
            shared_text[module] = text
        return shared[module]

    def session_fixture(module: str) -> str | None:
        shares_a_module_fixture(module)
        return next((f for f in _SESSION_FIXTURES if f in shared_text[module]), None)

    class ModuleFixtureScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return session_fixture(module) or (module if shares_a_module_fixture(module) else nodeid)

    return ModuleFixtureScheduling(config, log)
