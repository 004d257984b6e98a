"""The certified reference of a comparison on continuous-discrete data (an SDE measured at
discrete, irregular times: ``compare(..., times=)``): the
:class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter` through the simulator's
Euler–Maruyama steps, certified on the particle ladder, against the exact Kalman filter of a linear
model, beating the continuous-discrete EKF on a nonlinear one; and its refusals."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel, compare
from nlfilter.errors import ReferenceWarning
from nlfilter.filters import ContinuousDiscreteEKF, ContinuousDiscreteParticleFilter, Estimates, GridFilter
from nlfilter.sde_step import SUBSTEPS
from nlfilter.simulate import simulate_continuous_discrete

X = sp.Symbol("x")
A, Q, R, SUB = 1.0, 1.0, 0.1, 5
OU = SDEModel([X], [-A * X], [X], Q=Q, R=R)
TIMES = np.cumsum(np.random.default_rng(3).uniform(0.05, 0.6, 16))  # irregular intervals, 0.05 .. 0.6
M0, P0 = [0.0], [[0.5]]


class ExactKF:
    """The Kalman filter of the model the simulator draws from: ``SUB`` Euler–Maruyama steps of
    ``dx = −a x dt + dβ`` per interval ``Δ_k`` are the linear-Gaussian transition
    ``x_k = (1 − a δ)^SUB x_{k−1} + w``, ``Var w = Q δ Σ_{j<SUB} (1 − a δ)^{2j}``, ``δ = Δ_k / SUB``:
    its posterior is exactly the optimal filter's."""

    def run(self, ys, m0, P0, **kw):
        B, T, _ = ys.shape
        m, P = np.full(B, float(m0[0])), float(P0[0][0])
        means, covs = np.empty((B, T, 1)), np.empty((B, T, 1, 1))
        self.loglik = np.zeros(B)  # log p(y_1..y_T): the innovations' Gaussian densities
        for k, dk in enumerate(np.diff(np.concatenate([[0.0], TIMES[:T]]))):
            d = dk / SUB
            a = (1 - A * d) ** np.arange(SUB)
            m, P = m * (1 - A * d) ** SUB, P * (1 - A * d) ** (2 * SUB) + Q * d * np.sum(a * a)
            S, r = P + R, ys[:, k, 0] - m
            self.loglik -= 0.5 * (np.log(2 * np.pi * S) + r * r / S)
            m, P = m + P / S * r, R / S * P
            means[:, k, 0], covs[:, k, 0, 0] = m, P
        return Estimates(means, covs, np.zeros(B, bool), np.full(B, -1))


def test_linear_reference_is_the_exact_kalman_filter():
    """OU at 16 irregular times, 40 paths: the certified reference (2000 particles; its check
    8000 on 16 paths) and the exact KF of the simulator's model agree within the certificate's
    tolerance (``rtol = 0.02`` of its MSE: the particles' extra error is ~ P/ESS per step, far
    below), the reference checks pass (no filter beats it beyond 2 s.e.: the exact KF cannot), and
    the continuous-discrete EKF (RK4 moment equations: ``e^{−Δ}`` for ``(1 − δ)^SUB``, a change of
    the transition below 2 %) has no gap beyond 3 s.e. and the tolerance."""
    flts = {"exact-kf": ExactKF(), "cd-ekf": ContinuousDiscreteEKF(OU, None, substeps=SUB)}
    res = compare(OU, flts, len(TIMES), paths=40, m0=M0, P0=P0, times=TIMES, substeps=SUB, rng=0, certify_paths=16)
    cert = res.params["reference"]
    assert cert["certified"] and cert["kind"] == "particle" and cert["size"] == 2000 and not cert["contradicted"]
    assert "discrete times" in cert["reason"] and res.params["substeps"] == SUB
    tol = cert["rungs"][-1]["tolerance"][0]
    gap = res.get("exact-kf", "gap_to_optimal", component=0)
    assert abs(gap.value) <= tol, (gap, tol)
    ekf = res.get("cd-ekf", "gap_to_optimal", component=0)
    assert abs(ekf.value) <= 3 * ekf.stderr + tol, (ekf, tol)
    assert not any("no reference" in n for n in res.notes)
    nees = res.get("optimal", "nees")
    assert abs(nees.value - 1.0) < 3 * nees.stderr + 0.05, nees  # the posterior's NEES ≈ n = 1


def test_nonlinear_reference_beats_the_cd_ekf():
    """A double-well drift ``x − x³`` measured through ``x²`` (the sign is not observed: the EKF,
    linearizing at its mean, cannot split the modes) at 12 irregular times, 24 paths: the
    reference is certified and the EKF's gap is positive by more than 2 s.e. (3.5 s.e. on this
    seed; the gap comes from the few paths where the EKF follows the wrong well, so its ratio to
    its s.e. varies over seeds: 3.5, 3.3, 1.0, 1.7 on seeds 2, 3, 4, 7 — the seed is fixed, the
    run deterministic)."""
    md = SDEModel([X], [X - X**3], [X**2], Q=0.5, R=0.05)
    times = TIMES[:12]
    res = compare(md, ["continuous-discrete-ekf"], len(times), paths=24, m0=[0.5], P0=[[1.0]], times=times,
                  substeps=SUB, rng=2, certify_paths=8)
    assert res.params["reference"]["certified"]
    gap = res.get("continuous-discrete-ekf", "gap_to_optimal", component=0)
    assert gap.value > 2 * gap.stderr > 0, gap


def test_the_filter_reads_the_data_and_refuses():
    """The filter takes the Simulation's times and substeps (its run on the arrays at those times
    is the same, bitwise) and estimates the exact log-likelihood; one given as ``compare``'s reference with other substeps than the
    simulation's has another model, which its certificate says; a grid reference is refused,
    naming it."""
    sim = simulate_continuous_discrete(OU, 4, paths=3, rng=1, m0=M0, P0=P0, times=TIMES[:4],
                                       process="euler-maruyama", substeps=3)
    assert sim.timing.substeps == 3
    flt = ContinuousDiscreteParticleFilter(OU, None, 50)
    a = flt.run(sim, M0, P0, rng=4)
    b = ContinuousDiscreteParticleFilter(OU, None, 50, substeps=3).at_times(TIMES[:4]).run(sim.ys, M0, P0, rng=4)
    np.testing.assert_array_equal(a.means, b.means)
    # the log-likelihood estimate against the exact one (16 times, 4000 particles: its s.d. over
    # seeds, measured, 0.04-0.11 per path; 0.4 is ~4 s.d. of the widest)
    sim = simulate_continuous_discrete(OU, len(TIMES), paths=5, rng=1, m0=M0, P0=P0, times=TIMES,
                                       process="euler-maruyama", substeps=SUB)
    kf = ExactKF()
    kf.run(sim.ys, M0, P0)
    est = ContinuousDiscreteParticleFilter(OU, None, 4000).run(sim, M0, P0, rng=2, loglik=True)
    assert np.max(np.abs(est.loglik - kf.loglik)) < 0.4, est.loglik - kf.loglik
    with warnings.catch_warnings():  # 200 particles on 4 paths: whether it is certified is not the point here
        warnings.simplefilter("ignore", ReferenceWarning)
        res = compare(OU, ["continuous-discrete-ekf"], 4, paths=4, m0=M0, P0=P0, times=TIMES[:4], certify_paths=4,
                      reference=ContinuousDiscreteParticleFilter(OU, None, 200, substeps=3))  # the data's: 10
    assert "substeps=3 where the simulation has 10" in res.params["reference"]["reason"]
    with pytest.raises(ValueError, match=r"reference: no grid filter reads an SDE measured at discrete times"):
        compare(OU, ["continuous-discrete-ekf"], 4, paths=2, m0=M0, P0=P0, times=TIMES[:4], reference="grid")
    with pytest.raises(ValueError, match=r"reference: no grid filter"):
        compare(OU, ["continuous-discrete-ekf"], 4, paths=2, m0=M0, P0=P0, times=TIMES[:4],
                reference=GridFilter(OU, (-3, 3), 51, dt=0.1))
    with pytest.raises(TypeError, match=r"model: ContinuousDiscreteParticleFilter expects an SDEModel"):
        ContinuousDiscreteParticleFilter(object(), None)
    with pytest.raises(ValueError, match=r"times"):
        ContinuousDiscreteParticleFilter(OU, None).at_times(TIMES[::-1])


def test_the_simulators_default_is_the_references_model():
    """Simulated with the defaults, the data are the SDE by Euler–Maruyama at
    :data:`~nlfilter.sde_step.SUBSTEPS` steps per interval — the scheme the reference integrates,
    at the substeps it takes unless told (the one constant; ``compare`` and ``nlfilter simulate``
    read the same defaults) —, not the RK4 flow with noise added once per interval (only on
    request). Statistically, one interval Δ = 0.5 of ``dx = −2x dt + dβ`` from N(2, 0.01): the
    simulator's and the reference's prediction (20000 particles, the measurement missing) both
    have the moments of SUBSTEPS Euler steps, ``c = (1 − 2δ)^N``, mean ``2c``, variance ``0.01 c²
    + Q δ Σ_j (1 − 2δ)^{2j}`` (4 standard errors); the flow's mean ``2e^{−1}`` is 10 s.e. away."""
    import inspect
    sig = inspect.signature(simulate_continuous_discrete).parameters
    assert sig["process"].default == "euler-maruyama" and sig["substeps"].default is SUBSTEPS
    md, dt, paths, m0, p0 = SDEModel([X], [-2 * X], [X], Q=Q, R=R), 0.5, 20000, [2.0], [[0.01]]
    sim = simulate_continuous_discrete(md, 1, paths=paths, rng=4, m0=m0, P0=p0, dt=dt)
    flt = ContinuousDiscreteParticleFilter(md, dt, paths)
    assert sim.timing.substeps == SUBSTEPS == flt.substeps == flt.for_timing(sim.timing)[0].substeps
    pred = flt.run(np.full((1, 1, 1), np.nan), m0, p0, rng=5)  # nothing measured: the prediction
    d = dt / SUBSTEPS
    c, w = (1 - 2 * d) ** SUBSTEPS, (1 - 2 * d) ** (2 * np.arange(SUBSTEPS))
    mean, var = 2 * c, 0.01 * c * c + Q * d * w.sum()
    se = np.sqrt(var / paths)
    for got_mean, got_var in ((sim.xs[:, 0, 0].mean(), sim.xs[:, 0, 0].var(ddof=1)),
                              (pred.means[0, 0, 0], pred.covs[0, 0, 0, 0])):
        assert abs(got_mean - mean) < 4 * se and abs(got_var / var - 1) < 4 * np.sqrt(2 / (paths - 1))
    assert abs(2 * np.exp(-1.0) - mean) > 10 * se  # the flow's mean: this check tells the two apart
