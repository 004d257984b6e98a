"""cubic-sensor experiment (seed 001 Tables 5.1-5.2): quick path, paper cells, and the
independent Monte Carlo check of the cells where the paper disagrees."""

import numpy as np
import pytest

from nlfilter.experiments import get
from nlfilter.experiments.cubic_sensor import simulate_cubic, stationary_lift_moments, cubic_model
from nlfilter.bilinear import BilinearModel
from nlfilter.filters.bilinear import TensorFilter


@pytest.fixture(scope="module")
def offline():
    return get("cubic-sensor").run({"monte_carlo": False}, quick=True)


def _half_unit(paper):
    """Half a unit of the last printed digit (0.540 -> 0.0005, 5.63 -> 0.005)."""
    s = f"{paper:.3g}"
    dec = len(s.split(".")[1]) if "." in s else 0
    return 0.5 * 10.0 ** -dec + 1e-12


def test_paper_cells_reproduced_to_printed_digits(offline):
    """Every off-line paper cell of Tables 5.1-5.2 matches its printed digits, except the two
    tensor cells of Table 5.2 (tested below) and Table 5.1's tensor x³ cell, which the paper
    truncated (5.4963 printed 5.49; the 2.5 % printed beside it is (5.63 − 5.49)/5.63)."""
    exceptions = {("tensor", "mse_x", 1.0), ("tensor", "mse_x3", 1.0), ("tensor", "mse_x3", 2.0)}
    checked = 0
    for row in offline.rows:
        if row.paper is None:
            continue
        if (row.filter, row.quantity, row.params["q"]) in exceptions:
            continue
        assert abs(row.value - row.paper) <= _half_unit(row.paper), row
        checked += 1
    assert checked == 7
    trunc = offline.get("tensor", "mse_x3", q=2.0, r=1.0).value
    assert 5.49 <= trunc < 5.50  # truncation, not rounding, of 5.4963


def test_table_5_2_tensor_cells_differ_and_monte_carlo_sides_with_ours(offline):
    """Table 5.2 (q = r = 1) prints tensor MSEs .371 (x) and 1.31 (x³); the exact moments give
    0.3776 and 1.264. A Monte Carlo of the same filters on common noise measures the linear-minus-
    tensor MSE difference (paired, so its standard error is small): it agrees with ours within
    3 standard errors and excludes the paper's differences (.378 − .371, 1.33 − 1.31)."""
    q = r = 1.0
    lin_x = offline.get("linear", "mse_x", q=q, r=r).value
    ten_x = offline.get("tensor", "mse_x", q=q, r=r).value
    lin_3 = offline.get("linear", "mse_x3", q=q, r=r).value
    ten_3 = offline.get("tensor", "mse_x3", q=q, r=r).value
    assert abs(ten_x - 0.371) > 0.005 and abs(ten_3 - 1.31) > 0.04
    lift = BilinearModel.from_polynomial(cubic_model(q, r))
    tf = TensorFilter(lift, 0.01, targets=[0, 2])
    tf.fit()
    xs, dys = simulate_cubic(q, r, 0.01, 3000, 600, np.random.default_rng(21))
    zhat = tf.linear.run(dys, *stationary_lift_moments(q), return_augmented=True).means
    post = tf.post_process(zhat)
    for lin_e, ten_e, truth, ours, paper in (
            (zhat[..., 0], post[..., 0], xs, lin_x - ten_x, 0.378 - 0.371),
            (zhat[..., 2], post[..., 1], xs ** 3, lin_3 - ten_3, 1.33 - 1.31)):
        d = (((lin_e - truth) ** 2 - (ten_e - truth) ** 2)[:, 300:]).mean(axis=1)
        mc, se = d.mean(), d.std(ddof=1) / np.sqrt(d.size)
        assert abs(mc - ours) < 3 * se, (mc, se, ours)
        assert abs(mc - paper) > 3 * se, (mc, se, paper)


def test_bound_and_ordering_far_below_paper_noise(offline):
    """The direct solve has no noise-to-signal limit: r = 0.01 with q = 1 (the thesis could not)."""
    res = get("cubic-sensor").run({"q": [1.0], "r": [0.01], "monte_carlo": False}, quick=True)
    g = lambda f, qty: res.get(f, qty, q=1.0, r=0.01).value  # noqa: E731
    assert g("bz-bound", "mse_x") < g("tensor5", "mse_x") <= g("tensor", "mse_x") < g("linear", "mse_x")
    assert 100 * (1 - g("tensor", "mse_x") / g("linear", "mse_x")) > 5.0  # the thesis' conjecture holds


def test_quick_monte_carlo_rows_present():
    res = get("cubic-sensor").run({"q": [2.0], "r": [1.0]}, quick=True, runs=3)
    names = {r.filter for r in res.rows if r.quantity == "mse_x_mc"}
    assert {"linear", "tensor", "updated-innovations", "ekf"} <= names
    for r in res.rows:
        if r.quantity.endswith("_mc"):
            assert np.isfinite(r.value) and r.stderr is not None and r.stderr > 0
