"""Per-path random streams (nlfilter.streams) and the simulators that use them: a path depends on
the seed and its index only."""

import numpy as np
import pytest
import scipy.stats as st
import sympy as sp

from nlfilter import DiscreteModel, Independent, SDEModel, problems
import importlib

S = importlib.import_module("nlfilter.simulate")  # the module (nlfilter.simulate is also a function name)
from nlfilter.bounded import BoundedNoiseModel, ZeroOrderModel
from nlfilter.streams import FILTER, PathRNG, child, path_seeds, root

x, y = sp.symbols("x y")


def test_root_child_and_path_seeds_are_spawn():
    s = np.random.SeedSequence(11)
    kids = np.random.SeedSequence(11).spawn(5)
    for p in range(5):
        assert child(s, p).generate_state(4).tolist() == kids[p].generate_state(4).tolist()
    assert s.n_children_spawned == 0  # stateless
    assert [q.spawn_key for q in path_seeds(11, range(2, 4))] == [(2,), (3,)]
    assert [q.spawn_key for q in path_seeds(11, 2, key=FILTER)] == [(0, FILTER), (1, FILTER)]
    assert root(s) is s and root(3).entropy == 3
    g = np.random.default_rng(4)
    a, b = root(g), root(g)  # two calls with one Generator: two different roots
    assert a.generate_state(2).tolist() != b.generate_state(2).tolist()
    with pytest.raises(TypeError, match="rng"):
        root("seed")
    with pytest.raises(ValueError, match="paths"):
        PathRNG(0, range(0, 4, 2))
    with pytest.raises(ValueError, match="rng: expected a PathRNG over 3"):
        PathRNG.of(PathRNG(0, 2), 3)


def test_path_rng_rows_take_and_draw():
    r = PathRNG(5, 6)
    z = r.standard_normal((3, 2))
    for p in (0, 4):
        g = np.random.default_rng(np.random.SeedSequence(5).spawn(6)[p])
        np.testing.assert_array_equal(z[p], g.standard_normal((3, 2)))
    # take: the same generator objects; drawing from the subset advances those paths only
    r1, r2 = PathRNG(5, 6), PathRNG(5, 6)
    sub = r1.take(np.array([False, True, False, True, False, False]))
    assert sub.generators[0] is r1.generators[1] and sub.paths == (1, 3)
    u = sub.random((2,))
    np.testing.assert_array_equal(u, r2.take([1, 3]).random((2,)))
    np.testing.assert_array_equal(r1.random(()), r2.random(()))  # both advanced alike on rows 1, 3 only
    law = Independent(st.laplace(0, 2))
    d = PathRNG(1, range(3, 5)).draw(law.sample, (4,))
    np.testing.assert_array_equal(d, PathRNG(1, 5).sample(law, (4,))[3:])
    assert d.shape == (2, 4, 1)
    a, b = PathRNG(2, 3).draw(lambda g, s: (g.random(s), g.standard_normal(s)), (2,))
    assert a.shape == b.shape == (3, 2)


def test_sequential_fill_blocks_equal_one_draw():
    # the SDE simulators draw per block of steps: numpy fills sequentially, so blocks equal one draw
    g1, g2 = np.random.default_rng(3), np.random.default_rng(3)
    one = g1.standard_normal((7, 5))
    np.testing.assert_array_equal(np.concatenate([g2.standard_normal((3, 5)), g2.standard_normal((4, 5))]), one)


def _same(a, b):
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)


SIMS = {
    "discrete": lambda paths, rng: S.simulate(
        DiscreteModel([x], [0.8 * x], [x ** 2], R=0.5, process_noise=Independent(st.laplace(0, 0.3))),
        6, paths=paths, rng=rng, m0=0.0, P0=1.0),
    "sde": lambda paths, rng: S.simulate(SDEModel([x, y], [y, -x], [x], Q=np.eye(2), R=0.1), 5, paths=paths,
                                          rng=rng, m0=[0.0, 1.0], P0=np.eye(2), dt=0.1, substeps=3),
    "phase": lambda paths, rng: S.simulate_phase(1.0, 0.5, 0.1, 5, paths, rng),
    "ou": lambda paths, rng: S.simulate_ou(2.0, 1.0, 0.05, 5, paths, rng),
    "continuous-discrete": lambda paths, rng: S.simulate_continuous_discrete(
        SDEModel([x], [-x], [x], Q=0.5, R=0.1), 4, paths=paths, rng=rng, m0=0.0, P0=1.0, dt=0.5, substeps=2),
    "falling body": lambda paths, rng: S.simulate_continuous_discrete(
        problems.falling_body().model, 3, paths=paths, rng=rng, x0=problems.falling_body().x0, dt=1.0),
    "initial": lambda paths, rng: (S.initial_states(2, paths, rng, m0=[1.0, 0.0], P0=np.eye(2), shape=(3,)),),
    "bounded": lambda paths, rng: BoundedNoiseModel.first_order(0.5, 1.0, w_law=st.uniform(-1, 2)).simulate(
        4, paths, rng, burn=3),
    "zero-order": lambda paths, rng: ZeroOrderModel(4).simulate(5, paths, rng, noise=True),
    "zero-order copula": lambda paths, rng: ZeroOrderModel(4, copula_r=0.5).simulate(5, paths, rng),
}


@pytest.mark.parametrize("name", SIMS)
def test_simulators_rows_of_a_range_equal_the_full_run(name):
    full = SIMS[name](10, 42)
    part = SIMS[name](range(3, 7), 42)
    again = SIMS[name](10, np.random.SeedSequence(42))
    rows = full._replace(xs=full.xs[3:7], ys=full.ys[3:7], x0=full.x0[3:7]) if isinstance(full, S.Simulation) \
        else tuple(a[3:7] for a in full)
    _same(rows, part)
    _same(full, again)
    assert any(not np.array_equal(a[0], a[1]) for a in rows if np.ndim(a) > 1)  # paths differ


@pytest.mark.parametrize("name", ["sde", "phase", "ou"])
def test_sde_blocks_do_not_change_the_paths(name, monkeypatch):
    full = SIMS[name](4, 9)
    monkeypatch.setattr(S, "_BLOCK", 1)  # one step per block
    _same(full, SIMS[name](4, 9))
