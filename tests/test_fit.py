"""Parameter estimation (issue 12): ``nlfilter.fit`` (maximum likelihood on a filter's
log-likelihood, standard errors from the observed information) and ``nlfilter.fit_em`` (EM for
linear-Gaussian models). Every assertion compares the estimate with the truth of simulated data
within its own standard errors, or with an independent estimate of the same MLE."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, fit, fit_em, simulate
from nlfilter.filters import GridFilter

x, a, b = sp.symbols("x a b")
q, r, s, th = sp.symbols("q r s theta", positive=True)
AR = DiscreteModel([x], [a * x], [x], Q=[[q]], R=[[r]], params={a: 0.8, q: 0.3, r: 0.5})
PRIOR = dict(m0=[0.0], P0=[[1.0]])


@pytest.fixture(scope="module")
def ar_fit():
    ys = simulate(AR, 300, paths=2, rng=1, **PRIOR).ys
    return ys, fit(AR, ys, {"a": 0.5, "q": 1.0, "r": 1.0}, filter="kf", **PRIOR)


def test_linear_fit_recovers_the_truth_within_two_standard_errors(ar_fit):
    _, res = ar_fit
    assert res.converged and res.se_ok
    for k, truth in {"a": 0.8, "q": 0.3, "r": 0.5}.items():
        assert abs(res.params[k] - truth) < 2 * res.se[k], (k, res.params[k], res.se[k])
    assert res.model.params["a"] == res.params["a"]


def test_every_gaussian_filter_finds_the_kalman_mle(ar_fit):
    """On a linear model the UKF's likelihood is the Kalman filter's: the same optimum (to the
    optimizer's tolerance, 1e-4 relative on the parameters, 1e-8 on log L)."""
    ys, res = ar_fit
    ukf = fit(AR, ys, {"a": 0.5, "q": 1.0, "r": 1.0}, filter="ukf", se=False, **PRIOR)
    for k in res.params:
        assert abs(ukf.params[k] - res.params[k]) < 1e-4 * abs(res.params[k])
    assert abs(ukf.loglik - res.loglik) < 1e-8 * abs(res.loglik)


@pytest.mark.skipif(not __import__("nlfilter.filters.compiled", fromlist=["x"]).available(), reason="no numba")
def test_compiled_filter_finds_the_same_mle(ar_fit):
    """``fit(..., backend="numba")``: the compiled EKF's likelihood is the NumPy loop's to rounding
    (1e-12), so the optimizer ends at the same optimum (its tolerance, as above)."""
    ys, res = ar_fit
    ekf = fit(AR, ys, {"a": 0.5, "q": 1.0, "r": 1.0}, filter="ekf", se=False, backend="numba", **PRIOR)
    for k in res.params:
        assert abs(ekf.params[k] - res.params[k]) < 1e-4 * abs(res.params[k])
    assert abs(ekf.loglik - res.loglik) < 1e-8 * abs(res.loglik)


def test_em_climbs_to_the_same_mle(ar_fit):
    """EM (Shumway & Stoffer) never decreases the likelihood and converges to the MLE that the
    direct maximization finds: log L within 1e-6 relative, parameters within 3e-3 (EM's slow
    last iterations, far below the standard errors ~0.05). Measured with EM's tolerance 1e-8 (113
    iterations): log L within 1e-7 relative, parameters within 9e-4 (1e-10: 162 iterations, 1e-9
    and 9e-5)."""
    ys, res = ar_fit
    em = fit_em(ys, [[0.5]], [[1.0]], [[1.0]], [[1.0]], [0.0], [[1.0]], estimate=("F", "Q", "R"), tol=1e-8)
    assert em.converged and np.all(np.diff(em.loglik) >= -1e-9 * abs(em.loglik[-1]))
    assert abs(em.loglik[-1] - res.loglik) < 1e-6 * abs(res.loglik)
    for got, k in ((em.F[0, 0], "a"), (em.Q[0, 0], "q"), (em.R[0, 0], "r")):
        assert abs(got - res.params[k]) < 3e-3, (k, got, res.params[k])


def test_em_on_a_two_state_model_increases_the_likelihood():
    F = np.array([[0.9, 0.1], [0.0, 0.7]])
    md = DiscreteModel.linear(F, [[1.0, 0.0], [0.5, 1.0]], np.diag([0.2, 0.1]), np.diag([0.3, 0.2]))
    ys = simulate(md, 200, paths=3, m0=[0.0, 0.0], P0=np.eye(2), rng=2).ys
    em = fit_em(ys, np.eye(2) * 0.5, [[1.0, 0.0], [0.5, 1.0]], np.eye(2), np.eye(2), [0.0, 0.0], np.eye(2),
                estimate=("F", "Q", "R"), iterations=30)  # 30 steps of EM: log L up by 475 (80: 476)
    assert np.all(np.diff(em.loglik) >= -1e-9 * abs(em.loglik[-1])) and em.loglik[-1] > em.loglik[0] + 10
    assert np.abs(em.F - F).max() < 0.15  # 600 observations: sampling error of F ~0.05 (measured 0.039; 80 steps: 0.034)


def test_standard_errors_agree_with_the_spread_over_repeated_simulations():
    """30 records of 200 steps, (a, q) fitted on each: the standard deviation of the estimates
    over the records and the mean of the standard errors agree within ±35 % (the sample s.d. of
    30 estimates has a relative error ≈ 1/√58 ≈ 13 %: 2.7 of those)."""
    est, ses = [], []
    ys = simulate(AR, 200, paths=30, rng=5, **PRIOR).ys
    for p in range(30):
        res = fit(AR, ys[p], {"a": 0.6, "q": 0.5}, filter="kf", **PRIOR)
        assert res.converged and res.se_ok
        est.append([res.params["a"], res.params["q"]])
        ses.append([res.se["a"], res.se["q"]])
    ratio = np.std(est, axis=0, ddof=1) / np.mean(ses, axis=0)
    assert np.all((0.65 < ratio) & (ratio < 1.35)), ratio


def test_nonlinear_discrete_fit_with_the_grid_likelihood():
    """x' = a x + b x / (1 + x²) + w, y = x + v: the grid filter's log-evidence (exact to its
    resolution) recovers (a, b, q) within 2 standard errors."""
    md = DiscreteModel([x], [a * x + b * x / (1 + x**2)], [x], Q=[[q]], R=0.3, params={a: 0.5, b: 1.2, q: 0.4})
    ys = simulate(md, 400, paths=1, rng=3, **PRIOR).ys
    res = fit(md, ys, {"a": 0.3, "b": 0.5, "q": 1.0}, filter=lambda m: GridFilter(m, (-8, 8), 241), **PRIOR)
    assert res.converged and res.se_ok
    for k, truth in {"a": 0.5, "b": 1.2, "q": 0.4}.items():
        assert abs(res.params[k] - truth) < 2 * res.se[k], (k, res.params[k], res.se[k])


def test_sde_with_state_dependent_diffusion():
    """dx = −θ x dt + s √(1 + x²) dβ, dy = x dt + dη (R = 0.05): the grid filter's density of the
    increments recovers (θ, s) within 2 standard errors."""
    md = SDEModel([x], [-th * x], [x], G=[[s * sp.sqrt(1 + x**2)]], Q=1.0, R=0.05, params={th: 1.0, s: 0.6})
    dt = 0.05
    ys = simulate(md, 600, paths=1, dt=dt, rng=4, **PRIOR).ys
    res = fit(md, ys, {"theta": 0.5, "s": 1.0}, filter=lambda m: GridFilter(m, (-6, 6), 161, dt=dt), **PRIOR)
    assert res.converged and res.se_ok
    for k, truth in {"theta": 1.0, "s": 0.6}.items():
        assert abs(res.params[k] - truth) < 2 * res.se[k], (k, res.params[k], res.se[k])


def test_bad_input_is_named():
    ys = np.zeros((10, 1))
    with pytest.raises(ValueError, match="unknown parameter 'z'"):
        fit(AR, ys, {"z": 1.0}, filter="kf", **PRIOR)
    with pytest.raises(TypeError, match="params0"):
        fit(AR, ys, {}, filter="kf", **PRIOR)
    with pytest.raises(ValueError, match="params0: q = -1.0 is outside"):
        fit(AR, ys, {"q": -1.0}, filter="kf", **PRIOR)
    with pytest.raises(ValueError, match="bounds: 'r'"):
        fit(AR, ys, {"q": 1.0}, filter="kf", bounds={"r": (0, 1)}, **PRIOR)
    with pytest.raises(TypeError, match="filter"):
        fit(AR, ys, {"q": 1.0}, filter=3, **PRIOR)
    with pytest.raises(ValueError, match="filter: expected one of"):
        fit(AR, ys, {"q": 1.0}, filter="nope", **PRIOR)
    with pytest.raises(ValueError, match="ys: fit_em"):
        fit_em(np.full((5, 1), np.nan), [[0.5]], [[1.0]], [[1.0]], [[1.0]], [0.0], [[1.0]])
    with pytest.raises(ValueError, match="estimate"):
        fit_em(ys, [[0.5]], [[1.0]], [[1.0]], [[1.0]], [0.0], [[1.0]], estimate=("G",))
