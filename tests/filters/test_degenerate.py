"""Degenerate but legal priors and noises, and data far out (issue 26, item 2): every registered
smoother (found through the registry) handles a singular predicted covariance — the gain
``D P⁻⁺`` on the range of P⁻ — or refuses naming the cause; a log-likelihood term is finite or
its path is marked diverged with the reason (``extras["loglik_failed"]``), never a silent
−inf/NaN."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import DivergenceError
from nlfilter.evaluate import loglik
from nlfilter.filters import REGISTRY, GridFilter, KalmanBucy, KalmanFilter
from nlfilter.filters.rule_filter import RuleFilter
from nlfilter.filters.square_root import SquareRootFilter
from nlfilter.filters.smoothing import SINGULAR_RTOL, _solve_right

x, x1, x2 = sp.symbols("x x1 x2")
DT = 0.05
T = 6
SMOOTHERS = {name: cls for name, cls in REGISTRY.items() if getattr(cls, "smoother", None)}


def _make(cls, model):
    """The registered class on ``model`` with default options (a grid needs its bounds)."""
    if cls is GridFilter:
        return GridFilter(model, (-3.0, 3.0), 41, dt=DT if model.kind == "sde" else None)
    return cls.for_model(model, dt=DT)


def _model(cls, **noise):
    """A scalar model of the kind the class accepts: x⁺ = 0.9 x (discrete) or dx = −x dt (SDE)."""
    if "discrete" in cls.accepts:
        return DiscreteModel([x], [0.9 * x], [x], **{"Q": 0.1, "R": 0.2, **noise})
    return SDEModel([x], [-x], [x], **{"Q": 0.5, "R": 0.1, **noise})


def _ys(seed=1):
    return 0.3 * np.random.default_rng(seed).standard_normal((3, T, 1))


def test_the_registry_has_the_smoothers_of_the_issue():
    """Eighteen Gaussian (RTS) smoothers, the grid and particle smoothers and the IMM's (Kim's,
    through its members' RTS steps): the issue's twelve that returned NaN are among them; every one
    is tested below. (Besides them, the RTS smoothers of the rule filters, one registry line each:
    ``rule_filter``, and of the square-root filters.)"""
    made = [c for c in SMOOTHERS.values() if issubclass(c, (RuleFilter, SquareRootFilter))]
    assert made and all(c.smoother == "rts" for c in made)
    rts = sum(c.smoother == "rts" for c in SMOOTHERS.values())
    assert len(SMOOTHERS) - len(made) == 21 and rts - len(made) == 18


@pytest.mark.parametrize("name", list(SMOOTHERS))
def test_known_state_smooths_to_its_filter_or_is_refused(name):
    """Q = 0 and P0 = 0: the state is known at every step (P = P⁻ = 0). The Gaussian smoothers'
    gain is then 0 (the pseudo-inverse of 0), so discrete-time and continuous-discrete smoothers
    return the filtered estimates: to 1e-12 (a node rule's covariance is the rounding of its
    weighted sums, ~(eps·|m|)² ≈ 1e-33, not 0, and its gain the ratio of two such roundings,
    applied to a difference of means of the same order), covariances below 1e-30. The continuous RTS smoother
    (Kalman–Bucy, continuous EKF and second order) integrates ``dmˢ/dt = f + F (mˢ − m) = −mˢ``
    backwards by Euler steps: ``mˢ_k = mˢ_{k+1} (1 + dt)`` exactly, compared to 1e-12 relative
    (a few roundings per step). The grid and particle smoothers need a density (P0 positive
    definite, a transition density): refused naming it."""
    cls = SMOOTHERS[name]
    flt = _make(cls, _model(cls, Q=0.0))
    ys = _ys()
    if cls.smoother not in ("rts", "imm-kim"):  # the IMM: its members' RTS steps
        with pytest.raises(ValueError, match=r"^(P0|process_noise):"):
            flt.smooth(ys, [0.5], [[0.0]], rng=1)
        return
    filt = flt.run(ys, [0.5], [[0.0]])
    sm = flt.smooth(ys, [0.5], [[0.0]])
    assert not sm.diverged.any() and np.all(np.abs(sm.covs) < 1e-30)
    if flt.time == "continuous":
        want = sm.means[:, -1:, 0] * (1 + DT) ** np.arange(T - 1, -1, -1)
        np.testing.assert_allclose(sm.means[..., 0], want, rtol=1e-12, atol=0)
    else:
        np.testing.assert_allclose(sm.means, filt.means, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", [n for n, c in SMOOTHERS.items() if c.accepts == ("sde",) and c.time == "discrete"])
def test_exact_measurements_smooth_to_the_data(name):
    """Continuous-discrete smoothers with R = 0 (an exact measurement of the state): each update
    gives ``m = y``, ``P = 0``, so ``C(t) = Cov[x_k, x(t)]`` starts at 0 and stays there, the gain
    ``C P⁻⁺`` is 0 and the smoother returns the data (to 1e-14: a node rule's gain
    ``Cov[x, h] / Cov[h]`` is 1 up to the rounding of its weighted sums, a few eps, on |y| < 1)."""
    flt = _make(SMOOTHERS[name], _model(SMOOTHERS[name], R=0.0))
    ys = _ys(2)
    sm = flt.smooth(ys, [0.5], [[0.3]])
    assert not sm.diverged.any()
    np.testing.assert_allclose(sm.means, ys, rtol=0, atol=1e-14)
    np.testing.assert_allclose(sm.covs, 0.0, rtol=0, atol=1e-14)


def test_one_known_state_smooths_as_the_reduced_model():
    """A 2-D linear model whose second state is a known constant (Q = 0 and P0 = 0 in it):
    P⁻ is singular on every step, and the RTS smoother of the first state is that of the 1-D
    model with the known input 0.1·x2 (x1⁺ = 0.9 x1 + 0.1·x2). Compared to 1e-12: the same
    recursions, the pseudo-inverse against a scalar division."""
    full = KalmanFilter(DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, x2], [x1], Q=np.diag([0.1, 0.0]), R=0.2))
    x2_value = 2.0
    red = KalmanFilter(DiscreteModel([x1], [0.9 * x1 + 0.1 * x2_value], [x1], Q=0.1, R=0.2))
    ys = _ys(3)
    a = full.smooth(ys, [0.5, x2_value], np.diag([0.3, 0.0]))
    b = red.smooth(ys, [0.5], [[0.3]])
    np.testing.assert_allclose(a.means[..., 0], b.means[..., 0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.covs[..., 0, 0], b.covs[..., 0, 0], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(a.means[..., 1], x2_value)


def test_the_gain_is_the_solve_where_nonsingular_and_the_pseudo_inverse_where_singular():
    """``_solve_right`` per path: a nonsingular path gets the LU solve bitwise (the batch's singular
    paths do not change it); a singular one ``B A⁺`` (numpy's pinv with the same cut, to 1e-12)."""
    rng = np.random.default_rng(0)
    L = rng.standard_normal((4, 3, 3))
    A = L @ np.swapaxes(L, -1, -2)
    A[1] = np.outer(L[1, :, 0], L[1, :, 0])  # rank 1
    A[3, 2, :] = A[3, :, 2] = 0.0  # a known component
    B = rng.standard_normal((4, 3, 3))
    out = _solve_right(A, B)
    for p in (0, 2):
        np.testing.assert_array_equal(out[p], np.linalg.solve(A[p], B[p].T).T)
    for p in (1, 3):
        np.testing.assert_allclose(out[p], B[p] @ np.linalg.pinv(A[p], rtol=SINGULAR_RTOL, hermitian=True),
                                   rtol=0, atol=1e-12 * np.abs(out[p]).max())


# -- log-likelihoods of data far out ----------------------------------------------------------------
FAR = 1e200  # the squared innovation / S of such data, ~1e400, has no float64


def test_loglik_overflow_is_raised_naming_the_step():
    ys = _ys()
    ys[1, 2, 0] = FAR
    with pytest.raises(DivergenceError, match=r"log-likelihood term is not finite .* at step 2 on 1 path") as err:
        KalmanFilter(_model(KalmanFilter)).run(ys, [0.5], [[0.3]], loglik=True)
    assert err.value.what == "loglik" and err.value.paths == (1,)


@pytest.mark.parametrize("make", [lambda: KalmanFilter(_model(KalmanFilter)), lambda: KalmanBucy(_model(KalmanBucy), DT)],
                         ids=["kf", "kalman-bucy"])
def test_loglik_overflow_is_marked_with_the_reason(make):
    """Path 1 has a measurement of 1e200 at step 2: marked diverged there, ``loglik_failed``
    says why; paths 0 and 2 are those of a run without path 1 (to 1e-12: chunked arithmetic)."""
    flt = make()
    ys = _ys()
    ys[1, 2, 0] = FAR
    est = flt.run(ys, [0.5], [[0.3]], loglik=True, on_divergence="mark")
    assert est.diverged.tolist() == [False, True, False] and est.diverged_step[1] == 2
    assert est.extras["loglik_failed"].tolist() == [[False] * T, [False, False, True] + [False] * (T - 3), [False] * T]
    assert np.isnan(est.loglik[1]) and np.isfinite(est.loglik[[0, 2]]).all()
    rest = flt.run(ys[[0, 2]], [0.5], [[0.3]], loglik=True)
    np.testing.assert_allclose(est.loglik[[0, 2]], rest.loglik, rtol=1e-12, atol=0)
    ev = loglik(flt, ys, [0.5], [[0.3]], on_divergence="mark")
    assert ev.diverged.tolist() == [False, True, False]


def test_loglik_of_no_steps_is_zero():
    est = KalmanFilter(_model(KalmanFilter)).run(_ys()[:, :0], [0.5], [[0.3]], loglik=True)
    assert est.loglik.tolist() == [0.0, 0.0, 0.0] and est.innovations.shape == (3, 0, 1)


@pytest.mark.parametrize("name", ["grid", "particle", "ekf"])
def test_smoothers_of_no_steps_return_empty_estimates(name):
    cls = SMOOTHERS[name]
    sm = _make(cls, _model(cls)).smooth(_ys()[:, :0], [0.5], [[0.3]], rng=1)
    assert sm.means.shape == (3, 0, 1) and sm.covs.shape == (3, 0, 1, 1) and not sm.diverged.any()


def test_a_smoother_that_leaves_a_path_non_finite_marks_it():
    """The run loop's guarantee for any backward pass: a non-finite smoothed value on a path the
    forward pass kept is raised (``what="smoother"``) or marked, never returned silently."""
    flt = KalmanFilter(_model(KalmanFilter))

    def broken(est, beliefs, ys, t0):  # a backward pass that loses path 0 at step 3
        m, P = est.means.copy(), est.covs.copy()
        m[0, 3] = np.nan
        return m, P

    flt._smooth = broken
    with pytest.raises(DivergenceError, match="smoother's backward pass became non-finite at step 3") as err:
        flt.smooth(_ys(), [0.5], [[0.3]])
    assert err.value.what == "smoother"
    sm = flt.smooth(_ys(), [0.5], [[0.3]], on_divergence="mark")
    assert sm.diverged.tolist() == [True, False, False] and sm.diverged_step[0] == 3
    assert np.isnan(sm.means[0]).all() and np.isfinite(sm.means[1:]).all()


def test_the_compiled_loop_marks_a_loglik_failure_as_the_run_loop():
    """``compiled.run.finish`` (pure Python: no compilation here) on outputs where path 1's term at
    step 2 is −inf: marked there with ``loglik_failed``, its outputs from step 2 on NaN, the others
    untouched; with ``on_divergence="raise"`` the run loop's error. A covariance failure at an
    earlier step keeps its own reason."""
    from nlfilter.filters.compiled.run import finish
    flt = KalmanFilter(_model(KalmanFilter))
    B, K = 3, 4

    def outputs():
        ll = np.zeros((B, K))
        ll[1, 2] = -np.inf
        return np.ones((B, K, 1)), np.ones((B, K, 1, 1)), ll, np.zeros((B, K, 1)), np.ones((B, K, 1, 1))

    m, P, ll, inn, icov = outputs()
    est = finish(flt, "mark", np.full(B, -1), (B,), m, P, True, ll, inn, icov)
    assert est.diverged.tolist() == [False, True, False] and est.diverged_step.tolist() == [-1, 2, -1]
    assert np.argwhere(est.extras["loglik_failed"]).tolist() == [[1, 2]]
    assert np.isnan(est.means[1, 2:]).all() and np.all(est.means[1, :2] == 1) and np.all(est.means[[0, 2]] == 1)
    assert np.isnan(est.extras["loglik"][1, 2:]).all() and np.all(est.extras["loglik"][[0, 2]] == 0)
    with pytest.raises(DivergenceError, match="log-likelihood term is not finite .* at step 2") as err:
        finish(flt, "raise", np.full(B, -1), (B,), *outputs()[:2], True, *outputs()[2:])
    assert err.value.what == "loglik"
    with pytest.raises(DivergenceError, match="covariance lost positive definiteness .* at step 1"):
        finish(flt, "raise", np.array([-1, -1, 1]), (B,), *outputs()[:2], True, *outputs()[2:])


def test_no_steps_on_a_loaded_compiled_loop():
    """A run of no steps where the compiled loop is already loaded (``backend="auto"`` then picks it,
    as in a process that ran the model before): empty estimates and a zero log-likelihood, as the
    NumPy loop (the compiled run's finish once failed on the empty record)."""
    pytest.importorskip("numba")
    flt = KalmanFilter(_model(KalmanFilter))
    est = flt.run(_ys()[:, :0], [0.5], [[0.3]], loglik=True, backend="numba")
    assert est.loglik.tolist() == [0.0, 0.0, 0.0] and est.means.shape == (3, 0, 1)
    assert est.extras["loglik_failed"].shape == (3, 0)
