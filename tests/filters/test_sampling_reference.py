"""Posterior trajectory samples through the reference filters (:func:`nlfilter.sample_posterior`,
issue 30 item 4): forward filtering backward sampling on the grid filter, backward simulation on
the particle filter — checked against the Kalman RTS smoother on a linear-Gaussian model, against
the particle smoother on the same clouds, on a bimodal posterior that no Gaussian draw can show,
and for the per-path streams.

Tolerances. A sample mean of ``N`` draws is compared within 5 standard errors ``sqrt(var / N)``;
a sample variance within 5 of its standard error ``sqrt((μ₄ − σ⁴) / N)`` (μ₄ the draws' own
fourth central moment; ``2σ⁴`` for a Gaussian), a cross-time covariance within 5 of
``sqrt((Σ_ii Σ_jj + Σ_ij²) / N)`` (Gaussian). The chance that one of ~30 such checks exceeds 5 s.e.
is ~30 · 6e-7; the seeds are fixed. The grid's own error (its spacing h = 0.05 is below a tenth
of the smallest smoothed standard deviation, 0.66, so the point-mass sums of the Gaussian's
moments are exact to far below 1e-10, Poisson summation ~exp(−2π²(σ/h)²)) is measured, not
assumed: the grid smoother's moments equal the RTS smoother's to 1e-8.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, sample_posterior, simulate
from nlfilter.filters import UKF, GridFilter, KalmanFilter, ParticleFilter
from nlfilter.filters.quasilinear import DiscreteQuasilinearFilter
from nlfilter.filters.sampling import SAMPLE
from nlfilter.streams import PathRNG

x = sp.Symbol("x")
LINEAR = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.5, R=1.0)
YS = np.random.default_rng(1).normal(size=(2, 6, 1))


def _z(sample, expect, se):
    return float(np.max(np.abs(sample - expect) / se))


def test_grid_draws_have_the_rts_smoothers_moments_on_a_linear_gaussian_model():
    """Scalar AR(1), two paths, 6 steps, 4000 draws: at each step the draws' mean and variance
    are the RTS smoother's, and the cross-time covariance Cov[x_k, x_{k+1}] its lag-one
    covariance (a whole-trajectory property, not a marginal one)."""
    N = 4000
    grid = GridFilter(LINEAR, (-8.0, 8.0), 321)
    rts = KalmanFilter(LINEAR).smooth(YS, 0.0, 1.0)
    gs = grid.smooth(YS, 0.0, 1.0)
    np.testing.assert_allclose(gs.means, rts.means, atol=1e-8)  # the grid's discretisation error, measured
    np.testing.assert_allclose(gs.covs, rts.covs, atol=1e-8)
    d = sample_posterior(grid, YS, 0.0, 1.0, n=N, rng=3)[..., 0]  # (2, N, 6)
    m, P = rts.means[..., 0], rts.covs[..., 0, 0]
    assert _z(d.mean(1), m, np.sqrt(P / N)) < 5
    mu4 = np.mean((d - d.mean(1, keepdims=True)) ** 4, axis=1)
    assert _z(d.var(1, ddof=1), P, np.sqrt((mu4 - P**2) / N)) < 5
    C = rts.extras["lag_one_cov"][..., 0, 0]  # C[:, k] = Cov[x_k, x_{k+1} | Y]
    c = np.mean((d[..., :-1] - d[..., :-1].mean(1, keepdims=True)) * (d[..., 1:] - d[..., 1:].mean(1, keepdims=True)), 1)
    assert _z(c, C[:, :-1], np.sqrt((P[:, :-1] * P[:, 1:] + C[:, :-1] ** 2) / N)) < 5


def test_particle_draws_have_the_particle_smoothers_marginals_on_the_same_clouds():
    """Backward simulation's marginals given the clouds are FFBSm's (the same backward kernel):
    the smoother run on the sampler's streams (its forward pass: the same clouds) gives the
    expectation; only the N draws' Monte Carlo error remains."""
    N, B = 2000, 2
    pf = ParticleFilter(LINEAR, 300)
    d = sample_posterior(pf, YS, 0.0, 1.0, n=N, rng=5)[..., 0]
    sm = pf.smooth(YS, 0.0, 1.0, rng=PathRNG(5, B, key=SAMPLE))
    m, P = sm.means[..., 0], sm.covs[..., 0, 0]
    assert _z(d.mean(1), m, np.sqrt(P / N)) < 5
    mu4 = np.mean((d - d.mean(1, keepdims=True)) ** 4, axis=1)
    assert _z(d.var(1, ddof=0), P, np.sqrt((mu4 - P**2) / N)) < 5


def test_particle_draws_agree_with_the_rts_smoother_within_their_monte_carlo_error():
    """8 independent particle runs (own clouds, own draws) on one record: the spread of their
    draw means and variances across the runs measures the whole Monte Carlo error (particles
    and draws); their average is within 6 of its standard error sd/sqrt(8) of the RTS value
    (Student t with 7 d.o.f.: P(|t| > 6) = 5e-4 per check, 12 checks)."""
    R = 8
    ys = np.broadcast_to(YS[0], (R, 6, 1))
    d = sample_posterior(ParticleFilter(LINEAR, 300), ys, 0.0, 1.0, n=500, rng=9)[..., 0]  # (R, 500, 6)
    rts = KalmanFilter(LINEAR).smooth(YS[0], 0.0, 1.0)
    for stat, ref in ((d.mean(1), rts.means[:, 0]), (d.var(1), rts.covs[:, 0, 0])):
        assert _z(stat.mean(0), ref, stat.std(0, ddof=1) / np.sqrt(R)) < 6


def test_grid_draws_show_both_modes_of_a_bimodal_posterior_where_gaussian_draws_cannot():
    """h(x) = x², y ≈ 4 and a random walk: the posterior has modes near x = ±2 for the whole
    trajectory (weights ≈ 0.62 / 0.38 from the prior N(0.5, 4)). The grid's draws fall in both
    modes, none between them, and each draw stays in one mode over all steps; the UKF's draws (a
    Gaussian) put more mass in the gap |x| < 1 than in the negative mode."""
    md = DiscreteModel([x], f=[x], h=[x**2], Q=0.02, R=0.5)
    ys = np.array([[4.2], [3.6], [4.4], [3.9], [4.1]])
    g = sample_posterior(GridFilter(md, (-6.0, 6.0), 241), ys, 0.5, 4.0, n=2000, rng=1)[..., 0]
    u = sample_posterior(UKF(md), ys, 0.5, 4.0, n=2000, rng=1)[..., 0]
    pos, neg, gap = (np.abs(g - 2) < 1).mean(0), (np.abs(g + 2) < 1).mean(0), (np.abs(g) < 1).mean(0)
    assert pos.min() > 0.5 and neg.min() > 0.3 and gap.max() < 0.01, (pos, neg, gap)
    assert np.all(np.sign(g) == np.sign(g[:, :1]))  # whole trajectories in one mode
    u_neg, u_gap = (np.abs(u + 2) < 1).mean(0), (np.abs(u) < 1).mean(0)
    assert np.all(u_gap > 3 * u_neg) and u_gap.min() > 0.3, (u_neg, u_gap)


@pytest.mark.parametrize("make", [lambda: GridFilter(LINEAR, (-8.0, 8.0), 161), lambda: ParticleFilter(LINEAR, 100)],
                         ids=["grid", "particle"])
def test_each_path_draws_from_its_own_stream(make):
    """Paths 2..3 sampled alone (PathRNG(seed, range(2, 4), key=SAMPLE)) are rows 2..3 of the
    four-path run, bitwise; another seed gives other draws."""
    ys = np.random.default_rng(0).normal(size=(4, 5, 1))
    full = sample_posterior(make(), ys, 0.0, 1.0, n=3, rng=7)
    part = sample_posterior(make(), ys[2:], 0.0, 1.0, n=3, rng=PathRNG(7, range(2, 4), key=SAMPLE))
    np.testing.assert_array_equal(part, full[2:])
    assert full.shape == (4, 3, 5, 1)
    assert not np.array_equal(sample_posterior(make(), ys, 0.0, 1.0, n=3, rng=8), full)


def test_bad_input_is_named():
    ys = np.zeros((5, 1))
    for flt in (GridFilter(LINEAR, (-8.0, 8.0), 81), ParticleFilter(LINEAR, 50)):
        with pytest.raises(ValueError, match="n: "):
            sample_posterior(flt, ys, 0.0, 1.0, n=0, rng=0)
        with pytest.raises(TypeError, match="n: expected an integer"):
            sample_posterior(flt, ys, 0.0, 1.0, n=1.5, rng=0)
    with pytest.raises(TypeError, match="flt: .*DiscreteQuasilinearFilter"):
        sample_posterior(DiscreteQuasilinearFilter(LINEAR), ys, 0.0, 1.0, rng=0)
    sde = SDEModel([x], f=[-x], h=[x], Q=1.0, R=0.1)
    with pytest.raises(TypeError, match="flt: ParticleFilter .*substeps=1"):
        sample_posterior(ParticleFilter(sde, 50, dt=0.1, substeps=4), ys, 0.0, 1.0, rng=0)


def test_a_two_state_grid_and_a_particle_filter_on_an_sde_draw_their_smoothers_marginals():
    """The other kernels: a 2-D grid (its forward–backward smoother's means, per state) and a
    particle filter on an SDE (substeps=1: the Euler–Maruyama density, and the next increment's
    left-point likelihood weighing x_k; its FFBSm on the same clouds). 1000 draws, 5 s.e."""
    N = 1000
    y = sp.Symbol("y")
    md2 = DiscreteModel([x, y], f=[0.9 * x + 0.1 * y, 0.8 * y], h=[x], Q=0.3 * np.eye(2), R=0.5)
    ys = np.random.default_rng(0).normal(size=(2, 5, 1))
    grid = GridFilter(md2, [(-5.0, 5.0), (-5.0, 5.0)], 25)
    d = sample_posterior(grid, ys, [0.0, 0.0], np.eye(2), n=N, rng=2)
    sm = grid.smooth(ys, [0.0, 0.0], np.eye(2))
    assert _z(d.mean(1), sm.means, np.sqrt(np.diagonal(sm.covs, axis1=-2, axis2=-1) / N)) < 5
    sde = SDEModel([x], f=[-x], h=[x], Q=1.0, R=0.1)
    sim = simulate(sde, 10, paths=2, dt=0.05, rng=0, substeps=1, m0=0.0, P0=1.0)
    pf = ParticleFilter(sde, 200, dt=0.05, substeps=1)
    d = sample_posterior(pf, sim, 0.0, 1.0, n=N, rng=1)
    sm = pf.smooth(sim, 0.0, 1.0, rng=PathRNG(1, 2, key=SAMPLE))
    assert _z(d.mean(1)[..., 0], sm.means[..., 0], np.sqrt(sm.covs[..., 0, 0] / N)) < 5
