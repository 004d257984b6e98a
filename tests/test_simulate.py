import numpy as np
import pytest
import scipy.stats as st
import sympy as sp

from nlfilter import DiscreteModel, Independent, SDEModel
from nlfilter.simulate import simulate

x = sp.Symbol("x")


def test_reproducible_and_common_noise():
    md = DiscreteModel([x], [0.5 * x], [x**3], Q=1.0, R=1.0)
    a = simulate(md, 10, paths=4, rng=7, m0=0.0, P0=1.0)
    b = simulate(md, 10, paths=4, rng=7, m0=0.0, P0=1.0)
    np.testing.assert_array_equal(a.ys, b.ys)
    assert a.xs.shape == (4, 10, 1) and a.t.tolist() == list(range(10))


def test_ou_moments_by_euler_maruyama():
    """dx = -x dt + dβ from x0 = 1: E x(1) = e^-1, Var = (1 - e^-2)/2; EM with 100 steps/unit is
    weakly first order (bias ~ 0.5 %); 20000 paths give stderr 0.005 on the mean."""
    md = SDEModel([x], [-x], [x], Q=1.0, R=1.0)
    sim = simulate(md, 10, paths=20000, rng=1, x0=[1.0], dt=0.1, substeps=10)
    xT = sim.xs[:, -1, 0]
    assert abs(xT.mean() - np.exp(-1)) < 4 * xT.std() / np.sqrt(xT.size) + 0.005
    assert abs(xT.var() - (1 - np.exp(-2)) / 2) < 0.02


def test_non_gaussian_noise_law():
    md = DiscreteModel([x], [0 * x], [x], R=1 / 3, process_noise=Independent(st.uniform(-1, 2)),
                       measurement_noise=Independent(st.uniform(-1, 2)))
    sim = simulate(md, 50, paths=200, rng=2, x0=[0.0])
    v = sim.ys - sim.xs
    assert np.abs(v).max() <= 1.0 and np.abs(sim.xs[:, 1:]).max() <= 1.0


def test_bad_arguments():
    md = DiscreteModel([x], [x], [x], Q=1.0, R=1.0)
    with pytest.raises(ValueError, match="steps"):
        simulate(md, 0, m0=0.0, P0=1.0)
    with pytest.raises(ValueError, match="dt: a DiscreteModel"):
        simulate(md, 3, m0=0.0, P0=1.0, dt=0.1)
    with pytest.raises(ValueError, match="dt: expected the measurement step"):
        simulate(SDEModel([x], [-x], [x], Q=1.0, R=1.0), 3, m0=0.0, P0=1.0)
    with pytest.raises(TypeError, match="rng"):
        simulate(md, 3, m0=0.0, P0=1.0, rng="seed")
