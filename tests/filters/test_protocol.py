"""The protocol's own parts: the one integrator (stated order per scheme, measured), the run loop
over a belief that is not Gaussian, ``Estimates`` helpers."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest

from nlfilter.errors import DivergenceError
from nlfilter.filters.base import Estimates, ode_step

# the coin-flip belief of docs/implementing.rst, imported from the file the page shows (one source)
_spec = importlib.util.spec_from_file_location(
    "implementing_coin", pathlib.Path(__file__).resolve().parents[2] / "docs" / "implementing_coin.py")
_coin = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_coin)
Coin = _coin.Coin


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


def test_run_loop_over_a_non_gaussian_belief():
    ys = np.array([[1, 0, 1, np.nan, 1], [0, 0, np.nan, 1, 1]], float)[..., None]
    est = Coin().run(ys)
    a = 1 + np.nancumsum(ys[..., 0], axis=1)
    b = 1 + np.nancumsum(1 - ys[..., 0], axis=1)
    np.testing.assert_allclose(est.means[..., 0], a / (a + b), rtol=1e-15)
    np.testing.assert_array_equal(est.extras["count"], a + b - 2)
    assert est.covs.shape == (2, 5, 1, 1) and not est.diverged.any()
    bad = ys.copy()
    bad[1, 2, 0] = 5.0
    with pytest.raises(DivergenceError) as info:
        Coin().run(bad)
    assert info.value.step == 2 and info.value.paths == (1,)
    marked = Coin().run(bad, on_divergence="mark")
    assert marked.diverged.tolist() == [False, True] and marked.diverged_step[1] == 2
    assert np.isnan(marked.means[1, 2:]).all() and np.isnan(marked.extras["count"][1, 2:]).all()
    np.testing.assert_array_equal(marked.means[0], est.means[0])
    with pytest.raises(ValueError, match=r"^t0\b"):
        Coin().run(ys, t0=1.0)


def test_the_documented_example():
    """``example`` of docs/implementing.rst: Beta(1, 1) prior, so after k flips with h heads the mean
    is (1 + h) / (2 + k); a flip of 5 is impossible: that path is marked at step 0."""
    est, marked = _coin.example()
    heads = np.nancumsum([[1, 0, 1, np.nan, 1], [0, 0, np.nan, 1, 1]], axis=1)
    flips = np.array([[1, 2, 3, 3, 4], [1, 2, 2, 3, 4]])
    np.testing.assert_allclose(est.means[..., 0], (1 + heads) / (2 + flips), rtol=1e-15)
    np.testing.assert_array_equal(est.extras["count"], flips)
    assert marked.diverged.tolist() == [True] and marked.diverged_step.tolist() == [0]


def test_estimates_take_and_concatenate_keep_extras():
    est = Coin().run(np.ones((3, 4, 1)))
    parts = [est.take(slice(0, 1)), est.take(slice(1, 3))]
    both = Estimates.concatenate(parts)
    for f in ("means", "covs", "diverged", "diverged_step"):
        np.testing.assert_array_equal(getattr(both, f), getattr(est, f))
    np.testing.assert_array_equal(both.extras["count"], est.extras["count"])
