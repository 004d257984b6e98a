"""The Gaussian skeleton as functions (issue 27, item 2): ``condition`` is exact on partly missing
measurements for every kind of rule, the iterated update's likelihood moments are the Taylor-1
rule's, the skeleton reads no rule by name, and the filter classes stay configurations (at most
4 classes deep below ``Filter``, mix-ins counted)."""

import inspect

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import REGISTRY, GaussianState
from nlfilter.filters import skeleton
from nlfilter.filters.base import Filter
from nlfilter.filters.gaussian import ContinuousDiscreteGaussianFilter, ContinuousGaussianFilter, GaussianFilter
from nlfilter.filters.rules import Cubature, GaussHermite, Taylor1, Taylor2, Unscented

x1, x2 = sp.symbols("x1 x2")
R2 = np.array([[0.2, 0.08], [0.08, 0.1]])  # correlated: the observed block is not R with rows zeroed
BELIEF = GaussianState(np.array([[0.5, -0.2], [1.0, 0.3]]), np.array([[[0.3, 0.05], [0.05, 0.2]], [[0.4, 0.0], [0.0, 0.1]]]))
H = [x1 + 0.5 * x2**2, sp.sin(x1) * x2]


def _model(h, R):
    return DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, x2 - 0.05 * x1**2], h, Q=0.1 * np.eye(2), R=R)


@pytest.mark.parametrize("rule", [Taylor1(), Taylor2("gaussian"), Taylor2("truncated-jazwinski"), Unscented(0.5),
                                  Cubature(), GaussHermite(3)], ids=lambda r: getattr(r, "form", r.name))
def test_a_partly_missing_measurement_is_the_update_on_its_observed_component(rule):
    """``condition`` on ``y = (y₁, NaN)`` of a two-component measurement with correlated R equals
    ``condition`` on the model that measures only ``h₁`` with ``R₁₁`` (the Gaussian marginal). The
    two computations do the same sums in other shapes (a zero column, a unit diagonal): they agree
    to rounding, 1e-12 relative on O(1) numbers."""
    y = np.array([[0.7, np.nan], [1.2, np.nan]])
    full, bad_f, (yhat_f, S_f) = skeleton.condition(rule, _model(H, R2), BELIEF, y, 0)
    part, bad_p, (yhat_p, S_p) = skeleton.condition(rule, _model(H[:1], R2[:1, :1]), BELIEF, y[:, :1], 0)
    assert bad_f is None or not bad_f.any()
    assert bad_p is None or not bad_p.any()
    np.testing.assert_allclose(full.mean, part.mean, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(full.cov, part.cov, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(yhat_f[:, :1], yhat_p, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(S_f[:, :1, :1], S_p, rtol=1e-12, atol=1e-14)


def test_the_iterated_update_reports_the_taylor1_moments_exactly():
    """The likelihood's ``(ŷ, S)`` of ``iterated_update(..., info=True)`` is the first (EKF)
    linearization: the same operations as ``condition`` with the Taylor-1 rule, so equal bit for
    bit; one iteration is the EKF update, also bit for bit."""
    md, y = _model(H, R2), np.array([[0.7, 0.1], [1.2, np.nan]])
    ekf, _, (yhat, S) = skeleton.condition(Taylor1(), md, BELIEF, y, 0)
    one, (yhat_i, S_i) = skeleton.iterated_update(md, BELIEF, y, 0, 1, 1e-10, info=True)
    np.testing.assert_array_equal(yhat_i, yhat)
    np.testing.assert_array_equal(S_i, S)
    np.testing.assert_array_equal(one.mean, ekf.mean)
    np.testing.assert_array_equal(one.cov, ekf.cov)


def test_the_skeleton_reads_no_rule_by_name():
    """The steps apply the rule's moments and table entries (``symmetrize``, ``screen``, ``second``)
    the same way for every rule: no ``getattr`` / ``isinstance`` on the rule in their source."""
    for fn in (skeleton.predict, skeleton.condition, skeleton.moment_rhs, skeleton.propagate, skeleton.ito_gain,
               skeleton.ito_rhs):
        src = inspect.getsource(fn)
        assert "getattr(rule" not in src and "isinstance(rule" not in src, fn.__name__
    for rule in (Taylor1(), Taylor2(), Unscented(), Cubature(), GaussHermite(2)):
        assert isinstance(rule.symmetrize, bool) and isinstance(rule.screen, bool), rule


def test_gaussian_classes_are_at_most_four_deep():
    """Every registered Gaussian filter (and the skeletons) has ``Filter`` at most 4 places down its
    MRO: the classes are configurations of the skeleton's functions, not towers of mix-ins."""
    roots = (GaussianFilter, ContinuousDiscreteGaussianFilter, ContinuousGaussianFilter)
    classes = set(roots) | {c for c in REGISTRY.values() if issubclass(c, (GaussianFilter, ContinuousGaussianFilter))}
    assert len(classes) > 15  # the family: EKF, UKF, CKF, GHKF, SLF, IEKF, second-order, their CD versions, ...
    deep = {c.__name__: c.__mro__.index(Filter) for c in classes if c.__mro__.index(Filter) > 4}
    assert not deep, deep
