"""Smoothers through the protocol (``Filter.smooth``, issue 12): every Gaussian filter's RTS
smoother through its moment rule equals the exact smoothing posterior (dense Gaussian
conditioning of the stacked states on the observed components) on linear models to 1e-9 —
time-invariant and time-varying, missing data, both start conventions; the continuous-discrete
smoothers equal the RTS smoother of the exactly discretized model (to the RK4 error); the
continuous RTS smoother converges to the discrete one as dt → 0."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter.filters import REGISTRY

from .test_likelihood import GAUSSIAN, LIN, M0, ONE, P0, Q, R, TV, _data, _mats, _one_data, dense


def exact_smoother(ys, Fs, Hs, ds, start):
    mx, Cxx, my, Syy, Cxy = dense(Fs, Hs, ds, M0, P0, Q, R, start)
    y = ys.ravel()
    o = ~np.isnan(y)
    K = Cxy[:, o] @ np.linalg.inv(Syy[np.ix_(o, o)])
    ms = mx + K @ (y[o] - my[o])
    Ps = Cxx - K @ Cxy[:, o].T
    T = len(Hs)
    return ms.reshape(T, 2), np.array([Ps[2 * t:2 * t + 2, 2 * t:2 * t + 2] for t in range(T)])


@pytest.mark.parametrize("start", ["update", "predict"])
@pytest.mark.parametrize("model", [LIN, TV], ids=["time-invariant", "time-varying"])
@pytest.mark.parametrize("name", GAUSSIAN)
def test_rts_is_the_exact_smoothing_posterior(name, model, start):
    T = 7
    ys = _data(T)
    Fs, Hs, ds = _mats(model, T, start)
    est = REGISTRY[name](model, start=start).smooth(ys, M0, P0)
    for p in range(3):
        ms, Ps = exact_smoother(ys[p], Fs, Hs, ds, start)
        np.testing.assert_allclose(est.means[p], ms, rtol=0, atol=1e-9)
        np.testing.assert_allclose(est.covs[p], Ps, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", GAUSSIAN)
def test_scalar_rts_is_the_exact_smoothing_posterior(name):
    """n = m = 1 (the elementwise paths of the update and the smoother's gain), missing data."""
    ys = _one_data()
    T = ys.shape[1]
    a, qv, rv = 0.9, 0.5, 0.3
    C = np.array([[a ** abs(i - j) * (a ** (2 * min(i, j)) * 1.0 + qv * (1 - a ** (2 * min(i, j))) / (1 - a * a))
                   for j in range(T)] for i in range(T)])  # Cov[x_i, x_j], x_0 ~ N(0, 1)
    est = REGISTRY[name](ONE).smooth(ys, [0.0], [[1.0]])
    for p in range(2):
        o = ~np.isnan(ys[p, :, 0])
        K = C[:, o] @ np.linalg.inv(C[np.ix_(o, o)] + rv * np.eye(o.sum()))
        np.testing.assert_allclose(est.means[p, :, 0], K @ ys[p, o, 0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(est.covs[p, :, 0, 0], np.diag(C - K @ C[:, o].T), rtol=0, atol=1e-9)


x1, x2 = sp.symbols("x1 x2")
A = np.array([[0.0, 1.0], [-1.0, -0.5]])
SLIN = SDEModel([x1, x2], list(sp.Matrix(A) * sp.Matrix([x1, x2])), [x1, x2 + x1], Q=np.diag([0.1, 0.3]),
                R=np.array([[0.2, 0.05], [0.05, 0.1]]))


def _discretized(dt):
    """The exact discretization of SLIN over dt (Van Loan), measured by h with noise R."""
    n = 2
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = -A, np.diag([0.1, 0.3]), A.T
    E = sla.expm(M * dt)
    Fd = E[n:, n:].T
    Qd = Fd @ E[:n, n:]
    return DiscreteModel.linear(Fd, [[1.0, 0.0], [1.0, 1.0]], 0.5 * (Qd + Qd.T), SLIN.R)


@pytest.mark.parametrize("name", ["continuous-discrete-ekf", "continuous-discrete-ukf", "continuous-discrete-ckf",
                                  "continuous-discrete-ghkf", "continuous-discrete-second-order",
                                  "continuous-discrete-iekf", "continuous-discrete-slf"])
def test_continuous_discrete_rts_is_the_smoother_of_the_exact_discretization(name):
    """The moment equations with dC/dt = C Fᵀ (RK4, 20 substeps per interval of 0.2): the RTS
    smoother of the exact discretization to 1e-8 (RK4's error, (0.01)^4 ≈ 1e-8 relative)."""
    dt, T = 0.2, 8
    ys = simulate(_discretized(dt), T, paths=2, m0=M0, P0=P0, rng=4).ys
    ys[0, 3, 1] = np.nan
    ref = REGISTRY["kf"](_discretized(dt)).smooth(ys, M0, P0)
    # the data measure x(t_0) first (the discrete simulator's start="update"); the continuous-discrete
    # filters' default is the SDE simulator's "predict": stated here
    flt = REGISTRY[name](SLIN, dt, substeps=20, start="update").smooth(ys, M0, P0)
    np.testing.assert_allclose(flt.means, ref.means, rtol=0, atol=1e-8)
    np.testing.assert_allclose(flt.covs, ref.covs, rtol=0, atol=1e-8)


def test_continuous_rts_converges_to_the_discrete_smoother():
    """Kalman–Bucy smoother (continuous RTS, backward Euler) on an Ornstein–Uhlenbeck record:
    the gap to the RTS smoother of the exactly discretized model measured by dy/dt (noise R/dt)
    halves with dt (first order: the Euler steps and the Itô gain)."""
    x = sp.Symbol("x")
    sde = SDEModel([x], [-x], [x], Q=1.0, R=0.2)
    gaps = []
    for dt in (0.02, 0.01, 0.005):
        T = int(round(2.0 / dt))
        dys = simulate(sde, T, paths=1, dt=dt, m0=[0.0], P0=[[0.5]], rng=7, substeps=4).ys
        kb = REGISTRY["kalman-bucy"](sde, dt).smooth(dys, [0.0], [[0.5]])
        a = np.exp(-dt)
        disc = DiscreteModel.linear([[a]], [[1.0]], [[0.5 * (1 - a * a)]], [[0.2 / dt]])
        # the discrete model measures x(t_{k+1}) by dy_k / dt: start="predict" from the prior at t_0
        ref = REGISTRY["kf"](disc, start="predict").smooth(dys / dt, [0.0], [[0.5]])
        mid = slice(T // 4, 3 * T // 4)
        gaps.append(np.abs(kb.covs[0, mid, 0, 0] - ref.covs[0, mid, 0, 0]).max())
    # measured 4.9e-4, 2.6e-4, 1.4e-4 (smoothed variance ≈ 0.15): first order
    assert all(1.6 < a / b < 2.4 for a, b in zip(gaps, gaps[1:])) and gaps[2] < 2e-4, gaps


def test_statistically_linearized_filter_has_the_exact_gaussian_moments():
    """The SLF's prediction of x³ under N(m, P) is the exact statistical linearization:
    E[x³] = m³ + 3mP, Var[x³] = 9m⁴P + 36m²P² + 15P³, Cov[x, x³] = 3m²P + 3P² (1e-12), and its
    smoother uses that cross-covariance (on the cubic growth model, a smoother gain G = Cov[x, f] / P⁻)."""
    x = sp.Symbol("x")
    md = DiscreteModel([x], [x**3], [x], Q=0.1, R=1.0)
    flt = REGISTRY["slf"](md)
    m, P = 0.7, 0.4
    from nlfilter.filters import GaussianState
    pred, cross = flt._predict_cross(GaussianState(np.array([m]), np.array([[P]])), 0)
    assert abs(pred.mean[0] - (m**3 + 3 * m * P)) < 1e-12
    assert abs(pred.cov[0, 0] - (9 * m**4 * P + 36 * m**2 * P**2 + 15 * P**3 + 0.1)) < 1e-12
    assert abs(cross[0, 0] - (3 * m**2 * P + 3 * P**2)) < 1e-12
    assert flt.order == 4
