"""phase-tracking experiment (seed 001 Figs. 4.3-4.4, Table 4.1): quick path."""

import numpy as np
import pytest

from nlfilter.experiments import get


@pytest.fixture(scope="module")
def quick():
    # 16 runs: the standard error across runs is itself estimated from the runs, and from 4 of them
    # (3 degrees of freedom) it is too noisy for a 3 s.e. check: P(|t_3| > 3) ≈ 6 % per cell, and
    # over seeds 0-8 one of the six Table 4.1 cells failed on 1 to 3 of 8 seeds (old and new random
    # streams alike); with 15 degrees of freedom P(|t_15| > 3) ≈ 0.9 % per cell
    return get("phase-tracking").run({"P": [0.3]}, quick=True, runs=16, seed=3)


def test_fig_4_3_peak(quick):
    """Off-line (deterministic): 9.2 % at P = 0.129 to the printed digit; the exact maximum of the
    curve is 9.18 % at P ≈ 0.118 (the thesis reports the maximum 'at' 0.129, its sampled grid)."""
    assert abs(quick.get("tensor", "reduction_x1", P=0.129).value - 9.2) < 0.05
    assert abs(quick.get("tensor", "peak_reduction_x1").value - 9.2) < 0.05
    assert 0.10 < quick.get("tensor", "peak_P").value < 0.14
    assert quick.get("tensor", "reduction_x1", P=0.3).paper is None  # --param P adds rows


def test_table_4_1_within_monte_carlo_error(quick):
    """Short runs (quick): each Table 4.1 cell within 3 standard errors (across runs) of the paper."""
    for f in ("pll", "lqf", "tensor"):
        for qty in ("mse_theta", "one_minus_cos"):
            row = quick.get(f, qty, P=0.129)
            assert abs(row.value - row.paper) < 3 * row.stderr, row
    mc = dict(P=0.129, method="monte carlo")
    assert quick.get("optimal", "mse_x1", **mc).value < quick.get("lqf", "mse_x1", **mc).value


def test_series_for_figures(quick):
    assert {"Fig. 4.3: MSE reduction of x1 = sin θ", "Fig. 4.4: post-processor α, β"} <= set(quick.series)
    red = np.asarray(quick.series["Fig. 4.3: MSE reduction of x1 = sin θ"]["lines"]["cubic post-processor"])
    assert np.all(red > -1e-9) and red.max() < 9.3


def test_figure(quick, check_figure):
    f43, f44 = "Fig. 4.3: MSE reduction of x1 = sin θ", "Fig. 4.4: post-processor α, β"
    tab = "Table 4.1: phase error at P_θℓ = 0.129 (16 runs × 40 time constants)"
    check_figure(quick, {f43: {"cubic post-processor", "quintic post-processor"}, f44: {"α", "β"},
                         tab: {"ours (Monte Carlo)"}}, paper={f43, tab})
    assert quick.series[f43]["paper"]["cubic post-processor"] == (0.129, 9.2)
    bars = quick.series[tab]
    assert bars["categories"] == ["pll", "lqf", "tensor", "optimal"]
    assert bars["paper"]["ours (Monte Carlo)"] == [0.1401, 0.1477, 0.1511, None]  # 001 Table 4.1
    assert bars["bars"]["ours (Monte Carlo)"][0] == quick.get("pll", "mse_theta", P=0.129).value
