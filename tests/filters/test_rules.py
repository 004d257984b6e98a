"""Moment rules and the Gaussian skeletons (issue 10, item 5): CKF against filterpy, GHKF against a
naive implementation and closed forms, the iterated EKF against the EKF and an independent
Gauss–Newton, every rule = the Kalman filter on linear models, the continuous-discrete filters
against the continuous-discrete second-order filter's first-order form and the exact discretization."""

import itertools

import numpy as np
import pytest
import scipy.linalg as sla
import sympy as sp
from scipy import optimize

from nlfilter import DiscreteModel, SDEModel
from nlfilter.filters import (CKF, EKF, GHKF, UKF, ContinuousDiscreteCKF, ContinuousDiscreteEKF,
                              ContinuousDiscreteGaussianFilter, ContinuousDiscreteGHKF, ContinuousDiscreteIEKF,
                              ContinuousDiscreteSecondOrderFilter, ContinuousDiscreteUKF, GaussianFilter,
                              GaussianState, IteratedEKF, KalmanFilter)
from nlfilter.filters.rules import Cubature, GaussHermite, Taylor1, Unscented
from nlfilter.simulate import simulate

x, x1, x2, x3 = sp.symbols("x x1 x2 x3")
M0 = np.array([0.5, -0.2, 0.1])
P0 = np.diag([0.3, 0.2, 0.1])
RC = np.array([[0.2, 0.08], [0.08, 0.1]])


def _const_G(md):
    """``nonlinear3`` with G frozen at its value at 0 (filterpy adds a constant Q)."""
    G0 = md.G(np.zeros(md.n), 0)
    return DiscreteModel(md.states, md.sym["f"], md.sym["h"], sp.Matrix(G0.tolist()), md.Q, md.R)


# -- CKF -----------------------------------------------------------------------------------------------
def test_ckf_matches_filterpy_step_by_step(nonlinear3):
    """filterpy's CubatureKalmanFilter, with its update's points redrawn from the predicted (m⁻, P⁻)
    (Arasaratnam & Haykin 2009, time update step 1 of the measurement update; filterpy reuses the
    propagated points, a different filter when Q ≠ 0)."""
    from filterpy.kalman import CubatureKalmanFilter
    from filterpy.kalman.CubatureKalmanFilter import spherical_radial_sigmas
    md = _const_G(nonlinear3)
    ys = simulate(md, 40, paths=1, rng=7, m0=M0, P0=P0, start="predict").ys[0]
    fp = CubatureKalmanFilter(3, 2, 1.0, hx=lambda s: md.h(s, 0), fx=lambda s, dt: md.f(s, 0))
    fp.x, fp.P, fp.Q, fp.R = M0[:, None].copy(), P0.copy(), md.GQGT(np.zeros(3)), md.R.copy()
    ours = CKF(md, start="predict").run(ys[None], M0, P0)
    for k, y in enumerate(ys):
        fp.predict()
        fp.sigmas_f = spherical_radial_sigmas(fp.x, fp.P)
        fp.update(y[:, None])  # its mean is a column
        np.testing.assert_allclose(ours.means[0, k], fp.x[:, 0], atol=1e-9)
        np.testing.assert_allclose(ours.covs[0, k], fp.P, atol=1e-9)


def test_ckf_is_the_unscented_filter_with_alpha_1_beta_kappa_0(nonlinear3):
    ys = simulate(nonlinear3, 20, paths=3, rng=2, m0=M0, P0=P0).ys
    a = CKF(nonlinear3).run(ys, M0, P0)
    b = UKF(nonlinear3, alpha=1.0, beta=0.0, kappa=0.0).run(ys, M0, P0)
    np.testing.assert_allclose(a.means, b.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.covs, b.covs, rtol=1e-12, atol=1e-12)


# -- GHKF ----------------------------------------------------------------------------------------------
def _naive_ghkf(md, ys, m0, P0, order):
    """One path, loops over the tensor grid: Ito & Xiong (2000) sec. 4, state-dependent G averaged."""
    z, w = np.polynomial.hermite_e.hermegauss(order)
    w = w / w.sum()
    n = len(m0)

    def points(m, P):
        L = np.linalg.cholesky(P)
        pts, wts = [], []
        for idx in itertools.product(range(order), repeat=n):
            pts.append(m + L @ z[list(idx)])
            wts.append(np.prod(w[list(idx)]))
        return pts, wts

    m, P, out = m0.copy(), P0.copy(), []
    for k, y in enumerate(ys):
        if k:
            pts, wts = points(m, P)
            fs = [md.f(p, 0) for p in pts]
            mp = sum(wi * fi for wi, fi in zip(wts, fs))
            Pp = sum(wi * (np.outer(fi - mp, fi - mp) + md.GQGT(p, 0)) for wi, fi, p in zip(wts, fs, pts))
            m, P = mp, Pp
        pts, wts = points(m, P)
        hs = [md.h(p, 0) for p in pts]
        yp = sum(wi * hi for wi, hi in zip(wts, hs))
        S = sum(wi * np.outer(hi - yp, hi - yp) for wi, hi in zip(wts, hs)) + md.R
        C = sum(wi * np.outer(p - m, hi - yp) for wi, hi, p in zip(wts, hs, pts))
        K = C @ np.linalg.inv(S)
        m, P = m + K @ (y - yp), P - K @ S @ K.T
        out.append((m, P))
    return out


def test_ghkf_order_3_matches_a_naive_implementation(nonlinear3):
    ys = simulate(nonlinear3, 25, paths=2, rng=3, m0=M0, P0=P0).ys
    est = GHKF(nonlinear3, order=3).run(ys, M0, P0)
    for i in range(2):
        for k, (m, P) in enumerate(_naive_ghkf(nonlinear3, ys[i], M0, P0, 3)):
            np.testing.assert_allclose(est.means[i, k], m, atol=1e-10)
            np.testing.assert_allclose(est.covs[i, k], P, atol=1e-10)


def test_high_order_ghkf_prediction_is_the_exact_gaussian_moments():
    """f = (sin x1, cos x1 + x2): closed forms E[sin x] = sin m e^{−P/2} etc. under a correlated prior."""
    md = DiscreteModel([x1, x2], [sp.sin(x1), sp.cos(x1) + x2], [x1], Q=np.diag([0.01, 0.02]), R=0.1)
    m, P = np.array([0.7, -0.3]), np.array([[0.8, 0.3], [0.3, 0.5]])
    s = GHKF(md, order=24).predict(GaussianState(m, P), 0)
    a, v = m[0], P[0, 0]
    Es, Ec = np.sin(a) * np.exp(-v / 2), np.cos(a) * np.exp(-v / 2)
    Vs = 0.5 * (1 - np.cos(2 * a) * np.exp(-2 * v)) - Es**2
    Vc = 0.5 * (1 + np.cos(2 * a) * np.exp(-2 * v)) - Ec**2
    Csc = 0.5 * np.sin(2 * a) * np.exp(-2 * v) - Es * Ec
    Cc2 = -P[0, 1] * np.sin(a) * np.exp(-v / 2)  # Stein: Cov[cos x1, x2] = P12 E[−sin x1]
    Cs2 = P[0, 1] * Ec
    want_m = np.array([Es, Ec + m[1]])
    want_P = np.array([[Vs, Csc + Cs2], [Csc + Cs2, Vc + 2 * Cc2 + P[1, 1]]]) + md.Q
    np.testing.assert_allclose(s.mean, want_m, atol=1e-12)
    np.testing.assert_allclose(s.cov, want_P, atol=1e-12)


def test_rules_on_an_exponential():
    """E[e^{aᵀx}] = e^{aᵀm + ½aᵀPa}, Cov[x, e^{aᵀx}] = P a E (Stein); GH converges, cubature does not."""
    m, P, a = np.array([0.2, -0.1]), np.array([[0.3, 0.1], [0.1, 0.2]]), np.array([1.0, -0.4])
    g = lambda X, t: np.exp(X @ a)[..., None]  # noqa: E731
    E = np.exp(a @ m + 0.5 * a @ P @ a)
    mo = GaussHermite(20).moments(GaussianState(m, P), g, 0)
    np.testing.assert_allclose(mo.mean, [E], rtol=1e-13)
    np.testing.assert_allclose(mo.cross[:, 0], P @ a * E, rtol=1e-12)
    np.testing.assert_allclose(mo.cov, [[E**2 * (np.exp(a @ P @ a) - 1)]], rtol=1e-12)
    assert abs(Cubature().moments(GaussianState(m, P), g, 0).mean[0] - E) > 1e-5


# -- iterated EKF --------------------------------------------------------------------------------------
def test_iekf_with_one_iteration_is_the_ekf_exactly(nonlinear3):
    ys = simulate(nonlinear3, 30, paths=4, rng=4, m0=M0, P0=P0).ys
    ys[1, 3, 0] = np.nan
    ys[2, 5] = np.nan
    a = IteratedEKF(nonlinear3, iterations=1).run(ys, M0, P0)
    b = EKF(nonlinear3).run(ys, M0, P0)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.covs, b.covs)


def _gauss_newton(md, m, P, y, iterations):
    """Gauss–Newton on J(x) = ½|x − m|²_{P⁻¹} + ½|y − h(x)|²_{R⁻¹}, information form."""
    Pi, Ri = np.linalg.inv(P), np.linalg.inv(md.R)
    xi = m.copy()
    for _ in range(iterations):
        H = md.h_x(xi, 0)
        A = Pi + H.T @ Ri @ H
        xn = xi + np.linalg.solve(A, H.T @ Ri @ (y - md.h(xi, 0)) - Pi @ (xi - m))
        Pn = np.linalg.inv(A)
        xi = xn
    return xi, Pn


@pytest.mark.parametrize("iterations", [2, 5])
def test_iekf_update_is_gauss_newton(nonlinear3, iterations):
    rng = np.random.default_rng(0)
    m = M0 + rng.normal(size=(5, 3)) * 0.3
    y = rng.normal(size=(5, 2))
    flt = IteratedEKF(nonlinear3, iterations=iterations, tol=0.0)
    new = flt.update(GaussianState(m, np.broadcast_to(P0, (5, 3, 3))), y, 0)
    for i in range(5):
        xm, Pm = _gauss_newton(nonlinear3, m[i], P0, y[i], iterations)
        np.testing.assert_allclose(new.mean[i], xm, atol=1e-11)
        np.testing.assert_allclose(new.cov[i], Pm, atol=1e-11)


def test_converged_iekf_is_the_map_estimate():
    """Cubic sensor, far from linear: the converged update maximizes the posterior (scipy minimize)."""
    md = DiscreteModel([x1, x2], [x1, x2], [x1**3 + x2, x2**2], Q=np.eye(2), R=np.diag([0.01, 0.05]))
    m, P, y = np.array([1.0, 0.5]), np.array([[0.5, 0.1], [0.1, 0.3]]), np.array([8.0, 0.36])
    new = IteratedEKF(md, iterations=50, tol=1e-13).update(GaussianState(m, P), y, 0)
    Pi, Ri = np.linalg.inv(P), np.linalg.inv(md.R)

    def J(z):
        r = y - md.h(z, 0)
        return 0.5 * (z - m) @ Pi @ (z - m) + 0.5 * r @ Ri @ r

    ref = optimize.minimize(J, new.mean + 0.05, method="BFGS", options={"gtol": 1e-12}).x
    np.testing.assert_allclose(new.mean, ref, atol=1e-6)
    ekf = EKF(md).update(GaussianState(m, P), y, 0).mean
    assert J(new.mean) < J(ekf) - 1.0


def test_iekf_stops_at_tol_and_never_exceeds_its_iterations():
    calls = []

    def counted(model):
        h_x = model.h_x
        model.h_x = lambda X, t=0.0: (calls.append(1), h_x(X, t))[1]
        return model

    lin = counted(DiscreteModel([x1, x2], [x1, x2], [x1 + 2 * x2], Q=np.eye(2), R=0.1))
    s = GaussianState(np.zeros((3, 2)), np.broadcast_to(np.eye(2), (3, 2, 2)))
    IteratedEKF(lin, iterations=10).update(s, np.ones((3, 1)), 0)
    assert len(calls) == 2  # linear h: the second iterate repeats the first, all paths stop
    calls.clear()
    cub = counted(DiscreteModel([x], [x], [x**3], Q=1.0, R=0.01))
    IteratedEKF(cub, iterations=7, tol=0.0).update(GaussianState(np.ones((2, 1)), np.ones((2, 1, 1))),
                                                   np.array([[8.0], [np.nan]]), 0)
    assert len(calls) == 7


def test_iekf_iterates_only_the_observed_components():
    md = DiscreteModel([x1, x2], [x1, x2], [x1**3, x2**3 + x1], Q=np.eye(2), R=RC)
    md1 = DiscreteModel([x1, x2], [x1, x2], [x1**3], Q=np.eye(2), R=RC[:1, :1])
    s = GaussianState(np.array([1.0, 0.5]), np.array([[0.5, 0.2], [0.2, 0.4]]))
    a = IteratedEKF(md, tol=0.0).update(s, np.array([8.0, np.nan]), 0)
    b = IteratedEKF(md1, tol=0.0).update(s, np.array([8.0]), 0)
    np.testing.assert_allclose(a.mean, b.mean, atol=1e-13)
    np.testing.assert_allclose(a.cov, b.cov, atol=1e-13)


# -- linear models: every rule is the Kalman filter ----------------------------------------------------
LIN = DiscreteModel.linear([[0.95, 0.1], [-0.05, 0.9]], [[1.0, 0.5], [0.0, 1.0]], np.diag([0.1, 0.2]), RC)
DISCRETE = {"ekf": lambda md, **k: EKF(md, **k), "ukf": lambda md, **k: UKF(md, alpha=0.5, kappa=1.0, **k),
            "ckf": lambda md, **k: CKF(md, **k), "ghkf": lambda md, **k: GHKF(md, order=3, **k),
            "ghkf2": lambda md, **k: GHKF(md, order=2, **k), "iekf": lambda md, **k: IteratedEKF(md, **k),
            "rule-taylor": lambda md, **k: GaussianFilter(md, Taylor1(), **k)}


@pytest.mark.parametrize("name", sorted(DISCRETE))
@pytest.mark.parametrize("start", ["update", "predict"])
def test_every_rule_is_the_kalman_filter_on_a_linear_model(name, start):
    m0, P0_ = np.array([0.3, -0.2]), np.array([[0.5, 0.1], [0.1, 0.4]])
    ys = simulate(LIN, 30, paths=4, rng=9, m0=m0, P0=P0_, start=start).ys
    ys[0, 4, 1] = np.nan  # partly missing (correlated R)
    ys[1, 6] = np.nan
    est = DISCRETE[name](LIN, start=start).run(ys, m0, P0_)
    kf = KalmanFilter(LIN, start=start).run(ys, m0, P0_)
    np.testing.assert_allclose(est.means, kf.means, atol=1e-10)
    np.testing.assert_allclose(est.covs, kf.covs, atol=1e-10)


# -- continuous-discrete -------------------------------------------------------------------------------
S2G = SDEModel([x1, x2], [x2, -x1 - 0.5 * x2 - 0.1 * x1**3], [x1 + 0.1 * x2**2, x2],
               G=[[0.5, 0.0], [0.1 * x1, 0.6 + 0.1 * x2**2]], Q=np.eye(2) * 0.3, R=RC)
DT = 0.1


def _cd_data(md, T, paths, seed):
    sim = simulate(md, T, paths=paths, rng=seed, m0=[0.3, -0.2], P0=np.eye(2) * 0.2, dt=DT)
    rng = np.random.default_rng(seed)
    xs = sim.xs
    ys = np.stack([md.h(xs[:, k], 0) for k in range(T)], axis=1)
    return ys + rng.multivariate_normal(np.zeros(md.m), md.R, size=ys.shape[:2])


@pytest.mark.parametrize("scheme,substeps", [("rk4", 1), ("rk4", 3), ("euler", 5)])
def test_cd_ekf_is_the_first_order_cd_second_order_filter(scheme, substeps):
    ys = _cd_data(S2G, 15, 3, 1)
    ys[0, 3, 0] = np.nan
    m0, P0_ = np.array([0.3, -0.2]), np.eye(2) * 0.2
    a = ContinuousDiscreteEKF(S2G, DT, scheme=scheme, substeps=substeps).run(ys, m0, P0_)
    b = ContinuousDiscreteSecondOrderFilter(S2G, DT, form="first-order", scheme=scheme,
                                            substeps=substeps).run(ys, m0, P0_)
    np.testing.assert_allclose(a.means, b.means, atol=1e-12)
    np.testing.assert_allclose(a.covs, b.covs, atol=1e-12)
    c = ContinuousDiscreteIEKF(S2G, DT, iterations=1, scheme=scheme, substeps=substeps).run(ys, m0, P0_)
    np.testing.assert_array_equal(c.means, a.means)
    np.testing.assert_array_equal(c.covs, a.covs)


SLIN = SDEModel([x1, x2], [x2, -x1 - 0.5 * x2], [x1, x1 + x2], G=[[0.3, 0.0], [0.2, 0.7]], Q=np.eye(2), R=RC)
CD = {"cd-ekf": lambda md, **k: ContinuousDiscreteEKF(md, DT, **k),
      "cd-ukf": lambda md, **k: ContinuousDiscreteUKF(md, DT, alpha=0.5, kappa=1.0, **k),
      "cd-ckf": lambda md, **k: ContinuousDiscreteCKF(md, DT, **k),
      "cd-ghkf": lambda md, **k: ContinuousDiscreteGHKF(md, DT, **k),
      "cd-iekf": lambda md, **k: ContinuousDiscreteIEKF(md, DT, **k)}


def _exact_discretization(md, dt):
    """x[k+1] = e^{A dt} x + w, Cov w = ∫ e^{As} G Q Gᵀ e^{Aᵀs} ds (Van Loan 1978)."""
    z = np.zeros(2)
    A, GQG = md.f_x(z, 0), md.GQGT(z, 0)
    E = sla.expm(np.block([[-A, GQG], [np.zeros((2, 2)), A.T]]) * dt)
    F = E[2:, 2:].T
    Qd = F @ E[:2, 2:]
    H = md.h_x(z, 0)
    return DiscreteModel.linear(F, H, 0.5 * (Qd + Qd.T), md.R)


@pytest.mark.parametrize("name", sorted(CD))
def test_cd_filters_are_the_kalman_filter_of_the_exact_discretization(name):
    ys = _cd_data(SLIN, 20, 3, 2)
    ys[1, 5, 1] = np.nan
    m0, P0_ = np.array([0.3, -0.2]), np.eye(2) * 0.2
    est = CD[name](SLIN, substeps=20).run(ys, m0, P0_)
    kf = KalmanFilter(_exact_discretization(SLIN, DT), start="predict").run(ys, m0, P0_)  # the CD default
    np.testing.assert_allclose(est.means, kf.means, atol=1e-10)
    np.testing.assert_allclose(est.covs, kf.covs, atol=1e-10)
    ekf = CD["cd-ekf"](SLIN, substeps=20).run(ys, m0, P0_)  # same ODE on a linear model: to rounding
    np.testing.assert_allclose(est.means, ekf.means, atol=1e-12)
    np.testing.assert_allclose(est.covs, ekf.covs, atol=1e-12)


def test_cd_node_rules_approach_the_gauss_hermite_limit_on_a_nonlinear_sde():
    """dx = −x³ dt + dβ from N(0.5, 0.4): the prediction needs E[x³] and E[x·x³] (degree ≤ 4), which
    Gauss–Hermite of order 3 (exact to degree 5) already gets as order 12 does; cubature (degree 3) not."""
    md = SDEModel([x], [-x**3], [x], Q=1.0, R=0.1)
    s = GaussianState(np.array([0.5]), np.array([[0.4]]))
    ref = ContinuousDiscreteGHKF(md, 0.5, order=12, substeps=50).predict(s, 0)
    gh3 = ContinuousDiscreteGHKF(md, 0.5, order=3, substeps=50).predict(s, 0)
    ckf = ContinuousDiscreteCKF(md, 0.5, substeps=50).predict(s, 0)
    np.testing.assert_allclose(gh3.mean, ref.mean, atol=1e-12)  # E[x³] is degree 3: exact for both
    np.testing.assert_allclose(gh3.cov, ref.cov, atol=1e-12)  # E[x·x³] degree 4 ≤ 5
    assert abs(ckf.cov[0, 0] - ref.cov[0, 0]) > 1e-4  # E[x⁴] is beyond the third-degree rule


# -- bad paths, options, registry attributes -----------------------------------------------------------
@pytest.mark.parametrize("make", [CKF, GHKF, UKF, lambda md: GaussianFilter(md, Unscented(0.5))])
def test_non_psd_covariance_poisons_only_that_path(nonlinear3, make):
    P = np.broadcast_to(P0, (3, 3, 3)).copy()
    P[1] = -P0
    s = make(nonlinear3).predict(GaussianState(np.broadcast_to(M0, (3, 3)), P), 0)
    assert np.isnan(s.mean[1]).all() and np.isnan(s.cov[1]).all()
    ok = make(nonlinear3).predict(GaussianState(M0, P0), 0)
    np.testing.assert_allclose(s.mean[[0, 2]], np.broadcast_to(ok.mean, (2, 3)), atol=1e-14)


def test_bad_options_name_the_argument(nonlinear3):
    with pytest.raises(ValueError, match="^order"):
        GHKF(nonlinear3, order=0)
    with pytest.raises(ValueError, match="^order"):
        GaussHermite(2.5)
    with pytest.raises(ValueError, match="^order"):
        GHKF(nonlinear3, order=50)  # 125000 nodes
    with pytest.raises(ValueError, match="^alpha"):
        Unscented(alpha=-1.0)
    with pytest.raises(ValueError, match="^kappa"):
        UKF(nonlinear3, kappa=-5.0)
    with pytest.raises(ValueError, match="^kappa"):
        GaussianFilter(nonlinear3, Unscented(kappa=-5.0))
    with pytest.raises(TypeError, match="^rule"):
        GaussianFilter(nonlinear3, "cubature")
    with pytest.raises(ValueError, match="^iterations"):
        IteratedEKF(nonlinear3, iterations=0)
    with pytest.raises(ValueError, match="^tol"):
        IteratedEKF(nonlinear3, tol=-1.0)
    with pytest.raises(TypeError, match="^model"):
        ContinuousDiscreteCKF(nonlinear3, 0.1)
    with pytest.raises(TypeError, match="^model"):
        CKF(SLIN)
    fm = DiscreteModel.from_functions(1, 1, lambda X, t=0: X, lambda X, t=0: X, Q=1.0, R=1.0)
    CKF(fm)  # node rules need no derivatives
    with pytest.raises(ValueError, match="h_x"):
        IteratedEKF(fm)


NEW = [CKF, GHKF, IteratedEKF, EKF, UKF, ContinuousDiscreteEKF, ContinuousDiscreteIEKF, ContinuousDiscreteUKF,
       ContinuousDiscreteCKF, ContinuousDiscreteGHKF, GaussianFilter, ContinuousDiscreteGaussianFilter]


@pytest.mark.parametrize("cls", NEW, ids=[c.__name__ for c in NEW])
def test_registry_attributes(cls):
    assert cls.family == "gaussian" and cls.time == "discrete"
    assert cls.accepts == (("sde",) if "ContinuousDiscrete" in cls.__name__ else ("discrete",))
    assert isinstance(cls.source, str) and cls.source
    assert cls.needs == (("f_x", "h_x") if "EKF" in cls.__name__ or "IEKF" in cls.__name__ else ())
    if cls is not UKF:  # the UKF's example is its module's
        assert ">>>" in cls.__doc__


# -- Taylor-2: the Gaussian second-order filter of seed 004 as a rule ----------------------------------
def test_taylor2_rule_is_the_modified_gaussian_second_order_filter(nonlinear3):
    """State-dependent G (its fourth-moment term included): identical numbers to rounding."""
    from nlfilter.filters import SecondOrderFilter
    from nlfilter.filters.rules import Taylor2
    ys = simulate(nonlinear3, 25, paths=3, rng=8, m0=M0, P0=P0).ys
    ys[0, 4, 1] = np.nan
    a = GaussianFilter(nonlinear3, Taylor2()).run(ys, M0, P0)
    b = SecondOrderFilter(nonlinear3, form="modified-gaussian").run(ys, M0, P0)
    np.testing.assert_allclose(a.means, b.means, atol=1e-12)
    np.testing.assert_allclose(a.covs, b.covs, atol=1e-12)
    ys = _cd_data(S2G, 15, 3, 1)
    m0, P0_ = np.array([0.3, -0.2]), np.eye(2) * 0.2
    a = ContinuousDiscreteGaussianFilter(S2G, DT, Taylor2(), substeps=2).run(ys, m0, P0_)
    b = ContinuousDiscreteSecondOrderFilter(S2G, DT, form="modified-gaussian", substeps=2).run(ys, m0, P0_)
    np.testing.assert_allclose(a.means, b.means, atol=1e-12)
    np.testing.assert_allclose(a.covs, b.covs, atol=1e-12)


def test_taylor2_and_gauss_hermite_are_exact_on_a_quadratic():
    from nlfilter.filters.rules import Taylor2
    m, P = np.array([0.4, -0.3]), np.array([[0.5, 0.2], [0.2, 0.3]])
    B = np.array([[1.0, 0.5], [0.5, -2.0]])
    g = lambda X, t: np.einsum("...i,ij,...j->...", X, B, X)[..., None]  # noqa: E731
    jac = lambda X, t: (2 * X @ B)[..., None, :]  # noqa: E731
    hess = lambda X, t: np.broadcast_to(2 * B, (*X.shape[:-1], 1, 2, 2))  # noqa: E731
    E = m @ B @ m + np.trace(B @ P)  # E[xᵀBx]
    V = 2 * np.trace(B @ P @ B @ P) + 4 * m @ B @ P @ B @ m
    C = 2 * P @ B @ m
    for mo in (Taylor2().moments(GaussianState(m, P), g, 0, jac=jac, hess=hess),
               GaussHermite(3).moments(GaussianState(m, P), g, 0)):  # degree 4 ≤ 2·3 − 1
        np.testing.assert_allclose(mo.mean, [E], atol=1e-13)
        np.testing.assert_allclose(mo.cov, [[V]], atol=1e-13)
        np.testing.assert_allclose(mo.cross[:, 0], C, atol=1e-13)


# -- seed 004's forms as Taylor2(form), and the continuous (Itô) skeleton --------------------------------
def test_every_second_order_form_is_the_skeleton_with_its_taylor2_rule(nonlinear3):
    """SecondOrderFilter(form) is GaussianFilter(Taylor2(form)) to the last bit (its checks aside),
    PSD losses included; the continuous filters are ContinuousGaussianFilter over Taylor-1/Taylor-2."""
    from nlfilter.filters import ContinuousEKF, ContinuousSecondOrderFilter, SecondOrderFilter
    from nlfilter.filters.gaussian import ContinuousGaussianFilter
    from nlfilter.filters.rules import FORMS, Taylor2
    ys = simulate(nonlinear3, 25, paths=4, rng=9, m0=M0, P0=P0).ys
    ys[1, 3, 0] = np.nan
    for form in FORMS:
        a = GaussianFilter(nonlinear3, Taylor2(form)).run(ys, M0, P0, on_divergence="mark")
        b = SecondOrderFilter(nonlinear3, form=form).run(ys, M0, P0, on_divergence="mark")
        for f in ("means", "covs", "diverged_step"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    dys = 0.1 * _cd_data(S2G, 15, 3, 2)
    m0, P0_ = np.array([0.3, -0.2]), np.eye(2) * 0.2
    for form in ("truncated", "gaussian", "truncated-jazwinski"):
        a = ContinuousGaussianFilter(S2G, 0.01, Taylor2(form), substeps=2).run(dys, m0, P0_, on_divergence="mark")
        b = ContinuousSecondOrderFilter(S2G, 0.01, form=form, substeps=2).run(dys, m0, P0_, on_divergence="mark")
        np.testing.assert_array_equal(a.means, b.means)
    a = ContinuousGaussianFilter(S2G, 0.01, Taylor1()).run(dys, m0, P0_)
    np.testing.assert_array_equal(a.means, ContinuousEKF(S2G, 0.01).run(dys, m0, P0_).means)
    with pytest.raises(TypeError, match="rule"):
        ContinuousGaussianFilter(S2G, 0.01, Cubature())
    with pytest.raises(ValueError, match="form: expected one of"):
        Taylor2("second")
