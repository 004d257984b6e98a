"""Log-likelihood through the protocol (``run(..., loglik=True)``, issue 12): the Gaussian filters'
prediction-error decomposition equals the exact log-density of the stacked observations on
linear-Gaussian models (dense Gaussian, ``scipy.stats.multivariate_normal``) — time-invariant and
time-varying, with missing data, both start conventions; the grid log-evidence converges to it
with resolution; the particle estimate is within its standard error; a continuous filter's
density of the increments converges to the exact (grid) one."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy.stats import multivariate_normal

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter.evaluate import loglik
from nlfilter.filters import REGISTRY, GridFilter, ParticleFilter
from nlfilter.filters.gaussian import ContinuousGaussianFilter
from nlfilter.filters.rules import Taylor1

GAUSSIAN = ["kf", "ekf", "iekf", "ukf", "ckf", "ghkf", "slf", "second-order"]

x1, x2, k = sp.symbols("x1 x2 k")
F = np.array([[0.9, 0.2], [0.0, 0.8]])
H = np.array([[1.0, 0.5], [0.3, -1.0]])
Q = np.array([[0.3, 0.1], [0.1, 0.2]])
R = np.array([[0.5, 0.2], [0.2, 0.4]])
M0, P0 = np.array([0.5, -0.2]), np.array([[1.0, 0.3], [0.3, 0.7]])
LIN = DiscreteModel.linear(F, H, Q, R)
# time-varying: F_k = [[0.9 + 0.1 sin k, 0.2], [0, 0.8]], an offset in h
TV = DiscreteModel([x1, x2], [(0.9 + 0.1 * sp.sin(k)) * x1 + 0.2 * x2, 0.8 * x2],
                   [x1 + 0.5 * x2 + 0.1 * k, 0.3 * x1 - x2], Q=Q, R=R, time=k)


def dense(Fs, Hs, ds, m0, P0, Q, R, start="update"):
    """Mean and covariance of the stacked states and observations of a linear-Gaussian model,
    ``x_{k+1} = F_k x_k + w_k``, ``y_k = H_k x_k + d_k + v_k``, built by brute force (every
    covariance block from the transition products): an implementation independent of any filter."""
    T, n = len(Hs), len(m0)
    # states x_0..x_{T-1} measured by y_0..y_{T-1}; with start="predict" the prior is one step before x_0
    A = [np.eye(n)]  # x_t = A_t x_prior + Σ B_{t,l} w_l
    first = 0 if start == "update" else 1
    for t in range(1, T + first):
        A.append(Fs[t - 1] @ A[-1])
    A = A[first:]

    def trans(t, l):  # the map from w_l to x_t (w_l enters x_{l+1}), in run indices
        M = np.eye(n)
        for j in range(l + 1, t + first):
            M = Fs[j] @ M
        return M

    mx = np.concatenate([A[t] @ m0 for t in range(T)])
    C = np.zeros((T * n, T * n))
    for i in range(T):
        for j in range(T):
            c = A[i] @ P0 @ A[j].T
            for l in range(min(i, j) + first):
                c = c + trans(i, l) @ Q @ trans(j, l).T
            C[i * n:(i + 1) * n, j * n:(j + 1) * n] = c
    Hb = np.zeros((T * len(ds[0]), T * n))
    for t in range(T):
        Hb[t * len(ds[0]):(t + 1) * len(ds[0]), t * n:(t + 1) * n] = Hs[t]
    my = Hb @ mx + np.concatenate(ds)
    Syy = Hb @ C @ Hb.T + np.kron(np.eye(T), R)
    return mx, C, my, Syy, C @ Hb.T


def exact_loglik(y, my, Syy):
    y = y.ravel()
    o = ~np.isnan(y)
    return multivariate_normal(my[o], Syy[np.ix_(o, o)]).logpdf(y[o])


def _data(T, paths=3, seed=1):
    ys = np.random.default_rng(seed).normal(size=(paths, T, 2))
    ys[0, 2, 1] = np.nan  # partly missing
    ys[1, 3, :] = np.nan  # missing on one path
    ys[:, 4, 0] = np.nan  # one component missing on every path
    return ys


def _mats(model, T, start):
    off = 0 if start == "update" else 1
    z = np.zeros(2)
    Fs = [model.f_x(z, t) for t in range(T + 1)]
    Hs = [model.h_x(z, t + off) for t in range(T)]
    ds = [model.h(z, t + off) for t in range(T)]
    return Fs, Hs, ds


@pytest.mark.parametrize("start", ["update", "predict"])
@pytest.mark.parametrize("model", [LIN, TV], ids=["time-invariant", "time-varying"])
@pytest.mark.parametrize("name", GAUSSIAN)
def test_gaussian_loglik_is_the_exact_log_density(name, model, start):
    """Every rule is exact on a linear-Gaussian model, so its prediction-error decomposition is
    the exact log-density of the observed components (1e-9: roundoff of T = 7 steps)."""
    T = 7
    ys = _data(T)
    Fs, Hs, ds = _mats(model, T, start)
    _, _, my, Syy, _ = dense(Fs, Hs, ds, M0, P0, Q, R, start)
    est = REGISTRY[name](model, start=start).run(ys, M0, P0, loglik=True)
    want = [exact_loglik(ys[p], my, Syy) for p in range(3)]
    np.testing.assert_allclose(est.loglik, want, rtol=0, atol=1e-9)
    # the innovations are those of the Kalman filter: white with the predicted covariances
    kf = REGISTRY["kf"](model, start=start).run(ys, M0, P0, loglik=True)
    np.testing.assert_allclose(est.innovations, kf.innovations, rtol=0, atol=1e-9)
    np.testing.assert_allclose(est.innovation_covs[0, :2], kf.innovation_covs[0, :2], rtol=0, atol=1e-9)


def test_innovations_are_the_chain_rule_terms():
    """Per step, extras["loglik"] is log p(y_k | y_0..y_{k-1}): the difference of the exact
    log-densities of the records up to k and k − 1 (1e-9)."""
    T = 5
    ys = _data(T)[:1]
    Fs, Hs, ds = _mats(LIN, T, "update")
    est = REGISTRY["ukf"](LIN).run(ys, M0, P0, loglik=True)
    cum = []
    for t in range(1, T + 1):
        _, _, my, Syy, _ = dense(Fs[:t + 1], Hs[:t], ds[:t], M0, P0, Q, R)
        cum.append(exact_loglik(ys[0, :t], my, Syy))
    np.testing.assert_allclose(est.extras["loglik"][0], np.diff([0.0, *cum]), rtol=0, atol=1e-9)


ONE = DiscreteModel.linear([[0.9]], [[1.0]], [[0.5]], [[0.3]])


def _one_data(T=10):
    ys = np.random.default_rng(5).normal(size=(2, T, 1))
    ys[0, 3, 0] = np.nan
    return ys


def test_grid_log_evidence_converges_to_the_exact_one():
    """The grid's log-evidence log Σ p⁻_i p(y | x_i) is a quadrature of the exact evidence: its
    error falls with the resolution (the trapezoid rule on smooth Gaussians converges
    geometrically) to 1e-9 at 401 points over ±8 s.d."""
    ys = _one_data()
    exact = REGISTRY["kf"](ONE).run(ys, [0.0], [[1.0]], loglik=True).loglik
    err = {N: np.abs(GridFilter(ONE, (-8, 8), N).run(ys, [0.0], [[1.0]], loglik=True).loglik - exact).max()
           for N in (21, 41, 401)}
    assert err[21] > err[41] and err[401] < 1e-9, err


def test_particle_loglik_is_within_its_standard_error():
    """The bootstrap filter's estimate over 20 independent runs (2000 particles): the mean of the
    log-estimates is within 3 standard errors of the exact log-likelihood (its log is biased low
    by about half its variance, ~1e-3 here, far below the standard error ~1e-2)."""
    ys = _one_data()[:1]
    exact = REGISTRY["kf"](ONE).run(ys, [0.0], [[1.0]], loglik=True).loglik[0]
    vals = np.array([ParticleFilter(ONE, 2000).run(ys, [0.0], [[1.0]], loglik=True, rng=s).loglik[0]
                     for s in range(20)])
    se = vals.std(ddof=1) / np.sqrt(len(vals))
    assert 0 < se < 0.05 and abs(vals.mean() - exact) < 3 * se, (vals.mean() - exact, se)
    # the same through evaluate.loglik: 20 replicates in one batch on independent streams
    res = loglik(ParticleFilter(ONE, 2000), ys, [0.0], [[1.0]], replicates=20, rng=0)
    assert res.value.shape == (1,) and 0 < res.stderr[0] < 0.05 and abs(res.value[0] - exact) < 3 * res.stderr[0]
    np.testing.assert_allclose(res.spread, res.stderr * np.sqrt(20))
    kf = loglik(REGISTRY["kf"](ONE), ys, [0.0], [[1.0]])
    assert kf.value[0] == exact and kf.stderr[0] == 0.0
    with pytest.raises(ValueError, match="replicates"):
        loglik(REGISTRY["kf"](ONE), ys, [0.0], [[1.0]], replicates=3)
    with pytest.raises(TypeError, match="log-likelihood"):
        loglik(REGISTRY["discrete-quasilinear"].for_model(ONE), ys)


def test_continuous_loglik_converges_to_the_grid_density():
    """Increments dy of an Ornstein–Uhlenbeck SDE: the density of the record under the
    discretised measurement (the update form of the continuous EKF, the Kalman–Bucy filter) and
    under the grid filter (exact up to its O(dt) transition) agree within O(dt); the update form
    and the grid to 1e-4 at dt = 0.01 (measured 5e-7), the Itô form within 0.05 (measured 5e-3)."""
    x = sp.Symbol("x")
    sde = SDEModel([x], [-x], [x], Q=1.0, R=0.2)
    dt = 0.01
    dys = simulate(sde, 200, paths=2, dt=dt, m0=[0.0], P0=[[0.5]], rng=3).ys
    grid = GridFilter(sde, (-5, 5), 401, dt=dt).run(dys, [0.0], [[0.5]], loglik=True).loglik
    upd = ContinuousGaussianFilter(sde, dt, Taylor1(), innovation="update").run(dys, [0.0], [[0.5]],
                                                                                loglik=True).loglik
    kb = REGISTRY["kalman-bucy"](sde, dt).run(dys, [0.0], [[0.5]], loglik=True).loglik
    np.testing.assert_allclose(upd, grid, rtol=0, atol=1e-4)
    np.testing.assert_allclose(kb, grid, rtol=0, atol=0.05)


@pytest.mark.parametrize("name", GAUSSIAN)
def test_loglik_with_control_inputs_is_exact(name):
    """x[k+1] = 0.9 x + u[k] + w, y = x + v with a known input sequence (``with_inputs``) and
    missing data: the exact log-density of the stacked observations (mean shifted by the input
    response), to 1e-9."""
    x, u = sp.symbols("x u")
    md = DiscreteModel([x], [0.9 * x + u], [x], Q=0.5, R=0.3, inputs=[u])
    T = 8
    us = np.sin(np.arange(T))[:, None]
    ys = _one_data(T)
    a = 0.9
    C = np.array([[a ** abs(i - j) * (a ** (2 * min(i, j)) + 0.5 * (1 - a ** (2 * min(i, j))) / (1 - a * a))
                   for j in range(T)] for i in range(T)])
    mean = np.zeros(T)
    for t in range(1, T):
        mean[t] = a * mean[t - 1] + us[t - 1, 0]
    est = REGISTRY[name](md.with_inputs(us)).run(ys, [0.0], [[1.0]], loglik=True)
    for p in range(2):
        o = ~np.isnan(ys[p, :, 0])
        want = multivariate_normal(mean[o], C[np.ix_(o, o)] + 0.3 * np.eye(o.sum())).logpdf(ys[p, o, 0])
        assert abs(est.loglik[p] - want) < 1e-9


def test_conditional_moment_filters_give_the_assumed_density_evidence():
    """The conditional-moment family's likelihood: the log-evidence of each measurement under its
    assumed density, by the Bayes update's Gauss–Hermite quadrature. With the Gaussian closure on
    a linear-Gaussian model the assumed density is the exact one, so it converges to the exact
    log-likelihood with the points per axis (measured 0.11, 1.9e-3, 1.2e-6 at 6, 12, 24); the
    continuous filter's density of the increments of an OU record agrees with the grid's (7e-5)."""
    T = 7
    ys = _data(T)
    exact = REGISTRY["kf"](LIN).run(ys, M0, P0, loglik=True).loglik
    err = [np.abs(REGISTRY["discrete-conditional-moment"](LIN, points=p).run(ys, M0, P0, loglik=True).loglik
                  - exact).max() for p in (6, 12, 24)]
    assert err[0] > err[1] > err[2] and err[2] < 1e-5, err
    x = sp.Symbol("x")
    sde = SDEModel([x], [-x], [x], Q=1.0, R=0.2)
    dt = 0.01
    dys = simulate(sde, 200, paths=2, dt=dt, m0=[0.0], P0=[[0.5]], rng=3).ys
    grid = GridFilter(sde, (-5, 5), 401, dt=dt).run(dys, [0.0], [[0.5]], loglik=True).loglik
    cmf = REGISTRY["conditional-moment"](sde, dt).run(dys, [0.0], [[0.5]], loglik=True).loglik
    np.testing.assert_allclose(cmf, grid, rtol=0, atol=1e-3)
    with pytest.raises(TypeError, match="loglik"):
        REGISTRY["conditional-moment"](sde, dt, update="ito").run(dys, [0.0], [[0.5]], loglik=True)
