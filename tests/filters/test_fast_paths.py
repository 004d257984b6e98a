"""The NumPy loop's fast paths (issue 28, "fast by default") give the numbers of the general
paths bit for bit: one state's model functions on NumPy scalars, the scalar Kalman update on
Python floats, the innovation screen's Cholesky pre-test, the recorder's time-major buffer."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import EKF, SecondOrderFilter, recorder
from nlfilter.filters.beliefs import GaussianState
from nlfilter.filters.linalg import gaussian_update, symmetrize
from nlfilter.filters.skeleton import _pd_mask

x1, x2 = sp.symbols("x1 x2")


def test_one_state_on_scalars_equals_the_batch_row():
    """A kernel of ufunc calls and the four operations (scalar path) and one with ``**`` (array
    path) give a lone state the numbers of its row in a batch."""
    md = DiscreteModel([x1, x2], [sp.sin(x1) * sp.exp(x2 / 3), x1 / (1 + x2 * x2) + x2 / x1], [x1 ** 2.5 + sp.cos(x2)],
                       Q=0.1 * np.eye(2), R=0.1)
    X = np.random.default_rng(0).uniform(0.1, 3.0, (200, 2))
    X[7::21, 0] = 0.0  # 1/0: inf as NumPy gives it (a Python float raises)
    for fn in (md.f, md.f_x, md.h, md.h_x, md.f_xx):
        with np.errstate(divide="ignore", invalid="ignore"):
            batch = fn(X, 0)
        for i in range(0, 200, 7):
            with np.errstate(divide="ignore", invalid="ignore"):
                assert np.array_equal(fn(X[i:i + 1], 0)[0], batch[i], equal_nan=True)
                assert np.array_equal(fn(X[i], 0), batch[i], equal_nan=True)


@pytest.mark.parametrize("joseph", [True, False])
def test_scalar_update_equals_the_array_update(joseph):
    """One path, scalar state and measurement (Python floats) = the same path in a batch of two
    (NumPy arrays), a missing measurement included."""
    rng = np.random.default_rng(1)
    for y0 in (*rng.standard_normal(20), np.nan):
        m, P = rng.standard_normal((1, 1)), rng.uniform(0.1, 2.0, (1, 1, 1))
        yp, C, H, R = rng.standard_normal((1, 1)), rng.standard_normal((1, 1, 1)), rng.standard_normal((1, 1, 1)), \
            np.array([[0.3]])
        S = H * P * H + R if joseph else rng.uniform(0.5, 2.0, (1, 1, 1))
        y = np.array([[y0]])
        one = gaussian_update(GaussianState(m, P), y, yp, S, C, *((H, R) if joseph else ()))
        two = gaussian_update(GaussianState(np.repeat(m, 2, 0), np.repeat(P, 2, 0)), np.repeat(y, 2, 0),
                              np.repeat(yp, 2, 0), np.repeat(S, 2, 0), np.repeat(C, 2, 0),
                              *((np.repeat(H, 2, 0), R) if joseph else ()))
        assert np.array_equal(one.mean, two.mean[:1]) and np.array_equal(one.cov, two.cov[:1])


def test_innovation_screen_agrees_with_eigvalsh():
    """The Cholesky pre-test never clears a covariance eigvalsh would flag (near-singular,
    indefinite, zero)."""
    rng = np.random.default_rng(2)
    for _ in range(300):
        m, B = int(rng.integers(2, 6)), int(rng.integers(1, 20))
        U = np.linalg.qr(rng.standard_normal((B, m, m)))[0]
        w = rng.uniform(0, 1, (B, m)) * 10.0 ** rng.uniform(-6, 6, (B, 1))
        w[:, 0] *= rng.choice([1.0, 0.0, -1.0, 1e-16, -1e-16], B)
        S = (U * w[:, None, :]) @ U.swapaxes(-1, -2)
        with np.errstate(invalid="ignore"):
            assert np.array_equal(_pd_mask(S), ~np.all(np.linalg.eigvalsh(symmetrize(S)) > 0, axis=-1))


@pytest.mark.parametrize("make", [EKF, lambda md: SecondOrderFilter(md, form="truncated")])
def test_time_major_buffer_writes_every_step(make, monkeypatch):
    """A batch's outputs through the buffer (several flushes, a partial last one, missing steps and
    the log-likelihood extras) equal the direct column writes."""
    md = DiscreteModel([x1], [0.9 * x1 + 0.1 * sp.sin(x1)], [x1 + 0.2 * x1 ** 2], Q=0.1, R=0.2)
    ys = np.random.default_rng(3).standard_normal((5, 150, 1))
    ys[1, 20:30] = np.nan
    ys[:, 40] = np.nan
    flt = make(md)
    est = flt.run(ys, [0.0], [[1.0]], loglik=True, backend="numpy", on_divergence="mark")
    monkeypatch.setattr(recorder, "CHUNK_STEPS", 1)  # the direct writes
    ref = flt.run(ys, [0.0], [[1.0]], loglik=True, backend="numpy", on_divergence="mark")
    for a, b in zip((est.means, est.covs, *est.extras.values()), (ref.means, ref.covs, *ref.extras.values())):
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
