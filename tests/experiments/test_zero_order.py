"""Table 1 and Fig. 10 of seed 000 (zero-order problem).

Table 1 cells and the OCR: the printed table was partly garbled; cells read as follows (see
``PAPER_TABLE1`` in the experiment module): U / ^ / li / 1+ stand for 4, I for 1, O for 0.  The
J = 4, N = 2 cell reads "0.151^8" with one digit lost: it is the only illegible cell, and it is
checked only against the legible part of its digits.
"""

import numpy as np
import pytest

from nlfilter.experiments import get
from nlfilter.experiments.zero_order_problem import (ILLEGIBLE_TABLE1, PAPER_TABLE1, exact_mse, linear_gain,
                                             paper_value, sample_power_density)
from nlfilter.filters.moment_bayes import ZeroOrderMomentFilter, power_density_estimate
from nlfilter.moments.densities import power_density_moments

NAMES = ["optimal", "moment2", "moment4", "moment6", "linear"]


def _value(J, name, nodes=100):
    if name == "optimal":
        return exact_mse(lambda z: power_density_estimate(z, J), J, nodes=nodes)[0]
    if name == "linear":
        g = linear_gain(J)
        return exact_mse(lambda z: g * z, J, nodes=nodes)[0]
    N = int(name[-1])
    f = ZeroOrderMomentFilter(N, moments=power_density_moments(N, J), invalid_moments="ignore")
    return exact_mse(lambda z: f.estimate(z)[0], J, switch=lambda z: f.estimate(z)[1], nodes=nodes)[0]


# Cells where the estimator jumps to its fallback (eq. 3.16) inside (0, 2): the paper's numbers
# there differ from the exact integral (see test_disputed_cell_by_monte_carlo).
SWITCHING = {(6, "moment2"), (8, "moment2"), (10, "moment2"), (10, "moment4")}
# J = 10, smooth integrands: the paper is off by 5e-7 (e_op) and 4e-6 (e_6).
J10_SMOOTH = {(10, "optimal"): 1e-6, (10, "moment6"): 5e-6}


@pytest.mark.parametrize("J", sorted(PAPER_TABLE1))
def test_table1_cell_by_cell(J):
    for name in NAMES:
        ours = _value(J, name)
        paper = paper_value(J, name)
        if (J, name) in ILLEGIBLE_TABLE1:
            # legible digits "0.151" and a final "8": our 0.151448 fits "0.151^8" with ^ = 44
            assert f"{ours:.6f}".startswith("0.151") and f"{ours:.6f}".endswith("8")
        elif (J, name) in SWITCHING:
            # documented discrepancy, at most 0.0019 (1.4 %): independent check below
            assert abs(ours - paper) < 2e-3, (J, name, ours, paper)
        elif (J, name) in J10_SMOOTH:
            assert abs(ours - paper) < J10_SMOOTH[(J, name)], (J, name, ours, paper)
        else:
            # equal to the printed six decimals
            assert abs(ours - paper) <= 0.5e-6 + 1e-12, (J, name, ours, paper)


def test_quadrature_converged():
    for J, name in [(10, "optimal"), (8, "moment2"), (10, "moment4"), (10, "moment6")]:
        assert _value(J, name, nodes=100) == pytest.approx(_value(J, name, nodes=200), abs=1e-12)


def test_disputed_cell_by_monte_carlo():
    # J = 8, N = 2: ours 0.203392, paper 0.201550.  A Monte Carlo with 4e6 samples (standard error
    # ~1.5e-4) agrees with ours within 4 standard errors and puts the paper's value > 6 se away.
    J, N = 8, 2
    rng = np.random.default_rng(2024)
    f = ZeroOrderMomentFilter(N, moments=power_density_moments(N, J))
    s1 = s2 = 0.0
    n = 0
    for _ in range(4):
        x = sample_power_density(rng, J, 1_000_000)
        z = x + rng.uniform(-1, 1, x.shape)
        e2 = (x - f.estimate(z)[0]) ** 2
        s1, s2, n = s1 + e2.sum(), s2 + (e2 ** 2).sum(), n + e2.size
    mc = s1 / n
    se = np.sqrt((s2 / n - mc ** 2) / n)
    ours = _value(J, "moment2")
    assert abs(mc - ours) < 4 * se
    assert abs(mc - paper_value(J, "moment2")) > 6 * se


def test_J0_all_equal_optimal_eq_3_26():
    vals = [_value(0, name) for name in NAMES]
    np.testing.assert_allclose(vals, 1 / 6, atol=1e-12)


def test_experiment_quick_rows_and_mc_check(check_figure):
    res = get("zero-order").run({"J": [4, 10], "N": [2, 6]}, quick=True, runs=40_000, seed=1)
    fig, diff = "Table 1 (Fig. 8): ensemble MSE vs J, exact quadrature", "Table 1 cell by cell: ours − the paper's printed value"
    names = {"optimal", "moment2", "moment6", "linear"}
    check_figure(res, {fig: names, diff: names}, paper={fig})
    assert res.series[fig]["paper"]["moment2"] == ([4, 10], [0.151448, 0.210309])
    assert res.series[diff]["lines"]["moment2"][1] == pytest.approx(res.get("moment2", "mse", J=10).value - 0.210309)
    for J in (4, 10):
        for name in ("optimal", "moment2", "moment6", "linear"):
            det = res.get(name, "mse", J=J)
            mc = res.get(name, "mse_mc", J=J)
            assert det.paper == paper_value(J, name)
            assert abs(mc.value - det.value) < 4.5 * mc.stderr  # MC check of the quadrature
        assert res.get("moment6", "mse_gap", J=J).value >= -1e-12
    # any even J and any N <= 12 are accepted; odd J / N > 12 are not
    r2 = get("zero-order").run({"J": [12], "N": [12]}, quick=True, runs=2000)
    assert r2.get("moment12", "mse", J=12).value == pytest.approx(r2.get("optimal", "mse", J=12).value, abs=1e-9)
    with pytest.raises(ValueError, match="J"):
        get("zero-order").run({"J": [3]}, quick=True)
    with pytest.raises(ValueError, match="N"):
        get("zero-order").run({"N": [13]}, quick=True)


def test_adaptive_quick_rows(check_figure):
    res = get("zero-order-adaptive").run({}, quick=True, runs=30, seed=3)
    names = {"moment2", "moment4", "moment6", "linear", "optimal"}
    check_figure(res, {"Fig. 10 J=10": names, "Fig. 10 J=0": names})
    panel = res.series["Fig. 10 J=0"]
    assert panel["x"][-1] == 600 and panel["lines"]["optimal"][-1] == pytest.approx(res.get("optimal", "mse_n600", J=0).value)
    q = "mse_n600"
    for J in (10, 0):
        for name in ("moment2", "moment4", "moment6", "linear", "optimal"):
            r = res.get(name, q, J=J)
            assert r.stderr > 0 and np.isfinite(r.value)
        # the optimal filter is never beaten on average by more than noise (paired gap >= -3 se)
        for name in ("moment2", "moment4", "moment6", "linear"):
            g = res.get(name, "gap_n600", J=J)
            assert g.value > -3 * g.stderr - 1e-12
    # J = 0: linear = optimal exactly (both z/2)
    assert res.get("linear", q, J=0).value == pytest.approx(res.get("optimal", q, J=0).value, abs=1e-12)
    assert any(n.startswith("claim J=10") for n in res.notes)
    assert "Fig. 10 J=10" in res.series
    # the refresh failure rate of each adaptive filter: N = 2 always possible, N = 6 mostly impossible
    # on J = 10 (quick run, seed 0: 92 % of the refreshes)
    assert res.get("moment2", "refresh_failure_rate", J=10).value == 0.0
    r6 = res.get("moment6", "refresh_failure_rate", J=10)
    assert r6.value > 0.7 and r6.stderr > 0


# ------------------------------------------------------------------ robustness (Chapter III)

from nlfilter.experiments.zero_order_problem import copula_corr, correlated_optimal, correlated_pair  # noqa: E402


def test_correlated_optimal_reference():
    z = np.linspace(-1.95, 1.95, 27)
    # r = 0: the copula is independent, the reference is eq. 3.20
    np.testing.assert_allclose(correlated_optimal(z, 10, 0.0), power_density_estimate(z, 10), atol=1e-6)
    # quadrature converged (node clustering at the ends of (l, u))
    for r in (0.3, 0.9):
        np.testing.assert_allclose(correlated_optimal(z, 10, r, nodes=160), correlated_optimal(z, 10, r, nodes=400),
                                   atol=2e-5)
    # marginals of the coupled pair are the model's: E[x^2] = 11/13, v uniform (E v^2 = 1/3)
    x, v = correlated_pair(np.random.default_rng(0), 10, 0.6, 200_000)
    assert np.mean(x ** 2) == pytest.approx(11 / 13, abs=4 * np.std(x ** 2) / np.sqrt(x.size))
    assert np.mean(v ** 2) == pytest.approx(1 / 3, abs=4 * np.std(v ** 2) / np.sqrt(v.size))
    assert 0.45 < copula_corr(10, 0.6) < 0.56


def test_correlated_optimal_beats_filters_by_monte_carlo():
    # the reference is the conditional mean: no estimator beats it (paired, 3 se)
    rng = np.random.default_rng(4)
    x, v = correlated_pair(rng, 10, 0.6, 30_000)
    z = x + v
    e_opt = (x - correlated_optimal(z, 10, 0.6)) ** 2
    for est in (power_density_estimate(z, 10), linear_gain(10) * z):
        d = (x - est) ** 2 - e_opt
        assert d.mean() > -3 * d.std() / np.sqrt(d.size)


def test_robustness_quick(check_figure):
    res = get("zero-order-robustness").run({"r": [0.6, 0.0], "beta": [0.0, 0.5], "N": [2, 4]},
                                           quick=True, runs=16, seed=9)
    corr = "correlated input and noise: MSE against the copula r"
    scaled = "non-additive noise z = x + (1 + βx)v: MSE against β"
    check_figure(res, {corr: {"optimal", "linear", "moment2 (adaptive)", "moment4 (known moments)"},
                       scaled: {"optimal", "linear", "moment4 (exact likelihood)", "moment4 (additive filter)"}})
    assert list(res.series[corr]["x"]) == [0.0, 0.6]  # sorted, whatever the order given
    assert res.series[corr]["lines"]["moment4 (known moments)"][1] == res.get(
        "moment4-known", "mse_n400", case="correlated", r=0.6).value
    for case, key, vals in (("correlated", "r", (0.0, 0.6)), ("scaled-noise", "beta", (0.0, 0.5))):
        for val in vals:
            for name in ("linear", "moment2", "moment4"):
                g = res.get(name, "gap_n400", case=case, **{key: val})
                assert g.value > -3 * g.stderr - 1e-12
    for name in ("moment2", "moment4", "moment4-additive"):
        assert 0.0 <= res.get(name, "refresh_failure_rate", case="scaled-noise", beta=0.5).value <= 1.0
    assert 0.0 <= res.get("moment4", "refresh_failure_rate", case="correlated", r=0.6).value <= 1.0
    # beta = 0: the non-additive filter is the additive one
    for N in (2, 4):
        a = res.get(f"moment{N}", "mse_n400", case="scaled-noise", beta=0.0).value
        b = res.get(f"moment{N}-additive", "mse_n400", case="scaled-noise", beta=0.0).value
        assert a == pytest.approx(b, abs=1e-9)
    # beta = 0.5: modelling the state-dependent noise helps (paired over the same data)
    assert (res.get("moment4", "mse_n400", case="scaled-noise", beta=0.5).value
            < res.get("moment4-additive", "mse_n400", case="scaled-noise", beta=0.5).value)
    with pytest.raises(ValueError, match="param r=1.0: expected a value >-1 and <1"):
        get("zero-order-robustness").run({"r": [1.0]}, quick=True, runs=2)
