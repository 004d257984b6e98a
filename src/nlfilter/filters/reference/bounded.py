"""Reference (near-optimal) filters for the bounded-noise problems of seed 000: the yardsticks of
the method-of-moments filters (``nlfilter reproduce moment-first-order``, ``moment-second-order``).

* :class:`BoundedGridFilter1D` — point-mass filter for ``x' = h x + w``, ``z = x + v`` with exact
  cell transition probabilities (CDF differences of the bounded input law);
* :class:`BoundedParticleFilter` — bootstrap particle filter for ``x' = A x + b w``,
  ``z = c.x + v`` with the uniform likelihood ``1{|z - c.x| <= c_v}`` (000 eq. 3.3).

Both are :class:`~nlfilter.filters.base.Filter` s on a :class:`~nlfilter.bounded.BoundedNoiseModel`
whose ``w_law`` (a frozen ``scipy.stats`` law) is known to them: ``run(ys)`` with ``ys (..., T, 1)``
returns :class:`~nlfilter.filters.estimates.Estimates` (posterior means and covariances). A missing
measurement: predict only.

(To move into the ``filters/reference/`` package as ``reference/bounded.py``.)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ... import _validate as V
from ...bounded import BoundedNoiseModel
from ...streams import FILTER, PathRNG
from ..base import Filter
from ..pointmass import cells, moments

__all__ = ["BoundedGridFilter1D", "BoundedParticleFilter", "GridBelief", "ParticleBelief"]


class _BoundedReference(Filter):
    family = "reference"
    accepts = ("bounded",)
    time = "discrete"
    own_prior = True  # the grid's stationary law / the sampler ``initial``: m0 = P0 = None

    @property
    def data_dim(self) -> int:
        return 1

    def _check_model(self, model, n=None):
        if getattr(model, "kind", None) != "bounded":
            raise TypeError(f"model: {type(self).__name__} expects a BoundedNoiseModel, got {type(model).__name__}")
        if n is not None and model.n != n:
            raise ValueError(f"model: expected n = {n}, got n = {model.n}")
        if model.w_law is None:
            raise ValueError("model: the reference filter needs the input law (w_law), got None")
        self.model = model
        self.c = model.noise_halfwidth


class GridBelief(NamedTuple):
    """Cell probabilities ``p (B, G)`` of a batch of grid filters."""

    p: np.ndarray


class BoundedGridFilter1D(_BoundedReference):
    """Point-mass (grid) optimum for ``x_{k+1} = h x_k + w_k``, ``z_k = x_k + v_k`` with bounded
    ``w`` (known law, a frozen ``scipy.stats`` distribution with a CDF) and ``v ~ U(-c, c)``.

    ``BoundedGridFilter1D(model, G=400)`` with a first-order :class:`~nlfilter.bounded.BoundedNoiseModel`
    carrying ``w_law`` (or the raw ``(h, w_law, w_bound, G=..., noise_halfwidth=...)``).
    The grid covers the stationary reachable interval ``|x| <= w_b/(1-|h|)`` with ``G`` cells;
    the transition matrix holds the exact probability that ``h x_i + w`` falls in cell j (CDF
    differences: no smoothing of the discontinuous input densities), the likelihood is the exact
    fraction of each cell inside ``[z - c, z + c]``. The prior of ``x_0`` is the grid's stationary
    law. Error: O(cell width) in the state, far below the filters' errors at G = 400. An
    impossible measurement (no cell consistent with it) raises ValueError naming ``ys``.
    """

    blas_threads = 1  # small dense products per step: one BLAS thread (base.Filter.blas_threads)
    name = "bounded-grid"
    source = "seed 000 eqs. 1.9, 1.13, 3.3 (point-mass reference)"
    needs = ("first-order model", "input law with a CDF")

    def __init__(self, model, *args, G: int = 400, noise_halfwidth: float | None = None):
        if not isinstance(model, BoundedNoiseModel):
            h, (w_law, w_bound) = model, args
            model = BoundedNoiseModel.first_order(h, w_bound, w_law=w_law,
                                                  noise_halfwidth=1.0 if noise_halfwidth is None else noise_halfwidth)
        elif args:
            raise TypeError(f"G: expected BoundedGridFilter1D(model, G=...), got {len(args)} more positional")
        self._check_model(model, 1)
        self.h = model.h
        self.G = int(V.positive("G", G, integer=True))
        B = model.w_bound / (1.0 - abs(self.h))
        self.edges, self.x = cells(-B, B, self.G)
        # T[i, j] = P(h x_i + w in cell j)
        hi = self.edges[None, 1:] - self.h * self.x[:, None]
        lo = self.edges[None, :-1] - self.h * self.x[:, None]
        Tm = model.w_law.cdf(hi) - model.w_law.cdf(lo)
        self.T = Tm / Tm.sum(axis=1, keepdims=True)
        p = np.full(self.G, 1.0 / self.G)
        for _ in range(500):
            p = p @ self.T
        self.p0 = p

    def point_likelihood(self, z):
        a = np.maximum(self.edges[:-1], z[..., None] - self.c)
        b = np.minimum(self.edges[1:], z[..., None] + self.c)
        return np.clip(b - a, 0.0, None)

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        for name, v in (("m0", m0), ("P0", P0), ("initial", initial)):
            if v is not None:
                raise ValueError(f"{name}: the grid filter starts from its grid's stationary law; expected None, got {v!r}")
        return GridBelief(np.broadcast_to(self.p0, (math.prod(batch), self.G)).copy())

    def predict(self, belief, k):
        return GridBelief(belief.p @ self.T)

    def update(self, belief, y, k):
        z = y[:, 0]
        obs = ~np.isnan(z)
        p = belief.p * self.point_likelihood(np.where(obs, z, 0.0))
        s = p.sum(axis=-1, keepdims=True)
        if np.any(~(s[obs] > 0)):
            raise ValueError(f"ys: measurement at step {k} impossible under the grid model")
        p = p / s
        return GridBelief(np.where(obs[:, None], p, belief.p))

    def summary(self, belief):
        mean, cov = moments(belief.p, self.x[:, None])
        return mean, np.maximum(cov, 0.0)  # 1-D: a variance below 0 by rounding is 0


class ParticleBelief(NamedTuple):
    """Particles ``x (B, P, n)`` (equally weighted), the posterior ``mean (B, n)`` and ``cov (B, n, n)``
    of the weighted particles before resampling, and the per-path generators ``rng`` (a
    :class:`~nlfilter.streams.PathRNG`, one object for the run)."""

    x: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    rng: object

    _shared = ("rng",)


class BoundedParticleFilter(_BoundedReference):
    """Bootstrap particle filter for the bounded system (the near-optimal reference in 2-D).

    Uniform likelihood ``1{|z - c.x| <= c_v}`` (000 eq. 3.3), systematic resampling every step;
    the input is drawn from ``model.w_law``. ``run(ys, initial=x0_sampler, rng=...)``:
    ``x0_sampler(generator, shape) -> (*shape, n)`` draws ``x_0``, called per path with that path's
    generator (``rng``: a seed, SeedSequence or Generator, path ``p`` then draws from the stream
    ``FILTER`` of path ``p``, :mod:`nlfilter.streams`; or a PathRNG over the paths). When every particle of a path is
    excluded by a measurement the nearest ones are kept (rare). Means and covariances are those of
    the weighted particles.
    """

    name = "bounded-particle"
    source = "seed 000 eq. 3.3 (bootstrap particle reference)"
    needs = ("input law to sample",)
    random = True

    def __init__(self, model, particles: int = 4000):
        self._check_model(model)
        self.P = int(V.positive("particles", particles, integer=True))

    @property
    def state_dim(self) -> int:
        return self.model.n

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        for name, v in (("m0", m0), ("P0", P0)):
            if v is not None:
                raise ValueError(f"{name}: the particle filter draws x_0 from initial(rng, shape); expected None, got {v!r}")
        if not callable(initial):
            raise TypeError(f"initial: expected a sampler initial(rng, shape) -> (*shape, n), got {type(initial).__name__}")
        B, n = math.prod(batch), self.model.n
        rng = PathRNG.of(rng, B, key=FILTER)
        x = np.asarray(rng.draw(initial, (self.P,)), dtype=float).reshape(B, self.P, n)
        mean = x.mean(axis=1)
        return ParticleBelief(x, mean, _cov(x, np.full((B, self.P), 1.0 / self.P), mean), rng)

    def predict(self, belief, k):
        B = belief.x.shape[0]
        w = belief.rng.draw(lambda g, s: self.model.w_law.rvs(size=s, random_state=g), (self.P,))
        x = belief.x @ self.model.A.T + w[..., None] * self.model.b
        mean = x.mean(axis=1)
        return belief._replace(x=x, mean=mean, cov=_cov(x, np.full((B, self.P), 1.0 / self.P), mean))

    def update(self, belief, y, k):
        x, rng = belief.x, belief.rng
        R, P = x.shape[:2]
        z = y[:, 0]
        obs = ~np.isnan(z)
        zz = np.where(obs, z, 0.0)
        lik = (np.abs(zz[:, None] - x @ self.model.c) <= self.c).astype(float)
        lik = np.where(obs[:, None], lik, 1.0)
        s = lik.sum(axis=1)
        if np.any(s == 0):  # every particle excluded: keep the nearest ones (rare)
            dist = np.abs(zz[:, None] - x @ self.model.c)
            lik = np.where(s[:, None] == 0, (dist <= dist.min(axis=1, keepdims=True) + 1e-9), lik)
            s = lik.sum(axis=1)
        wts = lik / s[:, None]
        mean = np.einsum("rp,rpi->ri", wts, x)
        cov = _cov(x, wts, mean)
        cdf = np.cumsum(wts, axis=1)
        cdf[:, -1] = 1.0
        u = (rng.random((1,)) + np.arange(P)) / P
        idx = np.minimum(np.array([np.searchsorted(cdf[r], u[r]) for r in range(R)]), P - 1)
        xr = np.take_along_axis(x, idx[..., None], axis=1)
        xr = np.where(obs[:, None, None], xr, x)
        return ParticleBelief(xr, np.where(obs[:, None], mean, belief.mean),
                              np.where(obs[:, None, None], cov, belief.cov), rng)

    def summary(self, belief):
        return belief.mean, belief.cov


def _cov(x, w, mean):
    d = x - mean[:, None, :]
    C = np.einsum("rp,rpi,rpj->rij", w, d, d)
    return 0.5 * (C + np.swapaxes(C, -1, -2))
