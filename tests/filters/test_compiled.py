"""The compiled run loop (``run(..., backend="numba")``, issue 13 goal 3): the same filter as the
NumPy loop, which stays the reference.

Tolerance: 1e-12, relative to the size of each output (``|a − b| ≤ 1e-12 · max(1, |a|)``). The two
loops do the same arithmetic in a different order (an LU solve for NumPy's ``solve``, explicit sums
for ``einsum``/``matmul``): on these well-conditioned models the differences are rounding, measured
at ≤ 3e-14 relative over 60 steps; 1e-12 leaves a margin of 30 and still catches any change of
formula (those move outputs by 1e-4 or more). Compilation takes seconds per model and rule kind,
so the models here are few and small.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as hst

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import REGISTRY, compiled
from nlfilter.filters.beliefs import GaussianState
from nlfilter.filters.compiled import build as compiled_build
from nlfilter.filters.compiled.kernels import KERNELS
from nlfilter.filters.compiled.path_linalg import chol, pd_ok, psd_check, psd_root, sqrt_check
from nlfilter.filters.cubature import CKF, GHKF, StatisticallyLinearizedFilter
from nlfilter.filters.ekf import EKF, ContinuousDiscreteIEKF, IteratedEKF
from nlfilter.filters.linalg import PSD_TOL, _bad_paths_exact
from nlfilter.filters.rule_filter import RuleFilter
from nlfilter.filters.rules import FORMS
from nlfilter.filters.second_order import SecondOrderFilter
from nlfilter.filters.ukf import UKF
from nlfilter.simulate import simulate
from tests.filters.test_screen import _matrix  # the screen's test matrices, every kind

# every loop these tests compile must be one numba can keep on disk (a kernel that takes a model
# function as a pointer cannot be: "dynamic globals"), so that warning fails the test
pytestmark = [pytest.mark.skipif(not compiled.available(), reason="numba does not import"),
              pytest.mark.filterwarnings("error:Cannot cache compiled function")]

RTOL = 1e-12


@pytest.fixture(autouse=True)
def general_loops(monkeypatch):
    """The general (not dimension-specialized) loops: 3-7 s of compilation per model and rule kind
    instead of 8-16 s; the specialized loops do the same arithmetic, which
    :func:`test_specialized_loops_give_the_same_numbers` checks to the last bit."""
    monkeypatch.setattr(compiled_build, "SPECIALIZE_UP_TO", 0)

x1, x2, a, k = sp.symbols("x1 x2 a k")


def nonlinear():
    """Two states, two measurements, a parameter, a time-varying input and a state-dependent G."""
    f = [0.9 * x1 + 0.1 * sp.sin(x2) + 0.05 * sp.cos(0.3 * k), a * x2 - 0.05 * x1 * x2]
    h = [x1 + 0.1 * x2**2, sp.atan(x2)]
    G = [[1.0, 0.0], [0.1 * x1, 1.0]]
    return DiscreteModel([x1, x2], f, h, G, Q=[[0.02, 0.005], [0.005, 0.01]], R=[[0.1, 0.02], [0.02, 0.2]],
                         params={a: 0.8}, time=k, name="two-state")


def polynomial():
    """A polynomial model with constant G (the second-order and SLF filters' case)."""
    return DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2 - 0.1 * x1**2], [x1 + x2**2 / 4, x1 * x2 / 2],
                         Q=[[0.02, 0.0], [0.0, 0.01]], R=[[0.1, 0.0], [0.0, 0.2]], name="polynomial")


@pytest.fixture(scope="module")
def data():
    md = nonlinear()
    ys = simulate(md, 60, paths=6, rng=3, m0=[0.2, -0.1], P0=0.3 * np.eye(2)).ys.copy()
    ys[1, 4, 0] = np.nan  # partly missing
    ys[2, 9] = np.nan  # missing on one path
    ys[:, 15] = np.nan  # missing on every path
    ys[3, 20:23, 1] = np.nan
    return md, ys


def close(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)  # bool extras (loglik_failed) too
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    scale = np.maximum(1.0, np.abs(a[ok]))
    err = np.max(np.abs(a[ok] - b[ok]) / scale, initial=0.0)
    assert err <= RTOL, err


def same(e1, e2):
    close(e1.means, e2.means)
    close(e1.covs, e2.covs)
    np.testing.assert_array_equal(e1.diverged, e2.diverged)
    np.testing.assert_array_equal(e1.diverged_step, e2.diverged_step)
    assert set(e1.extras) == set(e2.extras)
    for name in e1.extras:
        close(e1.extras[name], e2.extras[name])


MAKERS = {"ekf": EKF, "ukf": UKF, "ckf": CKF, "ghkf": lambda md, **kw: GHKF(md, order=3, **kw),
          "ukf-scaled": lambda md, **kw: UKF(md, alpha=0.5, beta=2.0, kappa=1.0, **kw)}
MAKERS.update({name: cls for name, cls in REGISTRY.items() if issubclass(cls, RuleFilter)})  # rule_filter lines


@pytest.mark.parametrize("name", list(MAKERS))
@pytest.mark.parametrize("start", ["update", "predict"])
def test_same_estimates_and_likelihood_as_numpy(data, name, start):
    md, ys = data
    flt = MAKERS[name](md, start=start)
    m0 = np.array([[0.2, -0.1]] * 6) + 0.01 * np.arange(6)[:, None]  # a prior per path
    P0 = 0.3 * np.eye(2)
    ref = flt.run(ys, m0, P0, loglik=True)
    new = flt.run(ys, m0, P0, loglik=True, backend="numba")
    same(ref, new)
    assert np.isfinite(new.loglik).all()


@pytest.mark.parametrize("start", ["update", "predict"])
def test_scalar_batch_loop_as_numpy(start):
    """One state, measurement and noise: the EKF's scalar batch loop (all paths at each step)."""
    x = sp.Symbol("x")
    md = DiscreteModel([x], [a * x + 0.1 * sp.sin(k)], [x**3], G=[[1 + 0.1 * x**2]], Q=0.01, R=0.1,
                       params={a: 0.99}, time=k)
    ys = simulate(md, 80, paths=7, rng=2, m0=0.5, P0=0.1).ys.copy()
    ys[3, 5] = np.nan
    ys[:, 7] = np.nan
    flt = EKF(md, start=start)
    m0 = 0.5 + 0.1 * np.arange(7)[:, None]
    ref = flt.run(ys, m0, 0.1, loglik=True)
    new = flt.run(ys, m0, 0.1, loglik=True, backend="numba")
    same(ref, new)
    assert new.means.shape == (7, 80, 1) and new.extras["innovation_cov"].shape == (7, 80, 1, 1)
    same(flt.run(ys.reshape(7, 1, 80, 1), m0.reshape(7, 1, 1), 0.1, backend="numba"),
         flt.run(ys.reshape(7, 1, 80, 1), m0.reshape(7, 1, 1), 0.1))


@pytest.mark.parametrize("form", FORMS)
def test_second_order_forms_as_numpy(form):
    md = polynomial()
    ys = simulate(md, 40, paths=4, rng=5, m0=[0.1, 0.2], P0=0.2 * np.eye(2)).ys.copy()
    ys[0, 3, 1] = np.nan
    ys[:, 7] = np.nan
    flt = SecondOrderFilter(md, form=form)
    ref = flt.run(ys, [0.1, 0.2], 0.2 * np.eye(2), loglik=True, on_divergence="mark")
    new = flt.run(ys, [0.1, 0.2], 0.2 * np.eye(2), loglik=True, on_divergence="mark", backend="numba")
    same(ref, new)
    for a, b in ((ref.means, new.means), (ref.covs, new.covs), (ref.loglik[..., None], new.loglik[..., None])):
        assert relative(a, b) <= RTOL  # relative to each output's own size, not to max(1, ·)


def relative(a, b):
    """The largest ``‖a − b‖ / max(‖a‖, ‖b‖)`` over the path-steps (a mean vector, a covariance
    matrix, a log-likelihood each; NaN path-steps, diverged alike in both, skipped): relative to the
    output's size, however small (entries near 0 inside a vector or matrix are held to its norm)."""
    axes = tuple(range(2, a.ndim))
    d = np.sqrt(np.sum((a - b) ** 2, axis=axes))
    size = np.maximum(np.sqrt(np.sum(a**2, axis=axes)), np.sqrt(np.sum(b**2, axis=axes)))
    return float(np.nanmax(d / np.maximum(size, np.finfo(float).tiny), initial=0.0))


@pytest.mark.parametrize("make", [lambda md: SecondOrderFilter(md, form="truncated"),
                                  lambda md: SecondOrderFilter(md, form="first-order"), UKF],
                         ids=["truncated", "first-order", "ukf"])
def test_scalar_models_as_numpy_relative(make, monkeypatch):
    """One state and one measurement: the update is NumPy's scalar branch, its products in its order
    (``(1 − K H)² P + K² R``). Another order rounds apart by 1e-16 a step, which the cubic sensor
    grows along some paths (here 9e-12 relative for the truncated form before the branch; 4e-11 over
    1000 × 200 compiled; now NumPy's bits compiled, for every rule). The loop runs as plain Python
    (the text numba compiles, exec'd: no compile here; Python's ``x**3`` may round apart from
    NumPy's by an ulp, so 1e-12 relative, not bits), on a model of its own that no compiled run
    reuses."""
    from tests.filters.test_compiled_flatten import _python
    _python(monkeypatch)
    monkeypatch.setattr(compiled_build, "KERNELS", {})
    x = sp.Symbol("x")
    md = DiscreteModel([x], [0.99 * x], [x**3], Q=0.01, R=0.1, name="cubic sensor, as Python")
    ys = simulate(md, 200, paths=20, rng=7, m0=0.5, P0=0.1).ys.copy()
    ys[1, 9] = np.nan
    flt = make(md)
    ref = flt.run(ys, 0.5, 0.1, loglik=True)
    new = flt.run(ys, 0.5, 0.1, loglik=True, backend="numba")
    for a, b in ((ref.means, new.means), (ref.covs, new.covs), (ref.loglik[..., None], new.loglik[..., None])):
        assert relative(a, b) <= RTOL


def test_slf_and_smoother_as_numpy():
    md = polynomial()
    ys = simulate(md, 30, paths=3, rng=6, m0=[0.1, 0.2], P0=0.2 * np.eye(2)).ys
    flt = StatisticallyLinearizedFilter(md)
    same(flt.run(ys, [0.1, 0.2], 0.2 * np.eye(2)), flt.run(ys, [0.1, 0.2], 0.2 * np.eye(2), backend="numba"))
    same(flt.smooth(ys, [0.1, 0.2], 0.2 * np.eye(2)), flt.smooth(ys, [0.1, 0.2], 0.2 * np.eye(2), backend="numba"))


def test_parameters_are_read_at_run_time_and_the_code_is_shared(data):
    md, ys = data
    other = md.with_params(a=0.5)
    flt = EKF(other)
    same(flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2)), flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba"))
    assert compiled.model_kernels(other)["f"] is compiled.model_kernels(md)["f"]  # generated once
    a1 = EKF(md).run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba")
    a2 = flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba")
    assert np.abs(a1.means - a2.means).max() > 1e-3  # the new value is used


def _diverging():
    x = sp.Symbol("x")
    return DiscreteModel([x], [1.5 * x**2], [sp.Integer(0)], Q=0.1, R=1.0, name="blows up")  # x² grows unobserved


@pytest.mark.parametrize("make", [EKF, UKF, lambda md: SecondOrderFilter(md, form="gaussian")],
                         ids=["ekf", "ukf", "second-order"])
def test_divergence_marked_and_raised_as_numpy(make):
    """Paths that fail at different steps and paths that do not, marked and raised alike. The steps
    must not hang on rounding (a two-state blow-up that loses definiteness at 1e50 fails a step
    earlier or later in the other loop's order of arithmetic), so the failures here are overflows
    or a definiteness lost at once: the EKF on a scalar model whose state blows up unobserved (its
    scalar loop compiles in a second); the UKF and the second-order filter on the polynomial model,
    whose loops the other tests compile (a model of its own would be a compile of its own, ~20 s) —
    the UKF from means so large that its measurement's covariance overflows at once (x1 = 1e160) or
    after one prediction (x1 = 1e50), the second-order filter from means where its update loses
    positive definiteness at once (x1 ≥ 2.75; 3 and 3.5 here)."""
    if make is EKF:
        md, ys = _diverging(), np.zeros((4, 40, 1))
        m0, P0 = np.array([[0.1], [0.5], [2.0], [3.0]]), 0.1  # the last two blow up, at different steps
    else:
        md = polynomial()
        ys = simulate(md, 40, paths=4, rng=5, m0=[0.2, -0.1], P0=0.3 * np.eye(2)).ys
        m0 = np.array([[0.2, -0.1], [1e160, 0.0], [0.5, 0.0], [1e50, 0.0]]) if make is UKF else \
            np.array([[0.2, -0.1], [3.0, 0.0], [0.5, 0.0], [3.5, 0.0]])
        P0 = 0.1 * np.eye(2)
    flt = make(md)
    ref = flt.run(ys, m0, P0, on_divergence="mark", loglik=True)
    new = flt.run(ys, m0, P0, on_divergence="mark", loglik=True, backend="numba")
    assert ref.diverged.any() and len(set(ref.diverged_step.tolist())) > 1  # paths fail at different steps
    same(ref, new)
    with pytest.raises(DivergenceError) as e1:
        flt.run(ys, m0, P0)
    with pytest.raises(DivergenceError) as e2:
        flt.run(ys, m0, P0, backend="numba")
    assert str(e1.value) == str(e2.value)
    assert e1.value.step == e2.value.step


def test_singular_prior(data):
    """A known state component (P0 singular): the EKF needs no square root; the node rules take an
    eigen root of P, the same in both loops, so the same sigma points and moments on a nonlinear
    model (the two-state model: its loops are the other tests', no compile of its own)."""
    md, ys = data
    for flt in (EKF(md), UKF(md, start="predict"), CKF(md)):
        same(flt.run(ys, [0.0, 0.0], np.diag([1.0, 0.0])),
             flt.run(ys, [0.0, 0.0], np.diag([1.0, 0.0]), backend="numba"))


def test_what_it_does_not_take_is_named(data):
    md, ys = data
    with pytest.raises(ValueError, match="backend"):
        EKF(md).run(ys, [0.0, 0.0], np.eye(2), backend="jax")
    with pytest.raises(TypeError, match="backend: 'numba'.*IteratedEKF"):
        IteratedEKF(md).run(ys, [0.0, 0.0], np.eye(2), backend="numba")
    x = sp.Symbol("x")
    sde = SDEModel([x], [-x], [x], Q=1.0, R=1.0)
    with pytest.raises(TypeError, match="backend: 'numba'"):
        ContinuousDiscreteIEKF(sde, 0.1).run(np.zeros((1, 3, 1)), [0.0], [[1.0]], backend="numba")  # (the EKF's has one)
    varying = md.with_params(a=np.full(60, 0.7))
    with pytest.raises(TypeError, match="backend: 'numba'.*vary over time"):
        EKF(varying).run(ys, [0.0, 0.0], np.eye(2), backend="numba")
    with pytest.raises(TypeError, match="backend: 'numba'.*depends on neither the state nor the time"):
        SecondOrderFilter(md).run(ys, [0.0, 0.0], np.eye(2), backend="numba")  # G depends on x1


def test_chunks_and_progress_give_the_same_numbers(data):
    md, ys = data
    flt = UKF(md)
    one = flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba", loglik=True)
    same(one, flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba", loglik=True, chunk=4))
    same(one, flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba", loglik=True, progress=True))
    batch = flt.run(ys.reshape(2, 3, *ys.shape[1:]), [0.2, -0.1], 0.3 * np.eye(2), backend="numba")
    close(batch.means.reshape(one.means.shape), one.means)


@settings(max_examples=200, deadline=None)
@given(n=hst.integers(1, 6), seed=hst.integers(0, 2**32 - 1), log_scale=hst.floats(-4.0, 7.0),
       kind=hst.sampled_from(("pd", "psd-singular", "zero", "within", "near", "beyond", "negative", "nan",
                              "asymmetric")))
def test_compiled_screen_is_the_eigenvalue_test(n, seed, kind, log_scale):
    """The compiled divergence test (Cholesky screen, then Jacobi eigenvalues) flags exactly what
    the NumPy test flags (:func:`~nlfilter.filters.linalg._bad_paths_exact`)."""
    rng = np.random.default_rng(seed)
    P = _matrix(rng, n, kind, 10.0**log_scale)
    m = rng.standard_normal(n)
    W, L, ev = np.empty((n, n)), np.empty((n, n)), np.empty(n)
    ok = psd_check(m, P, n, PSD_TOL, W, L, ev)
    assert ok == (not _bad_paths_exact(m[None], P[None])[0])
    if ok and kind not in ("nan", "asymmetric"):  # L Lᵀ = P (the eigen root where Cholesky fails: up to
        # the clipped negatives); an asymmetric P: Cholesky reads its lower triangle, as NumPy's
        V = np.empty((n, n))
        assert sqrt_check(P, L, n, PSD_TOL, W, ev, V)
        np.testing.assert_allclose(L @ L.T, 0.5 * (P + P.T), rtol=0, atol=1e-8 * max(1.0, np.abs(P).max()))
    # the node rules' test (psd_root_): the same decision, and the factor it keeps (from n = 3) is
    # the one the next step's sigma points would take of the same P, to the last bit
    R, Pc = np.empty((n, n)), np.full((n, n), np.nan)
    assert psd_root(m, P, n, PSD_TOL, W, np.empty((n, n)), ev, R, Pc) == ok
    if n > 2 and ok and kind not in ("nan", "asymmetric"):
        if not np.isnan(Pc[0, 0]):
            np.testing.assert_array_equal(Pc[np.tril_indices(n)], P[np.tril_indices(n)])
            L2 = np.empty((n, n))
            assert sqrt_check(P, L2, n, PSD_TOL, W, ev, np.empty((n, n)))
            np.testing.assert_array_equal(R, L2)
        else:
            assert kind in ("psd-singular", "zero", "within", "near")  # P itself has no Cholesky factor


@settings(max_examples=200, deadline=None)
@given(n=hst.integers(1, 8), seed=hst.integers(0, 2**32 - 1), log_scale=hst.floats(-6.0, 6.0),
       log_gap=hst.floats(-7.0, 0.0))
def test_screen_pivots_decide_as_the_cholesky_factor(n, seed, log_scale, log_gap):
    """The divergence screen's decision without square roots (:func:`~nlfilter.filters.compiled.
    path_linalg.pd_ok_`) is the Cholesky factorization's (:func:`~nlfilter.filters.compiled.
    path_linalg.chol_`) on every symmetric matrix whose smallest eigenvalue is at least 1e-7 of the
    largest away from 0 (either sign): where both could round differently (|λ_min| within ~n·eps of
    ‖A‖), the screen only defers to the exact test, :func:`test_compiled_screen_is_the_eigenvalue_test`."""
    rng = np.random.default_rng(seed)
    U = np.linalg.qr(rng.standard_normal((n, n)))[0]
    lam = rng.uniform(0.1, 1.0, n)
    lam[0] = 10.0**log_gap * (1 if rng.random() < 0.5 else -1)
    A = 10.0**log_scale * (U * lam) @ U.T
    A = 0.5 * (A + A.T)
    got = pd_ok(A.copy(), n)  # (its lower triangle overwritten)
    assert got == chol(A, np.empty((n, n)), n) == (lam[0] > 0)


def test_node_rules_on_three_states_as_numpy():
    """From three states the node rules keep P's Cholesky factor from the divergence test for the
    next kernel's sigma points (:func:`~nlfilter.filters.compiled.path_linalg.psd_root_`): as the
    NumPy loop, with missing data and two paths that diverge (a measurement of 1e200, of −1e300),
    each followed by a path whose first square root is its own; the UKF and the CKF share the loop."""
    x3 = sp.Symbol("x3")
    md = DiscreteModel([x1, x2, x3], [0.9 * x1 + 0.1 * sp.sin(x2), 0.8 * x2 + 0.1 * x3 * x1, a * x3**2],
                       [x1 + 0.1 * x2**2, x2 - 0.2 * x1], Q=0.01 * np.eye(3), R=[[0.1, 0.02], [0.02, 0.2]],
                       params={a: 0.5})
    ys = simulate(md.with_params(a=0.0), 30, paths=8, rng=4, m0=[0.1, 0.0, 0.0], P0=0.1 * np.eye(3)).ys.copy()
    ys[1, 4, 0] = np.nan
    ys[:, 15] = np.nan
    ys[2, 10, 0], ys[6, 5, 1] = 1e200, -1e300
    m0 = np.zeros((8, 3)) + 0.01 * np.arange(8)[:, None]
    for flt in (UKF(md), CKF(md, start="predict")):
        ref = flt.run(ys, m0, 0.1 * np.eye(3), loglik=True, on_divergence="mark")
        new = flt.run(ys, m0, 0.1 * np.eye(3), loglik=True, on_divergence="mark", backend="numba")
        assert ref.diverged.sum() == 2
        same(ref, new)


@pytest.mark.parametrize("make", [EKF, UKF, lambda md: SecondOrderFilter(md, form="gaussian")],
                         ids=["taylor1", "nodes", "taylor2"])
def test_specialized_loops_give_the_same_numbers(data, make, monkeypatch):
    """Small models run loops with the dimensions compiled in and the helpers expanded into the
    loop's text (``SPECIALIZE_UP_TO``, :mod:`~nlfilter.filters.compiled.flatten`): the same
    operations in the same order, so the same bits. (The second-order filters: the polynomial
    model, whose G is constant.)"""
    md, ys = data
    if make not in (EKF, UKF):
        md = polynomial()
        ys = simulate(md, 40, paths=4, rng=5, m0=[0.2, -0.1], P0=0.3 * np.eye(2)).ys
    flt = make(md)
    general = flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), loglik=True, backend="numba")
    monkeypatch.setattr(compiled_build, "SPECIALIZE_UP_TO", 4)
    special = flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), loglik=True, backend="numba")
    store = KERNELS[md._kernels["f"]]
    assert any(key[0] == "steps" and key[-1] == (2, 2, 2, None) for key in store if isinstance(key, tuple))
    for a_, b_ in ((general.means, special.means), (general.covs, special.covs),
                   (general.extras["loglik"], special.extras["loglik"])):
        np.testing.assert_array_equal(a_, b_)


class InflatedEKF(EKF):
    """An EKF whose prediction inflates the covariance (``P⁻ · 1.38``): a step of its own, which the
    compiled loop (the family's steps) would not run — issue 27's example."""

    def predict(self, state, k):
        s = super().predict(state, k)
        return GaussianState(s.mean, 1.38 * s.cov)


def test_a_subclass_that_changes_a_step_is_refused_and_runs_its_own_steps_on_numpy():
    """Never silently run as its parent: ``backend="numba"`` refuses it naming the class and the
    method; the NumPy loop runs its own steps. Checked against the recursion written out
    (``P⁻ = 1.38 (0.81 P + 0.1)``, Joseph update): the same scalar operations in another order, so
    the tolerance is rounding (1e-12 relative, as the rest of this file)."""
    x = sp.Symbol("x")
    md = DiscreteModel([x], [0.9 * x], [x], Q=0.1, R=0.5)
    ys = np.array([[[0.3], [-0.2], [0.5], [0.1], [0.4]]])
    with pytest.raises(TypeError, match=r"^backend: 'numba' cannot run InflatedEKF: InflatedEKF overrides predict of EKF"):
        InflatedEKF(md).run(ys, [0.0], [[1.0]], backend="numba")
    est = InflatedEKF(md).run(ys, [0.0], [[1.0]])
    m, P, means, covs = 0.0, 1.0, [], []
    for k, y in enumerate(ys[0, :, 0]):
        if k > 0:
            m, P = 0.9 * m, 1.38 * (0.81 * P + 0.1)
        K = P / (P + 0.5)
        m, P = m + K * (y - m), (1 - K) ** 2 * P + K**2 * 0.5
        means.append(m)
        covs.append(P)
    close(est.means[0, :, 0], means)
    close(est.covs[0, :, 0, 0], covs)
    plain = EKF(md).run(ys, [0.0], [[1.0]])
    assert est.covs[0, -1, 0, 0] > 1.3 * plain.covs[0, -1, 0, 0]  # 0.2172 against the plain EKF's 0.1586
    patched = EKF(md)
    patched.predict = lambda state, k: state  # an instance's own step: refused too
    assert "predict" in compiled.unsupported(patched)


def test_a_subclass_that_overrides_no_step_runs_compiled(data):
    class Labelled(EKF):
        """An EKF under another name: its steps are EKF's."""

        name = "labelled-ekf"

    md, ys = data
    assert compiled.unsupported(Labelled(md)) is None
    same(Labelled(md).run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba"),
         EKF(md).run(ys, [0.2, -0.1], 0.3 * np.eye(2)))


def test_a_subclass_that_sets_compiled_false_is_refused(data):
    class NoLoop(UKF):
        compiled = False

    md, ys = data
    with pytest.raises(TypeError, match=r"^backend: 'numba' cannot run NoLoop: NoLoop has no compiled loop \(NoLoop sets"):
        NoLoop(md).run(ys, [0.2, -0.1], 0.3 * np.eye(2), backend="numba")
