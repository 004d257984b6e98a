"""The NumPy loop's fast paths give NumPy's own numbers (issue 28: the per-step overhead cut without
changing a number): the Cholesky/solve gufuncs called without np.linalg's wrapper, the one-entry
finiteness tests, the n = 2 PSD test, the Cholesky screen, the node rules' axis gather kept per
table, and a model function's constant entries written once per batch shape. Every comparison is
exact (``np.array_equal``): the fast paths run the same floating-point operations, so any
difference is a bug, not rounding (one stated tolerance: an eigen root squared). Small arrays: about
a second for the file."""

import gc

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import linalg as L
from nlfilter.filters.rules import Cubature, GaussHermite, Unscented

RNG = np.random.default_rng(28)


def _spd(B, n):
    A = RNG.standard_normal((B, n, n))
    return A @ A.swapaxes(-1, -2) + 0.1 * np.eye(n)


def test_sqrt_psd_is_numpys_cholesky_and_its_fallback():
    P = _spd(5, 3)
    root, bad = L.sqrt_psd(P)
    assert np.array_equal(root, np.linalg.cholesky(P)) and not bad.any()
    Q = P.copy()
    Q[1] = -Q[1]  # not PSD: the identity, flagged
    Q[3] = np.diag([2.0, 1.0, 0.0])  # PSD, singular: the eigen root
    root, bad = L.sqrt_psd(Q)
    assert bad.tolist() == [False, True, False, False, False]
    for p in (0, 2, 4):  # a path whose factorization succeeds keeps its factor, as alone
        assert np.array_equal(root[p], np.linalg.cholesky(Q[p]))
    assert np.array_equal(root[1], np.eye(3))
    # the eigen root of diag(2, 1, 0): √2² is 2 within one rounding of √2 (4.4e-16)
    assert np.allclose(root[3] @ root[3].T, Q[3], rtol=0, atol=1e-15)


def test_gaussian_update_solve_as_numpy_and_singular_paths_poisoned():
    B, n, m = 4, 3, 2
    P, S = _spd(B, n), _spd(B, m)
    C = RNG.standard_normal((B, n, m))
    y, yhat, mean = RNG.standard_normal((B, m)), RNG.standard_normal((B, m)), RNG.standard_normal((B, n))
    new = L.gaussian_update(L.GaussianState(mean, P), y, yhat, S, C)
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(C, -1, -2)), -1, -2)  # the public path's numbers
    assert np.array_equal(new.mean, mean + np.einsum("...ij,...j->...i", K, y - yhat))
    S[2] = 0.0  # singular on one path: that path poisoned, the others unchanged
    with np.errstate(invalid="ignore", divide="ignore"):
        bad = L.gaussian_update(L.GaussianState(mean, P), y, yhat, S, C)
    assert np.isnan(bad.mean[2]).all() and np.array_equal(bad.mean[[0, 1, 3]], new.mean[[0, 1, 3]])


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_quick_psd_tests_never_pass_what_the_exact_test_flags(n):
    cases = []
    for scale in (1.0, 1e-12, 1e150):
        P = scale * _spd(6, n)
        cases.append(P)
        for bad in (-1.0, np.nan, np.inf):
            Q = P.copy()
            Q[2, 0, 0] = bad * abs(Q[2, 0, 0]) if np.isfinite(bad) else bad
            cases.append(Q)
    for cov in cases:
        for B in (6, 1):  # the batch, and one path (the one-entry tests for n = 1)
            c, mean = cov[:B], np.zeros(cov[:B].shape[:-1])
            with np.errstate(over="ignore", invalid="ignore"):
                exact = L._bad_paths_exact(mean, c)
                ok = L._all_ok(mean, c)
                assert not (ok and exact.any())  # the quick test never passes a flagged batch
                if n == 1:  # its rule: every variance >= 0 and every number finite
                    assert ok == bool(np.all(c >= 0) and np.isfinite(c).all())
                if n == 2:  # exact
                    assert ok == (not exact.any())
                if n > 2 and L._screen_ok(mean, c):
                    assert not exact.any()
                assert np.array_equal(L.bad_paths(mean, c), exact)


def test_axis_gather_per_read_only_table():
    z, _, _ = Unscented().unit_nodes(3)
    col, zc = L.axis_gather(z)
    assert L.axis_gather(z)[0] is col  # kept
    assert np.array_equal(zc[:, 0], z[np.arange(len(z)), col]) and np.array_equal(z, zc * np.eye(3)[col])
    assert L.axis_gather(GaussHermite(3).unit_nodes(2)[0]) is None  # off the axes: the product
    w = np.array(Cubature().unit_nodes(2)[0])  # a writeable copy: answered, not kept
    before = len(L._AXIS_GATHER)
    assert L.axis_gather(w) is not None and len(L._AXIS_GATHER) == before
    r = np.array(w)
    r.flags.writeable = False
    L.axis_gather(r)
    assert len(L._AXIS_GATHER) == before + 1
    del r
    gc.collect()
    assert len(L._AXIS_GATHER) == before  # dropped with its table


def test_model_function_constant_entries_written_once_per_batch():
    x = sp.symbols("x1:4")
    md = DiscreteModel(list(x), [0.9 * x[0] + 0.1 * sp.sin(x[1]), 0.8 * x[1], x[2] - 0.5 * x[0]], [x[0]],
                       Q=0.01 * np.eye(3), R=0.1)

    def direct(X):  # the Jacobian entry by entry, the same operations as the generated code
        J = np.zeros((*X.shape[:-1], 3, 3))
        J[..., 0, 0], J[..., 0, 1], J[..., 1, 1] = 0.9, 0.1 * np.cos(X[..., 1]), 0.8
        J[..., 2, 0], J[..., 2, 2] = -0.5, 1.0
        return J

    big = md.f_x.TEMPLATE_MAX // 9 + 1 if hasattr(md.f_x, "TEMPLATE_MAX") else 10_000
    for shape in ((4, 3), (1, 3), (4, 3), (2, 5, 3), (big, 3)):  # batch shapes change and come back
        X = RNG.standard_normal(shape)
        out = md.f_x(X, 0)
        assert np.array_equal(out, direct(X))
        out[..., 0, 0] = 7.0  # a caller's write does not reach the next call
        assert np.array_equal(md.f_x(X, 0), direct(X))
