"""Per-path random streams: a result depends on the seed and the path index, never on the batch.

Every simulator and every filter that draws (``random = True``) draws path ``p`` from a generator
of its own, seeded by a child of the run's root ``numpy.random.SeedSequence`` computed without
state:

    path p's stream = ``SeedSequence(root.entropy, spawn_key=(*root.spawn_key, p))``
                    = ``SeedSequence(seed).spawn(P)[p]`` (for any ``P > p``)

so paths ``100..199`` can be simulated (or filtered) on their own, in any batch or chunk size, on
another process or machine, and give the rows ``100..199`` of the run on all paths, bitwise.

* :func:`root` — the root of a run from ``rng``: an ``int`` seed (or None: fresh entropy), a
  ``SeedSequence`` (itself), or a ``Generator`` (a child spawned from its seed sequence, so two
  calls with one Generator give different roots, as two draws from it would).
* :func:`child` — the child of a root at a key path, statelessly; :func:`path_seeds` the children
  of the paths.
* Named sub-streams: a run that needs several independent streams per path gives each a ``key``
  (an ``int``); path ``p``'s sub-stream ``key`` is ``child(root, p, key)``, independent of every
  path's main stream ``child(root, q)`` and of the other keys. The keys in use:

  - ``None`` — the simulation (:mod:`nlfilter.simulate`, the models' ``simulate``);
  - :data:`FILTER` (0) — a random filter's own stream (``Filter.run(rng=seed)`` on path ``p``
    draws from ``child(root(seed), p, FILTER)``), so a filter run with the simulation's seed
    does not reuse the simulation's noise.

  - other ints — free for a run's further streams, e.g. one key per random filter in a
    comparison: ``flt.run(ys, ..., rng=PathRNG(seed, rows, key=k))`` with ``k`` distinct per filter,
    while the simulation is ``simulate(model, steps, paths=rows, rng=seed)`` (the same streams
    as ``simulate(rng=seed)``).

  A root serves either paths (``child(root, p)``) or cases (``child(root, k)``, each the root of its
  own paths, as :func:`nlfilter.evaluate.stream` for an experiment's cases), never both: case
  ``k``'s path ``p`` is ``(k, p)``, which is path ``k``'s sub-stream ``p``.

* :class:`PathRNG` — the bundle of the generators of some paths: ``standard_normal``,
  ``random``, ``uniform``, ``normal`` draw ``(B, *shape)`` arrays path by path (row ``i`` from
  path ``paths[i]``'s generator, in the order of the calls), ``draw(fn, shape)`` for anything
  else (a noise law's ``sample``, a scipy ``rvs``), ``take(rows)`` a subset of the paths (the same
  generator objects: a resampling step on some rows advances those rows' streams only).

>>> r = PathRNG(7, 4)
>>> a = r.standard_normal((2,))
>>> b = PathRNG(7, range(2, 4)).standard_normal((2,))
>>> a.shape, bool(np.array_equal(a[2:], b))
((4, 2), True)
>>> bool(np.array_equal(a[1], np.random.default_rng(np.random.SeedSequence(7).spawn(4)[1]).standard_normal(2)))
True
"""

from __future__ import annotations

import numbers

import numpy as np

FILTER = 0
"""The key of a random filter's own stream (see the module docstring)."""


def root(rng) -> np.random.SeedSequence:
    """The root ``SeedSequence`` of a run: ``rng`` an int seed (None: fresh entropy), a
    ``SeedSequence`` (returned as it is), or a ``Generator`` (a child spawned from its seed
    sequence: each call gives a new, independent root)."""
    if isinstance(rng, np.random.SeedSequence):
        return rng
    if rng is None or (isinstance(rng, numbers.Integral) and not isinstance(rng, bool)):
        if rng is not None and rng < 0:
            raise ValueError(f"rng: expected a non-negative integer seed, got {rng!r}")
        return np.random.SeedSequence(None if rng is None else int(rng))
    if isinstance(rng, np.random.Generator):
        seq = rng.bit_generator.seed_seq
        if not isinstance(seq, np.random.SeedSequence):
            raise TypeError(f"rng: the Generator's bit generator has no SeedSequence to spawn from, got {type(seq).__name__}")
        return seq.spawn(1)[0]
    raise TypeError(f"rng: expected an integer seed, a numpy.random.SeedSequence or a numpy.random.Generator, "
                    f"got {type(rng).__name__}")


def child(seq: np.random.SeedSequence, *keys: int) -> np.random.SeedSequence:
    """The child of ``seq`` at ``keys`` without touching ``seq``'s state:
    ``SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, *keys))`` (``child(s, k)`` equals
    ``s.spawn(k + 1)[k]`` on a fresh ``s``)."""
    for k in keys:
        if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 0:
            raise ValueError(f"keys: expected non-negative integers, got {keys!r}")
    return np.random.SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, *map(int, keys)),
                                  pool_size=seq.pool_size)


def as_paths(paths) -> range:
    """``paths`` as a ``range`` of path indices: an int ``P`` is ``range(P)``; a ``range`` with
    step 1 and ``start >= 0`` is kept."""
    if isinstance(paths, range):
        if paths.step != 1 or paths.start < 0 or len(paths) == 0:
            raise ValueError(f"paths: expected a non-empty range of path indices with step 1 from >= 0, got {paths!r}")
        return paths
    if isinstance(paths, bool) or not isinstance(paths, numbers.Integral):
        raise TypeError(f"paths: expected a positive integer number of paths or a range of path indices, "
                        f"got {paths!r}")
    if paths < 1:
        raise ValueError(f"paths: expected a positive number of paths or a range of path indices, got {paths!r}")
    return range(int(paths))


def path_seeds(rng, paths, key: int | None = None) -> list:
    """The ``SeedSequence`` of each path of ``paths`` (an int or a range) under ``root(rng)``, or
    of its sub-stream ``key``."""
    r = root(rng)
    extra = () if key is None else (key,)
    return [child(r, p, *extra) for p in as_paths(paths)]


class PathRNG:
    """Generators of the paths ``paths`` (an int ``P``: paths ``0..P-1``; or a ``range``) under
    the root of ``rng`` (sub-stream ``key``, None: the main streams). Each draw returns
    ``(B, *shape)``: row ``i`` from path ``paths[i]``'s generator (see the module docstring)."""

    __slots__ = ("generators", "paths")

    def __init__(self, rng, paths, key: int | None = None):
        self.paths = as_paths(paths)
        self.generators = tuple(np.random.default_rng(s) for s in path_seeds(rng, self.paths, key))

    @classmethod
    def of(cls, rng, paths, key: int | None = None) -> "PathRNG":
        """``rng`` itself if it is a ``PathRNG`` over ``len(paths)`` paths (built by the caller,
        e.g. the streams of paths 100..199), else ``PathRNG(rng, paths, key)``."""
        if isinstance(rng, PathRNG):
            n = len(as_paths(paths))
            if len(rng) != n:
                raise ValueError(f"rng: expected a PathRNG over {n} paths, got one over {len(rng)}")
            return rng
        return cls(rng, paths, key)

    @classmethod
    def _from(cls, generators, paths) -> "PathRNG":
        new = cls.__new__(cls)
        new.generators, new.paths = tuple(generators), paths
        return new

    def __len__(self) -> int:
        return len(self.generators)

    def __repr__(self) -> str:
        return f"PathRNG({len(self)} paths: {self.paths!r})"

    def take(self, rows) -> "PathRNG":
        """The generators of the rows ``rows`` (a boolean mask ``(B,)``, integer indices or a
        slice): the same generator objects, so drawing from the subset advances those paths."""
        idx = np.arange(len(self))[rows]
        gens = self.generators
        paths = self.paths[rows] if isinstance(rows, slice) else tuple(self.paths[i] for i in np.ravel(idx))
        return PathRNG._from((gens[i] for i in np.ravel(idx)), paths)

    def draw(self, fn, shape=()):
        """``(B, *shape, ...)``: ``fn(generator, shape)`` of each path, stacked (a noise law's
        ``sample``, ``lambda g, s: law.rvs(size=s, random_state=g)`` ...). A tuple result is
        stacked component by component."""
        shape = tuple(shape) if np.ndim(shape) else (() if shape == () else (int(shape),))
        out = [fn(g, shape) for g in self.generators]
        if isinstance(out[0], tuple):
            return tuple(np.stack(c) for c in zip(*out))
        return np.stack([np.asarray(o) for o in out])

    def sample(self, law, shape=()):
        """``(B, *shape, d)`` draws of the noise law ``law`` (its ``sample(generator, shape)``)."""
        return self.draw(law.sample, shape)

    # the Generator methods the simulators use, with ``size`` the shape of one path's draw
    def standard_normal(self, size=()):
        return self.draw(lambda g, s: g.standard_normal(s), size)

    def random(self, size=()):
        return self.draw(lambda g, s: g.random(s), size)

    def uniform(self, low=0.0, high=1.0, size=()):
        return self.draw(lambda g, s: g.uniform(low, high, s), size)

    def normal(self, loc=0.0, scale=1.0, size=()):
        return self.draw(lambda g, s: g.normal(loc, scale, s), size)
