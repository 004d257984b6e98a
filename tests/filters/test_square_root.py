"""The square-root Gaussian filters (issue 30, item 1; :mod:`nlfilter.filters.square_root`): every
square-root form is its standard form on well-conditioned problems (means, covariances,
log-likelihood, innovation covariance, smoother), on a five-state coordinated-turn tracking model
too; on the classic near-noiseless, nearly collinear measurement the standard forms lose their
covariance (or its positive definiteness) and the square-root forms keep it, measured against the
exact posterior in 50-digit arithmetic, smoothed too; a failed downdate is reported; bad input is
named."""

from __future__ import annotations

import mpmath as mp
import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import CKF, EKF, GHKF, REGISTRY, UKF, IteratedEKF, KalmanFilter
from nlfilter.filters.rules import Cubature5, GaussHermite, Taylor2, Unscented
from nlfilter.filters.square_root import SqrtState, SquareRootFilter
from nlfilter.filters.square_root_filters import (SquareRootCKF, SquareRootEKF, SquareRootGHKF, SquareRootIEKF,
                                                  SquareRootKF, SquareRootUKF)
from nlfilter.filters.triangular import downdate, tria
from nlfilter.simulate import simulate

x1, x2, x3 = sp.symbols("x1 x2 x3")
RC = np.array([[0.2, 0.08], [0.08, 0.1]])  # correlated R: a partly missing y uses its observed block
# a nonlinear 3-state model with a state-dependent noise gain G(x) and measurement noise R(x)
G3 = sp.Matrix([[1 + 0.2 * sp.sin(x1), 0], [0.1 * x2, 1], [0, 0.5]])
D3 = DiscreteModel([x1, x2, x3], [0.9 * x1 + 0.1 * x2 * x3, 0.8 * x2 - 0.05 * x1**3, 0.95 * x3 + 0.1 * sp.cos(x1)],
                   [x1 + 0.1 * x2**2, x2 * x3], G=G3, Q=np.diag([0.1, 0.05]),
                   R=sp.Matrix([[0.2 + 0.05 * x1**2, 0.08], [0.08, 0.1]]))
D2 = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2 - 0.05 * x1**3], [x1 + 0.1 * x2**2, x2],
                   Q=np.diag([0.1, 0.05]), R=RC)
LIN = DiscreteModel.linear([[0.95, 0.1], [0.0, 0.9]], np.eye(2), np.diag([0.1, 0.2]), RC)
M3, P3 = np.array([0.3, -0.2, 0.5]), np.array([[0.5, 0.1, 0.0], [0.1, 0.4, 0.05], [0.0, 0.05, 0.3]])

# (square-root form, its standard form): the registry's defaults, the unscented rule with a
# negative centre weight (α = 0.5: wc_0 = −0.25, wm_0 = −3 — downdates in both the moments and the
# E[G Q Gᵀ] of a state-dependent G), the Gauss–Hermite rule of order 2
PAIRS = {"sr-ekf": (SquareRootEKF, EKF), "sr-iekf": (SquareRootIEKF, IteratedEKF), "sr-ukf": (SquareRootUKF, UKF), "sr-ckf": (SquareRootCKF, CKF),
         "sr-ghkf": (SquareRootGHKF, GHKF),
         "sr-ukf-alpha0.5": (lambda md, **k: SquareRootUKF(md, alpha=0.5, **k), lambda md, **k: UKF(md, alpha=0.5, **k)),
         "sr-ghkf-order2": (lambda md, **k: SquareRootGHKF(md, order=2, **k), lambda md, **k: GHKF(md, order=2, **k))}


def _data(model, m0, P0, T, paths=3, seed=4):
    ys = simulate(model, T, paths=paths, rng=seed, m0=m0, P0=P0).ys.copy()
    ys[0, 3, 1] = np.nan  # partly missing
    ys[1, 5] = np.nan  # missing on one path
    ys[:, 7] = np.nan  # missing on every path
    return ys


def _same(a, b, tol, scale=1.0):
    """Every output of two runs within ``tol · max(scale, |b|)`` (NaN where the other is NaN)."""
    for what in ("means", "covs"):
        np.testing.assert_allclose(getattr(a, what), getattr(b, what), rtol=tol, atol=tol * scale, err_msg=what)
    for name in b.extras:
        np.testing.assert_allclose(a.extras[name], b.extras[name], rtol=tol, atol=tol * scale, err_msg=name)


@pytest.mark.parametrize("start", ["update", "predict"])
@pytest.mark.parametrize("name", list(PAIRS))
def test_every_square_root_form_is_its_standard_form(name, start):
    """Well-conditioned (P of order 0.1-1, R ≥ 0.1): the square-root steps and the standard ones
    differ by rounding only — measured ≤ 4e-15 on the means, 7e-16 on the covariances, 3e-14 on the
    log-likelihood, 6e-15 on the smoothed moments over 30 steps — so 1e-10 leaves a wide margin and still catches any formula
    error (a weight, a missing noise column, a wrong cross term moves them by 1e-3 or more). The
    3-state model has G(x) and R(x) (the noise columns ``√wm_i G(X_i) Q^½``, R at the predicted
    mean), partly missing and missing steps; the RTS smoothers agree too."""
    sr, std = PAIRS[name]
    ys = _data(D3, M3, P3, 30)
    a = sr(D3, start=start).run(ys, M3, P3, loglik=True)
    b = std(D3, start=start).run(ys, M3, P3, loglik=True, backend="numpy")
    assert not a.diverged.any() and not b.diverged.any()
    _same(a, b, 1e-10)
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=0, atol=1e-10)
    sa, sb = sr(D3, start=start).smooth(ys, M3, P3), std(D3, start=start).smooth(ys, M3, P3, backend="numpy")
    _same(sa, sb, 1e-10)


D2X = DiscreteModel([x1, x2], D2.sym["f"], D2.sym["h"], Q=np.diag([0.1, 0.05]), R=RC,
                   cross_noise=[[0.05, 0.02], [0.0, 0.03]])  # E[w_k v_kᵀ] = S


@pytest.mark.parametrize("start", ["update", "predict"])
@pytest.mark.parametrize("name", ["sr-ekf", "sr-ukf-alpha0.5", "sr-ckf"])
def test_correlated_noise_is_the_standard_decorrelation(name, start):
    """Correlated process and measurement noise (``cross_noise``): the prediction from step k
    decorrelates with ``y_k`` (its observed components only) as the standard filters do; filter,
    likelihood and smoother equal theirs to 1e-10 (measured ≤ 1e-15 on the moments, 1.5e-14 on the
    log-likelihood), with partly missing and missing steps."""
    sr, std = PAIRS[name]
    ys = _data(D2X, M3[:2], P3[:2, :2], 30)
    a = sr(D2X, start=start).run(ys, M3[:2], P3[:2, :2], loglik=True)
    b = std(D2X, start=start).run(ys, M3[:2], P3[:2, :2], loglik=True, backend="numpy")
    _same(a, b, 1e-10)
    _same(sr(D2X, start=start).smooth(ys, M3[:2], P3[:2, :2]),
          std(D2X, start=start).smooth(ys, M3[:2], P3[:2, :2], backend="numpy"), 1e-10)


def test_square_root_slf_is_the_statistically_linearized_filter():
    """The polynomial model D2 (the order of exact Gaussian moments: 4 points per axis), correlated
    noise too: sr-slf = StatisticallyLinearizedFilter to 1e-10 (measured ≤ 1e-14), smoother included."""
    from nlfilter.filters import StatisticallyLinearizedFilter
    from nlfilter.filters.square_root_filters import SquareRootSLF
    for md in (D2, D2X):
        ys = _data(md, M3[:2], P3[:2, :2], 30)
        a = SquareRootSLF(md).run(ys, M3[:2], P3[:2, :2], loglik=True)
        b = StatisticallyLinearizedFilter(md).run(ys, M3[:2], P3[:2, :2], loglik=True, backend="numpy")
        assert a.diverged.sum() == 0 and SquareRootSLF(md).order == 4
        _same(a, b, 1e-10)
        _same(SquareRootSLF(md).smooth(ys, M3[:2], P3[:2, :2]),
              StatisticallyLinearizedFilter(md).smooth(ys, M3[:2], P3[:2, :2], backend="numpy"), 1e-10)


def _fading(flt, alpha):
    """``flt`` with fading memory ``alpha``: ``fading_memory`` where the Gaussian filters offer it
    (nlfilter.filters.fading), else the attribute that sets it."""
    if hasattr(flt, "fading_memory"):
        return flt.fading_memory(alpha)
    flt.fading = alpha
    return flt


def _fading_kalman(ys, m0, P0, a):
    """The fading-memory Kalman filter and its RTS smoother on LIN, written out: ``P⁻ = α² F P Fᵀ + Q``,
    the smoother's ``D = P Fᵀ`` (the inflation read as added process noise); ``(means, covs, smoothed
    means, smoothed covs, loglik)``, paths one by one."""
    F, H, Q, R = np.array([[0.95, 0.1], [0.0, 0.9]]), np.eye(2), np.diag([0.1, 0.2]), RC
    out = []
    for y in ys:
        m, P, ms, Ps, pm, pP, ll = m0, P0, [], [], [], [], 0.0
        for k in range(len(y)):
            if k:
                m, P = F @ m, a * a * F @ P @ F.T + Q
            pm.append(m), pP.append(P)
            S = H @ P @ H.T + R
            K = P @ H.T @ np.linalg.inv(S)
            e = y[k] - H @ m
            ll += -0.5 * (e @ np.linalg.solve(S, e) + np.linalg.slogdet(S)[1] + 2 * np.log(2 * np.pi))
            m, P = m + K @ e, P - K @ S @ K.T
            ms.append(m), Ps.append(P)
        sm, sP = [ms[-1]], [Ps[-1]]
        for k in range(len(y) - 2, -1, -1):
            G = Ps[k] @ F.T @ np.linalg.inv(pP[k + 1])
            sm.insert(0, ms[k] + G @ (sm[0] - pm[k + 1]))
            sP.insert(0, Ps[k] + G @ (sP[0] - pP[k + 1]) @ G.T)
        out.append((ms, Ps, sm, sP, ll))
    return [np.array([o[i] for o in out]) for i in range(5)]


@pytest.mark.parametrize("name", ["sr-kf", "sr-ckf", "sr-ukf-alpha0.5"])
def test_fading_memory_is_the_inflated_factor(name):
    """Fading memory α = 1.3 (the Gaussian filters' option): the prediction from the factor α S, and
    the smoother's joint factor read as added process noise; on the linear model the filter, its
    likelihood and its smoother are the fading-memory Kalman filter's written out, to 1e-10
    (measured ≤ 1e-15 on the moments, 1.5e-14 on the log-likelihood)."""
    make = SquareRootKF if name == "sr-kf" else PAIRS[name][0]
    ys = simulate(LIN, 20, paths=2, rng=5, m0=M3[:2], P0=P3[:2, :2]).ys
    m, P, sm, sP, ll = _fading_kalman(ys, M3[:2], P3[:2, :2], 1.3)
    a = _fading(make(LIN), 1.3).run(ys, M3[:2], P3[:2, :2], loglik=True)
    s = _fading(make(LIN), 1.3).smooth(ys, M3[:2], P3[:2, :2])
    for got, want in ((a.means, m), (a.covs, P), (a.loglik, ll), (s.means, sm), (s.covs, sP)):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)


def test_square_root_kf_is_the_kalman_filter():
    """Linear model, correlated R, missing data: sr-kf = KalmanFilter (Joseph form) to 1e-10 (measured
    ~1e-15); its smoother the RTS smoother."""
    ys = _data(LIN, M3[:2], P3[:2, :2], 40)
    a = SquareRootKF(LIN).run(ys, M3[:2], P3[:2, :2], loglik=True)
    b = KalmanFilter(LIN).run(ys, M3[:2], P3[:2, :2], loglik=True, backend="numpy")
    _same(a, b, 1e-10)
    _same(SquareRootKF(LIN).smooth(ys, M3[:2], P3[:2, :2]), KalmanFilter(LIN).smooth(ys, M3[:2], P3[:2, :2],
                                                                                      backend="numpy"), 1e-10)
    with pytest.raises(ValueError, match=r"^model: SquareRootKF needs a linear model"):
        SquareRootKF(D2)


def _turn_model():
    """Coordinated turn at an unknown rate ω (5 states: px, vx, py, vy, ω; Bar-Shalom, Li &
    Kirubarajan 2001, §11.7), range and bearing from the origin, sampling time 1 s."""
    px, vx, py, vy, w = sp.symbols("px vx py vy w")
    s, c = sp.sin(w), sp.cos(w)
    f = [px + s / w * vx - (1 - c) / w * vy, c * vx - s * vy, py + (1 - c) / w * vx + s / w * vy, s * vx + c * vy, w]
    h = [sp.sqrt(px**2 + py**2), sp.atan2(py, px)]
    G = [[0.5, 0, 0], [1, 0, 0], [0, 0.5, 0], [0, 1, 0], [0, 0, 1]]
    return DiscreteModel([px, vx, py, vy, w], f, h, G=G, Q=np.diag([0.1, 0.1, 1e-7]), R=np.diag([25.0, 1e-5]))


@pytest.mark.parametrize("name", ["sr-ekf", "sr-iekf", "sr-ukf", "sr-ckf", "sr-ghkf"])
def test_five_state_coordinated_turn(name):
    """A five-state coordinated-turn tracker from range and bearing (positions ~1000 m, ω ≈ 0.05
    rad/s ± 0.01): the square-root forms equal the standard ones over 40 steps. Compared relative to
    each entry's size (floor 1e-3; positions 1e3, covariances 1e-5 to 1e2): measured ≤ 7e-13 on the
    means, ≤ 6e-11 on the covariances (their smallest entries carry the rounding of the largest),
    6e-13 on the log-likelihood (≈ 30); the tolerances 1e-9, 1e-8 and 1e-9 leave 100-1000 times."""
    md = _turn_model()
    m0 = np.array([1000.0, 10.0, 1000.0, 0.0, 0.05])
    P0 = np.diag([100.0, 4.0, 100.0, 4.0, 1e-4])
    ys = _data(md, m0, P0, 40, paths=2, seed=7)
    sr, std = PAIRS[name]
    a = sr(md).run(ys, m0, P0, loglik=True)
    b = std(md).run(ys, m0, P0, loglik=True, backend="numpy")
    assert not a.diverged.any() and not b.diverged.any()
    for what in ("means", "covs"):
        A, B = getattr(a, what), getattr(b, what)
        assert np.max(np.abs(A - B) / np.maximum(np.abs(B), 1e-3)) < (1e-9 if what == "means" else 1e-8), what
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=0, atol=1e-9)


def _collinear(d):
    """The classic ill-conditioned measurement (as in Grewal & Andrews, *Kalman Filtering: Theory and
    Practice*, on implementation methods): three states, P0 = I, two nearly collinear near-noiseless
    measurements ``H = [[1, 1, 1], [1, 1, 1 + δ]]``, ``R = δ² I`` (R/P = δ²)."""
    return DiscreteModel.linear(np.eye(3), [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0 + d]], np.zeros((3, 3)), d * d * np.eye(2))


def _exact_posterior(d):
    """``P⁺ = P0 − P0 Hᵀ (H P0 Hᵀ + R)⁻¹ H P0`` in 50-digit arithmetic (mpmath), rounded to doubles."""
    with mp.workdps(50):
        d = mp.mpf(d)
        H = mp.matrix([[1, 1, 1], [1, 1, 1 + d]])
        K = H.T * mp.inverse(H * H.T + d**2 * mp.eye(2))
        return np.array((mp.eye(3) - K * H).tolist(), dtype=float)


@pytest.mark.parametrize("sr,std,d,lost", [
    ("sr-kf", "kf", 1e-8, "error"), ("sr-ekf", "ekf", 1e-8, "error"),
    ("sr-kf", "kf", 1e-9, "psd"), ("sr-ekf", "ekf", 1e-9, "psd"),
    ("sr-ckf", "ckf", 1e-7, "psd"), ("sr-ukf", "ukf", 1e-7, "psd")])
def test_near_noiseless_collinear_measurement(sr, std, d, lost):
    """What was measured (one update from P0 = I; the posterior's entries are O(1), its smallest
    eigenvalue ≈ δ²/6): the standard Kalman filter and EKF (Joseph form) are off by 0.43 in their
    covariance at δ = 1e-8 (R/P = 1e-16) and lose positive definiteness at δ = 1e-9 (the run loop's
    check marks the path); the CKF and UKF (``P⁻ − K S Kᵀ``) lose it from δ = 1e-7 (at δ = 1e-6,
    R/P = 1e-12, their smallest eigenvalue is already −7e-11 where the exact one is +1.7e-13). The
    square-root forms stay within 3e-9 (δ = 1e-8) and 6e-8 (δ = 1e-9) of the exact posterior — of
    the order eps/δ, the square root of the conditioning eps·cond(P⁺) ≈ eps/δ² that the standard
    forms suffer — symmetric, PSD to rounding (smallest eigenvalue ≥ −1e-15, measured −2e-16); the
    tolerance 1e-6 is 15 times what was measured and far below the standard forms' error."""
    md, ys = _collinear(d), np.zeros((1, 1, 2))
    exact = _exact_posterior(d)
    a = REGISTRY[sr](md).run(ys, np.zeros(3), np.eye(3), on_divergence="mark")
    b = REGISTRY[std](md).run(ys, np.zeros(3), np.eye(3), on_divergence="mark", backend="numpy")
    P = a.covs[0, 0]
    assert not a.diverged.any()
    assert np.abs(P - exact).max() < 1e-6
    np.testing.assert_array_equal(P, P.T)
    assert np.linalg.eigvalsh(P)[0] >= -1e-15
    if lost == "psd":
        assert b.diverged.all() and b.diverged_step[0] == 0
        with pytest.raises(DivergenceError):
            REGISTRY[std](md).run(ys, np.zeros(3), np.eye(3), backend="numpy")
    else:
        assert not b.diverged.any() and np.abs(b.covs[0, 0] - exact).max() > 0.1


def _exact_smoothed(d, q, T):
    """The RTS smoother's ``Pˢ_0`` of :func:`_collinear` with ``Q = q I`` over T zero measurements,
    in 60-digit arithmetic: the filter, then ``Pˢ_k = P_k + G (Pˢ_{k+1} − P⁻_{k+1}) Gᵀ``,
    ``G = P_k (P⁻_{k+1})⁻¹`` (F = I)."""
    with mp.workdps(60):
        d, q = mp.mpf(d), mp.mpf(q)
        H = mp.matrix([[1, 1, 1], [1, 1, 1 + d]])
        P, filt, pred = mp.eye(3), [], []
        for k in range(T):
            P = P + q * mp.eye(3) if k else P
            pred.append(P)
            P = P - P * H.T * mp.inverse(H * P * H.T + d**2 * mp.eye(2)) * H * P
            filt.append(P)
        Ps = filt[-1]
        for k in range(T - 2, -1, -1):
            G = filt[k] * mp.inverse(pred[k + 1])
            Ps = filt[k] + G * (Ps - pred[k + 1]) * G.T
        return np.array(Ps.tolist(), dtype=float)


@pytest.mark.parametrize("sr,std,d,q,err", [("sr-kf", "kf", 1e-8, 1e-4, 1e-7), ("sr-ckf", "ckf", 1e-6, 1e-12, 1e-9)])
def test_square_root_smoother_on_the_near_noiseless_measurement(sr, std, d, q, err):
    """The same measurement at three steps with ``Q = q I``: the smoothed ``Pˢ_0`` against the exact
    one (60 digits). Measured: the standard Kalman smoother is off by 0.15 at δ = 1e-8 and the
    standard CKF's by 0.33 at δ = 1e-6, q = 1e-12 (its filtered covariance already indefinite,
    −7e-11); the square-root smoothers (:func:`~nlfilter.filters.square_root.sqrt_rts`) by 2.7e-9
    and 4.2e-11, PSD; the tolerances ``err`` are 25-40 times those."""
    T = 3
    md = DiscreteModel.linear(np.eye(3), [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0 + d]], q * np.eye(3), d * d * np.eye(2))
    ys, exact = np.zeros((1, T, 2)), _exact_smoothed(d, q, T)
    a = REGISTRY[sr](md).smooth(ys, np.zeros(3), np.eye(3))
    b = REGISTRY[std](md).smooth(ys, np.zeros(3), np.eye(3), on_divergence="mark", backend="numpy")
    assert np.abs(a.covs[0, 0] - exact).max() < err and np.linalg.eigvalsh(a.covs[0, 0])[0] >= -1e-15
    assert b.diverged.any() or np.abs(b.covs[0, 0] - exact).max() > 0.1


def test_a_failed_downdate_is_reported():
    """The unscented rule with α = 0.8, β = 0, κ = −1 in n = 2 (centre weight wc_0 = −2.57) on
    f = (x² + y², y), P = I: at most prior means its predicted covariance Σ wc_i D_i D_iᵀ + Q is
    indefinite (smallest eigenvalue −1.28 at m = 0, −0.32 at m = (0, 1); PSD at m = (2, 0)), so the
    standard UKF's run loop marks those paths at step 1; the square-root form's downdate fails on
    exactly those paths at that step, and they are marked (or raised) the same way, never returned
    with a made-up factor."""
    x, y = sp.symbols("x y")
    md = DiscreteModel([x, y], [x**2 + y**2, y], [x], Q=1e-6 * np.eye(2), R=1.0)
    ys = np.zeros((5, 3, 1))
    m0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [2.0, 0.0], [1.0, 1.0]])
    flt = SquareRootUKF(md, alpha=0.8, beta=0.0, kappa=-1.0)
    a = flt.run(ys, m0, np.eye(2), on_divergence="mark")
    b = UKF(md, alpha=0.8, beta=0.0, kappa=-1.0).run(ys, m0, np.eye(2), on_divergence="mark", backend="numpy")
    np.testing.assert_array_equal(a.diverged, [True, True, True, False, True])
    np.testing.assert_array_equal(a.diverged, b.diverged)
    np.testing.assert_array_equal(a.diverged_step, b.diverged_step)
    assert np.isnan(a.means[a.diverged, 1:]).all() and np.isfinite(a.means[~a.diverged]).all()
    with pytest.raises(DivergenceError) as info:
        flt.run(ys, m0, np.eye(2))
    assert info.value.step == 1


def test_tria_and_downdate():
    """``tria(A) tria(A)ᵀ = A Aᵀ`` (lower-triangular, diagonal ≥ 0, fewer columns than rows too) and a
    downdate removes ``v vᵀ``; one that would leave an indefinite matrix fails (NaN factor)."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((4, 3, 5))
    L = tria(A)
    np.testing.assert_allclose(L @ np.swapaxes(L, -1, -2), A @ np.swapaxes(A, -1, -2), rtol=0, atol=1e-13)
    assert np.all(np.triu(L, 1) == 0) and np.all(np.diagonal(L, axis1=-2, axis2=-1) >= 0)
    B = rng.standard_normal((3, 2))
    np.testing.assert_allclose(tria(B) @ tria(B).T, B @ B.T, rtol=0, atol=1e-13)
    v = 0.3 * A[..., 0]
    Ld, failed = downdate(L, [v])
    assert not failed.any()
    np.testing.assert_allclose(Ld @ np.swapaxes(Ld, -1, -2), A @ np.swapaxes(A, -1, -2) - v[..., :, None] * v[..., None, :],
                               rtol=0, atol=1e-12)
    Lf, failed = downdate(L[:1], [1.1 * L[:1, :, 0]])  # L Lᵀ − 1.21 l₀ l₀ᵀ: −0.21 l₀ l₀ᵀ off the span of l₁, l₂
    assert failed.all() and np.isnan(Lf).all()


def test_bad_input_is_named():
    """A rule without a square-root form, a node rule whose points carry no covariance (one
    Gauss–Hermite node), a belief whose factor is not lower-triangular or not finite: each refused
    naming the argument. (Priors, data, options and model structures: the contract test.)"""
    with pytest.raises(TypeError, match=r"^rule: the square-root filters take Taylor1 or a node rule"):
        SquareRootFilter(D2, Taylor2())
    with pytest.raises(ValueError, match=r"^rule: the square-root update needs a rule whose points carry"):
        SquareRootFilter(D2, GaussHermite(1))
    with pytest.raises(ValueError, match=r"^order: the square-root GHKF needs order ≥ 2"):
        SquareRootGHKF(D2, order=1)
    flt = SquareRootEKF(D2)
    good = flt.belief([0.1, 0.2], [[1.0, 0.0], [0.3, 0.5]])
    assert isinstance(good, SqrtState)
    for factor, what in [([[1.0, 0.2], [0.3, 0.5]], r"lower-triangular"), ([[1.0, 0.0], [np.nan, 0.5]], r"finite"),
                         ([[1.0, 0.0, 0.0]], r"shape"), ([[-1.0, 0.0], [0.3, 0.5]], r"non-negative diagonal")]:
        with pytest.raises(ValueError, match=rf"^factor: .*{what}"):
            flt.belief([0.1, 0.2], factor)
    with pytest.raises(ValueError, match=r"^mean"):
        flt.belief([0.1, 0.2, 0.3], [[1.0, 0.0], [0.3, 0.5]])
    from nlfilter.filters import GaussianState
    cov = GaussianState(np.array([0.1, 0.2]), np.array([[1.0, 0.3], [0.3, 0.5]]))  # a covariance is no factor
    for step in (lambda: flt.predict(cov, 0), lambda: flt.update(cov, np.array([0.1, 0.2]), 0)):
        with pytest.raises(TypeError, match=r"^belief: the square-root filters step a SqrtState"):
            step()


def test_the_compiled_backend_refuses_the_forms_without_kernels_naming_why():
    """The Taylor-1 and node forms run on the compiled loop too (tests/filters/test_compiled_sqrt.py);
    the iterated one, the second-order one and fading memory do not: ``backend="numba"`` is a
    TypeError saying why, and ``backend="auto"`` runs the NumPy loop (no compile here)."""
    ys = np.zeros((2, 3, 2))
    flt = SquareRootIEKF(D2)
    with pytest.raises(TypeError, match=r"^backend: 'numba' cannot run SquareRootIEKF: .*iterated"):
        flt.run(ys, M3[:2], P3[:2, :2], backend="numba")
    assert flt.backend_for(1000, 1000)[0] == "numpy"
    flt.run(ys, M3[:2], P3[:2, :2])
    sec = REGISTRY["sr-second-order"](D2)
    with pytest.raises(TypeError, match=r"^backend: 'numba' cannot run SquareRootSecondOrderFilter: .*second-order"):
        sec.run(ys, M3[:2], P3[:2, :2], backend="numba")
    faded = SquareRootCKF(D2).fading_memory(1.1)
    assert faded.backend_for(1000, 1000) == ("numpy", "no compiled loop: SquareRootCKF with fading memory (alpha = "
                                                      "1.1, nlfilter.filters.fading) has no compiled form")


def test_the_fifth_degree_rule_runs_square_root_with_its_negative_weights():
    """Any node rule exact for second moments: Stroud's degree-5 rule in n = 5 has negative axis
    weights (downdated); on a linear model it is the Kalman filter to 1e-10 (measured 1e-15)."""
    A = 0.9 * np.eye(5) + 0.05 * np.eye(5, k=1)
    md = DiscreteModel.linear(A, np.eye(5)[:2], 0.1 * np.eye(5), 0.2 * np.eye(2))
    z, w, _ = Cubature5().unit_nodes(5)
    assert (w < 0).any()
    ys = simulate(md, 10, paths=2, rng=3, m0=np.zeros(5), P0=np.eye(5)).ys
    a = SquareRootFilter(md, Cubature5()).run(ys, np.zeros(5), np.eye(5), loglik=True)
    b = KalmanFilter(md).run(ys, np.zeros(5), np.eye(5), loglik=True, backend="numpy")
    _same(a, b, 1e-10)


def test_unscented_alpha_is_checked_as_the_ukf():
    """The square-root UKF takes the UKF's (alpha, beta, kappa) with its checks."""
    with pytest.raises(ValueError, match=r"^alpha"):
        SquareRootUKF(D2, alpha=0.0)
    assert SquareRootUKF(D2, alpha=0.5).rule == Unscented(0.5, 2.0, 0.0)
