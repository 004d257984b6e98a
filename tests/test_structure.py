"""Model structure beyond additive, uncorrelated noise with one constant R (issue 12, item 4):
state-dependent measurement noise R(x), correlated process and measurement noise, non-additive
process noise (the UKF on augmented sigma points). Each filter either handles a structure exactly
as documented (checked here against an independent implementation) or refuses it naming it."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate as si
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.filters import (CKF, EKF, GHKF, UKF, DiscreteConditionalMomentFilter, DiscreteQuasilinearFilter,
                              GridFilter, IteratedEKF, KalmanFilter, ParticleFilter, SecondOrderFilter)
from nlfilter.filters.linalg import gaussian_loglik
from nlfilter.simulate import simulate

x, x1, x2, x3 = sp.symbols("x x1 x2 x3")

# -- filterpy's radar EKF test (filterpy/kalman/tests/test_ekf.py), as an nlfilter model ----------
# state (horizontal position, velocity, altitude); x_{k+1} = F x_k + w_k, F = I + dt·E_12;
# y_k = slant range √(x1² + x3²) + v_k; Q = 0.001·diag(0, 1, 1); filterpy passes at each update
# R = 0.05·hx(x⁻) (the range at the predicted state): R(x) = 0.05·√(x1² + x3²), at the predicted
# mean. It updates first (start="update") from x = (−10, 90, 1100), P = 50 I.
DT = 0.05
RNG_RANGE = sp.sqrt(x1**2 + x3**2)
RADAR_R = {"filterpy": 0.05 * RNG_RANGE,          # filterpy's own test
           "range-dependent": (2.0 + 0.01 * RNG_RANGE) ** 2}  # R = (σ0 + c·range)²
RADAR_Rfn = {"filterpy": lambda r: 0.05 * r, "range-dependent": lambda r: (2.0 + 0.01 * r) ** 2}
X0 = np.array([-10.0, 90.0, 1100.0])
Q_RADAR = np.diag([0.0, 1.0, 1.0]) * 0.001
F_RADAR = np.eye(3) + DT * np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])


def radar_model(kind):
    return DiscreteModel([x1, x2, x3], [x1 + DT * x2, x2, x3], [RNG_RANGE], Q=Q_RADAR, R=[[RADAR_R[kind]]])


def radar_ranges(paths, steps, seed):
    """Slant ranges of an aircraft at about 1000 m altitude flying at about 100 m/s, whose
    velocity and altitude jitter at every return, with an error that grows with the distance
    (the scenario of filterpy's RadarSim, drawn here from a seeded Generator)."""
    rng = np.random.default_rng(seed)
    pos = np.zeros(paths)
    out = np.empty((paths, steps, 1))
    for k in range(steps):
        vel = 100.0 + 5.0 * rng.standard_normal(paths)
        alt = 1000.0 + 10.0 * rng.standard_normal(paths)
        pos = pos + vel * DT
        out[:, k, 0] = np.hypot(pos, alt) + 0.05 * pos * rng.standard_normal(paths)
    return out


def plain_ekf(ys, Rfn):
    """An independent EKF loop (one path at a time, plain numpy, filterpy's order: update with
    R = Rfn(range at x⁻) in Joseph form, then predict x = F x, P = F P Fᵀ + Q), returning the
    filtered means, covariances and the log-likelihood Σ log N(y; h(x⁻), H P Hᵀ + R)."""
    means, covs, lls = [], [], []
    for path in ys:
        xk, P = X0.copy(), 50.0 * np.eye(3)
        ms, Ps, ll = [], [], 0.0
        for (z,) in path:
            rng_ = np.sqrt(xk[0] ** 2 + xk[2] ** 2)
            H = np.array([[xk[0] / rng_, 0.0, xk[2] / rng_]])
            R = np.array([[Rfn(rng_)]])
            S = H @ P @ H.T + R
            K = P @ H.T @ np.linalg.inv(S)
            e = z - rng_
            ll += -0.5 * (e * e / S[0, 0] + np.log(2 * np.pi * S[0, 0]))
            xk = xk + K[:, 0] * e
            IKH = np.eye(3) - K @ H
            P = IKH @ P @ IKH.T + K @ R @ K.T
            ms.append(xk.copy())
            Ps.append(P.copy())
            xk = F_RADAR @ xk
            P = F_RADAR @ P @ F_RADAR.T + Q_RADAR
        means.append(ms)
        covs.append(Ps)
        lls.append(ll)
    return np.array(means), np.array(covs), np.array(lls)


@pytest.mark.parametrize("kind", ["filterpy", "range-dependent"])
def test_radar_ekf_with_state_dependent_R_equals_a_plain_ekf(kind):
    ys = radar_ranges(3, int(20 / DT), seed=1)  # filterpy's 400 returns, on 3 paths
    model = radar_model(kind)
    assert not model.R_constant and model.structure == {"state-dependent R"}
    est = EKF(model).run(ys, X0, 50.0 * np.eye(3), loglik=True)
    means, covs, ll = plain_ekf(ys, RADAR_Rfn[kind])
    np.testing.assert_allclose(est.means, means, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(est.covs, covs, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(est.loglik, ll, rtol=1e-10)
    # the track follows the aircraft: the position error stays within a few filter sigmas at the end
    assert np.all(np.abs(est.means[:, -1, 2] - 1000.0) < 100.0)


def test_state_dependent_R_the_unscented_and_second_order_rules_on_linear_h_equal_the_ekf():
    """h linear, R(x) = 0.1 + x1²: every rule has Cov[h] exact and R at the predicted mean."""
    model = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2], [x1 + x2], Q=np.diag([0.1, 0.05]),
                          R=[[0.1 + x1**2]])
    ys = simulate(model, 12, paths=4, rng=3, m0=[0.5, 0.0], P0=np.eye(2) * 0.3).ys
    ys[1, 4] = np.nan
    kw = dict(m0=[0.5, 0.0], P0=np.eye(2) * 0.3, loglik=True)
    ref = EKF(model).run(ys, **kw)
    for flt in (UKF(model), CKF(model), GHKF(model, order=3), SecondOrderFilter(model), IteratedEKF(model, iterations=1)):
        est = flt.run(ys, **kw)
        np.testing.assert_allclose(est.means, ref.means, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(est.covs, ref.covs, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(est.loglik, ref.loglik, rtol=1e-10)
    # R at the predicted mean: S = H P⁻ Hᵀ + 0.1 + (m⁻_1)²
    e0 = ref.innovation_covs[:, 0, 0, 0]
    np.testing.assert_allclose(e0, 0.6 + 0.1 + 0.25, rtol=1e-12)


R1 = 0.05 + 0.2 * x**2  # 1-D: y = x + v, v ~ N(0, 0.05 + 0.2 x²)
M1 = DiscreteModel([x], [0.8 * x], [x], Q=0.3, R=[[R1]])


def test_grid_uses_R_of_x_exactly_its_log_evidence_is_the_integral():
    """One measurement: p(y) = ∫ N(x; m0, P0) N(y; x, R(x)) dx (quad) and the posterior mean."""
    m0, P0, y = 0.3, 0.5, 1.7
    Rf = sp.lambdify(x, R1)
    dens = lambda s: np.exp(-0.5 * (s - m0) ** 2 / P0 - 0.5 * (y - s) ** 2 / Rf(s)) / (2 * np.pi * np.sqrt(P0 * Rf(s)))  # noqa: E731
    Z = si.quad(dens, -8, 8, epsabs=1e-14, epsrel=1e-13)[0]
    mean = si.quad(lambda s: s * dens(s), -8, 8, epsabs=1e-14, epsrel=1e-13)[0] / Z
    est = GridFilter(M1, (-8.0, 8.0), 4001).run(np.array([[[y]]]), [m0], [[P0]], loglik=True)
    assert abs(est.loglik[0] - np.log(Z)) < 1e-8
    assert abs(est.means[0, 0, 0] - mean) < 1e-8


def test_particle_filter_with_R_of_x_agrees_with_the_grid():
    sim = simulate(M1, 15, paths=3, rng=7, m0=0.0, P0=1.0)
    g = GridFilter(M1, (-6.0, 6.0), 801).run(sim.ys, [0.0], [[1.0]], loglik=True)
    runs = [ParticleFilter(M1, 20000).run(sim.ys, [0.0], [[1.0]], rng=s, loglik=True) for s in range(6)]
    assert np.max(np.abs(runs[0].means - g.means)) < 0.03
    # the log-likelihood estimate: within 3 standard errors of the grid's (its spread over seeds)
    ll = np.array([r.loglik for r in runs])
    se = ll.std(axis=0, ddof=1) / np.sqrt(len(runs))
    assert np.all(np.abs(ll.mean(axis=0) - g.loglik) < 3 * se + 0.01)
    # the innovation covariance is Cov[h] + E[R(x)] under the predictive law (grid: exact sums)
    assert np.all(g.innovation_covs[..., 0, 0] > 0.05)


def test_simulate_draws_v_with_covariance_R_of_x():
    model = DiscreteModel([x], [x], [0 * x], Q=0.0, R=[[0.1 + x**2]])  # x constant, y = v ~ N(0, 0.1 + x0²)
    sim = simulate(model, 400, paths=50, rng=2, x0=[2.0])
    v = sim.ys.ravel()
    assert abs(v.var() - 4.1) < 4 * 4.1 * np.sqrt(2 / v.size)
    assert abs(v.mean()) < 4 * np.sqrt(4.1 / v.size)


def test_R_of_x_not_positive_definite_is_reported():
    bad = DiscreteModel([x], [0.9 * x], [x], Q=0.1, R=[[x]])  # R(x) = x < 0 for x < 0
    with pytest.raises(ValueError, match=r"R: the state-dependent .* not positive definite at state x = \[-1.0\]"):
        bad.R_of(np.array([[1.0], [-1.0]]), 0)
    with pytest.raises(ValueError, match="R: the state-dependent"):
        EKF(bad).run(np.zeros((1, 3, 1)), [-1.0], [[0.1]])
    with pytest.raises(ValueError, match="R: the state-dependent"):
        GridFilter(bad, (-2.0, 2.0), 41).run(np.zeros((1, 3, 1)), [0.5], [[0.1]])
    with pytest.raises(ValueError, match="R: the state-dependent"):
        simulate(bad, 3, paths=2, rng=0, x0=[-1.0])


def test_filters_that_need_one_R_refuse_R_of_x_naming_it():
    model = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x], Q=0.1, R=[[0.1 + x**2]])
    for make in (KalmanFilter, DiscreteQuasilinearFilter, DiscreteConditionalMomentFilter):
        with pytest.raises(ValueError, match=r"^R: the model's measurement noise covariance depends on the state"):
            make(model)
    with pytest.raises(ValueError, match="model.R: this model's measurement noise covariance depends on the state"):
        model.R  # noqa: B018
    with pytest.raises(ValueError, match="R: an SDEModel's measurement intensity"):
        SDEModel([x], [-x], [x], Q=1.0, R=[[1.0 + x**2]])
    with pytest.raises(ValueError, match=r"R: uses symbol\(s\) \['z'\]"):
        DiscreteModel([x], [x], [x], Q=1.0, R=[[sp.Symbol("z")]])


def test_gaussian_loglik_of_per_point_R_is_the_dense_density():
    from scipy.stats import multivariate_normal
    rng = np.random.default_rng(0)
    A = rng.standard_normal((5, 3, 3))
    R = A @ np.swapaxes(A, -1, -2) + np.eye(3)
    r = rng.standard_normal((5, 3))
    want = [multivariate_normal(np.zeros(3), R[i]).logpdf(r[i]) for i in range(5)]
    np.testing.assert_allclose(gaussian_loglik(r, R), want, rtol=1e-12)
    obs = np.array([True, False, True])
    want = [multivariate_normal(np.zeros(2), R[i][np.ix_(obs, obs)]).logpdf(r[i, obs]) for i in range(5)]
    np.testing.assert_allclose(gaussian_loglik(r, R, obs), want, rtol=1e-12)


# -- correlated process and measurement noise, E[w_k v_kᵀ] = S ------------------------------------
F_C = np.array([[0.9, 0.2], [-0.1, 0.8]])
B_C = np.array([0.1, -0.05])
H_C = np.array([[1.0, 0.0], [0.3, 1.0]])
D_C = np.array([0.2, 0.0])
G_C = np.array([[1.0, 0.0], [0.5, 1.0]])
Q_C = np.array([[0.3, 0.05], [0.05, 0.2]])
R_C = np.array([[0.4, 0.1], [0.1, 0.25]])
S_C = np.array([[0.15, -0.05], [0.08, 0.1]])  # E[w vᵀ]
M0_C, P0_C = np.array([0.5, -0.3]), np.array([[0.6, 0.1], [0.1, 0.4]])


def correlated_model(S=S_C):
    X = sp.Matrix([x1, x2])
    f = sp.Matrix(F_C.tolist()) * X + sp.Matrix(B_C.tolist())
    h = sp.Matrix(H_C.tolist()) * X + sp.Matrix(D_C.tolist())
    return DiscreteModel([x1, x2], f, h, G=G_C.tolist(), Q=Q_C, R=R_C, cross_noise=S)


def dense_posterior(ys, start):
    """The filtered and smoothed moments and the log-density of the observed ys of one path,
    by conditioning the dense joint Gaussian of all states and measurements (built from the
    noises (x0 − m0, (w_j, v_j)_j) with Cov[(w_j, v_j)] = [[Q, S], [Sᵀ, R]])."""
    from scipy.stats import multivariate_normal
    T = ys.shape[0]
    off = 1 if start == "predict" else 0
    J = np.block([[Q_C, S_C], [S_C.T, R_C]])
    steps = T + off
    dim = 2 + 4 * steps
    Sig = np.zeros((dim, dim))
    Sig[:2, :2] = P0_C
    for j in range(steps):
        Sig[2 + 4 * j:6 + 4 * j, 2 + 4 * j:6 + 4 * j] = J
    X, cx = np.zeros((2, dim)), M0_C.copy()
    X[:, :2] = np.eye(2)
    Ax, cxs, Ay, cys = [], [], [], []
    for j in range(steps):
        Ev = np.zeros((2, dim))
        Ev[:, 4 + 4 * j:6 + 4 * j] = np.eye(2)
        if j >= off:
            Ax.append(X.copy())
            cxs.append(cx.copy())
            Ay.append(H_C @ X + Ev)
            cys.append(H_C @ cx + D_C)
        Ew = np.zeros((2, dim))
        Ew[:, 2 + 4 * j:4 + 4 * j] = np.eye(2)
        X, cx = F_C @ X + G_C @ Ew, F_C @ cx + B_C
    Ax, Ay = np.array(Ax), np.array(Ay)  # (T, 2, dim)
    y_flat = ys.reshape(-1)
    Ayf = Ay.reshape(-1, dim)
    cyf = np.array(cys).reshape(-1)

    def cond(k_obs, k):  # E, Cov of x_k given the observed y of steps < k_obs
        sel = np.flatnonzero(~np.isnan(y_flat) & (np.arange(y_flat.size) < 2 * k_obs))
        A, c = Ayf[sel], cyf[sel]
        Syy = A @ Sig @ A.T
        Sxy = Ax[k] @ Sig @ A.T
        K = Sxy @ np.linalg.inv(Syy)
        return cxs[k] + K @ (y_flat[sel] - c), Ax[k] @ Sig @ Ax[k].T - K @ Sxy.T

    filt = [cond(k + 1, k) for k in range(T)]
    smooth = [cond(T, k) for k in range(T)]
    sel = np.flatnonzero(~np.isnan(y_flat))
    A = Ayf[sel]
    ll = multivariate_normal(cyf[sel], A @ Sig @ A.T).logpdf(y_flat[sel])
    return filt, smooth, ll


@pytest.mark.parametrize("start", ["update", "predict"])
def test_kalman_filter_with_correlated_noise_is_the_dense_gaussian_posterior(start):
    model = correlated_model()
    assert model.structure == {"cross noise"}
    ys = simulate(model, 8, paths=3, rng=4, m0=M0_C, P0=P0_C, start=start).ys
    ys[0, 2, 1] = np.nan  # partly missing: only the observed component decorrelates
    ys[1, 4] = np.nan  # missing on one path
    ys[:, 6, 0] = np.nan
    kf = KalmanFilter(model, start=start)
    est = kf.run(ys, M0_C, P0_C, loglik=True)
    sm = kf.smooth(ys, M0_C, P0_C)
    for p in range(3):
        filt, smooth, ll = dense_posterior(ys[p], start)
        np.testing.assert_allclose(est.means[p], [m for m, _ in filt], rtol=0, atol=1e-9)
        np.testing.assert_allclose(est.covs[p], [P for _, P in filt], rtol=0, atol=1e-9)
        np.testing.assert_allclose(sm.means[p], [m for m, _ in smooth], rtol=0, atol=1e-9)
        np.testing.assert_allclose(sm.covs[p], [P for _, P in smooth], rtol=0, atol=1e-9)
        assert abs(est.loglik[p] - ll) < 1e-9
    # ignoring the correlation is measurably different (the test has power)
    plain = KalmanFilter(correlated_model(None), start=start).run(ys, M0_C, P0_C, loglik=True)
    assert np.max(np.abs(plain.means - est.means)) > 1e-2


@pytest.mark.parametrize("start", ["update", "predict"])
def test_gaussian_filters_with_correlated_noise_equal_the_kalman_filter_on_a_linear_model(start):
    model = correlated_model()
    ys = simulate(model, 10, paths=4, rng=5, m0=M0_C, P0=P0_C, start=start).ys
    ys[2, 3, 0] = np.nan
    ys[3, 5] = np.nan
    assert_kalman(KalmanFilter(model, start=start), ys,
                  (EKF(model, start=start), UKF(model, start=start), CKF(model, start=start),
                   GHKF(model, order=2, start=start), SecondOrderFilter(model, start=start),
                   IteratedEKF(model, start=start)))


def assert_kalman(kf, ys, filters):
    """Every filter's means, covariances, log-likelihood and RTS smoother equal the KF's (1e-10)."""
    kw = dict(m0=M0_C, P0=P0_C, loglik=True)
    ref, ref_s = kf.run(ys, **kw), kf.smooth(ys, M0_C, P0_C)
    for flt in filters:
        est = flt.run(ys, **kw)
        np.testing.assert_allclose(est.means, ref.means, rtol=0, atol=1e-10)
        np.testing.assert_allclose(est.covs, ref.covs, rtol=0, atol=1e-10)
        np.testing.assert_allclose(est.loglik, ref.loglik, rtol=1e-12, atol=1e-10)
        sm = flt.smooth(ys, M0_C, P0_C)
        np.testing.assert_allclose(sm.means, ref_s.means, rtol=0, atol=1e-10)
        np.testing.assert_allclose(sm.covs, ref_s.covs, rtol=0, atol=1e-10)


def test_correlated_noise_step_functions_carry_the_measurement():
    model = correlated_model()
    kf = KalmanFilter(model)
    b = kf.init(M0_C, P0_C, (2,))
    assert np.isnan(b.y).all()
    y = np.array([[0.3, 0.1], [np.nan, 0.2]])
    u = kf.update(b, y, 0)
    np.testing.assert_array_equal(u.y, y)
    p = kf.predict(u, 0)
    assert np.isnan(p.y).all()
    # a path with y missing entirely predicts as without correlation
    u2 = kf.update(b, np.full((2, 2), np.nan), 0)
    plain = KalmanFilter(correlated_model(None)).predict(kf.update(b, np.full((2, 2), np.nan), 0)[:2], 0)
    np.testing.assert_allclose(kf.predict(u2, 0).cov, plain.cov, rtol=1e-14)


def test_simulate_draws_the_noises_jointly():
    # x[k+1] = w_k, y_k = v_k: Cov[x_{k+1}, y_k] = S
    S = np.array([[0.3]])
    model = DiscreteModel([x], [0 * x], [0 * x], Q=1.0, R=0.5, cross_noise=S)
    for start in ("update", "predict"):
        sim = simulate(model, 200, paths=100, rng=6, x0=[0.0], start=start)
        xs, ys = sim.xs[:, 1:, 0].ravel(), sim.ys[:, :-1, 0].ravel()
        c = np.mean(xs * ys)
        assert abs(c - 0.3) < 4 * np.sqrt((1.0 * 0.5 + 0.09) / xs.size)
        assert abs(np.mean(sim.xs[:, 1:, 0] * sim.ys[:, 1:, 0])) < 4 * np.sqrt(0.5 / xs.size)  # same index: independent


def test_cross_noise_is_checked_and_refused_where_not_handled():
    with pytest.raises(ValueError, match=r"cross_noise: expected E\[w vᵀ\] of shape \(r, m\) = \(2, 2\)"):
        correlated_model(np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"cross_noise: the joint covariance .* not positive semi-definite"):
        correlated_model(np.eye(2) * 2.0)
    with pytest.raises(ValueError, match="cross_noise: correlated noise with a state-dependent R"):
        DiscreteModel([x], [x], [x], Q=1.0, R=[[1 + x**2]], cross_noise=[[0.1]])
    with pytest.raises(ValueError, match="cross_noise: correlated process and measurement noise needs a G"):
        DiscreteModel([x], [x], [x], G=[[x]], Q=1.0, R=1.0, cross_noise=[[0.1]])
    with pytest.raises(ValueError, match="cross_noise: correlated .* is supported for DiscreteModel only"):
        SDEModel([x], [-x], [x], Q=1.0, R=1.0, cross_noise=[[0.1]])
    model = correlated_model()
    for make in (lambda m: GridFilter(m, [(-3, 3), (-3, 3)], 11), lambda m: ParticleFilter(m, 10),
                 DiscreteQuasilinearFilter, DiscreteConditionalMomentFilter):
        with pytest.raises(ValueError, match="^cross_noise: the model's process and measurement noises are correlated"):
            make(model)


# -- non-additive process noise: x[k+1] = f(x[k], w[k]); the augmented UKF -------------------------
w1, w2, v1, v2 = sp.symbols("w1 w2 v1 v2")


@pytest.mark.parametrize("start", ["update", "predict"])
def test_augmented_ukf_on_additive_noise_written_non_additively_is_the_kalman_filter(start):
    """f = F x + b + G w and/or h = H x + d + v written with the noise symbols (noise=, meas_noise=):
    the augmented UKF (either alpha, kappa) is the KF of the additive model, smoother included."""
    X = sp.Matrix([x1, x2])
    f_lin = sp.Matrix(F_C.tolist()) * X + sp.Matrix(B_C.tolist())
    h = sp.Matrix(H_C.tolist()) * X + sp.Matrix(D_C.tolist())
    fw, hv = f_lin + sp.Matrix(G_C.tolist()) * sp.Matrix([w1, w2]), h + sp.Matrix([v1, v2])
    additive = DiscreteModel([x1, x2], f_lin, h, G=G_C.tolist(), Q=Q_C, R=R_C)
    written = DiscreteModel([x1, x2], fw, h, Q=Q_C, R=R_C, noise=[w1, w2])
    h_only = DiscreteModel([x1, x2], f_lin, hv, G=G_C.tolist(), Q=Q_C, R=R_C, meas_noise=[v1, v2])
    both = DiscreteModel([x1, x2], fw, hv, Q=Q_C, R=R_C, noise=[w1, w2], meas_noise=[v1, v2])
    assert written.structure == {"non-additive noise"} and not written.is_linear
    assert both.structure == {"non-additive noise", "non-additive measurement noise"}
    ys = simulate(written, 10, paths=3, rng=8, m0=M0_C, P0=P0_C, start=start).ys
    for other in (additive, h_only, both):  # the same noises simulate the same paths, however written
        np.testing.assert_allclose(simulate(other, 10, paths=3, rng=8, m0=M0_C, P0=P0_C, start=start).ys, ys,
                                   rtol=1e-12, atol=1e-12)
    ys[1, 3, 0] = np.nan
    assert_kalman(KalmanFilter(additive, start=start), ys,
                  (UKF(written, start=start), UKF(additive, augmented=True, start=start), UKF(additive, start=start),
                   UKF(written, alpha=0.5, kappa=1.0, start=start), UKF(h_only, start=start),
                   UKF(h_only, augmented=True, start=start), UKF(both, start=start)))
    assert UKF(written).augmented and not UKF(additive).augmented
    assert UKF(h_only).augmented and not UKF(h_only)._aug_predict


def test_augmented_ukf_on_multiplicative_noise_is_close_to_the_optimal_filter():
    """x[k+1] = x[k]·exp(w[k]) (log-normal growth), y = x + v: the augmented UKF against the
    particle filter (the near-optimal reference, 4000 particles) over 200 simulated paths. The
    UKF's MSE is within 10 % of the reference's; the reference is not beaten by more than its
    Monte Carlo noise; and both are far below the prior spread."""
    model = DiscreteModel([x], [x * sp.exp(w1)], [x], Q=0.04, R=0.09, noise=[w1])
    sim = simulate(model, 25, paths=200, rng=11, m0=[1.0], P0=[[0.04]])
    assert np.all(sim.xs > 0)
    u = UKF(model).run(sim.ys, [1.0], [[0.04]])
    p = ParticleFilter(model, 4000).run(sim.ys, [1.0], [[0.04]], rng=3)
    mse_u = np.mean((u.means - sim.xs) ** 2)
    mse_p = np.mean((p.means - sim.xs) ** 2)
    d = ((u.means - sim.xs) ** 2 - (p.means - sim.xs) ** 2).mean(axis=(1, 2))  # per path: paired
    se = d.std(ddof=1) / np.sqrt(d.size)
    assert mse_u <= 1.10 * mse_p
    assert d.mean() > -3 * se
    assert mse_p < 0.5 * np.var(sim.xs)


def test_non_additive_noise_is_refused_where_not_handled():
    model = DiscreteModel([x], [x * sp.exp(w1)], [x], Q=0.04, R=0.09, noise=[w1])
    for make in (EKF, CKF, SecondOrderFilter, KalmanFilter, lambda m: GridFilter(m, (0.1, 3.0), 21),
                 DiscreteQuasilinearFilter, DiscreteConditionalMomentFilter):
        with pytest.raises(ValueError, match="^noise: the model's process noise enters f non-additively"):
            make(model)
    with pytest.raises(ValueError, match="augmented: the model's noise enters f or h non-additively"):
        UKF(model, augmented=False)
    with pytest.raises(ValueError, match="augmented: augmented sigma points with correlated noise"):
        UKF(correlated_model(), augmented=True)
    with pytest.raises(ValueError, match="model.sym: the model's noise enters f or h non-additively"):
        model.sym  # noqa: B018
    with pytest.raises(ValueError, match="G: a model with non-additive noise"):
        DiscreteModel([x], [x * sp.exp(w1)], [x], G=[[1.0]], Q=0.04, R=0.09, noise=[w1])
    with pytest.raises(ValueError, match=r"h: uses symbol\(s\) \['w1'\]"):
        DiscreteModel([x], [x * sp.exp(w1)], [x + w1], Q=0.04, R=0.09, noise=[w1])
    with pytest.raises(ValueError, match="noise: correlated .* is supported for DiscreteModel only"):
        SDEModel([x], [-x], [x], Q=1.0, R=1.0, noise=[w1])
    # the nominal dynamics f(x, 0) and the noise gain ∂f/∂w at w = 0
    assert model.f(np.array([2.0]), 0).tolist() == [2.0] and model.G(np.array([2.0]), 0).tolist() == [[2.0]]
    np.testing.assert_allclose(model.transition(np.array([2.0]), np.array([0.5]), 0), [2.0 * np.exp(0.5)], rtol=1e-15)


def test_compare_on_a_non_additive_model_takes_a_particle_reference():
    from nlfilter import compare
    model = DiscreteModel([x], [x * sp.exp(w1)], [x], Q=0.04, R=0.09, noise=[w1])
    res = compare(model, "all", 10, paths=20, m0=[1.0], P0=[[0.04]])
    mse = {r.filter: r.value for r in res.rows if r.quantity == "mse"}
    assert set(mse) == {"ukf", "optimal"}  # the others refuse non-additive noise (listed in the notes)
    assert any("particles" in n and "reference" in n for n in res.notes)
    assert any("noise: the model's process noise enters f non-additively" in n for n in res.notes)
    assert mse["ukf"] < 1.2 * mse["optimal"] + 0.01


def test_multiplicative_measurement_noise_is_a_state_dependent_R():
    """y = x (1 + v), v ~ N(0, 0.04), is y = x + v' with R(x) = 0.04 x²: the augmented UKF on the
    first form against the grid filter on the second (the optimum), on the same data; the UKF's
    MSE is within 15 % of the optimum's and never below it by more than the paired noise."""
    f = [0.9 * x + 0.3]
    written = DiscreteModel([x], f, [x * (1 + v1)], Q=0.05, R=0.04, meas_noise=[v1])
    as_Rx = DiscreteModel([x], f, [x], Q=0.05, R=[[0.04 * x**2 + 1e-6]])
    sim = simulate(written, 30, paths=200, rng=12, m0=[3.0], P0=[[0.1]])
    u = UKF(written).run(sim.ys, [3.0], [[0.1]])
    g = GridFilter(as_Rx, (-0.5, 6.5), 1401).run(sim.ys, [3.0], [[0.1]])
    assert g.extras["edge_mass"].max() < 1e-8
    eu, eg = (u.means - sim.xs) ** 2, (g.means - sim.xs) ** 2
    d = (eu - eg).mean(axis=(1, 2))
    assert eu.mean() <= 1.15 * eg.mean()
    assert d.mean() > -3 * d.std(ddof=1) / np.sqrt(d.size)
    for make in (EKF, lambda m: ParticleFilter(m, 10), lambda m: GridFilter(m, (0.5, 5.5), 11)):
        with pytest.raises(ValueError, match="^meas_noise: the model's measurement noise enters h non-additively"):
            make(written)
