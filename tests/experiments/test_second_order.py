"""Experiment ``second-order`` (quick path) and the benchmark problems it uses."""

import json

import numpy as np
import pytest

from nlfilter import cli, problems as pb
from nlfilter.experiments import get

FILTERS = ("ekf", "ukf", "truncated", "truncated-jazwinski", "gaussian", "modified", "modified-gaussian",
           "optimal")


@pytest.fixture(scope="module")
def quick():
    return get("second-order").run({}, quick=True, seed=0)


def test_rows_cover_every_filter_problem_and_quantity(quick):
    for problem, n in (("quadratic", 1), ("state-noise", 1), ("falling-body", 3)):
        for f in FILTERS:
            quantities = [f"mse_x{i + 1}" for i in range(n)] + ["nees", "psd_loss_rate"]
            if f != "optimal":
                quantities += [f"gap_mse_x{i + 1}" for i in range(n)]
            if f not in ("optimal", "truncated"):
                quantities += [f"diff_truncated_x{i + 1}" for i in range(n)]
            if problem == "falling-body":
                quantities += [f"mse_x{i + 1}_late" for i in range(n)]
            for q in quantities:
                row = quick.get(f, q, problem=problem)
                assert row.paper is None  # seed 004 prints no numbers
                if q == "psd_loss_rate":
                    assert 0.0 <= row.value <= 1.0
    assert set(quick.series) == {"quadratic: MSE of x1 per step", "state-noise: MSE of x1 per step",
                                 "falling-body: MSE of x1 per step (paired: the 8 runs of the reference)",
                                 "falling-body: MSE of x3 per step (paired: the 8 runs of the reference)",
                                 "Covariance lost positive definiteness (fraction of runs)"}


def test_quadratic_pre_correction_loses_psd_and_correct_form_does_not(quick):
    """Andrade Netto et al.'s observation and 004's answer: the correct truncated form keeps X PSD
    (Joseph update of eq. 21, eq. 19 a sum of PSD terms: rate exactly 0); the pre-correction form
    loses it on significantly more runs (3 binomial standard errors)."""
    good = quick.get("truncated", "psd_loss_rate", problem="quadratic")
    bad = quick.get("truncated-jazwinski", "psd_loss_rate", problem="quadratic")
    assert good.value == 0.0
    assert bad.value > 3 * np.sqrt(bad.value * (1 - bad.value) / 24) or bad.value == 1.0


@pytest.mark.parametrize("problem", ["quadratic", "state-noise"])
def test_no_filter_beats_the_grid_reference(quick, problem):
    """The grid filter is the optimal (MMSE) filter up to grid error: each suboptimal filter's
    paired MSE gap must not be significantly negative (3 standard errors, plus 1 % of the MSE
    for the grid's discretization)."""
    opt = quick.get("optimal", "mse_x1", problem=problem).value
    for f in FILTERS[:-1]:
        g = quick.get(f, "gap_mse_x1", problem=problem)
        if np.isnan(g.value):  # every run diverged: no paired paths
            assert quick.get(f, "psd_loss_rate", problem=problem).value == 1.0
            continue
        assert g.value > -3 * g.stderr - 0.01 * opt, (f, g)


def test_continuous_modified_equals_truncated(quick):
    """004 sec. 3: in continuous time the modified filter is the correct truncated filter."""
    for q in ("mse_x1", "nees"):
        assert quick.get("modified", q, problem="state-noise").value == \
            quick.get("truncated", q, problem="state-noise").value


def test_falling_body_filters_track(quick):
    """All second-order forms track the altitude to well within the prior's 1000 ft standard
    deviation (RMS error below 1000 ft) on the quick run."""
    for f in ("ekf", "ukf", "truncated", "modified"):
        assert quick.get(f, "mse_x1", problem="falling-body").value < 1000.0**2


def test_cli_quick_json_and_bad_param(tmp_path, capsys):
    out = tmp_path / "so.json"
    assert cli.main(["reproduce", "second-order", "--quick", "--no-progress", "--param",
                     "problem=quadratic", "--param", "steps=5", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert {r["params"]["problem"] for r in data["rows"]} == {"quadratic"}
    assert all(set(r) == {"filter", "quantity", "params", "paper", "value", "stderr"} for r in data["rows"])
    assert cli.main(["reproduce", "second-order", "--quick", "--param", "problem=spiral"]) == 2
    assert "problem" in capsys.readouterr().err


def test_problems():
    p = pb.falling_body()
    x = p.x0
    np.testing.assert_allclose(p.model.f(x), [-2e4, -np.exp(-5e-5 * 3e5) * 4e8 * 1e-3, 0.0])
    np.testing.assert_allclose(p.model.h(x), [np.hypot(1e5, 2e5)])
    assert p.model.h_x(np.array([1e5, 0, 0]))[0, 0] == 0.0  # the body at the radar's altitude
    q = pb.quadratic(c=0.4)
    np.testing.assert_allclose(q.model.h_xx(np.zeros(1))[0, 0, 0], 0.8)
    s = pb.state_noise(s1=0.8, s2=0.1)
    np.testing.assert_allclose(s.model.G_x(np.array([1.0]))[0, 0, 0], 0.8 + 0.2)
    d = pb.euler_discretization(s.model, 0.01)
    np.testing.assert_allclose(d.f(np.array([2.0])), [2.0 - 1.0 * 2.0 * 0.01])
    np.testing.assert_allclose(d.G(np.array([1.0]))[0, 0], (0.3 + 0.8 + 0.1) * 0.1)
    with pytest.raises(ValueError, match="r"):
        pb.quadratic(r=-1.0)
    with pytest.raises(TypeError, match="model"):
        pb.euler_discretization(q.model, 0.1)


def test_figure(quick, check_figure):
    lines = {"ekf", "ukf", "truncated", "optimal"}
    psd = "Covariance lost positive definiteness (fraction of runs)"
    check_figure(quick, {**{n: lines for n in quick.series if n != psd},
                         psd: {"quadratic", "state-noise", "falling-body"}})
    bars = quick.series[psd]
    assert set(bars["bars"]) == {"quadratic", "state-noise", "falling-body"}
    i = bars["categories"].index("truncated-jazwinski")
    assert bars["bars"]["quadratic"][i] == quick.get("truncated-jazwinski", "psd_loss_rate", problem="quadratic").value
    # a form that lost PSD on every quadratic run has no MSE curve, and the panel says so
    assert "truncated-jazwinski" not in quick.series["quadratic: MSE of x1 per step"]["lines"]
    assert "truncated-jazwinski" in quick.series["quadratic: MSE of x1 per step"]["note"]
