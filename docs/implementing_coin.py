"""The worked example of ``docs/implementing.rst``: a filter over a belief that is not Gaussian.

The page shows this file (``literalinclude``) and ``tests/filters/test_protocol.py`` imports and
runs it, so the documented code is the tested code.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from nlfilter.filters.base import Filter


class Counts(NamedTuple):
    """A belief that is not Gaussian: a Beta(a, b) posterior of a coin's bias per path."""

    a: np.ndarray
    b: np.ndarray


class Coin(Filter):
    """Bernoulli observations y ∈ {0, 1} of a fixed bias with a Beta prior: the conjugate filter
    (the loop must handle any belief; ``predict`` is the identity: the bias does not move)."""

    name = "coin"

    class model:  # noqa: N801 - a stand-in model with the two dimensions the loop reads
        n = m = 1

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        B = int(np.prod(batch))
        return Counts(np.ones(B), np.ones(B))

    def predict(self, belief, k):
        return belief

    def update(self, belief, y, k):
        obs = ~np.isnan(y[:, 0])
        y0 = np.where(obs, y[:, 0], 0.0)
        a = np.where(y0 > 1, np.nan, belief.a + y0 * obs)  # an impossible count: that path fails
        return Counts(a, belief.b + (1 - y0) * obs)

    def summary(self, belief):
        s = belief.a + belief.b
        mean = belief.a / s
        return mean[:, None], (mean * (1 - mean) / (s + 1))[:, None, None]

    def extras(self, belief):
        return {"count": belief.a + belief.b - 2}


def example():
    """The page's run: two paths of five flips (NaN: not observed), and a path with an impossible flip."""
    ys = np.array([[1, 0, 1, np.nan, 1], [0, 0, np.nan, 1, 1]])[..., None]  # (paths, steps, m)
    est = Coin().run(ys)  # est.means: the posterior mean a / (a + b) after each flip
    marked = Coin().run(np.full((1, 3, 1), 5.0), on_divergence="mark")  # diverged: [True], at step 0
    return est, marked
