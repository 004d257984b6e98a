"""One measurement convention from simulator to reference (issue 25, item 1) and certificates that
can fail (item 2).

The models move fast within one measurement interval, so that how ``h`` is integrated along it
matters: a 1-state double well ``dx = 5 (x − x³) dt + dw`` read through ``dy = x dt + dv``
(``R = 0.002``, ``dt = 0.2``: the state moves by ~0.45 per interval against a noise of 0.1 in
``dy/dt``) and Lorenz-63 with noise, all three states measured (``dt = 0.02``, ``R = 0.1``).
The particle reference reads ``dy`` exactly as :func:`~nlfilter.simulate.simulate` builds it
(:mod:`nlfilter.sde_step`); the old reading (``h`` at the end of the interval, kept here as
``EndPoint``) is contradicted by the certificate's NEES check on the same data.
"""

import warnings

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, compare, simulate
from nlfilter.errors import ReferenceWarning
from nlfilter.evaluate import paired_difference
from nlfilter.filters import GridFilter, ParticleFilter
from nlfilter.streams import PathRNG
from nlfilter.sde_step import euler_maruyama, increment_loglik
from nlfilter.certificate_checks import CONTRADICTED, beaten_check, contradictions, nees_check
from nlfilter.yardstick import OPTIMAL, Certificate, check_given_reference, endpoint_error

x, y, z = sp.symbols("x y z")
WELL = SDEModel([x], [5 * (x - x**3)], [x], Q=1.0, R=0.002, name="double-well")
WKW = dict(dt=0.2, m0=[0.0], P0=[[1.0]])
LORENZ = SDEModel([x, y, z], [10 * (y - x), x * (28 - z) - y, x * y - sp.Rational(8, 3) * z], [x, y, z],
                  Q=4 * np.eye(3), R=0.1 * np.eye(3), name="lorenz")
LKW = dict(dt=0.02, m0=[1.0, 1.0, 20.0], P0=4 * np.eye(3))


class EndPoint(ParticleFilter):
    """The particle reference before issue 25: ``dy`` weighed with ``h`` at the particles' state at
    the end of the interval instead of the simulator's ``∫ h ds`` along their path."""

    def _loglik(self, x, y, k, hbar=None):
        return super()._loglik(x, y, k, None)


def test_euler_maruyama_is_the_simulators_step_and_the_increment_law_is_exact():
    """``simulate``'s SDE branch is :func:`euler_maruyama` (bitwise: the same arithmetic), and the
    Kallianpur–Striebel ratio is ``log N(dy; h̄ dt, R dt) − log N(dy; 0, R dt)`` (to rounding)."""
    sim = simulate(WELL, 1, paths=4, rng=1, substeps=5, dt=0.2, x0=[0.3])
    z = PathRNG.of(1, 4).standard_normal((1, 6))[:, 0]  # the path's draws of its step: 5 Brownian, 1 noise
    dB = z[:, :5].reshape(4, 5, 1) @ WELL.process_noise._sqrt.T * np.sqrt(0.2 / 5)
    x1, ih = euler_maruyama(WELL, sim.x0, 0.0, 0.2, 5, dB)
    np.testing.assert_array_equal(x1, sim.xs[:, 0])
    np.testing.assert_array_equal(ih + z[:, 5:] @ WELL.measurement_noise._sqrt.T * np.sqrt(0.2), sim.ys[:, 0])
    hbar, dy, R, dt = np.array([[[0.3], [-1.2]]]), np.array([[0.07]]), 0.002, 0.2
    ll = increment_loglik(hbar, dy, np.array([[1 / R]]), dt)
    lognorm = lambda mu: -0.5 * (dy[0, 0] - mu) ** 2 / (R * dt)  # noqa: E731
    np.testing.assert_allclose(ll[0], [lognorm(0.3 * dt) - lognorm(0.0), lognorm(-1.2 * dt) - lognorm(0.0)], rtol=1e-12)


@pytest.fixture(scope="module")
def well():
    sim = simulate(WELL, 40, paths=40, rng=3, substeps=5, **WKW)
    run = lambda flt: flt.run(sim.ys, WKW["m0"], WKW["P0"], rng=1)  # noqa: E731
    return sim, {"left": run(ParticleFilter(WELL, 300, dt=0.2, substeps=5)),
                 "fine": run(ParticleFilter(WELL, 300, dt=0.2, substeps=50)),
                 "end": run(EndPoint(WELL, 300, dt=0.2, substeps=5))}


def test_double_well_reference_agrees_with_10x_finer_substeps_and_its_nees_is_one(well):
    """40 paths × 40 steps, 300 particles. The reference at the simulator's 5 substeps and at 50
    agree within 3 s.e. of their paired MSE difference (measured +0.0001 ± 0.0012 on an MSE of
    0.071); its NEES is in the certificate's band (measured 1.19 ± 0.08, band [0.68, 1.32]). The
    end-point reading on the same paths is overconfident — NEES 9.3 ± 0.6, contradicted — and worse
    by 0.0083 ± 0.0017 in MSE (5 s.e.; 3 required)."""
    sim, est = well
    d = paired_difference(est["fine"], est["left"], sim.xs, window=0.5)
    assert abs(d.value) <= 3 * d.stderr, d
    (row,) = nees_check(est["left"], sim.xs, window=0.5)
    assert row["ok"] and abs(row["nees"] - 1) < 0.3, row
    (bad,) = nees_check(est["end"], sim.xs, window=0.5)
    assert not bad["ok"] and bad["nees"] > 4, bad
    d = paired_difference(est["end"], est["left"], sim.xs, window=0.5)
    assert d.value > 3 * d.stderr, d


def test_double_well_automatic_reference_reads_dy_as_the_simulator_and_is_not_beaten():
    """The grid would read ``dy`` at the interval's end point, off by ~2 noise s.d. here
    (:func:`endpoint_error` 1.9): the automatic reference takes particles, is certified, and passes
    both checks (NEES band; no filter below −2 s.e.)."""
    sim = simulate(WELL, 30, paths=32, rng=0, substeps=5, **WKW)
    assert endpoint_error(WELL, sim, 0.2) > 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", ReferenceWarning)
        res = compare(WELL, ["continuous-ekf", "conditional-moment"], 30, paths=32, substeps=5, rng=0,
                      certify_paths=16, **WKW)
    cert = res.params["reference"]
    assert cert["kind"] == "particle" and "end-point" in cert["reason"] and cert["label"] == OPTIMAL
    assert cert["contradicted"] == []
    for r in res.rows:
        if r.quantity == "gap_to_optimal":
            assert r.value >= -2 * r.stderr, r


@pytest.fixture(scope="module")
def lorenz():
    ref = ParticleFilter(LORENZ, 500, dt=0.02, substeps=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ReferenceWarning)  # 500 particles: its refinement may not certify
        return compare(LORENZ, ["continuous-ekf", "conditional-moment"], 50, paths=30, substeps=4, rng=3,
                       reference=ref, certify_paths=16, full_output=True, **LKW)


def test_lorenz_reference_is_not_contradicted_and_no_filter_beats_it(lorenz):
    """30 paths × 50 steps, 500 particles at the simulator's 4 substeps (the end-point error of
    :func:`endpoint_error` is 0.6 noise s.d.): the NEES check passes in every component (measured
    1.01 ± 0.11, 1.06 ± 0.15, 0.97 ± 0.11; band ≈ 1 ± 0.45) and no filter's gap is below −2 s.e. (the
    issue's failure: a conditional-moment filter ~2 s.e. below an end-point reference whose NEES
    was 4.75). The lower edge of the band is the fragile one — per-path NEES is right-skewed: with
    ``rng=2`` the same setting gives 0.74 ± 0.06 in z, inside the band [0.71, 1.29] only by its
    slack — so the seed here is not a borderline one."""
    res, sim, est = lorenz
    cert = res.params["reference"]
    assert cert["contradicted"] == [] and not cert["label"].startswith("reference (contradicted")
    gaps = [r for r in res.rows if r.quantity.startswith("gap_to")]
    assert gaps and all(r.value >= -2 * r.stderr for r in gaps), gaps
    assert all(row["ok"] for row in nees_check(est[cert["label"]], sim.xs, window=0.5))


def test_lorenz_reference_agrees_with_10x_finer_substeps_and_end_point_is_contradicted(lorenz):
    """On the first 8 paths, the reference at 40 substeps (10×) and at the simulator's 4 agree
    within 3 s.e. per component (measured −0.005 ± 0.064, −0.18 ± 0.22, +0.10 ± 0.06 on MSEs
    0.3-0.8); the end-point reading on all paths fails the NEES check (3.05 ± 0.29, 2.67 ± 0.30,
    3.15 ± 0.37; bands ≈ 1 ± 1.1) and the certificate is relabelled and warns."""
    res, sim, est = lorenz
    ref = est[res.params["reference"]["label"]]
    sub = slice(0, 8)
    fine = ParticleFilter(LORENZ, 500, dt=0.02, substeps=40).run(sim.ys[sub], LKW["m0"], LKW["P0"], rng=5)
    for i in range(3):
        d = paired_difference(fine, ref.take(sub), sim.xs[sub], component=i, window=0.5)
        assert abs(d.value) <= 3 * d.stderr, (i, d)
    end = EndPoint(LORENZ, 500, dt=0.02, substeps=4).run(sim.ys, LKW["m0"], LKW["P0"], rng=1)
    cert = Certificate("particle", True, OPTIMAL, 500)
    with pytest.warns(ReferenceWarning, match="contradicted: its NEES of x"):
        fails = contradictions(cert, end, {}, sim.xs, components=["x", "y", "z"])
    assert fails and cert.label == CONTRADICTED.format("NEES, x") and cert.to_dict()["contradicted"] == fails


# -- the certificate's checks on a deliberately wrong reference ------------------------------------------------
LIN = DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=0.5, name="linear")


@pytest.mark.parametrize("wrong_R, fails", [(0.5, False), (0.05, True)])
def test_given_reference_with_the_wrong_R_is_contradicted(wrong_R, fails):
    """A grid reference built on the model with R = 0.05 instead of 0.5 (it trusts the data 10×
    too much) on 64 paths × 30 steps: its NEES (8.2 ± 0.35) leaves the band and the Kalman filter
    beats it (gap −0.085 ± 0.010); with the right R it is certified and passes (NEES 0.97 ± 0.05,
    KF gap 0 to rounding: the check allows 1e-9 of the MSE for it)."""
    ref_model = DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=wrong_R)
    ref = GridFilter(ref_model, (-8, 8), 401)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always", ReferenceWarning)
        res = compare(LIN, ["kf"], 30, paths=64, m0=0.0, P0=1.0, rng=4, reference=ref, certify_paths=16)
    cert = res.params["reference"]
    if fails:
        assert cert["label"] == CONTRADICTED.format("NEES, x; beaten, kf/x")
        checks = {c["check"] for c in cert["contradicted"]}
        assert checks == {"NEES", "beaten"} and any("contradicted" in str(w.message) for w in got)
        assert res.get("kf", "gap_to_reference", component=0).value < 0
        assert any(n.startswith("reference checks FAILED") for n in res.notes)
    else:
        assert cert["label"] == OPTIMAL and cert["contradicted"] == [] and not got
        assert any(n.startswith("reference checks: ") and n.endswith("passed") for n in res.notes)


def test_checks_need_enough_paths_and_skip_selected_survivors():
    """Fewer than 16 paths: no verdict either way (a standard error from 4 paths is not one);
    a filter that diverged on more than 10 % of the paths is not judged (selected survivors)."""
    sim = simulate(LIN, 20, paths=8, rng=0, m0=0.0, P0=1.0)
    est = GridFilter(DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=0.05), (-8, 8), 201).run(sim.ys, 0.0, 1.0)
    assert nees_check(est, sim.xs) == [] and beaten_check(est, {"self": est}, sim.xs) == []
    sim = simulate(LIN, 20, paths=32, rng=0, m0=0.0, P0=1.0)
    good = GridFilter(LIN, (-8, 8), 201).run(sim.ys, 0.0, 1.0)
    wrong = GridFilter(DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=0.05), (-8, 8), 201).run(sim.ys, 0.0, 1.0)
    assert any(not r["ok"] for r in beaten_check(wrong, {"good": good}, sim.xs))
    div = good._replace(diverged=np.arange(32) < 8)  # 25 % diverged: not judged
    assert beaten_check(wrong, {"good": div}, sim.xs) == []


def test_check_given_reference_keeps_its_label_until_contradicted():
    """``check_given_reference`` certifies by refinement only; ``contradictions`` on its result is
    what the experiments run on their own references (recorded, label changed only on failure)."""
    sim = simulate(LIN, 30, paths=32, rng=1, m0=0.0, P0=1.0)
    flt = GridFilter(LIN, (-8, 8), 201)
    run = lambda f, ys, tag: f.run(ys, 0.0, 1.0)  # noqa: E731
    est = run(flt, sim.ys, "")
    cert = check_given_reference(flt, est, LIN, sim, run=run, certify_paths=16)
    assert contradictions(cert, est, {}, sim.xs) == [] and cert.label == OPTIMAL


def test_reference_checks_from_per_path_arrays_as_the_experiments_call_them():
    """The experiments' entry (:func:`reference_checks`, per-path arrays of Monte Carlo blocks):
    the wrong-R grid's per-path NEES and the KF's paired gap fail and warn, the right grid passes
    with no warning, and fewer than 16 paths is 'not run' (the note says so)."""
    from nlfilter.evaluate import mse
    from nlfilter.filters import KalmanFilter
    from nlfilter.certificate_checks import nees_per_component, reference_checks
    sim = simulate(LIN, 30, paths=32, rng=2, m0=0.0, P0=1.0)
    kf = KalmanFilter(LIN).run(sim.ys, 0.0, 1.0)
    for R, fails in ((0.5, False), (0.05, True)):
        ref = GridFilter(DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=R), (-8, 8), 201).run(sim.ys, 0.0, 1.0)
        d = paired_difference(kf, ref, sim.xs, window=0.5)
        gaps = [("kf", "x", d.value, d.stderr, d.paths, mse(ref, sim.xs, window=0.5).value)]
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always", ReferenceWarning)
            failed, note = reference_checks(nees_per_component(ref, sim.xs), gaps, components=["x"], who="test")
        assert bool(failed) == fails == bool(got) and note.startswith("reference checks FAILED" if fails else
                                                                     "reference checks: NEES")
    assert reference_checks(nees_per_component(ref, sim.xs)[:8], [])[1].startswith("reference checks: not run")


def test_end_point_grid_on_the_fast_double_well_is_certified_by_refinement_but_contradicted():
    """The issue's failure in one call: a grid (``h`` at the interval's end point) on the fast double
    well converges in its grid points — refinement certifies it — but reads the wrong likelihood:
    its NEES is 8.1 ± 0.75 (the same with 401 points), so the certificate withdraws "optimal"."""
    with pytest.warns(ReferenceWarning, match="contradicted: its NEES of x"):
        res = compare(WELL, ["continuous-ekf"], 30, paths=32, substeps=5, rng=0, certify_paths=16,
                      reference=GridFilter(WELL, (-2.5, 2.5), 201, dt=0.2), **WKW)
    cert = res.params["reference"]
    assert cert["certified"] is True and cert["label"] == CONTRADICTED.format("NEES, x")
    (row,) = cert["contradicted"]
    assert row["check"] == "NEES" and row["nees"] > row["band"][1] + 3
