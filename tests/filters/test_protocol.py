"""The protocol's own parts: the one integrator (stated order per scheme, measured), the run loop
over a belief that is not Gaussian, ``Estimates`` helpers."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from nlfilter.errors import DivergenceError
from nlfilter.filters.base import Estimates, Filter, ode_step


@pytest.mark.parametrize("scheme, order", [("euler", 1), ("rk4", 4)])
def test_ode_step_converges_at_its_stated_order(scheme, order):
    """dx/dt = −x + sin t on [0, 1] (and a tuple state): the global error falls as hᵒʳᵈᵉʳ.
    Halving h divides the error by 2ᵒʳᵈᵉʳ; the measured ratio must be within 15 % of it."""
    def rhs(x, t):
        return -x + np.sin(t)

    exact = 0.5 * (np.sin(1.0) - np.cos(1.0)) + 1.5 * np.exp(-1.0)  # x(0) = 1
    errs = [abs(ode_step(rhs, np.array(1.0), 0.0, 1.0, substeps=s, scheme=scheme) - exact) for s in (8, 16, 32)]
    for a, b in zip(errs, errs[1:]):
        assert a / b == pytest.approx(2.0**order, rel=0.15)
    tup = ode_step(lambda x, t: (rhs(x[0], t), -x[1]), (np.array(1.0), np.array(2.0)), 0.0, 1.0, substeps=16,
                   scheme=scheme)
    assert tup[0] == ode_step(rhs, np.array(1.0), 0.0, 1.0, substeps=16, scheme=scheme)


class _Counts(NamedTuple):
    """A belief that is not Gaussian: a Beta(a, b) posterior of a coin's bias per path."""

    a: np.ndarray
    b: np.ndarray


class _Coin(Filter):
    """Bernoulli observations y ∈ {0, 1} of a fixed bias with a Beta prior: the conjugate filter
    (the loop must handle any belief; ``predict`` is the identity: the bias does not move)."""

    name = "coin"

    class model:  # noqa: N801 - a stand-in model with the two dimensions the loop reads
        n = m = 1

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        B = int(np.prod(batch))
        return _Counts(np.ones(B), np.ones(B))

    def predict(self, belief, k):
        return belief

    def update(self, belief, y, k):
        obs = ~np.isnan(y[:, 0])
        y0 = np.where(obs, y[:, 0], 0.0)
        a = np.where(y0 > 1, np.nan, belief.a + y0 * obs)  # an impossible count: that path fails
        return _Counts(a, belief.b + (1 - y0) * obs)

    def summary(self, belief):
        s = belief.a + belief.b
        mean = belief.a / s
        return mean[:, None], (mean * (1 - mean) / (s + 1))[:, None, None]

    def extras(self, belief):
        return {"count": belief.a + belief.b - 2}


def test_run_loop_over_a_non_gaussian_belief():
    ys = np.array([[1, 0, 1, np.nan, 1], [0, 0, np.nan, 1, 1]], float)[..., None]
    est = _Coin().run(ys)
    a = 1 + np.nancumsum(ys[..., 0], axis=1)
    b = 1 + np.nancumsum(1 - ys[..., 0], axis=1)
    np.testing.assert_allclose(est.means[..., 0], a / (a + b), rtol=1e-15)
    np.testing.assert_array_equal(est.extras["count"], a + b - 2)
    assert est.covs.shape == (2, 5, 1, 1) and not est.diverged.any()
    bad = ys.copy()
    bad[1, 2, 0] = 5.0
    with pytest.raises(DivergenceError) as info:
        _Coin().run(bad)
    assert info.value.step == 2 and info.value.paths == (1,)
    marked = _Coin().run(bad, on_divergence="mark")
    assert marked.diverged.tolist() == [False, True] and marked.diverged_step[1] == 2
    assert np.isnan(marked.means[1, 2:]).all() and np.isnan(marked.extras["count"][1, 2:]).all()
    np.testing.assert_array_equal(marked.means[0], est.means[0])
    with pytest.raises(ValueError, match=r"^t0\b"):
        _Coin().run(ys, t0=1.0)


def test_estimates_take_and_concatenate_keep_extras():
    est = _Coin().run(np.ones((3, 4, 1)))
    parts = [est.take(slice(0, 1)), est.take(slice(1, 3))]
    both = Estimates.concatenate(parts)
    for f in ("means", "covs", "diverged", "diverged_step"):
        np.testing.assert_array_equal(getattr(both, f), getattr(est, f))
    np.testing.assert_array_equal(both.extras["count"], est.extras["count"])
