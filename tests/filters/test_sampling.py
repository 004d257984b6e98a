"""Posterior trajectory samples (:func:`nlfilter.sample_posterior`, issue 30 item 4): exact on a
linear-Gaussian model against the dense Gaussian posterior of the whole trajectory, the RTS
smoother's marginals on a nonlinear one, per-path streams independent of the batch split.

Tolerances: a sample mean of N draws is within 5 standard errors (sqrt(var / N)) of its
expectation and a sample covariance entry within 5 of its standard error
(sqrt((Σ_ii Σ_jj + Σ_ij²) / N), the Gaussian case); with at most ~80 compared quantities per
test, the chance that any exceeds 5 s.e. is ~80 · 6e-7 — and the seed is fixed.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, sample_posterior
from nlfilter.errors import DivergenceError
from nlfilter.filters import EKF, KalmanFilter
from nlfilter.filters.quasilinear import DiscreteQuasilinearFilter
from nlfilter.filters.sampling import SAMPLE
from nlfilter.streams import PathRNG

N = 20000


def _within(sample, expect, se, what):
    z = np.abs(sample - expect) / se
    assert np.all(z < 5.0), f"{what}: largest deviation {z.max():.2f} s.e."


def _moments_check(draws, mean, cov):
    """draws (N, d) against N(mean, cov): means and every covariance entry within 5 s.e."""
    _within(draws.mean(0), mean, np.sqrt(np.diag(cov) / len(draws)), "mean")
    d = np.diag(cov)
    _within(np.cov(draws, rowvar=False), cov, np.sqrt((np.outer(d, d) + cov**2) / len(draws)), "covariance")


def _tracking():
    """Constant velocity, position measured, the noise on the velocity only: G Q Gᵀ is singular,
    so the backward pass's conditional law of x_k given x_{k+1} is degenerate (rank 1)."""
    p, v = sp.symbols("p v")
    return DiscreteModel([p, v], f=[p + v, 0.95 * v], h=[p], G=[[0.0], [1.0]], Q=0.3, R=0.5)


def _dense_posterior(F, GQG, H, R, m0, P0, ys):
    """The Gaussian posterior of the stacked x_0..x_{T-1} (y_k measures x_k; NaN: missing)."""
    T, n = ys.shape[0], len(m0)
    mus, Ps = [m0], [P0]
    for _ in range(T - 1):
        mus.append(F @ mus[-1])
        Ps.append(F @ Ps[-1] @ F.T + GQG)
    S = np.zeros((T * n, T * n))
    for k in range(T):
        Fp = np.eye(n)
        for j in range(k, T):  # Cov[x_j, x_k] = F^{j-k} P_k
            S[j * n:(j + 1) * n, k * n:(k + 1) * n] = Fp @ Ps[k]
            S[k * n:(k + 1) * n, j * n:(j + 1) * n] = (Fp @ Ps[k]).T
            Fp = F @ Fp
    mu = np.concatenate(mus)
    rows = [(k, i) for k in range(T) for i in range(ys.shape[1]) if np.isfinite(ys[k, i])]
    A = np.zeros((len(rows), T * n))
    for r, (k, i) in enumerate(rows):
        A[r, k * n:(k + 1) * n] = H[i]
    y = np.array([ys[k, i] for k, i in rows])
    Ry = np.diag([R[i, i] for _, i in rows])
    K = S @ A.T @ np.linalg.inv(A @ S @ A.T + Ry)
    return mu + K @ (y - A @ mu), S - K @ A @ S


def test_exact_on_a_linear_gaussian_model_against_the_dense_posterior():
    """Tracking model, 6 steps, one measurement missing: the draws' joint mean and covariance
    (12 × 12, cross-time entries included) are the dense posterior's."""
    md = _tracking()
    ys = np.array([[0.3], [1.1], [np.nan], [2.0], [3.2], [3.9]])
    m0, P0 = np.array([0.0, 1.0]), np.diag([1.0, 0.5])
    draws = sample_posterior(KalmanFilter(md, start="update"), ys, m0, P0, n=N, rng=11)
    assert draws.shape == (N, 6, 2)
    F = np.array([[1.0, 1.0], [0.0, 0.95]])
    mu, S = _dense_posterior(F, np.diag([0.0, 0.3]), np.array([[1.0, 0.0]]), np.array([[0.5]]), m0, P0, ys)
    _moments_check(draws.reshape(N, 12), mu, S)


def test_the_marginals_are_the_rts_smoothers_on_a_nonlinear_model():
    """EKF on the cubic sensor, two paths: at each step the draws' mean and variance are the EKF
    RTS smoother's (the sampler's law is the Gaussian approximation the smoother summarizes)."""
    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[0.9 * x + 0.2 * sp.sin(x)], h=[x**3], Q=0.2, R=0.5)
    ys = np.random.default_rng(4).normal(size=(2, 8, 1))
    flt = EKF(md)
    draws = sample_posterior(flt, ys, 0.5, 0.4, n=N, rng=5, backend="numpy")
    sm = flt.smooth(ys, 0.5, 0.4, backend="numpy")
    for b in range(2):
        for k in range(8):
            _moments_check(draws[b, :, k], sm.means[b, k], sm.covs[b, k])


def test_each_path_draws_from_its_own_stream():
    """Paths 2..3 sampled alone (their streams: PathRNG(seed, range(2, 4), key=SAMPLE)) are rows
    2..3 of the four-path run, bitwise; another seed gives other draws."""
    md = _tracking()
    ys = np.random.default_rng(0).normal(size=(4, 5, 1))
    kf = KalmanFilter(md)
    full = sample_posterior(kf, ys, [0.0, 0.0], np.eye(2), n=3, rng=7)
    part = sample_posterior(kf, ys[2:], [0.0, 0.0], np.eye(2), n=3, rng=PathRNG(7, range(2, 4), key=SAMPLE))
    np.testing.assert_array_equal(part, full[2:])
    assert not np.array_equal(sample_posterior(kf, ys, [0.0, 0.0], np.eye(2), n=3, rng=8), full)


def test_bad_input_is_named():
    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.5, R=1.0)
    ys = np.zeros((5, 1))
    with pytest.raises(TypeError, match="flt: .*DiscreteQuasilinearFilter"):  # no backward pass
        sample_posterior(DiscreteQuasilinearFilter(md), ys, 0.0, 1.0, rng=0)
    with pytest.raises(ValueError, match="n: "):
        sample_posterior(KalmanFilter(md), ys, 0.0, 1.0, n=0, rng=0)
    with pytest.raises(TypeError, match="n: expected an integer"):
        sample_posterior(KalmanFilter(md), ys, 0.0, 1.0, n=2.5, rng=0)


def test_a_diverging_forward_pass_raises():
    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[x**3], h=[x], Q=0.1, R=0.1)
    with pytest.raises(DivergenceError):
        sample_posterior(EKF(md), np.full((30, 1), np.nan), 50.0, 1.0, rng=0, backend="numpy")  # x³ from 50, unmeasured: overflows
