"""Impossible learnt moments are never silent (issue 11, item 3): the moment-space test of the
truncated Hausdorff problem, and what every adaptive seed-000 filter does and reports when a
refresh learns moments that no law on the bound has (``invalid_moments``)."""

import re
import warnings

import numpy as np
import pytest
import scipy.stats as st

from nlfilter.bounded import BoundedNoiseModel, ZeroOrderModel
from nlfilter.filters.moment_bayes import (INVALID_MOMENTS, FirstOrderMomentFilter, MomentFilterWarning,
                                           ScaledNoiseZeroOrderFilter, SecondOrderMomentFilter, ZeroOrderMomentFilter,
                                           refresh_failure_rate)
from nlfilter.moments.densities import is_moment_sequence, power_density_moments, uniform_moments

# ------------------------------------------------------------------ the moment-space test


def _discrete(points, weights, N):
    """``m_1 .. m_N`` of the law ``sum_j weights_j delta(points_j)``."""
    i = np.arange(1, N + 1)
    return np.sum(np.asarray(weights)[:, None] * np.asarray(points, dtype=float)[:, None] ** i, axis=0)


@pytest.mark.parametrize("N", range(1, 17))
@pytest.mark.parametrize("a,b", [(-1.0, 1.0), (-2.0, 3.0), (0.0, 1.0), (-5.0, 5.0)])
def test_laws_on_the_interval_pass(N, a, b):
    # uniform; two points at the ends (localizing matrix exactly 0: the boundary of the moment
    # space); a point mass at an end and inside; three interior points; x^10 on (-1, 1)
    span = b - a
    laws = [uniform_moments(N, a, b), _discrete([a, b], [0.3, 0.7], N), _discrete([b], [1.0], N),
            _discrete([a + 0.37 * span], [1.0], N),
            _discrete([a + 0.05 * span, a + 0.5 * span, a + 0.98 * span], [0.2, 0.5, 0.3], N)]
    got = is_moment_sequence(np.array(laws), a, b)
    assert got.shape == (len(laws),) and got.all()
    if (a, b) == (-1.0, 1.0):
        assert is_moment_sequence(power_density_moments(N, 10))


@pytest.mark.parametrize("N", range(2, 17))
@pytest.mark.parametrize("a,b", [(-1.0, 1.0), (-2.0, 3.0), (0.0, 1.0)])
def test_sequences_beyond_the_moment_space_fail(N, a, b):
    # the two-point law at the ends is on the boundary: raising its top moment by 1e-6 (relative)
    # leaves the moment space; so does any law's moments with a point outside [a, b]
    m = _discrete([a, b], [0.3, 0.7], N)
    up = m.copy()
    up[-1] += 1e-6 * max(1.0, abs(m[-1]))
    out = _discrete([a, b + 0.05 * (b - a)], [0.5, 0.5], N)
    assert not is_moment_sequence(np.array([up, out]), a, b).any()


def test_the_n2_conditions_in_closed_form():
    # N = 2: a law on [a, b] with mean m1 and E x^2 = m2 exists iff a <= m1 <= b and
    # m1^2 <= m2 <= (a + b) m1 - a b (variance between 0 and that of the two-point law at the ends)
    a, b = -2.0, 3.0
    m1, m2 = np.meshgrid(np.linspace(-2.5, 3.5, 61), np.linspace(-0.5, 9.5, 101), indexing="ij")
    lower, upper = m1 ** 2, (a + b) * m1 - a * b
    inside = (m1 >= a) & (m1 <= b) & (m2 >= lower) & (m2 <= upper)
    margin = np.minimum.reduce([np.abs(m2 - lower), np.abs(m2 - upper), np.abs(m1 - a), np.abs(m1 - b)])
    clear = margin > 1e-9
    got = is_moment_sequence(np.stack([m1, m2], axis=-1), a, b)
    assert got.shape == m1.shape
    assert clear.sum() > 5000 and inside[clear].any() and (~inside[clear]).any()
    np.testing.assert_array_equal(got[clear], inside[clear])


def test_odd_and_even_variants_on_an_asymmetric_interval():
    # on [0, 1]: E x = 0.5, E x^2 = 0.5, E x^3 = 0.5 is the Bernoulli(1/2) law (feasible); E x^3 = 0.55
    # would need x^3 > x^2 somewhere (infeasible: the N = 3 matrices of x - a and b - x); E x^2 = 0.2 < 0.25
    # is a negative variance (the N = 2 Hankel matrix)
    assert is_moment_sequence([0.5, 0.5, 0.5], 0.0, 1.0)
    assert not is_moment_sequence([0.5, 0.5, 0.55], 0.0, 1.0)
    assert not is_moment_sequence([0.5, 0.2], 0.0, 1.0)
    # a negative 6th raw moment (the example) is never possible
    m = uniform_moments(6, -2.0, 2.0)
    m[5] = -0.1
    assert not is_moment_sequence(m, -2.0, 2.0)


def test_batched_over_paths_and_bad_arguments():
    m = np.stack([uniform_moments(4), [0.0, 1.2, 0.0, 1.3]])
    got = is_moment_sequence(np.broadcast_to(m, (3, 2, 4)))
    assert got.shape == (3, 2) and got[:, 0].all() and not got[:, 1].any()
    with pytest.raises(ValueError, match="a, b"):
        is_moment_sequence(m, 1.0, -1.0)
    with pytest.raises(ValueError, match="tol"):
        is_moment_sequence(m, tol=-1.0)


# ------------------------------------------------------------------ the adaptive filters

BN1 = BoundedNoiseModel.first_order(0.5, 2.0)
BN2 = BoundedNoiseModel(np.diag([0.6, -0.5]), [1.0, 1.0], [1.0, 1.0], 1.5)
W = 10  # refresh window: with n0 = 0 and 10 samples per refresh, 6 moments are often impossible


def _data(kind, T=200, B=6, seed=3):
    rng = np.random.default_rng(seed)
    if kind == "zero":  # x ~ 11/2 x^10 on (-1, 1): mass near the ends
        return ZeroOrderModel(10).simulate(T, B, rng)[1]
    wb = 2.0 if kind == 1 else 1.5
    law = st.beta(0.3, 0.3, loc=-wb, scale=2 * wb)  # U-shaped input on [-w_b, w_b]
    model = (BoundedNoiseModel.first_order(0.5, wb, w_law=law) if kind == 1
             else BoundedNoiseModel(BN2.A, BN2.b, BN2.c, wb, w_law=law))
    return model.simulate(T, B, rng, burn=100)[1]


CASES = {
    "zero-order": (lambda mode: ZeroOrderMomentFilter(6, adaptive=True, n0=0.0, window=W, invalid_moments=mode),
                   "zero", "moments", (-1.0, 1.0)),
    "scaled-noise": (lambda mode: ScaledNoiseZeroOrderFilter(6, 0.0, adaptive=True, n0=0.0, window=W,
                                                             invalid_moments=mode), "zero", "moments", (-1.0, 1.0)),
    "first-order": (lambda mode: FirstOrderMomentFilter(BN1, 6, adaptive=True, n0=0.0, window=W, invalid_moments=mode),
                    1, "w_moments", (-2.0, 2.0)),
    "second-order": (lambda mode: SecondOrderMomentFilter(BN2, 6, adaptive=True, n0=0.0, window=W,
                                                          invalid_moments=mode), 2, "w_moments", (-1.5, 1.5)),
}


def _run(name, mode, ys):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = CASES[name][0](mode).run(ys)
    return est, [w for w in caught if issubclass(w.category, MomentFilterWarning)]


@pytest.mark.parametrize("name", list(CASES))
def test_every_adaptive_filter_reports_and_warns_about_impossible_refreshes(name):
    make, kind, key, (lo, hi) = CASES[name]
    ys = _data(kind)
    B, T = ys.shape[:2]
    runs = {mode: _run(name, mode, ys) for mode in INVALID_MOMENTS}
    est, caught = runs["ignore"]
    # one refresh per window on every path, some of them impossible, and the flags say which
    np.testing.assert_array_equal(est.extras["refreshed"].sum(axis=-1), np.full(B, T // W))
    failed = est.extras["refresh_failed"]
    assert failed.any() and not failed[~est.extras["refreshed"]].any()
    ok = is_moment_sequence(est.extras[key], lo, hi)
    np.testing.assert_array_equal(failed, est.extras["refreshed"] & ~ok)  # "ignore" uses them as learnt
    rate = refresh_failure_rate(est)
    np.testing.assert_allclose(rate, failed.sum(-1) / (T // W), rtol=0, atol=0)
    assert caught == []
    # the learner does not depend on the choice: the same refreshes fail in every mode
    for mode in ("warn", "keep"):
        e, c = runs[mode]
        np.testing.assert_array_equal(e.extras["refresh_failed"], failed)
        assert len(c) == 1, [str(w.message) for w in c]
        msg = str(c[0].message)
        n_bad, n_all = int(failed.sum()), B * (T // W)
        assert msg.startswith(CASES[name][0](mode).name + ":")
        assert f"{n_bad} of {n_all} refreshes ({100 * n_bad / n_all:.1f} %)" in msg
        assert "N = 6" in msg and "window (now 10)" in msg and "n0 (now 0)" in msg
        assert re.search(rf"\[{lo:g}, {hi:g}\]", msg)
    # "keep": a failed refresh changes nothing; the moments in use are always possible
    e = runs["keep"][0]
    k = np.nonzero(failed)
    prev = e.extras[key][k[0], k[1] - 1]
    np.testing.assert_array_equal(e.extras[key][k], prev)
    assert is_moment_sequence(e.extras[key], lo, hi).all()
    # "warn": the impossible moments are not used
    e = runs["warn"][0]
    if key == "w_moments":  # the uniform law on the bound in their place
        np.testing.assert_allclose(e.extras[key][k], np.broadcast_to(uniform_moments(6, lo, hi), prev.shape),
                                   rtol=0, atol=0)
        assert is_moment_sequence(e.extras[key], lo, hi).all()
    else:  # the zero-order filters: eq. 3.16 (the midpoint) while the moments are impossible
        inv = e.extras["invalid"]
        assert inv[k].all() and e.extras["fallback"][inv].all()
    assert np.isfinite(e.means).all()


@pytest.mark.parametrize("name", list(CASES))
def test_no_warning_when_every_refresh_is_possible(name):
    # N = 2 with n0 = 100 (000's weight) learns possible moments: no refresh fails, nothing warns
    kind = CASES[name][1]
    ys = _data(kind, T=100, B=3)
    kw = dict(adaptive=True, n0=100.0, window=W, invalid_moments="warn")
    f2 = {"zero-order": lambda: ZeroOrderMomentFilter(2, **kw),
          "scaled-noise": lambda: ScaledNoiseZeroOrderFilter(2, 0.0, **kw),
          "first-order": lambda: FirstOrderMomentFilter(BN1, 2, **kw),
          "second-order": lambda: SecondOrderMomentFilter(BN2, 2, **kw)}[name]()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = f2.run(ys)
    assert est.extras["refreshed"].sum() == 3 * (100 // W)
    assert not est.extras["refresh_failed"].any()
    np.testing.assert_array_equal(refresh_failure_rate(est), np.zeros(3))


def test_missing_measurements_are_no_refresh():
    ys = _data(1, T=60, B=2)
    ys[0, 5:15] = np.nan  # 10 samples missing on path 0: one refresh fewer
    est, _ = _run("first-order", "ignore", ys)
    np.testing.assert_array_equal(est.extras["refreshed"].sum(-1), [5, 6])
    assert not est.extras["refreshed"][0, 5:15].any()


def test_option_is_checked_everywhere():
    for name in CASES:
        with pytest.raises(ValueError, match="invalid_moments"):
            CASES[name][0]("bogus")


def test_rate_needs_an_adaptive_run():
    est = FirstOrderMomentFilter(BN1, 2, w_moments=uniform_moments(2, -2, 2)).run(_data(1, T=10, B=2))
    with pytest.raises(ValueError, match="adaptive"):
        refresh_failure_rate(est)
