"""The optimal smoothers (issue 12): the forward–backward grid smoother and the particle smoother
(FFBSm) of :mod:`nlfilter.filters.reference.forward_backward` against the Rauch–Tung–Striebel smoother on
linear-Gaussian models (1-D and 2-D, missing data, both start conventions; an Ornstein–Uhlenbeck
SDE), and against their own filters on a nonlinear model."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter.filters import REGISTRY, GridFilter, KalmanFilter, ParticleFilter
from nlfilter.sde_step import SUBSTEPS

from .test_likelihood import LIN as LIN2
from .test_likelihood import M0 as M02
from .test_likelihood import P0 as P02

x = sp.Symbol("x")
LIN1 = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.3, R=0.5)  # stationary sd √(0.3/0.19) = 1.26
M0, P0 = [0.0], [[1.0]]


def _ys1(T=30, paths=3):
    ys = simulate(LIN1, T, paths=paths, m0=M0, P0=P0, rng=1).ys
    ys[0, 5] = np.nan
    ys[:, 10] = np.nan  # a step measured on no path
    return ys


@pytest.mark.parametrize("start", ["update", "predict"])
def test_grid_smoother_is_the_rts_smoother_1d(start):
    """801 points over ±10 (spacing 0.025, 1/22 of the process-noise sd √0.3): the grid's sums
    of Gaussian products are trapezoid rules on smooth integrands, spectrally accurate at that
    spacing, so the grid smoother is the RTS smoother to round-off (measured 1e-13; tolerance 1e-10)."""
    ys = _ys1()
    kf = KalmanFilter(LIN1, start=start).smooth(ys, M0, P0)
    g = GridFilter(LIN1, (-10.0, 10.0), 801, start=start).smooth(ys, M0, P0)
    np.testing.assert_allclose(g.means, kf.means, rtol=0, atol=1e-10)
    np.testing.assert_allclose(g.covs, kf.covs, rtol=0, atol=1e-10)
    filt = KalmanFilter(LIN1, start=start).run(ys, M0, P0)
    assert np.abs(kf.means - filt.means)[:, :-1].max() > 0.1  # the smoother does revise the filter
    # chunks of paths give the same numbers (to the last bits of a matrix product's blocking)
    c = GridFilter(LIN1, (-10.0, 10.0), 801, start=start).smooth(ys, M0, P0, chunk=2)
    np.testing.assert_allclose(c.means, g.means, rtol=0, atol=1e-14)


@pytest.mark.parametrize("start", ["update", "predict"])
def test_grid_smoother_is_the_rts_smoother_2d(start):
    """A 2-D linear model (correlated noises) on a 49 × 49 grid over ±7 (spacing 0.29, 1/1.3 of
    the smallest process-noise sd 0.37): the trapezoid error ~exp(−2π²(σ/h)²) is ~1e-15 per
    sum; measured 1.1e-9 (means) and 2.7e-9 (covariances), 9e-7 at 41 points, 2e-11 at 61."""
    ys = simulate(LIN2, 8, paths=2, m0=M02, P0=P02, rng=2).ys
    ys[0, 3, 1] = np.nan
    ys[1, 5] = np.nan
    kf = KalmanFilter(LIN2, start=start).smooth(ys, M02, P02)
    g = GridFilter(LIN2, [(-7.0, 7.0), (-7.0, 7.0)], 49, start=start).smooth(ys, M02, P02)
    np.testing.assert_allclose(g.means, kf.means, rtol=0, atol=1e-8)
    np.testing.assert_allclose(g.covs, kf.covs, rtol=0, atol=1e-8)


def test_grid_smoother_of_an_sde():
    """Ornstein–Uhlenbeck ``dx = −x dt + dβ``, ``dy = x dt + dη`` (R = 0.2), grid of 201 points
    over ±4. The grid filter on increments is the discrete filter of its Markov chain measured by
    ``dy/dt ~ N(x(t_{k+1}), R/dt)`` (the Kallianpur–Striebel factor is that Gaussian likelihood up
    to a constant), so its smoother is the RTS smoother of the exactly discretized model up to
    the chain's spatial error (measured ≤ 3.0e-4, as the filter's own 3.1e-4); the Kalman–Bucy
    (continuous RTS, backward Euler) smoother differs from both by O(dt): its gap halves with dt
    (measured 0.099, 0.054, 0.031)."""
    sde = SDEModel([x], [-x], [x], Q=1.0, R=0.2)
    gaps = []
    for dt in (0.04, 0.02, 0.01):
        T = int(round(2.0 / dt))
        dys = simulate(sde, T, paths=2, dt=dt, m0=[0.0], P0=[[0.5]], rng=7, substeps=4).ys
        g = GridFilter(sde, (-4.0, 4.0), 201, dt=dt).smooth(dys, [0.0], [[0.5]])
        a = np.exp(-dt)
        disc = DiscreteModel.linear([[a]], [[1.0]], [[0.5 * (1 - a * a)]], [[0.2 / dt]])
        ref = KalmanFilter(disc, start="predict").smooth(dys / dt, [0.0], [[0.5]])
        assert np.abs(g.means - ref.means).max() < 5e-4 and np.abs(g.covs - ref.covs).max() < 5e-4
        kb = REGISTRY["kalman-bucy"](sde, dt).smooth(dys, [0.0], [[0.5]])
        mid = slice(T // 4, 3 * T // 4)
        gaps.append(np.abs(g.means - kb.means)[:, mid].max())
    assert all(1.5 < a / b < 2.5 for a, b in zip(gaps, gaps[1:])), gaps


def test_grid_smoother_beats_the_grid_filter_on_a_nonlinear_model():
    """Cubic sensor ``y = x³ + v`` with nonlinear dynamics: the smoother's MSE over 100 simulated
    paths is below the filter's by many standard errors of the paired difference (measured
    0.104 against 0.137: 0.033 ± 0.0028, over every step but the last, where they are equal)."""
    md = DiscreteModel([x], f=[0.9 * x - 0.05 * x**3], h=[x**3], Q=0.1, R=0.2)
    sim = simulate(md, 40, paths=100, m0=[0.5], P0=[[0.3]], rng=3)
    grid = GridFilter(md, (-4.0, 4.0), 401)
    f = grid.run(sim.ys, [0.5], [[0.3]]).means[..., 0]
    s = grid.smooth(sim.ys, [0.5], [[0.3]]).means[..., 0]
    xs = sim.xs[..., 0]
    np.testing.assert_allclose(s[:, -1], f[:, -1], rtol=0, atol=1e-12)
    d = np.mean((f - xs)[:, :-1] ** 2 - (s - xs)[:, :-1] ** 2, axis=1)  # per path
    se = d.std(ddof=1) / np.sqrt(d.size)
    assert d.mean() > 5 * se, (d.mean(), se)


def _particle_z(flt, model, ys, m0, P0, ref, seeds):
    """Per entry (path, step, component) the mean error of the particle smoother's means over
    ``seeds`` divided by its standard error from their spread (a t-statistic)."""
    e = np.stack([flt.smooth(ys, m0, P0, rng=s).means - ref.means for s in seeds])
    return e.mean(axis=0) / (e.std(axis=0, ddof=1) / np.sqrt(len(seeds))), e


@pytest.mark.parametrize("start", ["update", "predict"])
def test_particle_smoother_is_the_rts_smoother_within_monte_carlo_error(start):
    """FFBSm with 400 particles, 16 seeds: every smoothed mean is within Monte Carlo error of the
    RTS smoother — the t-statistics of the mean over seeds (15 degrees of freedom, E t² = 1.15)
    have mean square ≈ 1 (measured 1.34, 0.94) and none beyond 4.5 (measured 3.0, 2.3); the Monte
    Carlo sd of one smoothed mean (over the seeds) has median 0.033 and is at most 0.12 (next to the
    step missing on every path), against a smoothed sd ≥ 0.43."""
    ys = _ys1(T=20, paths=3)
    kf = KalmanFilter(LIN1, start=start).smooth(ys, M0, P0)
    z, e = _particle_z(ParticleFilter(LIN1, 400, start=start), LIN1, ys, M0, P0, kf, range(16))
    assert np.mean(z**2) < 2.0 and np.abs(z).max() < 4.5, (np.mean(z**2), np.abs(z).max())
    sd = e.std(axis=0, ddof=1)
    assert np.median(sd) < 0.05 and sd.max() < 0.2, (np.median(sd), sd.max())


def test_particle_smoother_of_an_sde_is_the_smoother_of_its_euler_step():
    """On an SDE with ``substeps=1`` the particle filter is the discrete filter of the
    Euler–Maruyama chain ``x_{k+1} = (1 − dt) x_k + √dt w`` whose increment over ``[t_k, t_{k+1}]``
    is read with the simulator's left-point ``∫ h ds = x_k dt`` (:mod:`nlfilter.sde_step`):
    ``dy_k/dt ~ N(x_k, R/dt)``, ``start="update"``, and step ``k`` of the particle filter estimates
    ``x_{k+1}`` (one more KF step, measurement missing). Its smoother is that chain's RTS smoother
    within Monte Carlo error (t-statistics over 12 seeds: mean square 0.59, largest 1.4; without the
    backward factor of the next increment, `ffbsm(logg=)`, 7.1 and 4.7);
    with more substeps there is no transition density and ``smooth`` refuses, naming substeps."""
    sde = SDEModel([x], [-x], [x], Q=1.0, R=0.2)
    dt, T = 0.05, 30
    dys = simulate(sde, T, paths=2, dt=dt, m0=[0.0], P0=[[0.5]], rng=7, substeps=4).ys
    euler = DiscreteModel.linear([[1 - dt]], [[1.0]], [[dt]], [[0.2 / dt]])
    ys = np.concatenate([dys / dt, np.full_like(dys[:, :1], np.nan)], axis=1)  # x_T: nothing measures it
    ref = KalmanFilter(euler, start="update").smooth(ys, [0.0], [[0.5]])
    ref = ref._replace(means=ref.means[:, 1:])
    z, _ = _particle_z(ParticleFilter(sde, 400, dt=dt, substeps=1), sde, dys, [0.0], [[0.5]], ref, range(12))
    assert np.mean(z**2) < 2.0 and np.abs(z).max() < 4.5, (np.mean(z**2), np.abs(z).max())
    flt = ParticleFilter(sde, 100, dt=dt)
    assert flt.smoother is None
    with pytest.raises(TypeError, match=f"smooth.*substeps={SUBSTEPS}"):  # the default: simulate's
        flt.smooth(dys, [0.0], [[0.5]], rng=1)


def test_particle_smoother_needs_a_transition_density():
    """A state without process noise (G Q Gᵀ singular) has no transition density: refused."""
    x1, x2 = sp.symbols("x1 x2")
    md = DiscreteModel([x1, x2], [x1 + x2, 0.9 * x2], [x1], G=sp.Matrix([[0.0], [1.0]]), Q=0.1, R=0.2)
    ys = simulate(md, 5, paths=2, m0=[0.0, 0.0], P0=np.eye(2), rng=1).ys
    with pytest.raises(ValueError, match="transition density"):
        ParticleFilter(md, 50).smooth(ys, [0.0, 0.0], np.eye(2), rng=1)
