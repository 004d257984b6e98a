"""Fading memory (``flt.fading_memory(alpha)``, issue 30 item 5; nlfilter.filters.fading): the
Kalman filter against filterpy's fading-memory ``KalmanFilter`` (``alpha``) to 1e-10, ``alpha = 1``
bit for bit the filter itself, every Gaussian rule on a linear model the fading Kalman filter, the
smoother and sampler consistent with it, bad ``alpha`` named, the compiled loop refusing it."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, sample_posterior, simulate
from nlfilter.filters import CKF, EKF, GHKF, REGISTRY, UKF, ContinuousDiscreteEKF, KalmanFilter, SecondOrderFilter
from nlfilter.filters.compiled.support import static_refusal

p, v = sp.symbols("p v")
TRACK = DiscreteModel([p, v], f=[p + 0.5 * v, 0.9 * v], h=[p], G=[[0.1], [1.0]], Q=0.2, R=0.4)
M0, P0 = np.array([0.3, -0.1]), np.diag([0.5, 0.3])
YS = simulate(TRACK, 25, paths=2, rng=3, m0=M0, P0=P0, start="predict").ys


def test_the_kalman_filter_matches_filterpys_fading_memory_filter():
    """filterpy's KalmanFilter with alpha = 1.05: P⁻ = α² F P Fᵀ + Q, predict then update; its
    means, covariances and log-likelihood per step equal ours (start="predict") to 1e-10 (both
    are the same arithmetic in double precision: ~1e-15 apart on this 25-step run)."""
    fpk = pytest.importorskip("filterpy.kalman")
    alpha = 1.05
    ours = KalmanFilter(TRACK, start="predict").fading_memory(alpha).run(YS, M0, P0, loglik=True)
    F, H = np.array([[1.0, 0.5], [0.0, 0.9]]), np.array([[1.0, 0.0]])
    for b in range(2):
        fp = fpk.KalmanFilter(dim_x=2, dim_z=1)
        fp.x, fp.P, fp.F, fp.H = M0[:, None].copy(), P0.copy(), F, H
        fp.Q, fp.R, fp.alpha = TRACK.GQGT(np.zeros(2)), TRACK.R.copy(), alpha
        for k, y in enumerate(YS[b]):
            fp.predict()
            fp.update(y[:, None])
            np.testing.assert_allclose(ours.means[b, k], fp.x[:, 0], rtol=0, atol=1e-10)
            np.testing.assert_allclose(ours.covs[b, k], fp.P, rtol=0, atol=1e-10)
            np.testing.assert_allclose(ours.extras["loglik"][b, k], fp.log_likelihood, rtol=0, atol=1e-10)


def test_alpha_one_is_the_filter_bit_for_bit_and_alpha_above_one_forgets():
    for make in (lambda: KalmanFilter(TRACK), lambda: UKF(TRACK)):
        base = make().run(YS, M0, P0, loglik=True, backend="numpy")
        one = make().fading_memory(1.0).run(YS, M0, P0, loglik=True, backend="numpy")
        for a, b in zip(base[:2] + (base.loglik,), one[:2] + (one.loglik,)):
            np.testing.assert_array_equal(a, b)
    base = KalmanFilter(TRACK).run(YS, M0, P0, backend="numpy")
    faded = KalmanFilter(TRACK).fading_memory(1.1).run(YS, M0, P0, backend="numpy")
    assert np.all(np.linalg.eigvalsh(faded.covs[:, -1] - base.covs[:, -1]) > 0)  # a larger steady covariance


def test_every_rule_is_the_fading_kalman_filter_on_a_linear_model():
    """EKF, UKF, CKF, GHKF, the second-order filter and a registry rule filter (ckf5) with fading
    memory: their prediction from N(m, α² P) is exact on a linear model, so each equals the fading
    Kalman filter (1e-10: rounding of the node sums)."""
    kf = KalmanFilter(TRACK).fading_memory(1.2).run(YS, M0, P0, backend="numpy")
    for flt in (EKF(TRACK), UKF(TRACK), CKF(TRACK), GHKF(TRACK), SecondOrderFilter(TRACK), REGISTRY["ckf5"](TRACK)):
        est = flt.fading_memory(1.2).run(YS, M0, P0, backend="numpy")
        np.testing.assert_allclose(est.means, kf.means, atol=1e-10)
        np.testing.assert_allclose(est.covs, kf.covs, atol=1e-10)


def test_the_smoother_and_sampler_read_the_fading_filter_as_added_process_noise():
    """The fading Kalman filter is, step by step, the Kalman filter of the model with the extra
    process noise (α² − 1) F P_k Fᵀ; its RTS smoother (D = P Fᵀ) equals that model's exact
    smoother, computed here by hand (1e-10); the sampler's draws are finite (a PSD joint law)."""
    alpha, ys, F = 1.3, YS[:1], np.array([[1.0, 0.5], [0.0, 0.9]])
    flt = KalmanFilter(TRACK).fading_memory(alpha)
    est, sm = flt.run(ys, M0, P0), flt.smooth(ys, M0, P0)
    m, P = est.means[0], est.covs[0]
    ms, Ps = m.copy(), P.copy()
    for k in range(len(m) - 2, -1, -1):  # RTS with P⁻ = α² F P Fᵀ + Q and D = P Fᵀ
        Pp = alpha**2 * F @ P[k] @ F.T + TRACK.GQGT(np.zeros(2))
        G = P[k] @ F.T @ np.linalg.inv(Pp)
        ms[k] = m[k] + G @ (ms[k + 1] - F @ m[k])
        Ps[k] = P[k] + G @ (Ps[k + 1] - Pp) @ G.T
    np.testing.assert_allclose(sm.means[0], ms, atol=1e-10)
    np.testing.assert_allclose(sm.covs[0], Ps, atol=1e-10)
    assert np.isfinite(sample_posterior(flt, ys, M0, P0, n=50, rng=0)).all()


def test_a_continuous_discrete_filter_takes_it():
    """Continuous-discrete EKF on dx = −x dt + dβ: the prediction from α² P over dt is
    e^{−2dt} α² P + (1 − e^{−2dt}) / 2 (RK4, 20 substeps: 1e-9)."""
    x = sp.Symbol("x")
    flt = ContinuousDiscreteEKF(SDEModel([x], [-x], [x], Q=1.0, R=1.0), 0.1, substeps=20).fading_memory(1.5)
    from nlfilter.filters import GaussianState
    P = flt.predict(GaussianState(np.zeros(1), np.eye(1)), 0).cov[0, 0]
    assert abs(P - (np.exp(-0.2) * 2.25 + (1 - np.exp(-0.2)) / 2)) < 1e-9


def test_bad_alpha_is_named_and_the_compiled_loop_refuses_it():
    kf = KalmanFilter(TRACK)
    for bad in (0.9, float("nan"), float("inf"), -1.0):
        with pytest.raises(ValueError, match="alpha: expected a finite number >= 1"):
            kf.fading_memory(bad)
    class Opaque:  # an object whose repr raises: the message must not call it
        def __repr__(self):
            raise RuntimeError("repr")

    for bad in ("1.1", None, True, 1 + 0j, np.array([1.1, 1.2]), Opaque()):
        with pytest.raises(TypeError, match="alpha: expected a real number"):
            kf.fading_memory(bad)
    assert "fading memory" in static_refusal(kf.fading_memory(1.1)) and static_refusal(kf.fading_memory(1.0)) is None
    with pytest.raises(TypeError, match="backend: 'numba' cannot run KalmanFilter: .*fading memory"):
        kf.fading_memory(1.1).run(YS, M0, P0, backend="numba")
    assert kf.fading_memory(1.1).backend_for(2, 25)[0] == "numpy"
    with pytest.raises(ValueError, match="alpha: the exact diffuse initialisation"):
        kf.fading_memory(1.1).run(YS, M0, np.diag([np.inf, 1.0]))
