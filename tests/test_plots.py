"""plots.py: the panel kinds, legends and the figure file (experiment figures: tests/experiments)."""

import numpy as np
import pytest

from nlfilter.experiments import get
from nlfilter.results import Result


def _synthetic():
    res = Result("synthetic", "a synthetic result", "no paper", {})
    x = np.arange(1, 11)
    lines = {"ekf": 1.0 / x + 0.2, "ukf": 1.0 / x + 0.1, "optimal": 1.0 / x}
    res.series["per step"] = {"x": x, "lines": lines, "bands": {"optimal": (1.0 / x - 0.02, 1.0 / x + 0.02)},
                              "paper": {"ekf": ([10], [0.31]), "bound": (None, 0.05)},
                              "points": {"optimal (MC)": ([5], [0.2], [0.01])}, "ylabel": "MSE", "logy": True,
                              "note": "a note"}
    res.series["same filters again"] = {"x": x, "lines": lines, "ylabel": "MSE"}
    res.series["bars"] = {"kind": "bar", "categories": ["a", "b"], "bars": {"g1": [1.0, 2.0], "g2": [1.5, 0.5]},
                          "errors": {"g1": [0.1, 0.1]}, "paper": {"g1": [None, 2.1]}, "ylabel": "value"}
    return res


def test_every_panel_kind(check_figure):
    res = _synthetic()
    check_figure(res, {"per step": {"ekf", "ukf", "optimal"}, "same filters again": {"optimal"},
                       "bars": {"g1", "g2"}}, paper={"per step", "bars"})


def test_empty_series_raises(tmp_path):
    from nlfilter.plots import plot_result

    with pytest.raises(ValueError, match="no series"):
        plot_result(Result("empty", "t", "s", {}), tmp_path / "x.png")


def test_linear_gaussian_figure(check_figure):
    res = get("linear-gaussian").run({"steps": 30}, quick=True, runs=12, seed=1)
    name = "MSE of x1 per step (12 paths): all filters optimal, on the Riccati value"
    check_figure(res, {name: {"kf", "ekf", "ukf", "grid", "particle", "riccati"}})
    panel = res.series[name]
    assert np.all(panel["lines"]["riccati"] == res.get("riccati", "mse").value)
    lo, hi = panel["bands"]["kf"]
    assert np.all(lo < panel["lines"]["kf"]) and np.all(panel["lines"]["kf"] < hi)


def test_gallery_has_every_experiment_and_the_results_page_shows_it():
    from pathlib import Path

    from nlfilter.experiments import registry

    root = Path(__file__).resolve().parents[1]
    results = (root / "docs" / "guide" / "results.rst").read_text()
    for id in registry():
        png = root / "docs" / "figures" / f"{id}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size < 150_000, id
        assert f".. figure:: ../figures/{id}.png" in results, id


def test_log_y_when_curves_span_more_than_two_decades(tmp_path, monkeypatch):
    """A y-axis turns logarithmic when a panel's values are all positive and span more than two
    decades (one filter at MSE 2000 beside the others at 0.1-1 would flatten them); not for values
    within two decades, values ≤ 0 (a gap, a reduction), or a panel stating logy=False."""
    from matplotlib.axes import Axes

    from nlfilter.plots import log_scale, plot_result
    x = np.arange(1, 6)
    wide = {"x": x, "lines": {"ekf": 2000.0 + 0 * x, "ukf": 0.1 + 0.01 * x, "optimal": 0.1 + 0 * x}}
    assert log_scale(wide) and not log_scale({**wide, "logy": False})
    assert not log_scale({"x": x, "lines": {"a": 0.2 * x, "b": 10.0 + x}})           # 0.2 .. 15: linear
    assert not log_scale({"x": x, "lines": {"gap": x - 3.0, "b": 2000.0 + x}})      # a value ≤ 0
    assert log_scale({"kind": "bar", "categories": ["a", "b"], "bars": {"g": [0.01, 5.0]}})
    assert log_scale({"x": x, "lines": {"a": 0.5 + 0 * x}, "paper": {"a": ([2], [900.0])}})  # the paper's value counts
    scales = []
    monkeypatch.setattr(Axes, "set_yscale", lambda self, v, **k: scales.append(v))
    res = Result("wide", "a wide result", "seed 004 eqs. 18-23", {})
    res.series["one bad filter"] = wide
    res.series["within two decades"] = {"x": x, "lines": {"ukf": 0.1 + 0.01 * x}}
    plot_result(res, tmp_path / "w.png")
    assert scales == ["log"] and (tmp_path / "w.png").stat().st_size > 5_000
