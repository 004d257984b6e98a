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


# -- the problem-specific simulators (moved from the experiments) ---------------------------------
def test_simulate_ou_shapes_seed_and_stationary_law():
    """Exact OU transition: x stays in its stationary law N(0, q/(2 rate)) and has lag-1
    autocorrelation exp(−rate dt); both within 4 standard errors over 4000 paths."""
    from nlfilter.simulate import simulate_ou
    q, r, dt, rate, paths = 2.0, 1.0, 0.05, 1.5, 4000
    a = simulate_ou(q, r, dt, 20, paths, np.random.default_rng(4), rate=rate)
    b = simulate_ou(q, r, dt, 20, paths, np.random.default_rng(4), rate=rate)
    assert a.xs.shape == (paths, 20, 1) and a.ys.shape == (paths, 20, 1) and a.x0.shape == (paths, 1)
    np.testing.assert_allclose(a.t, dt * np.arange(1, 21))
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)
    var = q / (2 * rate)
    x = a.xs[:, -1, 0]
    assert abs(x.var(ddof=1) - var) < 4 * var * np.sqrt(2 / (paths - 1))
    rho = np.corrcoef(a.xs[:, -2, 0], a.xs[:, -1, 0])[0, 1]
    assert abs(rho - np.exp(-rate * dt)) < 4 * (1 - rho**2) / np.sqrt(paths)
    # h(x) = x: dy − (trapezoidal ∫ x dt) is the measurement noise, variance r dt
    c = simulate_ou(q, r, dt, 5, paths, np.random.default_rng(5), h=lambda x: x, substeps=1)
    xprev = np.concatenate([c.x0, c.xs[:, :-1, 0]], axis=1)
    v = c.ys[..., 0] - 0.5 * dt * (xprev + c.xs[..., 0])
    assert abs(v.var(ddof=1) / (r * dt) - 1) < 4 * np.sqrt(2 / (v.size - 1))
    with pytest.raises(ValueError, match=r"^q\b"):
        simulate_ou(-1.0, r, dt, 5, 2, 0)


def test_simulate_continuous_discrete_flow_noise_and_measurements():
    """``process="flow"``: RK4 flow of dx = −x dt (relative error < 1e-7 at 20 substeps per 0.5), discrete
    measurements y = x + v with Var v = R (4 standard errors), Euler–Maruyama noise per interval: stationary variance
    q dt / (1 − e^{−2 dt}) (4 standard errors)."""
    from nlfilter.simulate import simulate_continuous_discrete
    x = sp.Symbol("x")
    det = SDEModel([x], [-x], [x], Q=0.0, R=0.3)
    flow = {"process": "flow", "substeps": 20}  # asked for: the default is Euler–Maruyama (test_cd_reference)
    s = simulate_continuous_discrete(det, 10, paths=3000, rng=2, x0=[2.0], dt=0.5, **flow)
    s2 = simulate_continuous_discrete(det, 10, paths=3000, rng=2, x0=[2.0], dt=0.5, **flow)
    assert s.xs.shape == (3000, 10, 1) and s.ys.shape == (3000, 10, 1)
    np.testing.assert_array_equal(s.ys, s2.ys)
    np.testing.assert_allclose(s.t, 0.5 * np.arange(1, 11))
    np.testing.assert_allclose(s.xs[0, :, 0], 2.0 * np.exp(-s.t), rtol=1e-7)  # RK4, h = 0.025: ~2e-8
    v = (s.ys - s.xs).ravel()
    assert abs(v.var(ddof=1) / 0.3 - 1) < 4 * np.sqrt(2 / (v.size - 1))
    q, dt, paths = 0.8, 0.2, 4000
    noisy = SDEModel([x], [-x], [x], Q=q, R=0.3)
    n = simulate_continuous_discrete(noisy, 60, paths=paths, rng=3, m0=0.0, P0=1.0, dt=dt, **flow)
    var = q * dt / (1 - np.exp(-2 * dt))
    assert abs(n.xs[:, -1, 0].var(ddof=1) - var) < 4 * var * np.sqrt(2 / (paths - 1))
    with pytest.raises(TypeError, match=r"^model\b"):
        simulate_continuous_discrete(DiscreteModel([x], [x], [x], Q=1.0, R=1.0), 3, dt=1.0, x0=[0.0])


def test_bounded_noise_model_simulate_burn_in_and_stationary_variance():
    """x+ = h x + w, w ~ U(−1, 1): after a burn-in of 300 the variance is Var w / (1 − h²) (4 s.e.);
    the measurement noise is U(−1, 1) (variance 1/3, 4 s.e.); burn = 0 starts at 0."""
    from nlfilter.bounded import BoundedNoiseModel
    h, paths = 0.6, 4000
    md = BoundedNoiseModel.first_order(h, 1.0, w_law=st.uniform(-1, 2))
    xs, ys = md.simulate(5, paths, 7, burn=300)
    xs2, ys2 = md.simulate(5, paths, 7, burn=300)
    assert xs.shape == (paths, 5, 1) and ys.shape == (paths, 5, 1)
    np.testing.assert_array_equal(ys, ys2)
    var = (1 / 3) / (1 - h * h)
    assert abs(xs[:, -1, 0].var(ddof=1) - var) < 4 * var * np.sqrt(2 / (paths - 1))  # kurtosis < 3: conservative
    v = (ys - xs).ravel()
    assert np.all(np.abs(v) <= 1.0) and abs(v.var(ddof=1) * 3 - 1) < 4 * np.sqrt(0.8 / (v.size - 1))  # Var(3 s²) = 9 (μ4 − σ⁴) / n
    x0s, _ = md.simulate(3, 4, 1)
    np.testing.assert_array_equal(x0s[:, 0], 0.0)


def test_zero_order_model_draws_laws_and_arguments():
    # seed 000 ch. III: x ~ (J+1)/2 x^J (|x| = U^{1/(J+1)}, random sign), v ~ U(-1, 1), in this order
    from nlfilter.bounded import ZeroOrderModel
    from nlfilter.moments.densities import power_density_moments
    J = 4
    xs, zs = ZeroOrderModel(J).simulate(7, 3, 5)
    for p in range(3):  # path p from its own stream SeedSequence(5).spawn(3)[p]
        rng = np.random.default_rng(np.random.SeedSequence(5).spawn(3)[p])
        u, s = rng.random(7), rng.random(7) < 0.5
        x = np.where(s, -1.0, 1.0) * u ** (1.0 / (J + 1))
        np.testing.assert_array_equal(xs[p, :, 0], x)
        np.testing.assert_array_equal(zs[p, :, 0], x + rng.uniform(-1.0, 1.0, 7))
    # the laws: moments of x (eq. 3.22) within 5 standard errors; scaled noise z = x + (1 + beta x) v
    xs, zs, v = ZeroOrderModel(J, beta=0.5).simulate(200_000, 1, 1, noise=True)  # i.i.d. along a path
    x = xs[0, :, 0]
    for i, m in enumerate(power_density_moments(4, J), start=1):
        assert abs(np.mean(x ** i) - m) < 5 * np.std(x ** i) / np.sqrt(x.size)
    np.testing.assert_array_equal(zs[0, :, 0], x + (1 + 0.5 * x) * v[0])
    assert np.all(np.abs(v) <= 1)
    # Gaussian copula: each keeps its law, corr(x, v) > 0 for r > 0
    xs, zs, v = ZeroOrderModel(10, copula_r=0.6).simulate(100_000, 1, 2, noise=True)
    assert abs(np.mean(v) - 0.0) < 0.01 and abs(np.mean(v ** 2) - 1 / 3) < 0.01
    assert abs(np.mean(xs ** 2) - 11 / 13) < 0.01 and np.corrcoef(xs[0, :, 0], v[0])[0, 1] > 0.4
    for kw, name in (({"J": 3}, "J"), ({"J": 2, "beta": 1.0}, "beta"), ({"J": 2, "copula_r": 1.0}, "copula_r"),
                     ({"J": 2, "noise_halfwidth": 0.0}, "noise_halfwidth")):
        with pytest.raises(ValueError, match=name):
            ZeroOrderModel(**kw)
    with pytest.raises(ValueError, match="paths"):
        ZeroOrderModel(2).simulate(3, 0, 0)
