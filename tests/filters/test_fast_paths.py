"""The NumPy loop's fast paths (issue 28, "fast by default") give the numbers of the general
paths bit for bit: one state's model functions on NumPy scalars, the scalar Kalman update on
Python floats, one path's covariance update by np.dot, the innovation screen's Cholesky pre-test,
the recorder's time-major buffer, the measurements' time-major rows, the run's steps chosen once
per run, the 1 x 1 matmul, the n = 1 divergence screen."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, _npcall
from nlfilter._npcall import quiet
from nlfilter.filters import EKF, UKF, SecondOrderFilter, linalg, recorder
from nlfilter.filters.base import Filter
from nlfilter.filters.beliefs import GaussianState
from nlfilter.filters.gaussian import GaussianFilter
from nlfilter.filters.linalg import (
    _all_ok,
    _total,
    bad_paths,
    gaussian_update,
    matmul,
    symmetrize,
)
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


def test_rows_are_the_columns_and_a_held_row_stays():
    """``Rows``: every step's row is ``yf[:, k]`` (NaN included), contiguous; a row held across
    blocks keeps its numbers (each block a new array, never written again)."""
    yf = np.random.default_rng(4).standard_normal((7, 150, 2))
    yf[2, 30:40, 1] = np.nan
    rows = recorder.Rows(yf)
    held = rows[recorder.CHUNK_STEPS - 1]
    for k in range(150):
        r = rows[k]
        assert r.flags.c_contiguous and np.array_equal(r, yf[:, k], equal_nan=True)
    assert np.array_equal(held, yf[:, recorder.CHUNK_STEPS - 1])


def test_matmul_of_one_by_one_is_matmul_bit_for_bit():
    """``linalg.matmul`` of 1 x 1 batches (broadcast, transposed, one path) = ``@``, special values included."""
    v = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, -5e-324, 1e-300, -1e-300, 1e300, -1e300, 1.5, -2.5])
    A, B = np.repeat(v, v.size).reshape(-1, 1, 1), np.tile(v, v.size).reshape(-1, 1, 1)
    with np.errstate(all="ignore"):
        for a, b in ((A, B), (A.swapaxes(-1, -2), B[::-1]), (A, B[3]), (A[:1], B[:1]), (A[0], B[0])):
            assert np.array_equal(matmul(a, b).view(np.uint64), (a @ b).view(np.uint64))


@pytest.mark.parametrize("joseph", [True, False])
def test_one_path_update_by_dot_equals_the_batch(joseph, monkeypatch):
    """One path's covariance update on its 2-D matrices by ``np.dot`` (n, m ≥ 2; C- and Fortran-ordered
    operands, a missing component) = the same path in a batch of two (matmul), bit for bit."""
    prods = []
    posterior = linalg._posterior
    monkeypatch.setattr(linalg, "_posterior", lambda *a: prods.append(a[-1]) or posterior(*a))
    rng = np.random.default_rng(5)
    for n, m in ((2, 2), (3, 2), (4, 2), (5, 3), (6, 6)):
        A, H = rng.standard_normal((1, n, n)), rng.standard_normal((1, m, n))
        P, R = A @ A.swapaxes(-1, -2) + 0.1 * np.eye(n), 0.3 * np.eye(m) + 0.05
        C = P @ H.swapaxes(-1, -2)
        S = H @ C + R
        for Pl, Hl in ((P, H), (np.asfortranarray(P[0])[None], np.asfortranarray(H[0])[None])):
            for y in (rng.standard_normal((1, m)), np.where(np.arange(m) == 1, np.nan, 1.0)[None]):
                m0, yp = rng.standard_normal((1, n)), rng.standard_normal((1, m))
                one = gaussian_update(GaussianState(m0, Pl), y, yp, S, C, *((Hl, R) if joseph else ()))
                two = gaussian_update(GaussianState(np.repeat(m0, 2, 0), np.repeat(Pl, 2, 0)), np.repeat(y, 2, 0),
                                      np.repeat(yp, 2, 0), np.repeat(S, 2, 0), np.repeat(C, 2, 0),
                                      *((np.repeat(Hl, 2, 0), R) if joseph else ()))
                assert np.array_equal(one.mean, two.mean[:1])
                assert np.array_equal(one.cov.view(np.uint64), two.cov[:1].view(np.uint64))
                assert prods[-2:] == [_npcall.dot, linalg.mm]  # the one path by np.dot, the batch by matmul


def test_one_state_screen_flags_every_non_finite():
    """The n = 1 screen (a minimum, then one dot of cov and mean) passes a finite PSD batch and no
    batch with a NaN or inf in the mean or the covariance (0 · inf included); where the dot
    overflows the exact test decides."""
    mean, cov = np.ones((50, 1)), np.full((50, 1, 1), 0.5)
    assert _all_ok(mean, cov)
    for field, value in (("mean", np.nan), ("mean", np.inf), ("mean", -np.inf), ("cov", np.nan), ("cov", np.inf),
                         ("cov", -1.0)):
        m, c = mean.copy(), cov.copy()
        (m if field == "mean" else c)[7] = value
        if field == "mean":
            c[7] = 0.0  # 0 · inf and 0 · NaN: NaN
        with np.errstate(invalid="ignore"):
            assert not _all_ok(m, c) and bad_paths(m, c)[7]
    with np.errstate(over="ignore"):
        assert not _all_ok(np.full((50, 1), 1e300), np.full((50, 1, 1), 1e300))  # the dot overflows:
    assert not bad_paths(np.full((50, 1), 1e300), np.full((50, 1, 1), 1e300)).any()  # the exact test passes


class _CountingEKF(EKF):
    calls = 0

    def predict(self, state, k):
        type(self).calls += 1
        return super().predict(state, k)


@pytest.mark.parametrize("make", [EKF, UKF, lambda md: SecondOrderFilter(md, form="truncated"),
                                  lambda md: EKF(md).fading_memory(1.2), lambda md: EKF(md, start="predict")])
def test_steps_chosen_per_run_equal_the_layered_steps(make, monkeypatch):
    """``GaussianFilter._run_steps`` (the layers of options that are off skipped once per run) gives
    the numbers of ``_predict_unchecked``/``_update_unchecked`` — missing data, the likelihood and
    marked divergences included — and a subclass redefining ``predict`` is run through it."""
    md = DiscreteModel([x1], [0.9 * x1 + 0.1 * sp.sin(x1)], [x1 + 0.2 * x1 ** 2], Q=0.1, R=0.2)
    ys = np.random.default_rng(5).standard_normal((6, 40, 1))
    ys[1, 5:9] = np.nan
    ys[:, 12] = np.nan
    ys[3, 20:] *= 1e155  # this path fails (marked)
    flt = make(md)
    kw = {"loglik": True, "backend": "numpy", "on_divergence": "mark"}
    est = flt.run(ys, [0.0], [[1.0]], **kw)
    monkeypatch.setattr(GaussianFilter, "_run_steps", Filter._run_steps)
    ref = flt.run(ys, [0.0], [[1.0]], **kw)
    assert est.diverged.any()
    for a, b in zip((est.means, est.covs, est.diverged_step, *est.extras.values()),
                    (ref.means, ref.covs, ref.diverged_step, *ref.extras.values())):
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    monkeypatch.undo()
    _CountingEKF.calls = 0
    _CountingEKF(md).run(ys[:, :10], [0.0], [[1.0]], backend="numpy", on_divergence="mark")
    assert _CountingEKF.calls == 9


def test_total_is_finite_exactly_when_every_entry_is():
    """The finiteness sum (Python floats up to 32 entries, one reduction above): non-finite with
    any NaN or ±inf in the array, finite otherwise (entries far from overflow)."""
    rng = np.random.default_rng(3)
    for size in (1, 2, 16, 32, 33, 200):
        a = rng.normal(size=size)
        assert np.isfinite(_total(a)) and np.isclose(_total(a), a.sum())
        for value in (np.nan, np.inf, -np.inf):
            b = a.copy()
            b[size // 2] = value
            assert not np.isfinite(_total(b.reshape(1, -1)))


def test_quiet_ignores_warnings_and_restores_the_state():
    """``quiet`` runs its function with overflow/invalid/divide ignored, under a warning state and
    under one that is quiet already, and leaves the caller's state as it was."""
    big = np.array([1e308])
    with np.errstate(all="raise"):
        assert np.isinf(quiet(np.multiply, big, 10.0))
        assert np.geterr()["over"] == "raise"
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="raise"):
        assert np.isinf(quiet(np.multiply, big, 10.0))
        assert np.geterr()["under"] == "raise"
