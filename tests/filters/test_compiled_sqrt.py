"""The square-root filters on the compiled loop (issue 30 item 1: ``sr-ekf``, ``sr-kf`` as the
``"sqrt-taylor1"`` kind; ``sr-ukf``, ``sr-ckf``, ``sr-ghkf``, ``sr-slf`` as ``"sqrt-nodes"``): the
same estimates, likelihood and divergence as the NumPy square-root filters.

Tolerance: 1e-12 relative (``|a − b| ≤ 1e-12 · max(1, |a|)``), the compiled loop's (see
``test_compiled.py``): the loops do the same steps, NumPy's QR (LAPACK Householder) against a
hand-written Householder ``tria`` and explicit sums, so they differ by rounding (measured ≤ 3e-15
relative over 30 steps here); a change of formula moves the outputs by far more. The model is the
two-state one of ``test_compiled.py`` (a parameter, a time input, a state-dependent G). Compiles
cost 8-13 s of CPU each: every test shares the model of the module-scoped fixture, so the module
compiles two loops (one per kind; the square-root kinds always take the general loop, whatever
``SPECIALIZE_UP_TO``), and the node rules share theirs (the table is data).
"""

from __future__ import annotations

import numpy as np
import pytest

from nlfilter.errors import DivergenceError
from nlfilter.filters import compiled
from nlfilter.filters.compiled import build
from nlfilter.filters.compiled.sqrt_kernels import downdate, tria
from nlfilter.filters.square_root_filters import (SquareRootCKF, SquareRootEKF, SquareRootGHKF, SquareRootIEKF,
                                                  SquareRootKF, SquareRootSLF, SquareRootUKF)
from nlfilter.filters.triangular import downdate as np_downdate
from nlfilter.filters.triangular import tria as np_tria
from nlfilter.models import DiscreteModel
from nlfilter.simulate import simulate
from tests.filters.test_compiled import close, nonlinear, polynomial, same

pytestmark = [pytest.mark.skipif(not compiled.available(), reason="numba does not import"),
              pytest.mark.filterwarnings("error:Cannot cache compiled function")]

M0 = np.array([[0.2, -0.1]] * 5) + 0.01 * np.arange(5)[:, None]  # a prior per path
P0 = 0.3 * np.eye(2)


@pytest.fixture(scope="module")
def data():
    """One model for the module (its two loops compiled once), 30 steps on 5 paths with a
    measurement missing in part, on one path, on every path."""
    md = nonlinear()
    ys = simulate(md, 30, paths=5, rng=3, m0=[0.2, -0.1], P0=P0).ys.copy()
    ys[1, 4, 0] = np.nan  # partly missing
    ys[2, 9] = np.nan  # missing on one path
    ys[:, 15] = np.nan  # missing on every path
    ys[3, 20:23, 1] = np.nan
    return md, ys


MAKERS = {"sr-ekf": SquareRootEKF, "sr-ukf": SquareRootUKF, "sr-ckf": SquareRootCKF, "sr-ghkf": SquareRootGHKF,
          "sr-ukf-negative-weight": lambda md, **kw: SquareRootUKF(md, alpha=0.5, kappa=1.0, **kw)}  # wc_0 < 0


@pytest.mark.parametrize("name", list(MAKERS))
@pytest.mark.parametrize("start", ["update", "predict"])
def test_same_estimates_and_likelihood_as_numpy(data, name, start):
    md, ys = data
    flt = MAKERS[name](md, start=start)
    ref = flt.run(ys, M0, P0, loglik=True, backend="numpy")
    new = flt.run(ys, M0, P0, loglik=True, backend="numba")
    same(ref, new)
    assert np.isfinite(new.loglik).all() and not new.diverged.any()
    assert np.isnan(new.extras["innovation"][1, 4, 0]) and np.isfinite(new.extras["innovation"][1, 4, 1])
    assert (new.extras["loglik"][:, 15] == 0.0).all()  # a step measured on no path adds nothing


def test_the_kinds_and_their_loops(data):
    """The Taylor-1 filters run ``"sqrt-taylor1"``, the node rules ``"sqrt-nodes"``, on the general
    loop (no dimensions compiled in); ``sr-kf`` and ``sr-slf`` are served by the same kernels (their
    models: a linear and a polynomial one, not compiled here)."""
    md, _ = data
    assert build.loop_of(SquareRootEKF(md))[0] == "sqrt-taylor1"
    for flt in (SquareRootUKF(md), SquareRootCKF(md), SquareRootGHKF(md, order=4)):
        kind, _, scalar, dims, _ = build.loop_of(flt)
        assert (kind, scalar, dims) == ("sqrt-nodes", False, None)
    poly = polynomial()
    assert compiled.unsupported(SquareRootSLF(poly)) is None and build.loop_of(SquareRootSLF(poly))[0] == "sqrt-nodes"
    linear = DiscreteModel(poly.states, [0.9 * poly.states[0], 0.5 * poly.states[1]], list(poly.states),
                          Q=0.1 * np.eye(2), R=0.2 * np.eye(2))
    assert compiled.unsupported(SquareRootKF(linear)) is None
    assert build.loop_of(SquareRootKF(linear))[0] == "sqrt-taylor1"


def test_singular_prior_and_batch_shape(data):
    """A known state component (P0 singular: NumPy's prior factor is the eigen root, not triangular;
    the first step triangularizes it) and a batch of shape (5, 1)."""
    md, ys = data
    for flt in (SquareRootEKF(md), SquareRootCKF(md, start="predict")):
        same(flt.run(ys, [0.0, 0.0], np.diag([1.0, 0.0]), backend="numpy"),
             flt.run(ys, [0.0, 0.0], np.diag([1.0, 0.0]), backend="numba"))
    flt = SquareRootUKF(md)
    a = flt.run(ys[:, None], M0[:, None], P0, backend="numba")
    assert a.means.shape == (5, 1, 30, 2)
    close(a.covs[:, 0], flt.run(ys, M0, P0, backend="numpy").covs)


@pytest.mark.parametrize("kind", ["sqrt-taylor1", "sqrt-nodes"])
def test_divergence_marked_and_raised_as_numpy(data, kind):
    """Paths failing at different steps, marked and raised alike: overflows (from a mean of 1e200
    ``h = x1 + 0.1 x2²`` is infinite at once; unmeasured at step 0, ``f`` overflows at the
    prediction of step 1), and for the node rule (κ = −1.9, β = 0: the centre weight wc_0 = −19)
    failed Cholesky downdates from a broad prior (P0 = 6 I; the standard UKF's covariance would be
    indefinite there), reported as the NumPy filter reports them. The failures must not hang on
    rounding (a mean of 1e160 survives its first update with moments of cancelled digits, which the
    two loops' orders of arithmetic round differently), so they are overflows or failures at once."""
    md, ys = data
    ys = ys.copy()
    ys[3, 0] = np.nan
    m0 = np.array([[0.2, -0.1], [1e200, 1e200], [0.5, 0.0], [1e200, 1e200], [0.2, -0.1]])
    P = np.array([0.3, 0.3, 0.3, 0.3, 6.0])[:, None, None] * np.eye(2)
    flt = SquareRootEKF(md) if kind == "sqrt-taylor1" else SquareRootUKF(md, beta=0.0, kappa=-1.9)
    ref = flt.run(ys, m0, P, on_divergence="mark", loglik=True, backend="numpy")
    new = flt.run(ys, m0, P, on_divergence="mark", loglik=True, backend="numba")
    assert len(set(ref.diverged_step[ref.diverged].tolist())) > 1 and not ref.diverged[0]
    same(ref, new)
    assert np.isnan(new.means[1]).all() and np.isfinite(new.means[0]).all()
    assert (new.diverged_step[1], new.diverged_step[3]) == (0, 1)
    assert new.diverged[4] == (kind == "sqrt-nodes") and not new.diverged[2]  # the downdate's path
    with pytest.raises(DivergenceError) as e1:
        flt.run(ys, m0, P, backend="numpy")
    with pytest.raises(DivergenceError) as e2:
        flt.run(ys, m0, P, backend="numba")
    assert str(e1.value) == str(e2.value) and e1.value.step == e2.value.step


def test_auto_and_what_it_does_not_take(data):
    """``auto`` takes the loaded loop by the compiled loop's rule (:mod:`~nlfilter.filters.compiled.choice`);
    what the loop does not take is refused by ``"numba"`` naming why, and ``auto`` runs it on NumPy."""
    md, ys = data
    SquareRootCKF(md).run(ys[:1, :2], M0[:1], P0, backend="numba")  # the node loop: loaded (compiled above)
    assert SquareRootCKF(md).backend_for(5, 30) == ("numba", "the compiled loop is loaded in this process")
    faded = SquareRootEKF(md).fading_memory(1.05)
    with pytest.raises(TypeError, match=r"backend: 'numba' cannot run SquareRootEKF.*fading memory"):
        faded.run(ys, M0, P0, backend="numba")
    assert faded.backend_for(5, 30)[0] == "numpy"
    close(faded.run(ys, M0, P0).means, faded.run(ys, M0, P0, backend="numpy").means)
    with pytest.raises(TypeError, match=r"backend: 'numba' cannot run SquareRootIEKF.*iterated"):
        SquareRootIEKF(md).run(ys, M0, P0, backend="numba")


def test_bad_input_is_refused_alike(data):
    """Bad input is named before either loop runs: the same ValueError."""
    md, ys = data
    flt = SquareRootUKF(md)
    for kw in ({"m0": [0.0, 0.0, 0.0], "P0": P0}, {"m0": M0, "P0": [[1.0, 2.0], [2.0, 1.0]]}):
        with pytest.raises(ValueError) as e1:
            flt.run(ys, kw["m0"], kw["P0"], backend="numpy")
        with pytest.raises(ValueError) as e2:
            flt.run(ys, kw["m0"], kw["P0"], backend="numba")
        assert str(e1.value) == str(e2.value) and ("m0" in str(e1.value) or "P0" in str(e1.value))


def test_tria_and_downdate_kernels_as_numpy():
    """The kernels alone against :mod:`~nlfilter.filters.triangular` (random matrices, wide and
    narrow; downdates that succeed and that fail): the same factor to rounding (1e-12 of its scale),
    the same failures."""
    rng = np.random.default_rng(4)
    for p, q in ((3, 5), (4, 2), (2, 2)):
        A = rng.standard_normal((p, q))
        W = np.zeros((p, max(p, q) + 1))
        W[:, :q] = A
        tria(W, p, q, np.empty(max(p, q) + 1))
        np.testing.assert_allclose(W[:, :p], np_tria(A), rtol=0, atol=1e-12 * np.abs(A).max())
    for scale, fails in ((0.5, False), (3.0, True)):
        L = np.linalg.cholesky(np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]]))
        x = scale * np.array([1.0, 0.5, -0.7])
        ref, failed = np_downdate(L, [x])
        ok = downdate(L, x.copy(), 3)
        assert ok == (not failed) and bool(failed) == fails
        if ok:
            np.testing.assert_allclose(L, ref, rtol=0, atol=1e-13)


def test_smoothing_after_the_compiled_forward_pass(data):
    """``smooth(..., backend="numba")``: the compiled forward pass keeps no beliefs; the square-root
    RTS pass runs from the Cholesky factors of its reported ``S Sᵀ`` (the propagated factors, to
    rounding), so the smoothed moments and lag-one covariances equal the NumPy smoother's."""
    md, ys = data
    for flt in (SquareRootEKF(md), SquareRootUKF(md, alpha=0.5, kappa=1.0)):
        same(flt.smooth(ys, M0, P0, backend="numpy"), flt.smooth(ys, M0, P0, backend="numba"))
