"""The continuous-discrete square-root filters (issue 30, item 1; :mod:`nlfilter.filters.square_root_continuous`):
the square-root moment ODE and the standard one are the same flow, so RK4 on either converges to
it and their difference falls ~16x per halving of the substep (means, covariances, log-likelihood,
smoother); a singular prior is integrated in covariance form; bad input is named."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel
from nlfilter.filters import (REGISTRY, ContinuousDiscreteCKF, ContinuousDiscreteEKF, ContinuousDiscreteUKF,
                              GaussianState)
from nlfilter.filters.square_root_continuous import (SquareRootContinuousDiscreteCKF, SquareRootContinuousDiscreteEKF,
                                                     SquareRootContinuousDiscreteUKF, sqrt_moment_rhs)
from nlfilter.filters.rules import Cubature
from nlfilter.filters.skeleton import moment_rhs
from nlfilter.simulate import simulate

x1, x2 = sp.symbols("x1 x2")
# a Duffing-type oscillator with a state-dependent noise gain, measured nonlinearly
SG = SDEModel([x1, x2], [x2, -x1 - 0.5 * x2 - 0.3 * x1**3], [x1 + 0.1 * x2**2, x2],
              G=[[0.5 + 0.1 * x1**2, 0], [0.1 * x2, 0.6]], Q=np.eye(2) * 0.3, R=[[0.2, 0.05], [0.05, 0.1]])
M0, P0 = np.array([0.5, -0.3]), np.array([[0.5, 0.1], [0.1, 0.4]])
DT = 0.5
PAIRS = {"ekf": (SquareRootContinuousDiscreteEKF, ContinuousDiscreteEKF, {}),
         "ukf-alpha0.5": (SquareRootContinuousDiscreteUKF, ContinuousDiscreteUKF, {"alpha": 0.5}),
         "ckf": (SquareRootContinuousDiscreteCKF, ContinuousDiscreteCKF, {})}


def _data():
    ys = simulate(SG, 8, paths=3, rng=1, m0=M0, P0=P0, dt=DT).ys.copy()
    ys[0, 3, 1], ys[1, 5] = np.nan, np.nan  # partly missing, missing on a path
    return ys


def _gap(a, b):
    return max(np.abs(a.means - b.means).max(), np.abs(a.covs - b.covs).max())


@pytest.mark.parametrize("name", list(PAIRS))
def test_the_difference_falls_at_fourth_order(name):
    """RK4 with h = dt/4, dt/8, dt/16 (dt = 0.5, 8 steps, G(x), missing data): the square-root and
    the standard filter differ by the difference of their O(h⁴) discretisation errors (the ODEs
    differ: RK4 on (m, S) is not RK4 on (m, P)), measured 2.6e-6 → 1.6e-7 → 9.6e-9 (EKF) up to
    6.4e-6 → 3.8e-7 → 2.3e-8 (CKF) on the moments, 1.2e-5 → 4.7e-8 up to 2.2e-5 → 8.7e-8 on the
    log-likelihood: ratios 15.6-16.7. So: each ratio within [14, 19] (16 for a fourth-order scheme;
    a formula error would leave a gap that does not shrink, a first-order one halves), the finest
    gap ≤ 1e-7 on the moments (≤ 1e-6 on the log-likelihood), and the smoothers (the standard
    backward pass on the filter's moments) agree to 1e-7 (measured ≤ 1.4e-8)."""
    sr, std, kw = PAIRS[name]
    ys = _data()
    gaps, ll = [], []
    for sub in (4, 8, 16):
        a = sr(SG, DT, substeps=sub, **kw).run(ys, M0, P0, loglik=True)
        b = std(SG, DT, substeps=sub, **kw).run(ys, M0, P0, loglik=True)
        gaps.append(_gap(a, b))
        ll.append(np.abs(a.loglik - b.loglik).max())
    for g in (gaps, ll):
        ratios = np.array(g[:-1]) / np.array(g[1:])
        assert np.all((14 < ratios) & (ratios < 19)), (g, ratios)
    assert gaps[-1] < 1e-7 and ll[-1] < 1e-6
    sa = sr(SG, DT, substeps=16, **kw).smooth(ys, M0, P0)
    sb = std(SG, DT, substeps=16, **kw).smooth(ys, M0, P0)
    assert _gap(sa, sb) < 1e-7


def test_fading_memory_is_the_standard_filters():
    """Fading memory α = 1.1 (the prediction from α S): within RK4's gap of the standard filter with
    fading memory at h = dt/16, filter and smoother (measured 1.0e-8, 1.1e-8; 1e-7 as above)."""
    ys = _data()
    a = SquareRootContinuousDiscreteEKF(SG, DT, substeps=16).fading_memory(1.1)
    b = ContinuousDiscreteEKF(SG, DT, substeps=16).fading_memory(1.1)
    assert _gap(a.run(ys, M0, P0), b.run(ys, M0, P0)) < 1e-7
    assert _gap(a.smooth(ys, M0, P0), b.smooth(ys, M0, P0)) < 1e-7


def test_the_square_root_rhs_is_the_moment_equation():
    """``dS Sᵀ + S dSᵀ`` is the standard ``dP/dt`` and ``dm/dt`` the same (the cubature rule, G(x)),
    to rounding (measured ≤ 4e-16; 1e-13), with ``dS`` lower-triangular."""
    rng = np.random.default_rng(2)
    m = rng.standard_normal((5, 2))
    S = np.linalg.cholesky(P0 + 0.1 * np.eye(2)) * rng.uniform(0.5, 2.0, (5, 1, 1))
    Lq = np.linalg.cholesky(SG.Q)
    dm, dS = sqrt_moment_rhs(Cubature(), SG, m, S, 0.0, Lq)
    dm0, dP = moment_rhs(Cubature(), SG, m, S @ S.swapaxes(-1, -2), 0.0)
    assert np.all(np.triu(dS, 1) == 0)
    np.testing.assert_allclose(dm, dm0, rtol=0, atol=1e-13)
    np.testing.assert_allclose(dS @ S.swapaxes(-1, -2) + S @ dS.swapaxes(-1, -2), dP, rtol=0, atol=1e-13)


def test_a_singular_prior_is_integrated_in_covariance_form():
    """P0 = 0 (a known state): the factor ODE is singular at S = 0, so that interval is the standard
    filter's covariance-form step, re-factored: the first prediction equals the standard one to
    rounding (1e-12), and the later ones run the factor ODE (the gap then RK4's, ≤ 1e-4 at h = dt/4;
    measured 1.9e-6)."""
    ys = _data()
    a = SquareRootContinuousDiscreteCKF(SG, DT, substeps=4).run(ys, M0, np.zeros((2, 2)))
    b = ContinuousDiscreteCKF(SG, DT, substeps=4).run(ys, M0, np.zeros((2, 2)))
    flt = SquareRootContinuousDiscreteCKF(SG, DT, substeps=4)
    pred = flt.summary(flt.predict(flt.init(M0, np.zeros((2, 2)), (1,)), 0))
    want = ContinuousDiscreteCKF(SG, DT, substeps=4).predict(GaussianState(M0[None], np.zeros((1, 2, 2))), 0)
    np.testing.assert_allclose(pred[0], want.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pred[1], want.cov, rtol=0, atol=1e-12)
    assert not a.diverged.any() and 0 < _gap(a, b) < 1e-4


def test_bad_input_is_named():
    """The registry's lines; a discrete model, a bad scheme or substeps, a factor that is not
    lower-triangular and a covariance passed for a factor are refused naming the argument."""
    assert REGISTRY["sr-continuous-discrete-ekf"] is SquareRootContinuousDiscreteEKF
    assert REGISTRY["sr-continuous-discrete-ukf"] is SquareRootContinuousDiscreteUKF
    assert REGISTRY["sr-continuous-discrete-ckf"] is SquareRootContinuousDiscreteCKF
    from nlfilter import DiscreteModel
    with pytest.raises(TypeError, match=r"^model: .*SDEModel"):
        SquareRootContinuousDiscreteEKF(DiscreteModel([x1], [x1], [x1], Q=1.0, R=1.0), DT)
    with pytest.raises(ValueError, match=r"^scheme"):
        SquareRootContinuousDiscreteCKF(SG, DT, scheme="bogus")
    with pytest.raises(ValueError, match=r"^kappa"):
        SquareRootContinuousDiscreteUKF(SG, DT, kappa=-3.0)
    flt = SquareRootContinuousDiscreteUKF(SG, DT)
    with pytest.raises(ValueError, match=r"^factor: .*lower-triangular"):
        flt.belief(M0, np.ones((2, 2)))
    with pytest.raises(TypeError, match=r"^belief: the square-root filters step a SqrtState"):
        flt.predict(GaussianState(M0, P0), 0)


def test_a_near_noiseless_update_before_a_noisy_interval_takes_array_steps():
    """x1 measured with R = 1e-8 and driven by the noisy x2 (dx1 = 10 (x2 − x1) dt, dx2 = −x2 dt + dβ):
    after the update P is nearly singular, the factor ODE's rate ‖GQGᵀ‖/λ_min(P) ~ 1e8 sends the
    interval to the covariance form, whose RK4 stages turn the node rules' covariance indefinite — the
    standard CD-UKF loses every path at its first prediction; the square-root one takes discrete array
    steps there (a factor by construction) and keeps every path. Those steps are first order in h: on
    this linear model, against the exact moments (the CD-EKF's covariance ODE), the gap halves when the
    substeps double (measured 7.9e-3 → 3.9e-3 relative in the covariances, ratio 2.03; asserted
    1.8-2.3) and is below 1e-2 at 25 substeps."""
    from nlfilter.experiments.square_root_pairs import stiff_model
    from nlfilter.simulate import simulate_continuous_discrete

    md, m0, P0 = stiff_model(10.0, 1e-8), np.zeros(2), np.eye(2)
    gaps = []
    for sub in (25, 50):
        sim = simulate_continuous_discrete(md, 6, paths=2, rng=0, m0=m0, P0=P0, dt=0.1, substeps=sub)
        assert ContinuousDiscreteUKF(md, 0.1, substeps=sub).run(sim.ys, m0, P0, on_divergence="mark").diverged.all()
        exact = ContinuousDiscreteEKF(md, 0.1, substeps=sub).run(sim.ys, m0, P0)
        sr = SquareRootContinuousDiscreteUKF(md, 0.1, substeps=sub).run(sim.ys, m0, P0, on_divergence="mark")
        assert not sr.diverged.any()
        gaps.append(np.abs(sr.covs - exact.covs).max() / np.abs(exact.covs).max())
    assert gaps[0] < 1e-2 and 1.8 <= gaps[0] / gaps[1] <= 2.3, gaps
