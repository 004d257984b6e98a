"""Issue 15: bad input at the run / simulate / evaluate boundary is refused up front, naming the
argument, with what was given and what was expected; nothing hangs or returns NaN silently."""

from __future__ import annotations

import time

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel
from nlfilter.errors import ClosureDivergedError
from nlfilter.filters import MQLF, QLF
from nlfilter.filters import quasilinear

x = sp.Symbol("x")
CUBIC = SDEModel([x], [-x**3], [x], Q=0.05, R=0.05)
DYS = np.zeros((2, 5, 1))


def refused(call, err, pattern):
    with pytest.raises(err, match=pattern):
        call()


# -- the QLF's off-line solve: bounded ------------------------------------------------------------
@pytest.mark.parametrize("F", [QLF, MQLF])
@pytest.mark.parametrize("P0", [1e150, 1e300])
def test_huge_prior_of_the_qlf_is_refused_not_a_hang(F, P0):
    t = time.monotonic()
    refused(lambda: F(CUBIC, 0.01).run(DYS, m0=[0.0], P0=[[P0]]), ValueError,
            r"^P0: the off-line moment/Riccati equations of this prior cannot be integrated.*below 1e\+150")
    assert time.monotonic() - t < 5


def test_stalled_off_line_solve_is_a_named_error(monkeypatch):
    monkeypatch.setattr(quasilinear, "OFFLINE_SECONDS", 0.0)
    refused(lambda: QLF(CUBIC, 0.01).run(DYS, m0=[0.0], P0=[[1.0]]), ClosureDivergedError,
            r"^qlf: the off-line moment/Riccati equations did not reach t = 0.05 within 0 s .*prior m0/P0")


@pytest.mark.parametrize("t0", [np.nan, np.inf])
def test_non_finite_t0_of_the_qlf_is_refused(t0):
    for call in (lambda: QLF(CUBIC, 0.01).run(DYS, m0=[0.0], P0=[[1.0]], t0=t0),
                 lambda: QLF(CUBIC, 0.01).offline([0.0], [[1.0]], 5, t0=t0)):
        refused(call, ValueError, r"^t0: expected a finite real number, got")


def test_numerically_singular_prior_of_the_qlf_names_P0():
    refused(lambda: QLF(CUBIC, 0.01).run(DYS, m0=[0.5], P0=[[1e-300]]), ValueError,
            r"^P0: the statistical linearization .* positive definite .*got smallest eigenvalue 1e-300")


# -- simulate: refused up front, screened while running, valid runs bitwise unchanged --------------
import hashlib  # noqa: E402

from nlfilter import DiscreteModel, problems  # noqa: E402
from nlfilter.errors import DivergenceError  # noqa: E402
from nlfilter.simulate import simulate, simulate_continuous_discrete, simulate_ou, simulate_phase  # noqa: E402

D1 = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x + 0.1 * x**2], Q=0.1, R=0.2)
S1 = SDEModel([x], [-x**3], [x], Q=0.5, R=0.1)
CUBE = DiscreteModel([x], [x**3], [x], Q=0.1, R=0.2)
DOUBLE = DiscreteModel([x], [2 * x], [x], Q=0.1, R=0.2)
FALL = problems.falling_body()

BAD_SIMULATIONS = [  # (call, exception, message)
    (lambda: simulate(D1, 3, m0=np.nan, P0=1.0), ValueError, r"^m0: expected finite values"),
    (lambda: simulate(D1, 3, m0=0.0j, P0=1.0), TypeError, r"^m0: expected real numbers, got complex128"),
    (lambda: simulate(D1, 3, m0=[0.0], P0=[[1.0 + 0j]]), TypeError, r"^P0: expected real numbers, got complex"),
    (lambda: simulate(D1, 3, m0=0.0, P0=[[np.inf]]), ValueError, r"^P0: expected finite values"),
    (lambda: simulate(D1, 3, x0=[np.inf]), ValueError, r"^x0: expected finite values"),
    (lambda: simulate(D1, 3, x0=[1j]), TypeError, r"^x0: expected real numbers, got complex128"),
    (lambda: simulate(S1, 3, m0=0.0, P0=1.0, dt=0.1, t0=np.nan), ValueError, r"^t0: expected a finite real number"),
    (lambda: simulate_continuous_discrete(FALL.model, 3, x0=FALL.x0, dt=FALL.dt, t0=np.inf), ValueError,
     r"^t0: expected a finite real number"),
    (lambda: simulate(D1, 2.5, m0=0.0, P0=1.0), TypeError, r"^steps: expected an integer, got 2.5"),
    (lambda: simulate(D1, 3, paths=2.5, m0=0.0, P0=1.0), TypeError, r"^paths: expected a positive integer"),
    (lambda: simulate(D1, 3, paths=0, m0=0.0, P0=1.0), ValueError, r"^paths: expected a positive number"),
    (lambda: simulate(S1, 3, m0=0.0, P0=1.0, dt=0.1, substeps=2.5), TypeError, r"^substeps: expected an integer"),
    (lambda: simulate(D1, 10**9, paths=10, m0=0.0, P0=1.0), ValueError,
     r"^steps/paths: steps=1000000000 × paths=10 .* would need 298 GiB, more than the 8 GiB bound"),
    (lambda: simulate_ou(1.0, 1.0, 0.1, 10**9, 10, 0), ValueError, r"^steps/paths: .* GiB"),
    (lambda: simulate_phase(np.nan, 1.0, 0.1, 5, 3, 0), ValueError, r"^q: expected a positive number"),
    (lambda: simulate_phase(1.0, 1.0, 0.1, 5, 3, 0, theta0=np.inf), ValueError, r"^theta0: expected finite"),
    (lambda: simulate(D1, 3, m0=0.0, P0=1.0, on_divergence="ignore"), ValueError, r"^on_divergence: expected one of"),
]


@pytest.mark.parametrize("call,err,pattern", BAD_SIMULATIONS, ids=range(len(BAD_SIMULATIONS)))
def test_bad_simulation_input_is_refused_naming_the_argument(call, err, pattern):
    refused(call, err, pattern)


DIVERGING = {  # name: (simulate with on_divergence=..., first step of each path)
    "cubic map from 1e200": (lambda **k: simulate(CUBE, 5, paths=3, rng=0, x0=[1e200], **k), [1, 1, 1]),
    "x[k+1] = 2 x[k] + w over 1100 steps": (
        lambda **k: simulate(DOUBLE, 1100, paths=3, rng=0, m0=0.0, P0=1.0, **k), [1024, 1026, 1024]),
    "Euler step too large for -x^3": (
        lambda **k: simulate(S1, 20, paths=4, rng=0, m0=0.0, P0=4.0, dt=1.0, substeps=1, **k), [5, 6, 6, 6]),
    "continuous-discrete from 1e200": (
        lambda **k: simulate_continuous_discrete(S1, 5, paths=2, rng=0, x0=[1e200], dt=0.1, **k), [0, 0]),
    "OU through an h that overflows": (
        lambda **k: simulate_ou(1.0, 1.0, 0.1, 5, 3, 0, h=lambda v: np.where(v > 0, np.inf, v), **k), None),
}


@pytest.mark.parametrize("name", DIVERGING)
def test_simulation_that_overflows_raises_or_marks(name):
    call, first = DIVERGING[name]
    with pytest.raises(DivergenceError, match=r"became non-finite at step \d+ on \d+ path\(s\), first \[") as e:
        call()
    sim = call(on_divergence="mark")
    d, k = sim.diverged, sim.diverged_step
    assert e.value.step == k[d].min()
    if first is not None:
        assert d.all() and k.tolist() == first
    for p in np.flatnonzero(d):  # NaN from the step on, finite before: never a silent inf
        assert np.isnan(sim.xs[p, k[p]:]).all() and np.isnan(sim.ys[p, k[p]:]).all()
        assert np.isfinite(sim.xs[p, :k[p]]).all() and np.isfinite(sim.ys[p, :k[p]]).all()
    assert not np.isinf(sim.xs).any() and not np.isinf(sim.ys).any()


def test_marked_paths_leave_the_others_unchanged():
    """A diverging path (x0 = 1e200) beside valid ones: they are the rows of a run without it."""
    x0 = np.array([[0.1], [1e200], [0.3]])
    sim = simulate(CUBE, 6, paths=3, rng=1, x0=x0, on_divergence="mark")
    assert sim.diverged.tolist() == [False, True, False] and sim.diverged_step.tolist() == [-1, 1, -1]
    for p in (0, 2):
        alone = simulate(CUBE, 6, paths=range(p, p + 1), rng=1, x0=x0[p])
        np.testing.assert_array_equal(sim.xs[p], alone.xs[0])
        np.testing.assert_array_equal(sim.ys[p], alone.ys[0])


def _digest(*arrays):
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:32]


# computed with the simulators before issue 15 (commit 00edc0f): screening changes no valid number
REFERENCE = {
    "discrete": (lambda: simulate(D1, 7, paths=3, rng=1, m0=0.2, P0=0.5), "75d17c3790a74973952897759c8390b3"),
    "discrete_predict": (lambda: simulate(D1, 7, paths=3, rng=1, m0=0.2, P0=0.5, start="predict"),
                         "d6530be0aa4e090acb0433bba086eca0"),
    "sde": (lambda: simulate(S1, 7, paths=3, rng=2, m0=0.2, P0=0.5, dt=0.05, substeps=3),
            "a06e15a27182b5be252245395714825f"),
    "sde_range": (lambda: simulate(S1, 5, paths=range(2, 4), rng=2, x0=[0.3], dt=0.05),
                  "5d011beab063a50b7e7f2692cd5d96c2"),
    "phase": (lambda: simulate_phase(1.0, 0.5, 0.05, 6, 3, np.random.default_rng(3)), "f8c123c38a4018a3498f73e143a15dc0"),
    "ou": (lambda: simulate_ou(2.0, 1.0, 0.01, 6, 3, np.random.default_rng(4)), "97d5e0ef946583754cb3a2050756e26f"),
    "cd": (lambda: simulate_continuous_discrete(FALL.model, 4, paths=2, rng=5, x0=FALL.x0, dt=FALL.dt,
                                                process="flow", substeps=20),  # the default then
           "f3590d92090dc51fd367f26d5fbd6e59"),
}


@pytest.mark.parametrize("name", REFERENCE)
def test_valid_simulations_are_bitwise_unchanged(name):
    call, digest = REFERENCE[name]
    out = call()
    assert _digest(*out) == digest
    if hasattr(out, "diverged"):
        assert not out.diverged.any() and (out.diverged_step == -1).all()


# -- evaluate: a NaN truth or an empty batch is refused, never a NaN summary -----------------------
from nlfilter.evaluate import mse, mse_per_step, nees, paired_difference, squared_errors  # noqa: E402
from nlfilter.filters.base import Estimates  # noqa: E402

XS = np.zeros((4, 5, 1))
EST = Estimates(np.ones((4, 5, 1)), np.ones((4, 5, 1, 1)), np.zeros(4, bool), np.full(4, -1))


def _with(a, idx, v):
    a = a.copy()
    a[idx] = v
    return a


BAD_EVALUATIONS = [
    (lambda: mse(EST, XS * np.nan), ValueError, r"^xs: expected finite values"),
    (lambda: mse(EST, _with(XS, (1, 2, 0), np.inf)), ValueError, r"^xs: expected finite values"),
    (lambda: mse_per_step(EST, _with(XS, (0, 0, 0), np.nan)), ValueError, r"^xs: expected finite values"),
    (lambda: nees(EST, _with(XS, (3, 4, 0), -np.inf)), ValueError, r"^xs: expected finite values"),
    (lambda: paired_difference(EST, EST, XS * np.nan), ValueError, r"^xs: expected finite values"),
    (lambda: squared_errors(EST, XS + 0j), TypeError, r"^xs: expected real numbers, got complex128"),
    (lambda: mse(np.ones((0, 5, 1)), np.zeros((0, 5, 1))), ValueError, r"^xs: expected at least one path"),
    (lambda: mse(_with(np.ones((4, 5, 1)), (2, 1, 0), np.nan), XS), ValueError,
     r"^estimates: expected finite means on the paths that did not diverge, got non-finite ones on 1 path\(s\) \(first \[2\]\)"),
]


@pytest.mark.parametrize("call,err,pattern", BAD_EVALUATIONS, ids=range(len(BAD_EVALUATIONS)))
def test_bad_evaluation_input_is_refused_naming_the_argument(call, err, pattern):
    refused(call, err, pattern)


def test_diverged_paths_are_still_left_out():
    est = EST._replace(means=_with(EST.means, (1,), np.nan), diverged=np.array([False, True, False, False]))
    s = mse(est, XS)
    assert s.value == 1.0 and s.paths == 3 and s.diverged == 1


# -- a singular R or G: named, never a raw LinAlgError ----------------------------------------------
from nlfilter.filters import (ConditionalMomentFilter, ContinuousEKF, ContinuousSecondOrderFilter,  # noqa: E402
                              GridFilter, KalmanBucy, ParticleFilter)

NOISE_FREE = SDEModel([x], [-x], [x], Q=0.5, R=0.0)
R_MESSAGE = r"^R: must be positive definite: a noise-free measurement has no continuous-time filter, got \[\[0\.0\]\]"


@pytest.mark.parametrize("make", [
    lambda: ContinuousEKF(NOISE_FREE, 0.05), lambda: KalmanBucy(NOISE_FREE, 0.05),
    lambda: ContinuousSecondOrderFilter(NOISE_FREE, 0.05), lambda: QLF(NOISE_FREE, 0.05),
    lambda: ConditionalMomentFilter(NOISE_FREE, 0.05), lambda: GridFilter(NOISE_FREE, (-3, 3), 41, dt=0.05),
    lambda: ParticleFilter(NOISE_FREE, 50, dt=0.05)], ids=["cekf", "kalman-bucy", "c2", "qlf", "cmf", "grid", "particle"])
def test_noise_free_continuous_measurement_is_refused_naming_R(make):
    refused(make, ValueError, R_MESSAGE)


def test_grid_with_a_singular_G_on_the_grid_names_G():
    model = DiscreteModel([x], [0.9 * x], [x], G=[[x]], Q=0.5, R=0.1)
    flt = GridFilter(model, (-3, 3), 41)  # the grid holds x = 0, where G(x) = x is singular
    refused(lambda: flt.run(np.zeros((2, 3, 1)), m0=[0.5], P0=[[1.0]]), ValueError,
            r"^G: the grid filter's transition density needs G\(x\) invertible at every grid point, got a singular "
            r"one at x = \[0\.0\] \(step 0\)")


def test_estimate_memory_is_bounded_up_front():
    ys = np.broadcast_to(np.zeros(1), (10, 10**9, 1))  # a view: no memory
    refused(lambda: KalmanBucy(SDEModel([x], [-x], [x], Q=0.5, R=0.1), 0.05).run(ys, m0=[0.0], P0=[[1.0]]),
            ValueError, r"^ys: 10 path\(s\) × 1000000000 step\(s\) of estimates .* would need 149 GiB, more than "
                        r"the 8 GiB bound")


@pytest.mark.parametrize("chunk", [2.5, 0, True])
def test_chunk_is_a_positive_integer(chunk):
    flt = KalmanBucy(SDEModel([x], [-x], [x], Q=0.5, R=0.1), 0.05)
    refused(lambda: flt.run(np.zeros((3, 4, 1)), m0=[0.0], P0=[[1.0]], chunk=chunk),
            TypeError if chunk != 0 else ValueError, r"^chunk: expected a positive integer|^chunk: expected an integer")


def test_empty_time_axis_gives_empty_estimates_for_the_qlf():
    est = QLF(CUBIC, 0.01).run(np.zeros((2, 0, 1)), m0=[0.0], P0=[[1.0]])
    assert est.means.shape == (2, 0, 1) and est.covs.shape == (2, 0, 1, 1)
