"""The reference filters of the bounded-noise problems (seed 000): grid and bootstrap particle."""

import numpy as np
import pytest
import scipy.stats as st

from nlfilter.bounded import BoundedNoiseModel
from nlfilter.filters.reference.bounded import BoundedGridFilter1D, BoundedParticleFilter

LAW = st.uniform(-1, 2)
MODEL = BoundedNoiseModel.first_order(0.5, 1.0, w_law=LAW)


def _data(R=4, T=12, seed=3):
    xs, ys = MODEL.simulate(T + 30, R, seed)
    return xs[:, 30:], ys[:, 30:]


def test_grid_raw_parameters_equal_the_model_form():
    _, ys = _data()
    a = BoundedGridFilter1D(0.5, LAW, 1.0, G=200).run(ys)
    b = BoundedGridFilter1D(MODEL, G=200).run(ys)
    np.testing.assert_array_equal(a.means, b.means)
    assert a.covs.shape == (4, 12, 1, 1) and np.all(a.covs >= 0) and not a.diverged.any()


def test_grid_missing_measurement_is_prediction_and_impossible_one_raises():
    _, ys = _data()
    g = BoundedGridFilter1D(MODEL, G=200)
    e = ys.copy()
    e[0, 5] = np.nan
    r, full = g.run(e), g.run(ys)
    b = g.init(None, None, (1,))
    for k in range(6):
        if k:
            b = g.predict(b, k - 1)
        if k != 5:
            b = g.update(b, ys[:1, k], k)
    np.testing.assert_allclose(r.means[0, 5], g.summary(b)[0][0], atol=1e-14)
    np.testing.assert_array_equal(r.means[1:], full.means[1:])
    e[1, 2] = 9.0
    with pytest.raises(ValueError, match=r"^ys\b"):
        g.run(e)


def test_particle_filter_agrees_with_the_grid_optimum():
    # 1-D: the bootstrap particle filter and the grid filter compute the same posterior mean
    _, ys = _data(R=6, T=15)
    grid = BoundedGridFilter1D(MODEL, G=400).run(ys)

    def x0(rng, shape):  # the stationary law, by running the dynamics
        x = np.zeros((*shape, 1))
        for _ in range(60):
            x = 0.5 * x + LAW.rvs(size=shape, random_state=rng)[..., None]
        return x

    pf = BoundedParticleFilter(MODEL, particles=4000)
    r = pf.run(ys, initial=x0, rng=1)
    assert np.max(np.abs(r.means - grid.means)) < 0.05  # Monte Carlo error ~ 0.01
    np.testing.assert_allclose(r.covs, grid.covs, atol=0.05)
    np.testing.assert_array_equal(pf.run(ys, initial=x0, rng=1).means, r.means)  # reproducible from the seed
    e = ys.copy()
    e[:, 4] = np.nan
    m = pf.run(e, initial=x0, rng=1)
    assert np.isfinite(m.means).all() and not m.diverged.any()
    with pytest.raises(TypeError, match=r"^initial\b"):
        pf.run(ys, rng=1)
