"""The measurement convention travels with the data (issue 25 item 3): a Simulation carries its
Timing, the filters, ``evaluate.loglik`` and ``fit`` read it, a conflicting explicit convention is
refused, and the default call on simulated continuous-discrete data gives the exact likelihood."""

import pickle

import numpy as np
import pytest
import scipy.linalg
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter.evaluate import loglik
from nlfilter.filters import EKF, KalmanBucy, KalmanFilter
from nlfilter.filters.ekf import ContinuousDiscreteEKF
from nlfilter.sde_step import SUBSTEPS
from nlfilter.simulate import Simulation, Timing, simulate_continuous_discrete

x1, x2 = sp.symbols("x1 x2")
A = np.array([[-0.5, 1.0], [-1.0, -0.3]])
QC = np.diag([0.2, 0.4])
H = np.array([[1.0, 0.5]])
R = np.array([[0.3]])
LIN_SDE = SDEModel([x1, x2], list(sp.Matrix(A) * sp.Matrix([x1, x2])), list(sp.Matrix(H) * sp.Matrix([x1, x2])),
                   Q=QC, R=R)
DT, M0, P0 = 0.4, np.array([0.5, -0.2]), np.diag([0.6, 0.3])


def van_loan(A, Q, dt):
    """Exact discretisation of ``dx = A x dt + dβ``, ``E dβ dβᵀ = Q dt`` (Van Loan 1978): with
    ``M = expm([[−A, Q], [0, Aᵀ]] dt)``, ``F = M₂₂ᵀ`` and ``Q_d = F M₁₂``."""
    n = A.shape[0]
    M = scipy.linalg.expm(np.block([[-A, Q], [np.zeros((n, n)), A.T]]) * dt)
    F = M[n:, n:].T
    return F, F @ M[:n, n:]


def exact_loglik(ys, F, Qd, H, R, m0, P0):
    """The Kalman filter's prediction-error log-likelihood of one record, prior at t0 and the
    first measurement one interval later (predict, then update), written out here."""
    m, P, ll = m0, P0, 0.0
    for y in ys:
        m, P = F @ m, F @ P @ F.T + Qd
        S = H @ P @ H.T + R
        e = y - H @ m
        ll -= 0.5 * (e @ np.linalg.solve(S, e) + np.linalg.slogdet(2 * np.pi * S)[1])
        K = P @ H.T @ np.linalg.inv(S)
        m, P = m + K @ e, P - K @ S @ K.T
    return ll


@pytest.fixture(scope="module")
def cd_sim():
    return simulate_continuous_discrete(LIN_SDE, 25, paths=3, rng=4, m0=M0, P0=P0, dt=DT)


def test_default_call_on_cd_simulation_is_exact(cd_sim):
    F, Qd = van_loan(A, QC, DT)
    exact = np.array([exact_loglik(y, F, Qd, H, R, M0, P0) for y in cd_sim.ys])
    # the same exact value from the library's discrete Kalman filter on the discretised model
    kf = KalmanFilter(DiscreteModel.linear(F, H, Qd, R), start="predict").run(cd_sim.ys, M0, P0, loglik=True)
    np.testing.assert_allclose(kf.loglik, exact, rtol=1e-10)
    # default calls: the filter built without start, run on the Simulation or on its ys; RK4 with
    # 10 substeps on a linear moment ODE (|A| dt / 10 = 0.05: local error ~ 0.05⁵/120 ≈ 3e-9 per
    # step) leaves ~1e-7 on the log-likelihood over 25 steps: 1e-6 absolute
    flt = ContinuousDiscreteEKF(LIN_SDE, DT, substeps=10)
    for got in (flt.run(cd_sim, M0, P0, loglik=True).loglik, flt.run(cd_sim.ys, M0, P0, loglik=True).loglik,
                loglik(flt, cd_sim, M0, P0).value):
        np.testing.assert_allclose(got, exact, atol=1e-6, rtol=0)
    # the other convention, stated on purpose, is a different (wrong for these data) number — and
    # it is refused on the Simulation, naming both conventions
    wrong = ContinuousDiscreteEKF(LIN_SDE, DT, substeps=10, start="update")
    assert np.all(np.abs(wrong.run(cd_sim.ys, M0, P0, loglik=True).loglik - exact) > 1e-3)  # ≫ the 1e-6 above
    with pytest.raises(ValueError, match=r"start: ContinuousDiscreteEKF was built with start='update'.*start='predict'"):
        wrong.run(cd_sim, M0, P0)


def test_cd_t0_and_dt_are_read_or_refused():
    sim = simulate_continuous_discrete(LIN_SDE, 5, paths=2, rng=1, m0=M0, P0=P0, dt=DT, t0=3.0)
    assert sim.timing == Timing("continuous-discrete", "predict", 3.0, DT, SUBSTEPS)  # Euler–Maruyama's
    a = ContinuousDiscreteEKF(LIN_SDE, DT, substeps=4).run(sim, M0, P0, loglik=True)
    b = ContinuousDiscreteEKF(LIN_SDE, DT, substeps=4, t0=3.0, start="predict").run(sim.ys, M0, P0, loglik=True)
    np.testing.assert_array_equal(a.loglik, b.loglik)  # the same filter: bitwise
    with pytest.raises(ValueError, match=r"t0: .*t0=1.0.*t0=3.0"):
        ContinuousDiscreteEKF(LIN_SDE, DT, t0=1.0).run(sim, M0, P0)
    with pytest.raises(ValueError, match=r"dt: .*dt=0.2.*dt=0.4"):
        ContinuousDiscreteEKF(LIN_SDE, 0.2).run(sim, M0, P0)
    with pytest.raises(ValueError, match="ys: the Simulation holds continuous-discrete measurements"):
        KalmanBucy(LIN_SDE, DT).run(sim, M0, P0)


def test_discrete_start_is_read_or_refused():
    x = sp.Symbol("x")
    md = DiscreteModel([x], [0.8 * x], [x], Q=0.5, R=0.4)
    sim = simulate(md, 6, paths=2, rng=2, m0=[0.0], P0=[[1.0]], start="predict")
    assert sim.timing == Timing("discrete", "predict", 0.0, None)
    a = EKF(md).run(sim, [0.0], [[1.0]], loglik=True)
    b = EKF(md, start="predict").run(sim.ys, [0.0], [[1.0]], loglik=True)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.loglik, b.loglik)
    sm = EKF(md).smooth(sim, [0.0], [[1.0]])
    np.testing.assert_array_equal(sm.means, EKF(md, start="predict").smooth(sim.ys, [0.0], [[1.0]]).means)
    with pytest.raises(ValueError, match=r"start: EKF was built with start='update'.*start='predict'"):
        EKF(md, start="update").run(sim, [0.0], [[1.0]])
    with pytest.raises(ValueError, match="ys: the Simulation holds discrete measurements"):
        ContinuousDiscreteEKF(LIN_SDE, DT).run(sim, M0, P0)


def test_continuous_t0_and_dt():
    x = sp.Symbol("x")
    md = SDEModel([x], [-x], [x], Q=1.0, R=0.5)
    sim = simulate(md, 8, paths=2, rng=3, m0=[0.0], P0=[[1.0]], dt=0.05, t0=2.0)
    assert sim.timing == Timing("increments", None, 2.0, 0.05, 10)  # substeps: simulate's default
    a = KalmanBucy(md, 0.05).run(sim, [0.0], [[1.0]])
    np.testing.assert_array_equal(a.means, KalmanBucy(md, 0.05).run(sim.ys, [0.0], [[1.0]], t0=2.0).means)
    with pytest.raises(ValueError, match=r"t0: run was given t0=0.0.*t0=2.0"):
        KalmanBucy(md, 0.05).run(sim, [0.0], [[1.0]], t0=0.0)
    with pytest.raises(ValueError, match=r"dt: KalmanBucy was built with dt=0.1.*dt=0.05"):
        KalmanBucy(md, 0.1).run(sim, [0.0], [[1.0]])
    with pytest.raises(ValueError, match="ys: the Simulation holds increments measurements"):
        EKF(DiscreteModel([x], [x], [x], Q=1.0, R=1.0)).run(sim, [0.0], [[1.0]])


def test_simulation_keeps_its_timing_and_unpacks():
    sim = simulate_continuous_discrete(LIN_SDE, 3, paths=2, rng=0, m0=M0, P0=P0, dt=DT)
    xs, ys, x0, t = sim  # still a 4-tuple
    assert len(sim) == 4 and ys is sim.ys and t.tolist() == pytest.approx([0.4, 0.8, 1.2])
    for other in (pickle.loads(pickle.dumps(sim)), sim._replace(ys=ys[:1])):
        assert other.timing == sim.timing
    assert Simulation(xs, ys, x0, t).timing is None  # by hand, no convention: nothing checked
    with pytest.raises(TypeError, match="timing"):
        Simulation(xs, ys, x0, t, "predict")
    for bad, match in ((Timing("discrete", None, 0.0, None), "timing.start"),
                       (Timing("increments", "update", 0.0, 0.1), "timing.start"),
                       (Timing("continuous-discrete", "predict", 0.0, None), "timing.dt"),
                       (Timing("discrete", "update", 0.0, 0.1), "timing.dt"),
                       (Timing("sampled", "update", 0.0, None), "timing.kind"),
                       (Timing("discrete", "update", 0.0, None, 5), "timing.substeps"),
                       (Timing("increments", None, 0.0, 0.1, 0), "timing.substeps")):
        with pytest.raises((TypeError, ValueError), match=match):
            Simulation(xs, ys, x0, t, bad)


def test_compare_adapts_a_filter_built_without_start():
    """``compare(start="predict")`` with a filter instance built without ``start``: it runs in the
    comparison's convention (the same numbers as one built with it); one built with the other
    convention is refused, as before."""
    from nlfilter import compare

    x = sp.Symbol("x")
    md = DiscreteModel([x], [0.9 * x], [x], Q=0.1, R=0.5)
    kw = dict(paths=4, m0=0.0, P0=0.5, rng=1, start="predict", reference=None)
    a = compare(md, {"ekf": EKF(md)}, 10, **kw).get("ekf", "mse", component=0).value
    b = compare(md, {"ekf": EKF(md, start="predict")}, 10, **kw).get("ekf", "mse", component=0).value
    assert a == b
    with pytest.raises(ValueError, match=r"filters\['ekf'\]: its start='update' differs from start='predict'"):
        compare(md, {"ekf": EKF(md, start="update")}, 10, **kw)
