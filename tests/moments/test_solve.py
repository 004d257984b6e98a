"""Transient and steady-state moment solutions against closed forms, long-time ODE solutions,
the stationary density of the cubic drift and Monte Carlo."""
import numpy as np
import pytest
import sympy as sp
from scipy.special import gamma as Gamma

from nlfilter.errors import ClosureDivergedError, SingularSystemError
from nlfilter.moments import (CumulantClosure, EdgeworthClosure, GaussianClosure, PolynomialSDE,
                              discrete_moment_equations, gaussian_moments, iterate, moment_equations,
                              monomials, propagate, stationary_moments, steady_state)
from nlfilter import DiscreteModel

x, y = sp.symbols("x y")


def test_ou_2d_steady_state_direct_equals_lyapunov_and_long_time_ode():
    F = np.array([[-1.0, 0.5], [0.0, -2.0]])
    S = np.array([[1.0, 0.2], [0.2, 0.5]])
    sde = PolynomialSDE.from_sympy([x, y], sp.Matrix(F.tolist()) * sp.Matrix([x, y]), S.tolist())
    idx = monomials(2, 4)  # includes E[1]: its row becomes E[1] = 1
    eq = moment_equations(sde, idx)
    mu = steady_state(eq)
    from scipy.linalg import solve_continuous_lyapunov
    P = solve_continuous_lyapunov(F, -S)
    np.testing.assert_allclose(mu, gaussian_moments([0, 0], P, idx), rtol=1e-10, atol=1e-12)
    sol = propagate(eq, gaussian_moments([1.0, -1.0], np.eye(2) * 0.1, idx), [0.0, 40.0])
    np.testing.assert_allclose(sol.values[-1], mu, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("clo", [GaussianClosure(), CumulantClosure(4), EdgeworthClosure(4), EdgeworthClosure(6)],
                         ids=repr)
def test_cubic_drift_steady_state_direct_equals_long_time_ode(clo):
    sde = PolynomialSDE.from_sympy([x], [-x**3], [[1.0]])
    idx = monomials(1, clo.order, min_degree=1)
    eq = moment_equations(sde, idx)
    mu = steady_state(eq, closure=clo)
    sol = propagate(eq, gaussian_moments([0.5], [[0.2]], idx), [0.0, 40.0], closure=clo)
    np.testing.assert_allclose(sol.values[-1], mu, rtol=1e-6, atol=1e-9)


def test_cubic_drift_steady_state_against_stationary_density():
    """dx = −x³ dt + σ dβ: p ∝ exp(−x⁴/(2σ²)), E x^{2k} = (2σ²)^{k/2} Γ((2k+1)/4)/Γ(1/4).
    E x⁴ = σ²/2 holds exactly for every closure (row of E x²); E x² converges as the Edgeworth
    order grows (4: 6.4 %, 6: 2.3 %, 8: 0.5 % low — the truncated series is an approximation)."""
    s2 = 1.0
    exact2 = (2 * s2) ** 0.5 * Gamma(3 / 4) / Gamma(1 / 4)
    sde = PolynomialSDE.from_sympy([x], [-x**3], [[s2]])
    errs = []
    for N in (4, 6, 8):
        eq = moment_equations(sde, monomials(1, N, min_degree=1))
        mu = steady_state(eq, closure=EdgeworthClosure(N))
        assert mu[eq.index[(4,)]] == pytest.approx(s2 / 2, rel=1e-10)
        assert mu[eq.index[(1,)]] == pytest.approx(0.0, abs=1e-10)
        errs.append(abs(mu[eq.index[(2,)]] / exact2 - 1))
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] < 0.01


def _strang_cubic(m0, D0, Q, dt, paths, rng, t_out):
    """dx = −x³ dt + √Q dβ by Strang splitting: exact flow x/√(1 + 2x²h) for h = dt/2, noise, flow."""
    X = m0 + np.sqrt(D0) * rng.standard_normal(paths)
    flow = lambda X: X / np.sqrt(1 + X * X * dt)  # noqa: E731  (h = dt/2: 1 + 2 x² h)
    out, n = {}, int(round(max(t_out) / dt))
    for k in range(1, n + 1):
        X = flow(X)
        X = X + np.sqrt(Q * dt) * rng.standard_normal(paths)
        X = flow(X)
        for t in t_out:
            if k == int(round(t / dt)):
                out[t] = X.copy()
    return out


def test_cubic_drift_moments_against_monte_carlo():
    """Seed 003's example (m0 = 4, D0 = Q = 0.05): engine with Edgeworth-4 vs 10⁵ paths at
    t = 0.5, 1.0. Tolerance 4 standard errors + 6e-4 (splitting bias at dt = 0.004, measured by
    halving dt twice: the mean moved by < 5e-4). A wider start (m0 = 1, D0 = 0.5, Q = 1) shows the
    Gaussian closure failing (E x² 12 % low at t = 0.5) and Edgeworth-6 within tolerance."""
    rng = np.random.default_rng(2026)
    for (m0, D0, Q), clo_ok, clo_bad in [((4.0, 0.05, 0.05), EdgeworthClosure(4), None),
                                         ((1.0, 0.5, 1.0), EdgeworthClosure(6), GaussianClosure())]:
        mc = _strang_cubic(m0, D0, Q, 0.004, 100_000, rng, (0.5, 1.0))
        sde = PolynomialSDE.from_sympy([x], [-x**3], [[Q]])
        idx = monomials(1, clo_ok.order, min_degree=1)
        sol = propagate(moment_equations(sde, idx), gaussian_moments([m0], [[D0]], idx), [0, 0.5, 1.0],
                        closure=clo_ok)
        for j, t in enumerate((0.5, 1.0)):
            for k in (1, 2, 3, 4):
                est = np.mean(mc[t] ** k)
                se = np.std(mc[t] ** k) / np.sqrt(mc[t].size)
                assert abs(sol.moment((k,))[j + 1] - est) < 4 * se + 6e-4 * max(1, abs(est)), (m0, t, k)
        if clo_bad is not None:
            bad = propagate(moment_equations(sde, [(1,), (2,)]), [m0, D0 + m0**2], [0, 0.5], closure=clo_bad)
            est = np.mean(mc[0.5] ** 2)
            assert bad.values[-1, 1] < est - 20 * np.std(mc[0.5] ** 2) / np.sqrt(mc[0.5].size)


def test_blow_up_raises_naming_time_and_moment():
    sde = PolynomialSDE.from_sympy([x], [x**3], [[1.0]])
    eq = moment_equations(sde, [(1,), (2,)])
    with pytest.raises(ClosureDivergedError) as info:
        propagate(eq, [1.0, 1.5], np.linspace(0, 2, 5), closure=GaussianClosure())
    assert info.value.time is not None and 0 < info.value.time < 2
    assert info.value.moment in [(1,), (2,)]
    assert "t =" in str(info.value)


def test_singular_steady_state_and_missing_closure():
    sde = PolynomialSDE.from_sympy([x], [0 * x], [[1.0]])  # Brownian motion: no stationary law
    with pytest.raises(SingularSystemError, match=r"singular.*E\[x1\^2\] grows linearly"):
        steady_state(moment_equations(sde, [(1,), (2,)]))
    eq = moment_equations(PolynomialSDE.from_sympy([x], [-x**3], [[1.0]]), [(1,), (2,)])
    with pytest.raises(ValueError, match="closure"):
        steady_state(eq)
    with pytest.raises(ValueError, match="mu0"):
        propagate(eq, [1.0], [0, 1], closure=GaussianClosure())


def test_discrete_iterate_and_steady_state():
    a, q = 0.8, 0.5
    eq = discrete_moment_equations(DiscreteModel([x], [a * x], [x], Q=q, R=1.0), monomials(1, 4, min_degree=1))
    mu = steady_state(eq)
    P = q / (1 - a * a)
    np.testing.assert_allclose(mu, [0, P, 0, 3 * P * P], rtol=1e-12, atol=1e-14)
    sol = iterate(eq, np.array([[1.0, 1.0, 1.0, 1.0], [2.0, 4.0, 8.0, 16.0]]), 200)
    assert sol.values.shape == (2, 201, 4)
    np.testing.assert_allclose(sol.values[:, -1], np.broadcast_to(mu, (2, 4)), rtol=1e-8, atol=1e-12)


def test_negative_variance_raises_naming_time_and_moment():
    """A (deliberately wrong) closure claiming E x⁴ = 10 for dx = −x³ dt + dβ drives
    dE[x²]/dt = −2·10 + 1 < 0 until the variance crosses zero: the solver must stop there."""
    from nlfilter.moments.closures import Closure

    class Bad(Closure):
        order = 2
        name = "bad"

        def __call__(self, indices, values, wanted):
            return np.broadcast_to(np.array([0.0, 10.0]), (*np.shape(values)[:-1], 2))

    eq = moment_equations(PolynomialSDE.from_sympy([x], [-x**3], [[1.0]]), [(1,), (2,)])
    with pytest.raises(ClosureDivergedError) as info:
        propagate(eq, [0.0, 1.0], [0.0, 1.0], closure=Bad())
    assert info.value.moment == (2,)
    assert info.value.time == pytest.approx(1 / 19, rel=1e-3)  # μ2(t) = 1 − 19 t
    assert "variance of x_1" in str(info.value)


def test_stationary_moments_of_sde_model_ou_closed_form():
    """issue 10 item 8.3: stationary_moments takes an SDEModel (as moment_equations does). OU
    dx = −a x dt + g dβ, E dβ² = q dt: stationary N(0, g²q/(2a)), so E x² = g²q/(2a), E x⁴ = 3 (E x²)²."""
    from nlfilter import SDEModel
    x = sp.Symbol("x")
    a, g, q = 1.5, 0.7, 0.4
    md = SDEModel([x], [-a * x], [x], G=[[g]], Q=q, R=1.0)
    mom = stationary_moments(md, [(1,), (2,), (4,)])
    var = g * g * q / (2 * a)
    assert abs(mom[(1,)]) < 1e-14
    np.testing.assert_allclose(mom[(2,)], var, rtol=1e-12)
    np.testing.assert_allclose(mom[(4,)], 3 * var**2, rtol=1e-12)


def test_stationary_moments_of_2d_sde_model_solve_lyapunov():
    """A 2-D linear SDEModel: the stationary covariance solves F P + P Fᵀ + G Q Gᵀ = 0."""
    import scipy.linalg as sla
    from nlfilter import SDEModel
    x1, x2 = sp.symbols("x1 x2")
    F = np.array([[0.0, 1.0], [-2.0, -0.6]])
    GQG = np.array([[0.0, 0.0], [0.0, 0.5]])
    md = SDEModel([x1, x2], [x2, -2 * x1 - 0.6 * x2], [x1], Q=GQG, R=1.0)
    mom = stationary_moments(md, [(2, 0), (1, 1), (0, 2)])
    P = sla.solve_continuous_lyapunov(F, -GQG)
    np.testing.assert_allclose([mom[(2, 0)], mom[(1, 1)], mom[(0, 2)]], [P[0, 0], P[0, 1], P[1, 1]],
                               rtol=1e-12, atol=1e-15)


def test_stationary_moments_rejects_other_models():
    with pytest.raises(TypeError, match="sde: expected a PolynomialSDE or an SDEModel, got DiscreteModel"):
        x = sp.Symbol("x")
        stationary_moments(DiscreteModel([x], [0.5 * x], [x], Q=1.0, R=1.0), [(2,)])
