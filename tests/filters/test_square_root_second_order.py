"""The square-root second-order filters (issue 30, item 1; :mod:`nlfilter.filters.square_root_second_order`):
every form of seed 004's second-order filter in square-root form is the standard form on
well-conditioned problems (means, covariances, log-likelihood, smoother), with a state-dependent
G(x) and R(x), correlated noise and missing data; a path that loses definiteness is the standard
filter's; the noise columns are the second-order E[G V Gᵀ]; bad input is named."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import REGISTRY, SecondOrderFilter
from nlfilter.filters.contractions import noise_covariance
from nlfilter.filters.rules import FORM_TABLE, FORMS
from nlfilter.filters.square_root_second_order import SquareRootSecondOrderFilter, noise_columns
from nlfilter.filters.triangular import downdate, tria

from nlfilter.simulate import simulate

x1, x2, x3 = sp.symbols("x1 x2 x3")
# a nonlinear 3-state model with a state-dependent noise gain G(x) (its second-order noise columns)
# and measurement noise R(x) (at the predicted mean); a correlated-noise 2-state model
G3 = sp.Matrix([[1 + 0.2 * sp.sin(x1), 0], [0.1 * x2, 1], [0, 0.5]])
F3 = [0.9 * x1 + 0.1 * x2 * x3, 0.8 * x2 - 0.05 * x1**3, 0.95 * x3 + 0.1 * sp.cos(x1)]
R3 = sp.Matrix([[0.2 + 0.05 * x1**2, 0.08], [0.08, 0.1]])
D3 = DiscreteModel([x1, x2, x3], F3, [x1 + 0.1 * x2**2, x2 * x3], G=G3, Q=np.diag([0.1, 0.05]), R=R3)
D2X = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2 - 0.05 * x1**3], [x1 + 0.1 * x2**2, x2],
                    Q=np.diag([0.1, 0.05]), R=[[0.2, 0.08], [0.08, 0.1]], cross_noise=[[0.05, 0.02], [0.0, 0.03]])
M3, P3 = np.array([0.3, -0.2, 0.5]), np.array([[0.5, 0.1, 0.0], [0.1, 0.4, 0.05], [0.0, 0.05, 0.3]])


def _data(model, m0, P0, T):
    """Simulated measurements of 3 paths, partly missing at step 3, missing on a path at 5 and on all at 7."""
    ys = simulate(model, T, paths=3, rng=4, m0=m0, P0=P0).ys.copy()
    ys[0, 3, 1], ys[1, 5], ys[:, 7] = np.nan, np.nan, np.nan
    return ys


def _same(a, b, tol):
    for what in ("means", "covs"):
        np.testing.assert_allclose(getattr(a, what), getattr(b, what), rtol=tol, atol=tol, err_msg=what)
    for name in b.extras:
        np.testing.assert_allclose(a.extras[name], b.extras[name], rtol=tol, atol=tol, err_msg=name)

# the forms with a forcing term (004 eq. 33) move the covariance by the data: on D3's measurement
# (x2 x3: a unit Hessian) they lose definiteness within 20 steps, standard and square-root alike
# (test_a_path_that_loses_definiteness_is_the_standard_filters); a milder h keeps them PD
DM = DiscreteModel([x1, x2, x3], F3, [x1 + 0.1 * x2**2, x2 + 0.2 * x2 * x3], G=G3, Q=np.diag([0.1, 0.05]), R=R3)
FORCING = [f for f in FORMS if FORM_TABLE[f].forcing != "none"]


@pytest.mark.parametrize("start", ["update", "predict"])
@pytest.mark.parametrize("form", FORMS)
def test_every_form_is_its_standard_form(form, start):
    """Well-conditioned (P of order 0.1-1, R ≥ 0.1), 20 steps with partly missing and missing
    measurements, G(x) (its second-order noise columns) and R(x): the square-root and the standard
    steps differ by rounding only — measured ≤ 1.4e-15 on the means, 5e-16 on the covariances,
    1.4e-14 on the log-likelihood, 1.6e-15 on the smoothed moments — so 1e-10 leaves a wide margin
    and still catches a formula error: each form's second-order terms move the covariances from
    the EKF's (first-order) by 5e-4 to 0.1 (checked here, > 1e-3 on the means or covariances)."""
    md = DM if form in FORCING else D3
    ys = _data(md, M3, P3, 20)
    a = SquareRootSecondOrderFilter(md, form=form, start=start).run(ys, M3, P3, loglik=True)
    b = SecondOrderFilter(md, form=form, start=start).run(ys, M3, P3, loglik=True, backend="numpy")
    assert not a.diverged.any() and not b.diverged.any()
    _same(a, b, 1e-10)
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=0, atol=1e-10)
    _same(SquareRootSecondOrderFilter(md, form=form, start=start).smooth(ys, M3, P3),
          SecondOrderFilter(md, form=form, start=start).smooth(ys, M3, P3, backend="numpy"), 1e-10)
    if form != "first-order":
        ekf = SecondOrderFilter(md, form="first-order", start=start).run(ys, M3, P3, backend="numpy")
        assert max(np.abs(b.means - ekf.means).max(), np.abs(b.covs - ekf.covs).max()) > 1e-3


@pytest.mark.parametrize("form", ["truncated-jazwinski", "modified-gaussian"])
def test_correlated_noise_is_the_standard_decorrelation(form):
    """Correlated process and measurement noise: the decorrelated dynamics ``f + G K_w (y_k − h)``
    with its Hessian ``f_xx − G K_w h_xx`` in the second-order terms, as the standard filter; 1e-10
    (measured ≤ 7e-16 on the moments, 1.4e-14 on the log-likelihood)."""
    ys = _data(D2X, M3[:2], P3[:2, :2], 20)
    a = SquareRootSecondOrderFilter(D2X, form=form).run(ys, M3[:2], P3[:2, :2], loglik=True)
    b = SecondOrderFilter(D2X, form=form).run(ys, M3[:2], P3[:2, :2], loglik=True, backend="numpy")
    _same(a, b, 1e-10)
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=0, atol=1e-10)


def test_fading_memory_is_the_standard_filters():
    """Fading memory α = 1.1 (the prediction from the factor α S; the smoother's joint factor read
    as added process noise): filter and smoother equal the standard filter's with fading memory to
    1e-10 (measured ≤ 2.5e-15)."""
    ys = _data(D3, M3, P3, 15)
    a = SquareRootSecondOrderFilter(D3, form="modified-gaussian").fading_memory(1.1)
    b = SecondOrderFilter(D3, form="modified-gaussian").fading_memory(1.1)
    _same(a.run(ys, M3, P3), b.run(ys, M3, P3, backend="numpy"), 1e-10)
    _same(a.smooth(ys, M3, P3), b.smooth(ys, M3, P3, backend="numpy"), 1e-10)


@pytest.mark.parametrize("form", FORCING)
def test_a_path_that_loses_definiteness_is_the_standard_filters(form):
    """On D3 the forcing forms lose positive definiteness (the data-driven term of 004 eq. 33): the
    square-root form's downdate fails on exactly the paths and steps where the standard filter's
    covariance does, which are marked the same way; the other paths agree to 1e-10."""
    ys = _data(D3, M3, P3, 20)
    a = SquareRootSecondOrderFilter(D3, form=form).run(ys, M3, P3, on_divergence="mark")
    b = SecondOrderFilter(D3, form=form).run(ys, M3, P3, on_divergence="mark", backend="numpy")
    assert a.diverged.any()
    np.testing.assert_array_equal(a.diverged, b.diverged)
    np.testing.assert_array_equal(a.diverged_step, b.diverged_step)
    ok = ~a.diverged
    np.testing.assert_allclose(a.means[ok], b.means[ok], rtol=0, atol=1e-10)


@pytest.mark.parametrize("gaussian", [False, True])
def test_noise_columns_are_the_second_order_noise(gaussian):
    """``tria`` of the noise columns, downdated, is :func:`noise_covariance` (004 eqs. 13-14, 19;
    the Gaussian fourth moments too) for a state-dependent G at random beliefs, to rounding
    (measured ≤ 6e-17; 1e-12)."""
    rng = np.random.default_rng(3)
    m = rng.standard_normal((4, 3))
    A = rng.standard_normal((4, 3, 3))
    S = tria(A)
    Lq = np.linalg.cholesky(np.diag([0.1, 0.05]))
    cols, neg = noise_columns(D3, m, S, 0, Lq, gaussian=gaussian)
    assert (len(neg) == 0) == gaussian
    L, failed = downdate(tria(cols), neg)
    want = noise_covariance(S @ S.swapaxes(-1, -2), Lq @ Lq.T, D3.G(m, 0), D3.G_x(m, 0), D3.G_xx(m, 0),
                            gaussian=gaussian)
    np.testing.assert_allclose(L @ L.swapaxes(-1, -2), want, rtol=0, atol=1e-12)


def test_bad_input_is_named():
    """A bad form is a ValueError naming ``form``; a factor that is not lower-triangular, and a
    covariance passed for a factor, are refused as by every square-root filter; the registry line."""
    assert REGISTRY["sr-second-order"] is SquareRootSecondOrderFilter
    with pytest.raises(ValueError, match=r"^form"):
        SquareRootSecondOrderFilter(D3, form="bogus")
    flt = SquareRootSecondOrderFilter(D3, form="gaussian")
    with pytest.raises(ValueError, match=r"^factor: .*lower-triangular"):
        flt.belief(M3, np.ones((3, 3)))
    from nlfilter.filters import GaussianState
    with pytest.raises(TypeError, match=r"^belief: the square-root filters step a SqrtState"):
        flt.predict(GaussianState(M3, P3), 0)
