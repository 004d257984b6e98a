"""The divergence screen (issue 13): the batched Cholesky screen flags exactly the paths that the
per-path eigenvalue test flags, on random batches of symmetric matrices of every kind."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hst

from nlfilter.filters.linalg import PSD_TOL, _all_ok, _bad_paths_exact, _screen_ok, bad_paths, symmetrize


def reference_bad_paths(mean, cov, tol=PSD_TOL):
    """The screen of main before issue 13, verbatim: every path's smallest eigenvalue."""
    n = cov.shape[-1]
    ok = np.all(np.isfinite(mean), axis=-1) & np.all(np.isfinite(cov), axis=(-1, -2))
    safe = np.where(ok[..., None, None], cov, np.eye(n))
    if n == 1:
        low = safe[..., 0, 0]
    elif n == 2:
        a, b, c = safe[..., 0, 0], 0.5 * (safe[..., 0, 1] + safe[..., 1, 0]), safe[..., 1, 1]
        low = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    else:
        low = np.linalg.eigvalsh(symmetrize(safe))[..., 0]
    scale = np.maximum(1.0, np.max(np.abs(safe), axis=(-1, -2)))
    return ~ok | (low < -tol * scale)


KINDS = ("pd", "psd-singular", "zero", "within", "near", "beyond", "negative", "nan", "inf", "asymmetric")


def _matrix(rng, n, kind, scale):
    """One symmetric ``(n, n)`` matrix of the given kind: eigenvalues placed relative to the
    tolerance ``PSD_TOL · scale`` of the screen."""
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    w = scale * rng.uniform(0.1, 1.0, n)
    thr = PSD_TOL * max(1.0, scale)
    if kind == "psd-singular":
        w[rng.integers(n)] = 0.0
        if n > 2:
            w[rng.integers(n)] = 0.0
    elif kind == "zero":
        w[:] = 0.0
    elif kind == "within":  # an eigenvalue slightly negative, inside the tolerance
        w[0] = -rng.uniform(0.0, 0.5) * thr
    elif kind == "near":  # around the threshold itself: the two tests' rounding must agree
        w[0] = -rng.uniform(0.5, 1.5) * thr
    elif kind == "beyond":
        w[0] = -rng.uniform(1.5, 100.0) * thr
    elif kind == "negative":
        w[0] = -scale * rng.uniform(0.01, 1.0)
    P = (U * w) @ U.T
    P = 0.5 * (P + P.T)
    if kind == "nan":
        i, j = rng.integers(n, size=2)
        P[i, j] = np.nan
    elif kind == "inf":
        i, j = rng.integers(n, size=2)
        P[i, j] = P[j, i] = rng.choice([np.inf, -np.inf])
    elif kind == "asymmetric" and n > 1:  # not symmetric: both tests read the symmetrized part
        P[0, 1] += scale * rng.uniform(-1.0, 1.0)
    return P


@settings(max_examples=300, deadline=None)
@given(n=hst.integers(1, 6), batch=hst.integers(1, 12), seed=hst.integers(0, 2**32 - 1),
       kinds=hst.lists(hst.sampled_from(KINDS), min_size=1, max_size=4),
       log_scale=hst.floats(-4.0, 7.0), nan_mean=hst.booleans())
def test_screen_flags_exactly_the_paths_the_eigen_test_flags(n, batch, seed, kinds, log_scale, nan_mean):
    rng = np.random.default_rng(seed)
    scale = 10.0**log_scale
    cov = np.stack([_matrix(rng, n, kinds[rng.integers(len(kinds))], scale * rng.uniform(0.5, 2.0))
                    for _ in range(batch)])
    mean = rng.standard_normal((batch, n))
    if nan_mean:
        mean[rng.integers(batch), rng.integers(n)] = np.nan
    ref = reference_bad_paths(mean, cov)
    np.testing.assert_array_equal(bad_paths(mean, cov), ref)
    np.testing.assert_array_equal(_bad_paths_exact(mean, cov), ref)
    with np.errstate(over="ignore", invalid="ignore"):  # as inside run
        # the screens may defer to bad_paths (answer False too often), never clear a failing batch
        if _all_ok(mean, cov):
            assert not ref.any()
        if n > 2 and _screen_ok(mean, cov):
            assert not ref.any()
        if n == 2:
            assert _all_ok(mean, cov) == (not ref.any())
    # a batch of one path and an unbatched matrix give the same answers
    for k in range(batch):
        assert bool(bad_paths(mean[k], cov[k])) == bool(ref[k])


@pytest.mark.parametrize("n", [3, 4, 6, 16])
def test_screen_accepts_singular_and_catches_negative(n):
    rng = np.random.default_rng(n)
    P = np.zeros((5, n, n))
    P[1, 0, 0] = 1.0  # rank one
    P[2] = np.eye(n) * 1e6  # large scale
    P[2, -1, -1] = 0.0
    P[3] = np.eye(n)
    P[3, 1, 1] = -2e-9  # beyond tol · scale = 1e-9
    P[4] = np.eye(n)
    P[4, 1, 1] = -0.4e-9  # within
    m = rng.standard_normal((5, n))
    with np.errstate(over="ignore", invalid="ignore"):
        _check_fixed(m, P)


def _check_fixed(m, P):
    assert not _screen_ok(m, P)
    np.testing.assert_array_equal(bad_paths(m, P), [False, False, False, True, False])
    assert _screen_ok(m[[0, 1, 2, 4]], P[[0, 1, 2, 4]]) in (True, False)  # may defer, never wrong
    assert not bad_paths(m[[0, 1, 2, 4]], P[[0, 1, 2, 4]]).any()
    assert _screen_ok(m[:3], P[:3])  # PSD-singular batches are cleared in one call
