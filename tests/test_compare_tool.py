"""``compare`` in a user's hands (issue 25, items 5-7): the registry by model kind (every filter
that accepts a model runs or is listed as skipped, with the reason), honest rows for filters that
diverge on most paths, and ``nlfilter compare`` as a tool — a reference budget, runs in the
results store that resume after an interruption, and a report with the comparison's numbers."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, compare
from nlfilter.bilinear import BilinearModel
from nlfilter.compare_rows import MIN_SURVIVING_FRACTION, MIN_SURVIVORS
from nlfilter.evaluate import paired_difference
from nlfilter.filters import REGISTRY
from nlfilter.filters.registry import accepting, model_kind

x = sp.Symbol("x")

# -- item 7: the registry by kind --------------------------------------------------------------------
DISCRETE_BILINEAR = BilinearModel([[0.9]], [[1.0]], B=[[1.0]], R=[[1.0]], discrete=True)
MODELS = {  # a few models of each kind compare takes; dt for the continuous-time ones
    "discrete-linear": (DiscreteModel([x], [0.9 * x], [x], Q=0.1, R=0.5), None),
    "discrete-nonpolynomial": (DiscreteModel([x], [0.9 * x + 0.1 * sp.sin(x)], [x**3], Q=0.1, R=0.5), None),
    "sde-linear": (SDEModel([x], [-x], [x], Q=1.0, R=0.5), 0.05),
    "sde-cubic": (SDEModel([x], [-x], [x**3], Q=1.0, R=1.0), 0.05),
    "bilinear": (BilinearModel.from_polynomial(SDEModel([x], [-x], [x**3], Q=1.0, R=1.0)), 0.05),
    "bilinear-discrete": (DISCRETE_BILINEAR, None),
}


def test_a_discrete_bilinear_model_is_its_own_kind_and_gets_its_filter():
    """Regression: ``BilinearModel.kind`` is "bilinear" in both times; the registry maps a
    discrete one to "bilinear-discrete", so ``compare(.., "all")`` runs discrete-optimal-linear."""
    assert model_kind(DISCRETE_BILINEAR) == "bilinear-discrete" and model_kind(MODELS["bilinear"][0]) == "bilinear"
    assert "discrete-optimal-linear" in accepting(REGISTRY, DISCRETE_BILINEAR)
    assert "optimal-linear" not in accepting(REGISTRY, DISCRETE_BILINEAR)
    res = compare(DISCRETE_BILINEAR, "all", 5, paths=4, m0=[0.0], P0=[[0.5]], reference=None, rng=0)
    assert "discrete-optimal-linear" in {r.filter for r in res.rows}
    # on a linear model the optimal linear filter is the Kalman filter (same simulation, same paths)
    assert res.get("discrete-optimal-linear", "mse", component=0).value == pytest.approx(
        res.get("kf", "mse", component=0).value, rel=1e-9)


@pytest.mark.parametrize("case", list(MODELS))
def test_every_filter_accepting_the_kind_runs_or_is_skipped_with_a_reason(case):
    """The contract: every registered filter that accepts the model's kind (or that of the model
    it is simulated through) appears in ``compare(model, "all")``'s rows or in ``skipped``, with
    a non-empty reason — nothing is dropped silently."""
    md, dt = MODELS[case]
    res = compare(md, "all", 5, paths=4, m0=[0.0], P0=[[0.5]], reference=None, rng=0, dt=dt)
    views = [md] + ([md.to_discrete() if md.discrete else md.to_sde()] if isinstance(md, BilinearModel) else [])
    want = {name for m in views for name in accepting(REGISTRY, m)}
    ran = {r.filter for r in res.rows}
    skipped = res.params.get("skipped", {})
    assert ran | set(skipped) == want and not ran & set(skipped)
    assert all(isinstance(v, str) and len(v) > 10 for v in skipped.values()), skipped
    assert ran  # something ran
    if md.__class__ is SDEModel:  # the continuous-discrete filters read samples, not increments: said so
        cd = {n for n in want if n.startswith("continuous-discrete") and REGISTRY[n].family != "reference"}
        assert cd and all("discrete-time data" in skipped[n] for n in cd)
        assert "the reference family" in skipped["continuous-discrete-particle"]  # the yardstick, not judged
    assert any(n.startswith("not run: ") for n in res.notes)


# -- item 6: honest rows for diverging filters ------------------------------------------------------
FAST = SDEModel([x], [-2 * x**3], [x], Q=1.0, R=0.1)  # stiff at dt = 0.2: the moment filters blow up


def test_a_filter_diverging_on_most_paths_gets_no_mse_gap_or_nees_row():
    """The conditional-moment filter diverges on 35 of 40 paths of a fast SDE. Over its 5
    survivors its paired gap was −0.023 ± 0.010 against the end-point particle reference ("better
    than optimal" by 2.2 s.e.), and is −0.004 ± 0.005 against the reference of the simulator's
    convention (sde_step): a number over 5 selected paths either way. compare reports its
    divergence rate and a note, and no number with an s.e."""
    res, sim, est = compare(FAST, ["continuous-ekf", "conditional-moment", "quasilinear"], 20, paths=40, m0=[1.5],
                            P0=[[0.5]], rng=0, dt=0.2, substeps=10, full_output=True)
    assert res.params["reference"]["certified"] is True
    cm = est["conditional-moment"]
    survivors = int(np.sum(~cm.diverged))
    assert survivors < max(MIN_SURVIVORS, MIN_SURVIVING_FRACTION * 40)
    d = paired_difference(cm, est["optimal"], sim.xs, component=0, window=0.5)
    assert d.paths == survivors  # what the old rows printed: a gap over the few selected survivors
    for name in ("conditional-moment", "continuous-ekf"):
        assert {r.quantity for r in res.rows if r.filter == name} == {"divergence_rate"}
        assert any(n.startswith(f"{name}: diverged on ") and "no MSE, gap or NEES" in n for n in res.notes)
    assert res.get("conditional-moment", "divergence_rate").value == 1 - survivors / 40
    # no table row below the optimum by more than 2 s.e.
    assert all(r.value >= -2 * r.stderr for r in res.rows if r.quantity.startswith("gap"))
    assert "conditional-moment" not in next(iter(res.series.values()))["lines"]
    assert res.get("quasilinear", "gap_to_optimal", component=0).stderr > 0  # the survivor-free filter is judged


# -- item 5: nlfilter compare as a tool --------------------------------------------------------------
TURN = """\
# Coordinated-turn tracking (5 states: position, velocity, turn rate), range and bearing measured.
[model]
name = "coordinated-turn"
kind = "discrete"
states = ["px", "py", "vx", "vy", "w"]

[parameters]
dt = 0.5
q = 0.05

[dynamics]
f = ["px + dt*vx", "py + dt*vy", "vx*cos(dt*w) - vy*sin(dt*w)", "vx*sin(dt*w) + vy*cos(dt*w)", "w"]
G = [["0", "0", "0"], ["0", "0", "0"], ["1", "0", "0"], ["0", "1", "0"], ["0", "0", "1"]]
Q = [["q", 0, 0], [0, "q", 0], [0, 0, 0.001]]

[measurement]
h = ["sqrt(px**2 + py**2)", "atan2(py, px)"]
R = [[0.25, 0], [0, 0.01]]

[prior]
mean = [10.0, 0.0, 0.0, 1.0, 0.1]
cov = [1.0, 1.0, 0.1, 0.1, 0.01]

[run]
steps = 8
paths = 12
filters = ["ekf", "ukf"]
"""


@pytest.fixture
def turn(tmp_path):
    path = tmp_path / "turn.toml"
    path.write_text(TURN)
    return path


def test_cli_compare_on_a_five_state_model_keeps_to_its_reference_budget(turn, tmp_path, capsys):
    """``--reference-budget`` far below what even the smallest particle reference costs: the
    budget logic cuts the first rung to MIN_PARTICLES, says that it is run anyway, stops the
    ladder there (labelled not converged), and says so before the run (stderr) and in the notes,
    ``params["reference_budget"]`` and the report; the run is in the store and ``results list``
    lists it. (Decisions, not timings, are asserted: the estimate of a 2000-particle reference on
    a 5-state model exceeds 0.01 s on any machine — its pilot alone takes longer.)"""
    import json

    from nlfilter import cli
    from nlfilter.compare_budget import MIN_PARTICLES

    store, out, rep = tmp_path / "s.sqlite", tmp_path / "out.json", tmp_path / "report"
    assert cli.main(["compare", str(turn), "--reference-budget", "0.01", "--store", str(store), "--json", str(out),
                     "--report", str(rep)]) == 0
    captured = capsys.readouterr()
    assert "compare: reference: 200 particles on 12 paths (est." in captured.err  # said before it ran
    assert f"not even {MIN_PARTICLES} particles" in captured.err
    data = json.loads(out.read_text())
    ref, budget = data["params"]["reference"], data["params"]["reference_budget"]
    assert ref["kind"] == "particle" and ref["size"] == MIN_PARTICLES and len(ref["rungs"]) == 1
    assert ref["certified"] is False and "stopped by the reference budget" in ref["reason"]
    assert budget["seconds"] == 0.01 and budget["capped"] is True
    assert any("the ladder stops here" in line for line in budget["log"])
    assert any(n.startswith("reference budget: ") for n in data["notes"])
    assert cli.main(["results", "list", "--store", str(store)]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert listed[1].split("\t")[1:3] == ["compare", "done"] and "--reference-budget 0.01" in listed[1]
    # the report holds the comparison's own numbers: MSE, gap, NEES with s.e., the certificate
    index = (rep / "index.md").read_text()
    rows = {(r["filter"], r["quantity"], r["params"].get("component")): r for r in data["rows"]}
    from nlfilter.results import _fmt
    for name in ("ekf", "ukf"):
        m, g = rows[(name, "mse", 0)], rows[(name, "gap_to_reference", 0)]
        pm = lambda r: f"{_fmt(r['value'])} ± {_fmt(r['stderr'])}"  # noqa: E731
        assert f"| {name} | 0 | {pm(m)} | {pm(g)} |" in index
        nees = rows[(name, "nees", None)]
        assert f"| {name} | {_fmt(nees['value'])} ± {_fmt(nees['stderr'])} |" in index
    assert f"{MIN_PARTICLES} particles, not converged" in index and "Reference budget: 0.01 s" in index
    assert (rep / "compare.png").stat().st_size > 10_000


def test_cli_compare_resumes_after_an_interruption(turn, tmp_path, monkeypatch, capsys):
    """Ctrl-C during the reference (here: a KeyboardInterrupt raised by the 5th task, as Ctrl-C
    would) exits 130 with the run marked interrupted; the same command reads the finished tasks
    back from the store, computes only the others, and writes the numbers of an uninterrupted run."""
    import json

    from nlfilter import cli, compare_tasks
    from nlfilter.store import ResultsStore

    opts = ["--no-progress", "--block", "6", "--max-particles", "200", "--filters", "ekf,ukf"]
    fresh = tmp_path / "fresh.json"
    assert cli.main(["compare", str(turn), *opts, "--no-store", "--json", str(fresh)]) == 0
    real, calls = compare_tasks._filter_task, []

    def flaky(job):
        calls.append(job[0])
        if len(calls) == 5:
            raise KeyboardInterrupt
        return real(job)

    monkeypatch.setattr(compare_tasks, "_filter_task", flaky)
    store, out = tmp_path / "s.sqlite", tmp_path / "out.json"
    cmd = ["compare", str(turn), *opts, "--store", str(store), "--json", str(out)]
    assert cli.main(cmd) == 130
    assert "interrupted" in capsys.readouterr().err
    with ResultsStore(store) as st:
        assert st.runs()[0]["status"] == "interrupted" and st.count_blocks("compare") == 4
    calls.clear()
    assert cli.main(cmd) == 0
    resumed = json.loads(out.read_text())
    ex = resumed["meta"]["execution"]
    # 2 filters × 2 blocks, the reference's 2 blocks and its check's 2 (12 paths in blocks of 6)
    assert (ex["tasks_reused"], ex["tasks_computed"]) == (4, 4) and len(calls) == 4
    assert resumed["rows"] == json.loads(fresh.read_text())["rows"]
    with ResultsStore(store) as st:
        assert [r["status"] for r in st.runs()] == ["done", "interrupted"]


def test_reference_kinds_and_the_particle_cap():
    """``reference="particle"`` starts the ladder at particles on a 1-D model (where "auto" takes a
    grid), no more than ``max_particles``; ``"grid"`` on a model whose grid is too large is a
    ValueError naming ``reference`` and why; ``None`` gives no reference rows."""
    import warnings

    from nlfilter.errors import ReferenceWarning

    lin = MODELS["discrete-linear"][0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ReferenceWarning)  # 300 particles on 8 paths: may not certify
        res = compare(lin, ["kf"], 10, paths=8, m0=0.0, P0=0.5, rng=0, reference="particle", max_particles=300)
    ref = res.params["reference"]
    assert ref["kind"] == "particle" and ref["rungs"][0]["size"] == 300 and ref["size"] == 300
    y = sp.Symbol("y")
    wide = DiscreteModel([x, y], [0.9 * x, y], [x], Q=0.1 * np.eye(2), R=0.5)
    with pytest.raises(ValueError, match=r"^reference: 'grid' cannot serve this model \(the grid the model needs"):
        compare(wide, ["ekf"], 10, paths=4, m0=[0.0, 0.0], P0=np.eye(2), rng=0, reference="grid")
    # a budget no reference can keep: "grid" stays a grid (said), "auto" falls back to the fewest particles
    for kind, want in (("grid", "grid"), ("auto", "particle")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ReferenceWarning)
            res = compare(lin, ["kf"], 10, paths=8, m0=0.0, P0=0.5, rng=0, reference=kind, reference_budget=1e-6)
        assert res.params["reference"]["kind"] == want and res.params["reference_budget"]["capped"] is True
        assert "run anyway" in res.params["reference_budget"]["log"][0]
    with pytest.raises(ValueError, match=r"^reference: expected one of \('auto', 'grid', 'particle'\)"):
        compare(lin, ["kf"], 10, paths=4, m0=0.0, P0=0.5, rng=0, reference="none")
    with pytest.raises(ValueError, match=r"^reference_budget: expected a positive"):
        compare(lin, ["kf"], 10, paths=4, m0=0.0, P0=0.5, rng=0, reference_budget=0)


@pytest.mark.parametrize("opts, what", [
    (["--max-particles", "0"], "--max-particles: got 0; expected an integer ≥ 1"),
    (["--reference-budget", "-1"], "--reference-budget: got -1.0; expected a positive number of seconds"),
    (["--reference", "none", "--max-particles", "100"], "--reference none: given with --max-particles"),
])
def test_cli_reference_options_are_checked_before_the_run(turn, capsys, opts, what):
    from nlfilter import cli

    assert cli.main(["compare", str(turn), "--no-progress", *opts]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and what in err, err


def test_a_budget_needs_the_automatic_reference():
    lin = MODELS["discrete-linear"][0]
    with pytest.raises(ValueError, match=r"^reference_budget: budgets the automatic reference"):
        compare(lin, ["kf"], 10, paths=4, m0=0.0, P0=0.5, rng=0, reference=None, reference_budget=5)
