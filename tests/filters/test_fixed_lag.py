"""The fixed-lag smoother (:mod:`nlfilter.filters.fixed_lag`, issue 30 item 5): at lag L the
estimate of x_k is the fixed-interval (RTS) smoother's of the data y_0..y_{k+L}, on a linear and a
nonlinear model, with a missing measurement; a stream of measurements is read one at a time.
Tolerance 1e-10 relative: the same operations in another grouping of steps (the filter's steps one
at a time against the run loop), so only rounding separates them."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import UKF, KalmanFilter, ParticleFilter
from nlfilter.filters.fixed_lag import fixed_lag, fixed_lag_steps


def _tracking():
    p, v = sp.symbols("p v")
    return DiscreteModel([p, v], f=[p + v, 0.95 * v], h=[p], G=[[0.0], [1.0]], Q=0.3, R=0.5)


def _pendulum():
    a, w = sp.symbols("a w")
    return DiscreteModel([a, w], f=[a + 0.1 * w, w - 0.1 * sp.sin(a)], h=[sp.sin(a)], Q=[[1e-3, 0], [0, 1e-2]], R=0.1)


@pytest.mark.parametrize("case", ["kf", "ukf"])
@pytest.mark.parametrize("lag", [1, 3])
def test_equals_the_fixed_interval_smoother_of_the_data_so_far(case, lag):
    md = _tracking() if case == "kf" else _pendulum()
    flt = KalmanFilter(md) if case == "kf" else UKF(md)
    ys = np.random.default_rng(1).normal(size=(3, 7, 1))
    ys[1, 2] = np.nan
    m0, P0 = np.array([0.2, 0.0]), np.diag([0.5, 0.2])
    est = fixed_lag(flt, ys, m0, P0, lag)
    T = ys.shape[1]
    for k in range(T):
        sm = flt.smooth(ys[:, :min(k + lag, T - 1) + 1], m0, P0, backend="numpy")
        np.testing.assert_allclose(est.means[:, k], sm.means[:, k], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(est.covs[:, k], sm.covs[:, k], rtol=1e-10, atol=1e-12)


def test_a_stream_is_read_one_step_at_a_time():
    """The generator yields step k as soon as y_{k+lag} has come in, and a lag longer than the data
    gives the fixed-interval smoother."""
    flt = KalmanFilter(_tracking())
    ys = np.random.default_rng(2).normal(size=(2, 5, 1))
    seen = []

    def stream():
        for k in range(5):
            seen.append(k)
            yield ys[:, k]
    out = []
    for k, state in fixed_lag_steps(flt, stream(), [0.0, 0.0], np.eye(2), 2):
        out.append((k, seen[-1]))
    assert out == [(0, 2), (1, 3), (2, 4), (3, 4), (4, 4)]
    long = fixed_lag(flt, ys, [0.0, 0.0], np.eye(2), 10)
    np.testing.assert_allclose(long.means, flt.smooth(ys, [0.0, 0.0], np.eye(2)).means, rtol=1e-10, atol=1e-12)


def test_bad_input_is_named():
    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[x**3], h=[x], Q=0.1, R=0.1)
    kf_md = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.1)
    ys = np.zeros((1, 4, 1))
    for lag, err in ((0, ValueError), (-1, ValueError), (1.5, TypeError)):
        with pytest.raises(err, match="lag: "):
            fixed_lag(KalmanFilter(kf_md), ys, 0.0, 1.0, lag)
    with pytest.raises(TypeError, match="flt: .*ParticleFilter"):
        fixed_lag(ParticleFilter(kf_md, 100), ys, 0.0, 1.0, 1)
    with pytest.raises(ValueError, match=r"ys: expected measurements of shape \(paths, 1\)"):
        list(fixed_lag_steps(KalmanFilter(kf_md), [np.zeros(3)], 0.0, 1.0, 1))
    with pytest.raises(DivergenceError):  # x³ from 50, unmeasured: overflows
        fixed_lag(UKF(md), np.full((1, 20, 1), np.nan), 50.0, 1.0, 2)
