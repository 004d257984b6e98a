"""Experiment ``cubic-sensor-closures`` (quick path)."""
import pytest

from nlfilter.experiments import get

FILTERS = ("ekf", "gaussian-closure", "edgeworth4-closure", "optimal")


@pytest.fixture(scope="module")
def quick():
    return get("cubic-sensor-closures").run({}, quick=True, seed=1)


def test_rows_for_both_default_cases(quick):
    for q, r in ((2.0, 1.0), (1.0, 1.0)):
        for f in FILTERS:
            row = quick.get(f, "mse_x", q=q, r=r)
            assert row.params["q"] == q and row.params["r"] == r and row.stderr > 0
            if f != "optimal":
                quick.get(f, "mse_x_gap", q=q, r=r)


def test_closures_near_optimal_ekf_far(quick):
    """Gap to the optimal filter (paired): closures within 3 standard errors of 5 % of the optimal MSE;
    the EKF (stuck at 0) worse than the Gaussian closure."""
    for q, r in ((2.0, 1.0), (1.0, 1.0)):
        opt = quick.get("optimal", "mse_x", q=q, r=r).value
        for f in ("gaussian-closure", "edgeworth4-closure"):
            g = quick.get(f, "mse_x_gap", q=q, r=r)
            assert g.value < 0.05 * opt + 3 * g.stderr
        e = quick.get("ekf", "mse_x_gap", q=q, r=r)
        gc = quick.get("gaussian-closure", "mse_x_gap", q=q, r=r)
        assert e.value - gc.value > 0
    # the EKF never moves from 0: its MSE is the time-average of x², whose mean is q/2
    e = quick.get("ekf", "mse_x", q=2.0, r=1.0)
    assert abs(e.value - 1.0) < 4 * e.stderr


def test_custom_case_and_bad_params():
    res = get("cubic-sensor-closures").run({"q": "1.5", "r": "0.5"}, quick=True, seed=2, runs=4)
    assert {r.params["q"] for r in res.rows} == {1.5}
    with pytest.raises(ValueError, match="same"):
        get("cubic-sensor-closures").run({"q": [1.0, 2.0], "r": [1.0]}, quick=True)
    with pytest.raises(ValueError, match="q"):
        get("cubic-sensor-closures").run({"q": [-1.0], "r": [1.0]}, quick=True)


def test_figure(quick, check_figure):
    names = {f"q={q:g}, r=1: MSE over t (running mean over 0.5, 16 paths)" for q in (2, 1)}
    check_figure(quick, {n: {"ekf", "gaussian-closure", "edgeworth4-closure", "optimal"} for n in names},
                 paper=names)
    p = quick.series["q=2, r=1: MSE over t (running mean over 0.5, 16 paths)"]["paper"]
    assert p["best linear filter, 001 Tables 5.1-5.2"] == (None, 0.540)  # 001 Table 5.1 (context)
