"""The particle reference's Euler–Maruyama substeps agree with the data's (issue 25, "conventions
that cannot silently disagree"): a Simulation of an SDE records the substeps it was made with
(``sim.timing.substeps``), a ParticleFilter built without ``substeps`` takes them (``for_timing``:
``run``/``smooth`` on the Simulation, and ``compare``), one built with them keeps its own (recorded
in ``compare``'s certificate), and with no Simulation both default to the one constant
:data:`nlfilter.sde_step.SUBSTEPS`. Small runs (≤ 100 particles, ≤ 12 steps): all comparisons are
bitwise (the same model, the same streams, the same arithmetic), none has a tolerance."""

import inspect
import pickle
import warnings

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel, compare, simulate
from nlfilter.comparison import compare as compare_fn
from nlfilter.errors import ReferenceWarning
from nlfilter.filters import ContinuousEKF, ParticleFilter
from nlfilter.sde_step import SUBSTEPS
from nlfilter.simulate import Simulation, Timing
from nlfilter.yardstick import certified_reference, reference_filter

x = sp.Symbol("x")
WELL = SDEModel([x], [2 * (x - x**3)], [x], Q=1.0, R=0.05)  # moves within an interval: substeps matter
DT, M0, P0 = 0.1, [0.0], [[1.0]]


def _sim(substeps, paths=3, steps=12):
    return simulate(WELL, steps, paths=paths, rng=1, m0=M0, P0=P0, dt=DT, substeps=substeps)


def _run(flt, ys):
    return flt.run(ys, M0, P0, rng=3)


def test_the_two_defaults_are_one_constant():
    assert inspect.signature(simulate).parameters["substeps"].default is SUBSTEPS
    assert inspect.signature(compare_fn).parameters["substeps"].default is SUBSTEPS
    assert inspect.signature(certified_reference).parameters["substeps"].default is SUBSTEPS
    assert inspect.signature(reference_filter).parameters["substeps"].default is SUBSTEPS
    assert ParticleFilter(WELL, 10, dt=DT).substeps is SUBSTEPS
    assert simulate(WELL, 1, m0=M0, P0=P0, dt=DT, rng=0).timing.substeps == SUBSTEPS


def test_simulation_records_its_substeps_and_a_particle_filter_without_them_takes_them():
    sim = _sim(7)
    assert sim.timing == Timing("increments", None, 0.0, DT, 7)
    xs, ys, x0, t = sim  # still a 4-tuple, and it pickles with its timing
    assert pickle.loads(pickle.dumps(sim)).timing.substeps == 7
    assert Simulation(xs, ys, x0, t, Timing("increments", None, 0.0, DT)).timing.substeps is None  # 4 fields: none
    took = _run(ParticleFilter(WELL, 100, dt=DT), sim)
    seven = _run(ParticleFilter(WELL, 100, dt=DT, substeps=7), ys)
    np.testing.assert_array_equal(took.means, seven.means)
    np.testing.assert_array_equal(took.covs, seven.covs)
    default = _run(ParticleFilter(WELL, 100, dt=DT), ys)  # arrays carry no timing: SUBSTEPS = 10
    assert not np.array_equal(default.means, took.means)  # the substeps do change the numbers
    # an explicit, different substep is the filter's own choice (finer: nearer the SDE): kept
    np.testing.assert_array_equal(_run(ParticleFilter(WELL, 100, dt=DT, substeps=20), sim).means,
                                  _run(ParticleFilter(WELL, 100, dt=DT, substeps=20), ys).means)
    # a timing without substeps (hand-built) leaves the filter's default
    hand = Simulation(xs, ys, x0, t, Timing("increments", None, 0.0, DT))
    np.testing.assert_array_equal(_run(ParticleFilter(WELL, 100, dt=DT), hand).means, default.means)


def test_particle_smoother_takes_the_datas_single_substep():
    """FFBSm on an SDE needs substeps = 1 (one Euler–Maruyama transition density): a filter built
    without substeps smooths data simulated with one substep, and refuses data with more."""
    one = _sim(1, paths=2, steps=8)
    sm = ParticleFilter(WELL, 50, dt=DT).smooth(one, M0, P0, rng=2)
    np.testing.assert_array_equal(sm.means, ParticleFilter(WELL, 50, dt=DT, substeps=1).smooth(one.ys, M0, P0,
                                                                                               rng=2).means)
    with pytest.raises(TypeError, match="smooth.*got substeps=7"):
        ParticleFilter(WELL, 50, dt=DT).smooth(_sim(7, paths=2, steps=8), M0, P0, rng=2)


def test_compare_gives_a_particle_filter_its_substeps_and_records_a_different_one():
    """A reference given to compare without substeps runs at the comparison's (bitwise the one
    built with them); one built with other substeps runs at its own, and the certificate says so."""
    def run(ref):
        with warnings.catch_warnings():  # 100 particles on 4 paths: not certified, labelled so
            warnings.simplefilter("ignore", ReferenceWarning)
            res, sim, est = compare(WELL, {"cekf": ContinuousEKF(WELL, DT)}, 10, paths=4, m0=0.0, P0=1.0, rng=0,
                                    dt=DT, substeps=7, certify_paths=2, reference=ref, full_output=True)
        return res.params["reference"], sim, est[res.params["reference"]["label"]]

    took, sim, a = run(ParticleFilter(WELL, 100, dt=DT))
    seven, _, b = run(ParticleFilter(WELL, 100, dt=DT, substeps=7))
    assert sim.timing.substeps == 7
    np.testing.assert_array_equal(a.means, b.means)
    assert took["reason"] == seven["reason"] == "given by the caller"
    finer, _, c = run(ParticleFilter(WELL, 100, dt=DT, substeps=20))
    assert not np.array_equal(c.means, a.means)
    assert "substeps=20 where the simulation has 7" in finer["reason"] and "finer" in finer["reason"]
