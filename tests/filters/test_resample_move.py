"""The resample-move particle filter (reference for noise-free continuous dynamics, discrete
measurements) against the exact posterior of a linear problem."""

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.filters.kalman import KalmanFilter
from nlfilter.filters.reference import ResampleMoveParticleFilter
from nlfilter.simulate import simulate_continuous_discrete


def test_linear_noise_free_problem_matches_the_kalman_filter():
    """dx = −0.5 x dt, y_k = x(t_k) + v_k: the posterior is Gaussian, given by the Kalman filter of
    x+ = e^{−dt/2} x (Q = 0). The particle means agree within 4 Monte Carlo standard errors of the
    posterior standard deviation (√(P/N_eff), N_eff ≥ 0.2 N) at every step; moves are accepted."""
    x = sp.Symbol("x")
    dt, R, m0, P0 = 0.5, 0.2, np.array([1.0]), np.array([[0.5]])
    md = SDEModel([x], [-0.5 * x], [x], Q=0.0, R=R)
    sim = simulate_continuous_discrete(md, 12, paths=4, rng=1, m0=m0, P0=P0, dt=dt)
    est = ResampleMoveParticleFilter(md, 2000, dt=dt, substeps=10, start="predict").run(sim.ys, m0, P0, rng=3)
    kf = KalmanFilter(DiscreteModel.linear([[np.exp(-0.5 * dt)]], [[1.0]], [[0.0]], [[R]]), start="predict")
    ref = kf.run(sim.ys, m0, P0)
    sd = np.sqrt(ref.covs[..., 0, 0])
    assert np.all(np.abs(est.means[..., 0] - ref.means[..., 0]) < 4 * sd / np.sqrt(0.2 * 2000))
    np.testing.assert_allclose(est.covs[..., 0, 0], ref.covs[..., 0, 0], rtol=0.25)
    acc = est.extras["accepted"][:, -1].sum() / est.extras["proposed"][:, -1].sum()
    assert est.extras["proposed"][:, -1].sum() > 0 and 0.05 < acc < 1.0


def test_refuses_process_noise_and_bad_options():
    x = sp.Symbol("x")
    with pytest.raises(ValueError, match=r"^model\b"):
        ResampleMoveParticleFilter(SDEModel([x], [-x], [x], Q=1.0, R=1.0), 10, dt=0.1)
    with pytest.raises(TypeError, match=r"^model\b"):
        ResampleMoveParticleFilter(DiscreteModel([x], [x], [x], Q=1.0, R=1.0), 10, dt=0.1)
    with pytest.raises(ValueError, match=r"^particles\b"):
        ResampleMoveParticleFilter(SDEModel([x], [-x], [x], Q=0.0, R=1.0), 0, dt=0.1)
