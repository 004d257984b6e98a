"""The reference filters give the same numbers for any split of the paths (issue 15, item 6), and a
grid filter reports a path that left its grid.

One call on 12 paths equals the concatenation of three calls on 4 paths each (and ``chunk=4``).
The random filters (particle, resample-move, bounded particle) draw path ``p`` from its own stream
(:mod:`nlfilter.streams`): a call on paths ``a..b`` with ``rng=PathRNG(seed, range(a, b),
key=FILTER)`` gives those rows bitwise. The grid filters draw nothing and choose nothing from the
batch (their grid is the bounds and sizes given); their per-step products ``p @ K`` are BLAS matrix
products over the batch, whose blocking (and so the order of the additions) may depend on the
number of rows: they agree to 1e-12, not bitwise (the contract's tolerance for deterministic
filters; measured: ≤ 3e-15 on 1,000 paths vs 4 × 250).
"""

import numpy as np
import pytest
import scipy.stats as st
import sympy as sp

from nlfilter.bounded import BoundedNoiseModel
from nlfilter.errors import DivergenceError
from nlfilter.filters.reference import GridFilter, ParticleFilter, ResampleMoveParticleFilter
from nlfilter.filters.reference.bounded import BoundedGridFilter1D, BoundedParticleFilter
from nlfilter.filters.reference.grid import EDGE_LIMIT
from nlfilter.models import DiscreteModel, SDEModel
from nlfilter.simulate import simulate
from nlfilter.streams import FILTER, PathRNG

x, x1, x2 = sp.symbols("x x1 x2")
RC = np.array([[0.2, 0.08], [0.08, 0.1]])
D1 = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x + 0.1 * x**2], Q=0.1, R=0.2)
D2 = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2 - 0.05 * x1**3], [x1 + 0.1 * x2**2, x2],
                   Q=np.diag([0.1, 0.05]), R=RC)
S1 = SDEModel([x], [-x**3], [x], Q=0.5, R=0.1)
S2 = SDEModel([x1, x2], [x2, -x1 - 0.5 * x2 - 0.1 * x1**3], [x1 + 0.1 * x2**2, x2], Q=np.eye(2) * 0.3, R=RC)
S2_DET = SDEModel([x1, x2], S2.sym["f"], S2.sym["h"], Q=np.zeros((2, 2)), R=RC)
M1, P1 = np.array([0.5]), np.array([[0.3]])
M2, P2 = np.array([0.3, -0.2]), np.array([[0.5, 0.1], [0.1, 0.4]])
DT, T, B, SPLIT = 0.05, 12, 12, 4
BOUNDED = BoundedNoiseModel.first_order(0.5, 1.0, w_law=st.uniform(-1.0, 2.0))


def _ys(md, m0, P0, dt=None):
    return simulate(md, T, paths=B, rng=1, m0=m0, P0=P0, dt=dt).ys


def _x0(rng, shape):
    return rng.uniform(-0.4, 0.4, (*shape, 1))


# name: (filter, ys, run arguments, random)
CASES = {
    "grid-1d": (lambda: GridFilter(D1, (-4.0, 4.0), 81), lambda: _ys(D1, M1, P1), (M1, P1), {}, False),
    "grid-2d": (lambda: GridFilter(D2, [(-4.0, 4.0), (-4.0, 4.0)], 25), lambda: _ys(D2, M2, P2), (M2, P2), {}, False),
    "grid-sde": (lambda: GridFilter(S1, (-3.0, 3.0), 61, dt=DT), lambda: _ys(S1, M1, P1, DT), (M1, P1), {}, False),
    "grid-2d-sde": (lambda: GridFilter(S2, [(-4.0, 4.0), (-4.0, 4.0)], 25, dt=DT), lambda: _ys(S2, M2, P2, DT),
                    (M2, P2), {}, False),
    "particle": (lambda: ParticleFilter(D2, 200), lambda: _ys(D2, M2, P2), (M2, P2), {}, True),
    "particle-1d": (lambda: ParticleFilter(D1, 200, threshold=0.9), lambda: _ys(D1, M1, P1), (M1, P1), {}, True),
    "particle-sde": (lambda: ParticleFilter(S2, 200, dt=DT), lambda: _ys(S2, M2, P2, DT), (M2, P2), {}, True),
    "resample-move": (lambda: ResampleMoveParticleFilter(S2_DET, 200, dt=DT), lambda: _ys(S2_DET, M2, P2, DT),
                      (M2, P2), {}, True),
    "bounded-grid": (lambda: BoundedGridFilter1D(BOUNDED, G=120), lambda: BOUNDED.simulate(T, B, 3, burn=30)[1],
                     (), {}, False),
    "bounded-particle": (lambda: BoundedParticleFilter(BOUNDED, particles=300),
                         lambda: BOUNDED.simulate(T, B, 3, burn=30)[1], (), {"initial": _x0}, True),
}


def _outputs(est):
    return {"means": est.means, "covs": est.covs, "diverged": est.diverged, **dict(est.extras)}


@pytest.mark.parametrize("name", sorted(CASES))
def test_one_call_equals_any_split_of_the_paths(name):
    make, data, prior, kw, random = CASES[name]
    flt, ys = make(), data()
    one = _outputs(flt.run(ys, *prior, rng=7, on_divergence="mark", **kw))
    assert not one["diverged"].any()
    parts = [_outputs(flt.run(ys[lo:lo + SPLIT], *prior, rng=PathRNG(7, range(lo, lo + SPLIT), key=FILTER),
                              on_divergence="mark", **kw)) for lo in range(0, B, SPLIT)]
    chunked = _outputs(flt.run(ys, *prior, rng=7, chunk=SPLIT, on_divergence="mark", **kw))
    assert one.keys() == chunked.keys() == parts[0].keys()
    for key in one:
        split = np.concatenate([p[key] for p in parts])
        for other in (split, chunked[key]):
            if random:  # per-path streams: bitwise
                np.testing.assert_array_equal(other, one[key], err_msg=f"{name}: {key}")
            else:  # BLAS products over the batch: the last bits may differ with the number of rows
                np.testing.assert_allclose(other, one[key], rtol=0, atol=1e-12, err_msg=f"{name}: {key}")
    if random:  # the streams matter: another seed gives other numbers
        other = flt.run(ys, *prior, rng=8, on_divergence="mark", **kw).means
        assert np.max(np.abs(other - one["means"])) > 1e-6


def test_one_generator_for_several_calls_is_not_a_split():
    """A ``Generator`` is a root: each call spawns a new one from it (nlfilter.streams), so four calls
    with one Generator are four independent runs, not the rows of one run. A split passes the
    rows' streams, ``PathRNG(seed, rows, key=FILTER)``, as the test above."""
    flt, ys = ParticleFilter(D1, 200), _ys(D1, M1, P1)
    gen = np.random.default_rng(7)
    calls = np.concatenate([flt.run(ys[lo:lo + SPLIT], M1, P1, rng=gen).means for lo in range(0, B, SPLIT)])
    one = flt.run(ys, M1, P1, rng=np.random.default_rng(7)).means
    assert np.max(np.abs(calls - one)) > 1e-6
    np.testing.assert_array_equal(one, flt.run(ys, M1, P1, rng=PathRNG(np.random.default_rng(7), B, key=FILTER)).means)


# -- a path that leaves the grid ------------------------------------------------------------------
LIN = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.01)
LIN2 = DiscreteModel([x1, x2], f=[0.9 * x1, 0.5 * x2], h=[x1, x2], Q=np.diag([0.1, 0.1]), R=np.diag([0.01, 0.01]))


def _escape(md, steps=8):
    """Paths of ``md`` from 0, the path 2 pushed to x1 = 3 from step 4 on (beyond bounds ±2)."""
    sim = simulate(md, steps, paths=4, rng=5, m0=np.zeros(md.n), P0=0.01 * np.eye(md.n))
    ys = sim.ys.copy()
    ys[2, 4:, 0] += 3.0
    return ys


@pytest.mark.parametrize("md,bounds,size", [(LIN, (-2.0, 2.0), 201), (LIN2, [(-2.0, 2.0), (-2.0, 2.0)], 41)],
                         ids=["1-d", "2-d"])
def test_a_path_that_leaves_the_grid_is_marked_or_raises(md, bounds, size):
    ys = _escape(md)
    m0, P0 = np.zeros(md.n), 0.01 * np.eye(md.n)
    grid = GridFilter(md, bounds, size)
    est = grid.run(ys, m0, P0, on_divergence="mark")
    assert est.diverged.tolist() == [False, False, True, False] and est.diverged_step[2] == 4
    assert np.isnan(est.means[2, 4:]).all() and np.isfinite(est.means[2, :4]).all()
    unmarked = GridFilter(md, bounds, size, edge_limit=None).run(ys, m0, P0)
    assert not unmarked.diverged.any()
    assert unmarked.means[2, 4, 0] == pytest.approx(2.0, abs=0.05)  # what it hides: the mean at the edge
    np.testing.assert_array_equal(est.means[[0, 1, 3]], unmarked.means[[0, 1, 3]])  # the others as they were
    with pytest.raises(DivergenceError, match=r"left the grid.*at step 4 on 1 path\(s\), first \[2\]") as exc:
        grid.run(ys, m0, P0)
    assert exc.value.what == "edge" and exc.value.paths == (2,) and exc.value.step == 4
    b = grid.init(m0, P0, (4,))  # update on its own raises the same
    for k in range(5):
        if k:
            b = grid.predict(b, k - 1)
        if k < 4:
            b = grid.update(b, ys[:, k], k)
    with pytest.raises(DivergenceError, match=r"left the grid.*at step 4 on 1 path\(s\), first \[2\]"):
        grid.update(b, ys[:, 4], 4)


def test_an_sde_path_that_leaves_the_grid_is_marked():
    md = SDEModel([x], [-x], [x], Q=0.2, R=0.001)
    sim = simulate(md, 40, paths=3, rng=2, m0=np.zeros(1), P0=0.01 * np.eye(1), dt=DT)
    ys = sim.ys.copy()
    ys[1, 20:, 0] += 3.0 * DT  # the increments of a state at +3 (bounds ±1.5)
    est = GridFilter(md, (-1.5, 1.5), 151, dt=DT).run(ys, np.zeros(1), 0.01 * np.eye(1), on_divergence="mark")
    assert est.diverged.tolist() == [False, True, False] and 20 <= est.diverged_step[1] <= 22


def test_edge_ratio_and_edge_limit():
    grid = GridFilter(LIN, (-2.0, 2.0), 5)
    p = np.array([[0.0, 0.25, 0.5, 0.25, 0.0], [0.1, 0.2, 0.2, 0.3, 0.2], [0.5, 0.3, 0.2, 0.0, 0.0]])
    np.testing.assert_allclose(grid.edge_ratio(p), [0.0, 2 / 3, 1.0])
    assert grid.edge_limit == EDGE_LIMIT == 0.9
    assert GridFilter(LIN, (-2.0, 2.0), 5, edge_limit=0.5)._left(p).tolist() == [False, True, True]
    for bad in (0.0, 1.5, -1, "0.5", True):
        with pytest.raises(ValueError, match=r"edge_limit: expected a number in \(0, 1\] or None, got"):
            GridFilter(LIN, (-2.0, 2.0), 5, edge_limit=bad)
