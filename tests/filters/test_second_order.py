"""Second-order filters of seed 004: equivalences, closed-form moments, Monte Carlo moments,
dt → 0 convergence, bad input."""

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings, strategies as st

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import DivergenceError
from nlfilter.filters.base import GaussianState
from nlfilter.filters.ekf import EKF
from nlfilter.filters.kalman import KalmanBucy, KalmanFilter
from nlfilter.filters.second_order import (FORMS, ContinuousDiscreteSecondOrderFilter,
                                           ContinuousSecondOrderFilter, SecondOrderFilter,
                                           gaussian_quartic, hessian_trace, noise_covariance)

x1, x2 = sp.symbols("x1 x2")
F_LIN = np.array([[0.9, 0.2], [-0.1, 0.8]])
H_LIN = np.array([[1.0, 0.5], [0.0, 1.0]])
Q2 = np.array([[0.3, 0.05], [0.05, 0.2]])
R2 = np.array([[0.4, 0.1], [0.1, 0.5]])
X0 = np.array([[0.5, 0.1], [0.1, 0.3]])


def _linear_data(rng, T=12, paths=5):
    return rng.normal(size=(paths, T, 2))


@pytest.mark.parametrize("form", FORMS)
def test_discrete_linear_equals_kalman(form):
    """On a linear model every form is the Kalman filter (all second-order terms vanish)."""
    model = DiscreteModel.linear(F_LIN, H_LIN, Q2, R2)
    ys = _linear_data(np.random.default_rng(1))
    ref = KalmanFilter(model).run(ys, [0.2, -0.1], X0)
    est = SecondOrderFilter(model, form=form).run(ys, [0.2, -0.1], X0)
    np.testing.assert_allclose(est.means, ref.means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(est.covs, ref.covs, rtol=0, atol=1e-12)


@pytest.mark.parametrize("form", FORMS)
def test_continuous_linear_equals_kalman_bucy(form):
    """On a linear model every form is the Kalman–Bucy filter: the same Itô step (dt terms by
    Euler or RK4, ``K dy`` with the gain at the step start), so equal to 1e-12 for both schemes."""
    model = SDEModel.linear(-np.eye(2) + 0.1 * F_LIN, H_LIN, Q2, R2)
    dys = np.random.default_rng(2).normal(size=(4, 50, 2)) * np.sqrt(0.01)
    for scheme in ("euler", "rk4"):
        ref = KalmanBucy(model, 0.01, scheme=scheme).run(dys, [0.3, 0.1], X0)
        est = ContinuousSecondOrderFilter(model, 0.01, form=form, scheme=scheme).run(dys, [0.3, 0.1], X0)
        np.testing.assert_allclose(est.covs, ref.covs, rtol=0, atol=1e-12)
        np.testing.assert_allclose(est.means, ref.means, rtol=0, atol=1e-12)


def test_first_order_form_is_the_ekf():
    model = DiscreteModel([x1, x2], [x1 + 0.1 * sp.sin(x2), 0.9 * x2 + 0.05 * x1**2],
                          [x1 * x2, sp.exp(0.1 * x1)], Q=Q2, R=R2)
    ys = _linear_data(np.random.default_rng(3))
    ref = EKF(model).run(ys, [0.5, 1.0], X0)
    est = SecondOrderFilter(model, form="first-order").run(ys, [0.5, 1.0], X0)
    np.testing.assert_allclose(est.means, ref.means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(est.covs, ref.covs, rtol=0, atol=1e-12)


# -- quadratic f, Gaussian X: closed forms and 10^6-sample Monte Carlo ----------------------------
A1 = np.array([[1.0, 0.4], [0.4, -0.6]])
A2 = np.array([[0.3, -0.2], [-0.2, 0.8]])
B = np.array([[0.7, 0.1], [-0.3, 0.9]])
C0 = np.array([0.2, -0.4])
M = np.array([0.5, -1.0])


def _quad_model(Q=np.zeros((2, 2))):
    X = sp.Matrix([x1, x2])
    f = [C0[i] + (sp.Matrix(B[i]).T * X)[0] + sp.Rational(1, 2) * (X.T * sp.Matrix(A) * X)[0]
         for i, A in enumerate((A1, A2))]
    return DiscreteModel([x1, x2], f, [x1], Q=Q, R=1.0)


def _exact_quadratic_moments():
    """x ~ N(M, X0), f_i = c_i + b_iᵀx + ½xᵀA_i x: E f_i = f_i(M) + ½tr(A_i X0),
    Cov(f_i, f_j) = (b_i + A_i M)ᵀ X0 (b_j + A_j M) + ½tr(A_i X0 A_j X0)."""
    As = np.stack([A1, A2])
    fM = C0 + B @ M + 0.5 * np.einsum("a,iab,b->i", M, As, M)
    mean = fM + 0.5 * np.einsum("iab,ba->i", As, X0)
    J = B + As @ M
    quart = 0.5 * np.einsum("iab,bc,jcd,da->ij", As, X0, As, X0)
    return mean, J @ X0 @ J.T, quart


def test_quadratic_prediction_closed_forms():
    mean, lin, quart = _exact_quadratic_moments()
    state = GaussianState(M, X0)
    out = {form: SecondOrderFilter(_quad_model(), form=form)._predict(state, 0)
           for form in ("truncated", "gaussian", "truncated-jazwinski")}
    for s in out.values():  # 004 eq. 18: the truncated mean is exact for quadratic f
        np.testing.assert_allclose(s.mean, mean, atol=1e-12)
    np.testing.assert_allclose(out["gaussian"].cov, lin + quart, atol=1e-12)  # exact Cov[f(x)]
    np.testing.assert_allclose(out["truncated"].cov, lin, atol=1e-12)  # exact − fourth-moment term
    d = mean - (C0 + B @ M + 0.5 * np.einsum("a,iab,b->i", M, np.stack([A1, A2]), M))  # ½(X f_xx)
    q = np.outer(d, d)  # ¼(X f_xx)(X f_xx)ᵀ from the exact mean shift
    np.testing.assert_allclose(out["truncated-jazwinski"].cov, lin - q, atol=1e-12)
    # here that subtraction already makes the predicted covariance indefinite (Andrade Netto et al.)
    assert np.linalg.eigvalsh(lin - q)[0] < 0 and np.linalg.eigvalsh(lin)[0] > 0
    with pytest.raises(DivergenceError, match="predicted covariance"):
        SecondOrderFilter(_quad_model(), form="truncated-jazwinski").predict(state, 0)


def test_quadratic_prediction_monte_carlo():
    """10⁶ samples: the Gaussian form's covariance and the common mean agree within 5 standard
    errors; the correct truncated form misses exactly the fourth-moment term."""
    rng = np.random.default_rng(10)
    xs = rng.multivariate_normal(M, X0, size=1_000_000)
    fx = _quad_model().f(xs, 0)
    mc_mean = fx.mean(axis=0)
    se_mean = fx.std(axis=0) / np.sqrt(len(xs))
    d = fx - mc_mean
    prods = d[:, :, None] * d[:, None, :]
    mc_cov, se_cov = prods.mean(axis=0), prods.std(axis=0) / np.sqrt(len(xs))
    state = GaussianState(M, X0)
    g = SecondOrderFilter(_quad_model(), form="gaussian").predict(state, 0)
    t = SecondOrderFilter(_quad_model(), form="truncated").predict(state, 0)
    assert np.all(np.abs(g.mean - mc_mean) < 5 * se_mean)
    assert np.all(np.abs(g.cov - mc_cov) < 5 * se_cov)
    fourth = gaussian_quartic(X0, np.stack([A1, A2]))
    assert np.all(np.abs(t.cov + fourth - mc_cov) < 5 * se_cov)
    assert np.max(np.abs(t.cov - mc_cov)) > 20 * np.max(se_cov)  # the dropped term is visible


# -- state-dependent G (004 eqs. 13, 14, 19) ------------------------------------------------------
def _g_model(quadratic=True):
    c = 0.3 if quadratic else 0.0
    G = sp.Matrix([[1 + 0.5 * x1 + c * x1 * x2, 0.2 * x2], [0.1 + c * x2**2, 0.8 - 0.4 * x1]])
    return DiscreteModel([x1, x2], [x1, x2], [x1], G=G, Q=Q2, R=1.0)


@pytest.mark.parametrize("quadratic", [False, True])
def test_state_dependent_noise_moments(quadratic):
    """E[G(x) V G(x)ᵀ] for x ~ N(M, X0) against 10⁶ samples: exact for linear G; for quadratic G
    eq. 19 misses only ¼E[(G_xx δδ)V(G_xx δδ)ᵀ] (fourth order), the Gaussian form nothing."""
    model = _g_model(quadratic)
    rng = np.random.default_rng(11)
    xs = rng.multivariate_normal(M, X0, size=1_000_000)
    Gs = model.G(xs, 0)
    prods = np.einsum("sia,ab,sqb->siq", Gs, Q2, Gs)
    mc, se = prods.mean(axis=0), prods.std(axis=0) / np.sqrt(len(xs))
    args = (X0, Q2, model.G(M, 0), model.G_x(M, 0), model.G_xx(M, 0))
    trunc = noise_covariance(*args)
    gauss = noise_covariance(*args, gaussian=True)
    assert np.all(np.abs(gauss - mc) < 5 * se)
    if quadratic:
        dG = np.einsum("iapt,sp,st->sia", model.G_xx(M, 0), xs - M, xs - M)  # G_xx δδ
        q = 0.25 * np.einsum("sia,ab,sqb->iq", dG, Q2, dG) / len(xs)
        assert np.all(np.abs(trunc + q - mc) < 5 * se + 1e-3 * np.abs(q))
        assert np.max(np.abs(trunc - mc) / se) > 20
    else:
        np.testing.assert_allclose(trunc, gauss, atol=1e-14)
        assert np.all(np.abs(trunc - mc) < 5 * se)
    # the predicted covariance of eq. 19 with f = identity is X0 + that noise term
    pred = SecondOrderFilter(model).predict(GaussianState(M, X0), 0)
    np.testing.assert_allclose(pred.cov, X0 + trunc, atol=1e-12)


def test_contractions_match_loops():
    rng = np.random.default_rng(5)
    n, r = 3, 2
    X = np.cov(rng.normal(size=(n, 10)))
    Gm, Gx, Gxx = rng.normal(size=(n, r)), rng.normal(size=(n, r, n)), rng.normal(size=(n, r, n, n))
    Gxx = 0.5 * (Gxx + np.swapaxes(Gxx, -1, -2))
    Vn = np.cov(rng.normal(size=(r, 10)))
    loop = Gm @ Vn @ Gm.T
    for i in range(n):
        for q in range(n):
            for j in range(r):
                for l in range(r):
                    for p in range(n):
                        for t in range(n):  # 004 eq. 13 and eq. 14 (+ transpose) literally
                            loop[i, q] += X[p, t] * Vn[j, l] * (Gx[i, j, p] * Gx[q, l, t] + 0.5 * Gxx[
                                i, j, p, t] * Gm[q, l] + 0.5 * Gxx[q, l, p, t] * Gm[i, j])
    np.testing.assert_allclose(noise_covariance(X, Vn, Gm, Gx, Gxx), loop, atol=1e-12)
    A = rng.normal(size=(2, n, n))
    np.testing.assert_allclose(hessian_trace(X, A), [np.sum(X * A[i]) for i in range(2)], atol=1e-12)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(st.floats(-3, 3), st.floats(0.01, 5), st.floats(-10, 10), st.floats(0.05, 2))
def test_truncated_update_keeps_covariance_psd(m, P, y, c):
    x = sp.Symbol("x")
    model = DiscreteModel([x], [x], [x + c * x**2], Q=0.1, R=0.2)
    s = SecondOrderFilter(model).update(GaussianState(np.array([m]), np.array([[P]])), np.array([y]), 0)
    assert 0 <= s.cov[0, 0] <= P + 1e-12


def test_continuous_modified_is_truncated():
    """004 sec. 3: in continuous time the modified filter is the correct truncated filter."""
    x = sp.Symbol("x")
    model = SDEModel([x], [-x + 0.3 * x**2], [x + 0.5 * x**2], G=[[0.5 + 0.2 * x]], Q=1.0, R=0.1)
    dys = np.random.default_rng(4).normal(size=(3, 40, 1)) * 0.1
    a = ContinuousSecondOrderFilter(model, 0.01, form="modified").run(dys, [0.2], [[0.3]])
    b = ContinuousSecondOrderFilter(model, 0.01, form="truncated").run(dys, [0.2], [[0.3]])
    np.testing.assert_array_equal(a.means, b.means)


@pytest.mark.parametrize("form", ["truncated", "gaussian", "truncated-jazwinski"])
def test_continuous_is_limit_of_discrete(form):
    """One measurement path (fine Brownian increments) filtered at dt = 0.04 .. 0.0025 by the
    continuous filter and by the discrete filter on the Euler discretization (x + f dt, G √dt,
    y = dy/dt with R/dt). Their final means differ by O(dt): the gap must shrink with dt, to
    below 2 % of the first gap's size scale at the smallest step."""
    x = sp.Symbol("x")
    a, s0, s1, c, R, Tend = 1.0, 0.5, 0.3, 0.3, 0.2, 1.0
    f, G, h = -a * x + 0.2 * x**2, 0.5 * (s0 + s1 * x), x + c * x**2
    sde = SDEModel([x], [f], [h], G=[[G]], Q=1.0, R=R)
    rng = np.random.default_rng(7)
    fine = 0.0025 / 8
    N = int(round(Tend / fine))
    xt, dy = 0.3, np.empty(N)
    for k in range(N):  # truth and measurement increments on the fine grid
        dy[k] = (xt + c * xt**2) * fine + np.sqrt(R * fine) * rng.normal()
        xt = xt + (-a * xt + 0.2 * xt**2) * fine + 0.5 * (s0 + s1 * xt) * np.sqrt(fine) * rng.normal()
    gaps = []
    for dt in (0.04, 0.02, 0.01, 0.005, 0.0025):
        agg = dy.reshape(-1, int(round(dt / fine))).sum(axis=1)[None, :, None]
        cont = ContinuousSecondOrderFilter(sde, dt, form=form, scheme="euler").run(agg, [0.0], [[0.3]])
        disc_model = DiscreteModel([x], [x + f * dt], [h], G=[[G * np.sqrt(dt)]], Q=1.0, R=R / dt)
        flt = SecondOrderFilter(disc_model, form=form)
        est = flt.run(agg / dt, [0.0], [[0.3]])
        last = flt.predict(GaussianState(est.means[:, -1], est.covs[:, -1]), 0)  # to t = Tend
        gaps.append(abs(last.mean[0, 0] - cont.means[0, -1, 0]) + abs(last.cov[0, 0, 0] - cont.covs[0, -1, 0, 0]))
    gaps = np.array(gaps)
    assert np.all(np.diff(gaps) < 0), gaps
    assert gaps[-1] < gaps[0] / 8, gaps


def test_continuous_discrete_linear_matches_exact_discretization():
    """Linear SDE, measurements every dt: RK4 prediction (20 substeps) reproduces the Kalman filter on
    the exact discretization (F = e^{A dt}, Q_d = ∫ e^{As} Q e^{Aᵀs} ds) to 1e-9."""
    from scipy.linalg import expm
    A = np.array([[-0.5, 1.0], [-1.0, -0.5]])
    dt = 0.5
    sde = SDEModel.linear(A, H_LIN, Q2, R2)
    n = 2
    Mblk = np.block([[-A, Q2], [np.zeros((n, n)), A.T]]) * dt  # Van Loan
    E = expm(Mblk)
    Fd = E[n:, n:].T
    Qd = Fd @ E[:n, n:]
    disc = DiscreteModel.linear(Fd, H_LIN, 0.5 * (Qd + Qd.T), R2)
    ys = _linear_data(np.random.default_rng(8))
    ref = KalmanFilter(disc).run(ys, [0.1, 0.2], X0)
    for form in FORMS:
        # start="update" as the Kalman filter's (the continuous-discrete default is the simulator's "predict")
        est = ContinuousDiscreteSecondOrderFilter(sde, dt, form=form, substeps=20, start="update").run(ys, [0.1, 0.2], X0)
        np.testing.assert_allclose(est.means, ref.means, atol=1e-9)
        np.testing.assert_allclose(est.covs, ref.covs, atol=1e-9)


# -- bad input and divergence -------------------------------------------------------------------
def test_model_without_second_derivatives_is_rejected():
    model = DiscreteModel.from_functions(1, 1, lambda x, t=0: x, lambda x, t=0: x**2, Q=[[1.0]],
                                         R=[[1.0]], f_x=lambda x, t=0: np.ones((*x.shape, 1)),
                                         h_x=lambda x, t=0: 2 * x[..., None])
    with pytest.raises(ValueError, match="f_xx.*h_xx"):
        SecondOrderFilter(model)
    SecondOrderFilter(model, form="first-order")  # the EKF needs first derivatives only
    with pytest.raises(ValueError, match="form: expected one of"):
        SecondOrderFilter(_quad_model(), form="second")
    with pytest.raises(TypeError, match="model"):
        ContinuousSecondOrderFilter(_quad_model(), 0.1)


def test_pre_correction_form_loses_psd_and_is_reported():
    """Scalar quadratic measurement at the point where h_x = 0: Jazwinski's innovation variance
    H²X + W − ¼(X h_xx)² = 0.01 − 0.25·(2·0.5)² < 0, so the step is flagged (raise or mark), while
    the correct form stays PSD on the same data; no NaN is returned unflagged."""
    x = sp.Symbol("x")
    model = DiscreteModel([x], [0.9 * x], [x**2], Q=0.5, R=0.01)
    ys = np.array([[[0.3], [0.2]], [[0.25], [0.1]]])
    m0 = np.array([[0.0], [2.0]])  # path 0 at h_x = 0, path 1 well away from it
    bad = SecondOrderFilter(model, form="truncated-jazwinski")
    with pytest.raises(DivergenceError) as info:
        bad.run(ys, m0, [[1.0]])
    assert info.value.step == 0 and info.value.paths == (0,)
    est = bad.run(ys, m0, [[1.0]], on_divergence="mark")
    assert est.diverged.tolist() == [True, False] and est.diverged_step.tolist() == [0, -1]
    assert np.all(np.isnan(est.means[0])) and np.all(np.isfinite(est.means[1]))
    with pytest.raises(DivergenceError):
        bad.update(GaussianState(np.array([0.0]), np.array([[1.0]])), np.array([0.3]), 0)
    good = SecondOrderFilter(model).run(ys, m0, [[1.0]])
    assert not good.diverged.any() and np.all(good.covs > 0)


def test_update_innovation_is_stable_and_has_the_same_limit():
    """``innovation="update"`` (discrete update with W/dt, then propagation) and the explicit Itô
    step converge to each other as dt → 0 (gap shrinks at least 2.5-fold per 4-fold refinement),
    and with a large gain (K H dt ≈ 40 at the start) the explicit step blows up while the update
    form stays finite, its recorded (propagated) variance between the Kalman–Bucy steady state
    P∞ and P∞ + Q dt (the update brings it to about P∞, the propagation over dt adds at most Q dt)."""
    x = sp.Symbol("x")
    model = SDEModel([x], [-x + 0.2 * x**2], [x + 0.3 * x**2], G=[[0.5 + 0.2 * x]], Q=1.0, R=0.2)
    fine = np.random.default_rng(9).normal(size=(3, 400, 1)) * np.sqrt(0.2 * 0.00125)
    gaps = []
    for g in (16, 4, 1):
        dt = 0.00125 * g
        dys = fine.reshape(3, -1, g, 1).sum(axis=2)
        a = ContinuousSecondOrderFilter(model, dt, innovation="update").run(dys, [0.2], [[0.3]])
        b = ContinuousSecondOrderFilter(model, dt, innovation="ito").run(dys, [0.2], [[0.3]])
        gaps.append(np.max(np.abs(a.means[:, -1] - b.means[:, -1])))
    assert gaps[1] < gaps[0] / 2.5 and gaps[2] < gaps[1] / 2.5, gaps
    stiff = SDEModel.linear([[-1.0]], [[20.0]], [[1.0]], [[0.01]])
    dys = np.random.default_rng(1).normal(size=(2, 50, 1)) * 0.01
    with pytest.raises(DivergenceError):
        ContinuousSecondOrderFilter(stiff, 0.05, scheme="euler").run(dys, [0.0], [[1.0]])
    est = ContinuousSecondOrderFilter(stiff, 0.05, innovation="update").run(dys, [0.0], [[1.0]])
    from nlfilter.filters.kalman import steady_state_continuous
    P_inf = steady_state_continuous(stiff)[0, 0]
    assert not est.diverged.any()
    assert np.all((P_inf <= est.covs[:, -1, 0, 0]) & (est.covs[:, -1, 0, 0] <= P_inf + 1.0 * 0.05))


def test_scalar_quadratic_ukf_equals_modified_gaussian():
    """Independent check of the Gaussian terms: for a scalar model with quadratic f and h, the
    unscented transform with α = 1, β = 2, κ = 0 (points m, m ± √X, W₀ᶜ = 2) computes E, Var and
    Cov of a quadratic exactly under a Gaussian, so the UKF *is* the Gaussian second-order filter
    with C = 0 (1e-12)."""
    from nlfilter.filters.ukf import UKF
    x = sp.Symbol("x")
    model = DiscreteModel([x], [0.7 * x + 0.05 * x**2], [x + 0.3 * x**2], Q=0.5, R=0.2)
    ys = np.random.default_rng(6).normal(size=(6, 20, 1))
    a = UKF(model, alpha=1.0, beta=2.0, kappa=0.0).run(ys, [0.1], [[0.8]])
    b = SecondOrderFilter(model, form="modified-gaussian").run(ys, [0.1], [[0.8]])
    np.testing.assert_allclose(b.means, a.means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.covs, a.covs, rtol=0, atol=1e-12)


def test_forcing_tensor_is_the_third_cross_moment():
    """The C tensor (004 eqs. 17, 32-33): for x ~ N(M, X0) and quadratic h, the Gaussian form's
    M_ijk = (X h_xx⁽ᵏ⁾ X)_ij equals E[δ_i δ_j (h_k − E h_k)] (10⁶ samples, 5 s.e.); the
    pre-correction form's −½ X_ij (X h_xx)_k is that moment minus its fourth-order part
    ½E[δ_i δ_j δᵀh_xx⁽ᵏ⁾δ] (closed form)."""
    from nlfilter.filters.second_order import _forcing
    As = np.stack([A1, A2])
    rng = np.random.default_rng(12)
    d = rng.multivariate_normal(np.zeros(2), X0, size=1_000_000)
    hk = 0.5 * np.einsum("si,kij,sj->sk", d, As, d) + d @ B.T  # h(M + δ) up to a constant
    hk = hk - hk.mean(axis=0)
    prods = np.einsum("si,sj,sk->sijk", d, d, hk)
    mc, se = prods.mean(axis=0), prods.std(axis=0) / np.sqrt(len(d))
    gauss = _forcing("gaussian", X0, As)
    assert np.all(np.abs(gauss - mc) < 5 * se)
    fourth = 0.5 * (np.einsum("ij,kab,ba->ijk", X0, As, X0) + 2 * np.einsum("ia,kab,bj->ijk", X0, As, X0))
    np.testing.assert_allclose(_forcing("truncated-jazwinski", X0, As), gauss - fourth, atol=1e-12)
    assert _forcing("truncated", X0, As) is None and _forcing("modified", X0, As) is None
