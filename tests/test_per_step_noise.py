"""Noise given per step (issue 31 item 4): ``R`` ``(T, m, m)`` / ``(B, T, m, m)`` and ``Q``
``(T, r, r)`` / ``(B, T, r, r)``, or R written with a parameter given as an array over time. Every
check compares numbers with an independent computation (a plain NumPy Kalman filter or EKF loop,
filterpy's ``batch_filter(Rs=, Qs=)``, the constant-R filter, the run on each path alone)."""

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter.filters import CKF, EKF, UKF, DiscreteQuasilinearFilter, KalmanFilter, SecondOrderFilter
from nlfilter.filters.backends import refusal

x1, x2, r = sp.symbols("x1 x2 r")
T = 12
F = np.array([[1.0, 0.1], [0.0, 0.95]])
H = np.array([[1.0, 0.0], [0.5, 1.0]])
M0, P0 = np.array([0.5, -0.2]), np.diag([1.0, 0.5])


def per_step(T, B=None, seed=0):
    """R_k (m = 2, correlated, growing with k) and Q_k (r = 2), per path when B is given."""
    g = np.random.default_rng(seed)
    lead = () if B is None else (B,)
    A = g.normal(size=(*lead, T, 2, 2)) * 0.3
    k = np.arange(T).reshape(*(1,) * len(lead), T, 1, 1)
    R = A @ np.swapaxes(A, -1, -2) + (0.2 + 0.1 * k) * np.eye(2)
    Q = (0.01 + 0.005 * k) * np.array([[1.0, 0.3], [0.3, 0.5]]) + 0 * A
    return R, Q


def linear(R, Q):
    return DiscreteModel([x1, x2], list(F @ sp.Matrix([x1, x2])), list(H @ sp.Matrix([x1, x2])), Q=Q, R=R)


def plain_kf(ys, R, Q):
    """Textbook KF (update first), R[k], Q[k]: means, covs, per-step log N(y; ŷ, S)."""
    m, P = M0.copy(), P0.copy()
    ms, Ps, ll = [], [], []
    for k, y in enumerate(ys):
        S = H @ P @ H.T + R[k]
        K = P @ H.T @ np.linalg.inv(S)
        e = y - H @ m
        ll.append(-0.5 * (e @ np.linalg.solve(S, e) + np.linalg.slogdet(2 * np.pi * S)[1]))
        m, P = m + K @ e, P - K @ S @ K.T
        ms.append(m)
        Ps.append(P)
        m, P = F @ m, F @ P @ F.T + Q[k]
    return np.array(ms), np.array(Ps), np.array(ll)


def test_kalman_with_per_step_R_and_Q_equals_a_plain_loop_and_filterpy():
    """Means, covariances, log-likelihood to 1e-10 (the same recursion in other operation orders:
    Joseph form here, the standard form there; round-off ~1e-14 on O(1) numbers)."""
    from filterpy.common import Saver
    from filterpy.kalman import KalmanFilter as FPKF

    R, Q = per_step(T)
    model = linear(R, Q)
    ys = simulate(model, T, paths=2, rng=3, m0=M0, P0=P0).ys
    est = KalmanFilter(model).run(ys, M0, P0, loglik=True)
    for p in range(2):
        ms, Ps, ll = plain_kf(ys[p], R, Q)
        np.testing.assert_allclose(est.means[p], ms, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(est.covs[p], Ps, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(est.extras["loglik"][p], ll, rtol=1e-10, atol=1e-10)
        kf = FPKF(dim_x=2, dim_z=2)
        kf.x, kf.P, kf.F, kf.H = M0.copy(), P0.copy(), F, H
        saver = Saver(kf)
        means, covs, _, _ = kf.batch_filter(ys[p], Rs=list(R), Qs=list(Q), update_first=True, saver=saver)
        np.testing.assert_allclose(est.means[p], means, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(est.covs[p], covs, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(est.extras["loglik"][p], np.array(saver.log_likelihood), rtol=1e-10, atol=1e-10)
    # the RTS smoother runs on the same predictions: at the last step it is the filter
    sm = KalmanFilter(model).smooth(ys, M0, P0)
    np.testing.assert_allclose(sm.means[:, -1], est.means[:, -1], rtol=0, atol=1e-12)
    fp = FPKF(dim_x=2, dim_z=2)
    fp.x, fp.P, fp.F, fp.H = M0.copy(), P0.copy(), F, H
    means, covs, _, _ = fp.batch_filter(ys[0], Rs=list(R), Qs=list(Q), update_first=True)
    # filterpy's smoother predicts k -> k+1 with Qs[k + 1] (its predict-first convention): Q_k there
    xs, Ps, _, _ = fp.rts_smoother(means, covs, Fs=[F] * T, Qs=[Q[0]] + list(Q[:-1]))
    np.testing.assert_allclose(sm.means[0], xs, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(sm.covs[0], Ps, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("cls", [KalmanFilter, EKF, UKF])
def test_a_constant_array_equals_the_constant_R(cls):
    """R repeated over the steps: the same numbers bit for bit (the same matrix enters the same
    operations); Q repeated: to 1e-12 (carried by G as G Q^{1/2}, whose square root rounds). On the
    NumPy loop both: a constant R may run compiled by default (the Kalman filter's loop serves
    every linear model, so an earlier test in the process may have loaded it), a per-step one does
    not, and the two loops agree to rounding only."""
    R, Q = per_step(1)
    model = linear(R[0], Q[0])
    ys = simulate(model, T, paths=2, rng=5, m0=M0, P0=P0).ys
    ref = cls(model).run(ys, M0, P0, loglik=True, backend="numpy")
    est = cls(model.with_params(R=np.repeat(R, T, axis=0))).run(ys, M0, P0, loglik=True, backend="numpy")
    for a, b in zip((ref.means, ref.covs, ref.extras["loglik"]), (est.means, est.covs, est.extras["loglik"])):
        np.testing.assert_array_equal(a, b)
    est = cls(model.with_params(Q=np.repeat(Q, T, axis=0))).run(ys, M0, P0, loglik=True)
    np.testing.assert_allclose(est.means, ref.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(est.extras["loglik"], ref.extras["loglik"], rtol=1e-12)


def test_per_path_arrays_give_each_path_its_own_run():
    """(B, T, m, m) R and Q: the paths run together equal each path run alone with its own (T, ...)
    arrays, and a split of the paths (with_params of the rows, simulate(paths=range(a, b)))
    gives the same numbers (1e-12: the same operations on another batch size)."""
    B = 3
    R, Q = per_step(T, B, seed=1)
    model = linear(R, Q)
    sim = simulate(model, T, paths=B, rng=2, m0=M0, P0=P0)
    part = simulate(model, T, paths=range(1, 3), rng=2, m0=M0, P0=P0)
    np.testing.assert_array_equal(part.ys, sim.ys[1:])
    for cls in (KalmanFilter, EKF):
        est = cls(model).run(sim.ys, M0, P0, loglik=True)
        for p in range(B):
            one = cls(linear(R[p], Q[p])).run(sim.ys[p], M0, P0, loglik=True)
            np.testing.assert_allclose(est.means[p], one.means, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(est.extras["loglik"][p], one.extras["loglik"], rtol=1e-12, atol=1e-12)
        lo = cls(model.with_params(R=R[:1], Q=Q[:1])).run(sim.ys[:1], M0, P0, loglik=True)
        hi = cls(model._rows(range(1, 3))).run(sim.ys[1:], M0, P0, loglik=True)
        np.testing.assert_allclose(np.concatenate([lo.covs, hi.covs]), est.covs, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.concatenate([lo.loglik, hi.loglik]), est.loglik, rtol=1e-12)
    sm = KalmanFilter(model).smooth(sim.ys, M0, P0)
    one = KalmanFilter(linear(R[2], Q[2])).smooth(sim.ys[2], M0, P0)
    np.testing.assert_allclose(sm.means[2], one.means, rtol=1e-12, atol=1e-12)


# a nonlinear model, R_k growing over time: x' = 0.9 x + 0.5 sin x + w, y = x + 0.1 x³ + v
x = sp.Symbol("x")
RK = 0.05 * (1.0 + 0.3 * np.arange(T))  # R_k
QK = 0.1


def nonlinear(R):
    return DiscreteModel([x], [0.9 * x + 0.5 * sp.sin(x)], [x + 0.1 * x ** 3], Q=QK, R=R)


def plain_ekf(ys):
    m, P, ms, Ps, ll = 0.3, 0.8, [], [], []
    for k, y in enumerate(ys[:, 0]):
        Hk = 1 + 0.3 * m ** 2
        S = Hk * P * Hk + RK[k]
        K = P * Hk / S
        e = y - (m + 0.1 * m ** 3)
        ll.append(-0.5 * (e * e / S + np.log(2 * np.pi * S)))
        m, P = m + K * e, (1 - K * Hk) ** 2 * P + K * RK[k] * K  # Joseph form
        ms.append(m)
        Ps.append(P)
        Fk = 0.9 + 0.5 * np.cos(m)
        m, P = 0.9 * m + 0.5 * np.sin(m), Fk * P * Fk + QK
    return np.array(ms), np.array(Ps), np.array(ll)


def test_ekf_with_R_growing_over_time_equals_a_plain_ekf_and_the_parameter_form():
    """The EKF with R_k = 0.05 (1 + 0.3 k) equals a hand-written EKF to 1e-10; R written as
    ``[[r]]`` with ``r`` given per step (with_params) equals the R array to 1e-12 for the EKF,
    UKF, CKF and the second-order filter (the same R_k at each step by either route)."""
    model = nonlinear(RK[:, None, None])
    ys = simulate(model, T, paths=2, rng=7, m0=0.3, P0=0.8).ys
    est = EKF(model).run(ys, 0.3, 0.8, loglik=True)
    for p in range(2):
        ms, Ps, ll = plain_ekf(ys[p])
        np.testing.assert_allclose(est.means[p, :, 0], ms, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(est.covs[p, :, 0, 0], Ps, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(est.extras["loglik"][p], ll, rtol=1e-10, atol=1e-10)
    sym = DiscreteModel([x], [0.9 * x + 0.5 * sp.sin(x)], [x + 0.1 * x ** 3], Q=QK, R=[[r]], params={r: 1.0})
    sym = sym.with_params(r=RK)
    assert sym.structure == {"time-varying R"} and model.structure == {"time-varying R"}
    for cls in (EKF, UKF, CKF, SecondOrderFilter):
        a = cls(model).run(ys, 0.3, 0.8, loglik=True)
        b = cls(sym).run(ys, 0.3, 0.8, loglik=True)
        assert np.isfinite(a.means).all() and not a.diverged.any()
        np.testing.assert_allclose(a.means, b.means, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a.loglik, b.loglik, rtol=1e-12)
    # the Kalman filter reads R written in a per-step parameter too (a linear model)
    lin = DiscreteModel([x], [0.9 * x], [x], Q=QK, R=[[r]], params={r: 1.0})
    a = KalmanFilter(lin.with_params(r=RK)).run(ys, 0.3, 0.8, loglik=True)
    b = KalmanFilter(DiscreteModel([x], [0.9 * x], [x], Q=QK, R=1.0).with_params(R=RK[:, None, None])).run(
        ys, 0.3, 0.8, loglik=True)
    np.testing.assert_array_equal(a.loglik, b.loglik)


def test_simulate_run_loglik_with_per_step_noise():
    """simulate draws v_k ~ N(0, R_k), w_k ~ N(0, Q_k): over 4000 paths the standardized noises
    have unit variance within 5 standard errors (sqrt(2/N) = 0.022 each); the KF's normalized
    innovations of those data average m = 2 per step within 5 standard errors (sqrt(4/N))."""
    N = 4000
    R, Q = per_step(4, seed=4)
    model = linear(R, Q)
    sim = simulate(model, 4, paths=N, rng=11, m0=M0, P0=P0)
    v = sim.ys - sim.xs @ H.T
    w = sim.xs[:, 1:] - sim.xs[:, :-1] @ F.T
    for k in range(4):
        for e, C in ((v[:, k], R[k]), (w[:, k - 1] if k else None, Q[k - 1])):
            if e is None:
                continue
            z = e @ np.linalg.inv(np.linalg.cholesky(C)).T  # whitened: identity covariance
            np.testing.assert_allclose(np.cov(z.T), np.eye(2), atol=5 * np.sqrt(2 / N))
    est = KalmanFilter(model).run(sim, M0, P0, loglik=True)
    ll = est.extras["loglik"]
    assert np.isfinite(ll).all()
    # log N(e; 0, S) = -(e' S^-1 e + log det 2πS)/2: recover the normalized innovation e' S^-1 e
    S_logdet = np.array([np.linalg.slogdet(2 * np.pi * (H @ P @ H.T + R[k]))[1] for k, P in
                         enumerate(_predicted_covs(R, Q))])
    nis = -2 * ll - S_logdet
    np.testing.assert_allclose(nis.mean(axis=0), 2.0, atol=5 * np.sqrt(4 / N))


def _predicted_covs(R, Q):
    P, out = P0.copy(), []
    for k in range(len(R)):
        out.append(P)
        S = H @ P @ H.T + R[k]
        P = P - P @ H.T @ np.linalg.solve(S, H @ P)
        P = F @ P @ F.T + Q[k]
    return out


def test_bad_per_step_noise_is_named():
    R, Q = per_step(T)
    with pytest.raises(ValueError, match=r"^R: expected one \(2, 2\) covariance per step.*got shape \(12, 3, 3\)"):
        linear(np.zeros((T, 3, 3)), Q)
    bad = R.copy()
    bad[3, 0, 1] += 0.5
    with pytest.raises(ValueError, match=r"^R: .*at step k = 3 it is not symmetric"):
        linear(bad, Q)
    bad = np.repeat(R[None], 2, axis=0)
    bad[1, 5] = -np.eye(2)
    with pytest.raises(ValueError, match=r"^R: .*at step k = 5 of path 1 it is not positive semi-definite"):
        linear(bad, Q)
    bad = Q.copy()
    bad[4, 1, 1] = np.nan
    with pytest.raises(ValueError, match=r"^Q: expected finite values, got a non-finite entry at step k = 4"):
        linear(R, bad)
    model = linear(R, Q)
    ys = np.zeros((2, T + 1, 2))
    with pytest.raises(ValueError, match=r"^R: given for 12 step\(s\).*the data have 13 step\(s\): expected at least 13"):
        KalmanFilter(model).run(ys, M0, P0)
    with pytest.raises(ValueError, match=r"^R: given for 12 step\(s\)"):
        simulate(model, T + 1, m0=M0, P0=P0)
    per = linear(np.repeat(R[None], 3, axis=0), Q)
    with pytest.raises(ValueError, match=r"^R: a per-path array of shape \(3, 12, 2, 2\) for 2 path\(s\)"):
        EKF(per).run(ys[:, :T], M0, P0)
    with pytest.raises(ValueError, match=r"^R: a per-path array .* for 1 path\(s\).*not Filter.run\(chunk=...\)"):
        EKF(per).run(np.zeros((3, T, 2)), M0, P0, chunk=1)
    # R in a parameter given per step: a negative variance at step 2 is named
    sym = DiscreteModel([x], [x], [x], Q=1.0, R=[[r]], params={r: 1.0})
    with pytest.raises(ValueError, match=r"^R: .*at step k = 2 it is not positive semi-definite.*\['r'\]"):
        sym.with_params(r=[1.0, 0.5, -0.1])
    # what cannot take it says so
    with pytest.raises(ValueError, match=r"^R: .*varies over the steps"):
        DiscreteQuasilinearFilter(model)
    with pytest.raises(ValueError, match=r"^R/?Q?: one covariance per step is supported for DiscreteModel only"):
        SDEModel([x], [-x], [x], Q=1.0, R=np.ones((3, 1, 1)))
    with pytest.raises(ValueError, match=r"^R: this model's R is written in its parameters"):
        sym.with_params(R=np.ones((3, 1, 1)))
    # the compiled loops read one R: refused with the reason (backend="auto" runs NumPy)
    assert "varies over the steps" in refusal("numba", KalmanFilter(model))
    assert "varies over the steps" in refusal("numba", EKF(model))


def test_grid_and_particle_references_read_R_k():
    """The references take R_k where they take R(x): on a linear-Gaussian model with R_k growing the
    grid filter (401 points on [-5, 5], its posterior Gaussian: exact up to quadrature, ~1e-14 here)
    equals the Kalman filter to 1e-10 in means and covariances and to 1e-6 in log-likelihood (the
    prior mass outside the grid, ~1e-7); the particle filter (5000 particles, seeded) is within its
    Monte Carlo error: means to 0.05 (about 10 standard errors sqrt(P/N) ~ 0.005), log-likelihood to 0.3."""
    from nlfilter.filters import GridFilter, ParticleFilter
    model = DiscreteModel([x], [0.9 * x], [x], Q=QK, R=RK[:, None, None])
    sim = simulate(model, T, paths=2, rng=1, m0=0.3, P0=0.8)
    kf = KalmanFilter(model).run(sim, 0.3, 0.8, loglik=True)
    g = GridFilter(model, [(-5.0, 5.0)], 401).run(sim, 0.3, 0.8, loglik=True)
    np.testing.assert_allclose(g.means, kf.means, rtol=0, atol=1e-10)
    np.testing.assert_allclose(g.covs, kf.covs, rtol=0, atol=1e-10)
    np.testing.assert_allclose(g.loglik, kf.loglik, rtol=0, atol=1e-6)
    p = ParticleFilter(model, particles=5000).run(sim, 0.3, 0.8, rng=0, loglik=True)
    np.testing.assert_allclose(p.means, kf.means, rtol=0, atol=0.05)
    np.testing.assert_allclose(p.loglik, kf.loglik, rtol=0, atol=0.3)



def test_dynamax_time_varying_lgssm_case():
    """dynamax's time-varying LGSSM test case (linear_gaussian_ssm/parallel_inference_test.py,
    ``make_dynamic_lgssm_params``: F_t = a_t I + dt E (E the ones two above the diagonal), R_t =
    s_t² I per step, constant Q, H = [I 0], 50 steps; a_t ~ N(0, 0.5²), s_t ~ N(0, 0.1²) drawn
    here by NumPy), written as an nlfilter model: F_t through a parameter given per step, R_t
    as an array (R_t corrupts y_t in both libraries; dynamax's F_t drives x_{t-1} -> x_t, entry k
    here drives x_k -> x_{k+1}: the same law for drawn arrays). The KF and its RTS smoother equal
    filterpy's batch_filter(Fs, Rs) and rts_smoother to 1e-9 (R_t down to ~1e-6 makes S_k⁻¹
    large: round-off ~1e-12 relative)."""
    from filterpy.common import Saver
    from filterpy.kalman import KalmanFilter as FPKF

    Tn, n, dt = 50, 4, 0.1
    g = np.random.default_rng(0)
    a_t, s_t = g.normal(size=Tn) * 0.5, g.normal(size=Tn) * 0.1
    E = dt * np.eye(n, k=2)
    Fs = a_t[:, None, None] * np.eye(n) + E
    Qd = np.kron(np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]]), np.eye(2))
    Hd = np.eye(2, n)
    Rs = (s_t ** 2)[:, None, None] * np.eye(2)
    m0, S0 = np.array([0.0, 0.0, 1.0, -1.0]), np.eye(n)
    xs, a = sp.symbols("p1 p2 v1 v2"), sp.Symbol("a")
    f = list(a * sp.Matrix(xs) + sp.Matrix(E) * sp.Matrix(xs))
    model = DiscreteModel(list(xs), f, list(xs[:2]), Q=Qd, R=Rs, params={a: a_t})
    sim = simulate(model, Tn, paths=1, rng=1, m0=m0, P0=S0)
    est = KalmanFilter(model).run(sim, m0, S0, loglik=True)
    sm = KalmanFilter(model).smooth(sim, m0, S0)
    kf = FPKF(dim_x=n, dim_z=2)
    kf.x, kf.P, kf.H, kf.Q = m0.copy(), S0.copy(), Hd, Qd
    saver = Saver(kf)
    means, covs, _, _ = kf.batch_filter(sim.ys[0], Fs=list(Fs), Rs=list(Rs), update_first=True, saver=saver)
    # filterpy's smoother predicts k -> k+1 with Fs[k + 1] (its predict-first convention): F_k there
    sx, sP, _, _ = kf.rts_smoother(means, covs, Fs=[Fs[0]] + list(Fs[:-1]), Qs=[Qd] * Tn)
    np.testing.assert_allclose(est.means[0], means, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(est.covs[0], covs, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(est.extras["loglik"][0], np.array(saver.log_likelihood), rtol=1e-9)
    np.testing.assert_allclose(sm.means[0], sx, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(sm.covs[0], sP, rtol=1e-9, atol=1e-12)


def test_diffuse_kalman_reads_R_k():
    """The exact diffuse initialisation (P0 with inf) reads R_k too: from the step after the
    diffuse period on (step 1: two measurements of two states) it equals the KF from a finite
    P0 = 1e6 I on the same directions, to 1e-5 (the two differ by O(1/1e6) relative on O(1)
    numbers: 3e-7 here)."""
    R, Q = per_step(T)
    model = linear(R, Q)
    ys = simulate(model, T, paths=2, rng=8, m0=M0, P0=P0).ys
    diffuse = KalmanFilter(model).run(ys, np.zeros(2), np.diag([np.inf, np.inf]), loglik=True)
    big = KalmanFilter(model).run(ys, np.zeros(2), 1e6 * np.eye(2), loglik=True)
    np.testing.assert_allclose(diffuse.means[:, 1:], big.means[:, 1:], rtol=0, atol=1e-5)
    np.testing.assert_allclose(diffuse.covs[:, 1:], big.covs[:, 1:], rtol=0, atol=1e-5)
    assert np.isfinite(diffuse.loglik).all()
    # a constant R_k array: the same diffuse run bit for bit as the constant R
    const = linear(R[0], Q[0])
    a = KalmanFilter(const).run(ys, np.zeros(2), np.diag([np.inf, np.inf]), loglik=True)
    b = KalmanFilter(const.with_params(R=np.repeat(R[:1], T, axis=0))).run(
        ys, np.zeros(2), np.diag([np.inf, np.inf]), loglik=True)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.loglik, b.loglik)


def test_imm_of_kalman_filters_reads_R_k():
    """An IMM whose two modes are the same KF with R_k is that KF (the mixture of equal beliefs):
    to 1e-12 (round-off of the mixing)."""
    from nlfilter.filters import IMM
    R, Q = per_step(T)
    model = linear(R, Q)
    ys = simulate(model, T, paths=2, rng=3, m0=M0, P0=P0).ys
    kf = KalmanFilter(model).run(ys, M0, P0, loglik=True)
    imm = IMM([KalmanFilter(model), KalmanFilter(model)], [[0.9, 0.1], [0.1, 0.9]]).run(ys, M0, P0, loglik=True)
    np.testing.assert_allclose(imm.means, kf.means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(imm.loglik, kf.loglik, rtol=1e-12)
