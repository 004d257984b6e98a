"""Reference (near-optimal) filters for the bounded-noise problems of seed 000: the yardsticks of
the method-of-moments filters (``nlfilter reproduce moment-first-order``, ``moment-second-order``).

* :class:`BoundedGridFilter1D` — point-mass filter for ``x' = h x + w``, ``z = x + v`` with exact
  cell transition probabilities (CDF differences of the bounded input law);
* :func:`bootstrap_particle_means` — bootstrap particle filter for the 2-state system with the
  uniform likelihood ``1{|z - c.x| <= c_v}``.

(To move into the ``filters/reference/`` package as ``reference/bounded.py``.)
"""

from __future__ import annotations

import numpy as np

from .. import _validate as V

__all__ = ["BoundedGridFilter1D", "bootstrap_particle_means"]


class BoundedGridFilter1D:
    """Point-mass (grid) optimum for ``x_{k+1} = h x_k + w_k``, ``z_k = x_k + v_k`` with bounded
    ``w`` (known law, a frozen ``scipy.stats`` distribution with a CDF) and ``v ~ U(-c, c)``.

    The grid covers the stationary reachable interval ``|x| <= w_b/(1-|h|)`` with ``G`` cells;
    the transition matrix holds the exact probability that ``h x_i + w`` falls in cell j (CDF
    differences: no smoothing of the discontinuous input densities), the likelihood is the exact
    fraction of each cell inside ``[z - c, z + c]``.  The prior of ``x_0`` is the grid's stationary
    law.  Error: O(cell width) in the state, far below the filters' errors at G = 400.
    """

    def __init__(self, h, w_law, w_bound, *, G: int = 400, noise_halfwidth: float = 1.0):
        self.h = float(h)
        self.c = float(V.positive("noise_halfwidth", noise_halfwidth))
        self.G = int(V.positive("G", G, integer=True))
        B = float(w_bound) / (1.0 - abs(self.h))
        self.edges = np.linspace(-B, B, self.G + 1)
        self.x = 0.5 * (self.edges[1:] + self.edges[:-1])
        # T[i, j] = P(h x_i + w in cell j)
        hi = self.edges[None, 1:] - self.h * self.x[:, None]
        lo = self.edges[None, :-1] - self.h * self.x[:, None]
        Tm = w_law.cdf(hi) - w_law.cdf(lo)
        self.T = Tm / Tm.sum(axis=1, keepdims=True)
        p = np.full(self.G, 1.0 / self.G)
        for _ in range(500):
            p = p @ self.T
        self.p0 = p

    def likelihood(self, z):
        a = np.maximum(self.edges[:-1], z[..., None] - self.c)
        b = np.minimum(self.edges[1:], z[..., None] + self.c)
        return np.clip(b - a, 0.0, None)

    def run(self, zs):
        """Posterior means ``(..., T, 1)`` for ``zs`` (..., T)."""
        zs = np.asarray(zs, dtype=float)
        batch, T = zs.shape[:-1], zs.shape[-1]
        p = np.broadcast_to(self.p0, (*batch, self.G)).copy()
        out = np.empty((*batch, T, 1))
        for k in range(T):
            if k > 0:
                p = p @ self.T
            p = p * self.likelihood(zs[..., k])
            s = p.sum(axis=-1, keepdims=True)
            if np.any(~(s > 0)):
                raise ValueError(f"zs: measurement at step {k} impossible under the grid model")
            p = p / s
            out[..., k, 0] = p @ self.x
        return out


def bootstrap_particle_means(rng, zs, A, b, c, w_sampler, x0_sampler, *, particles: int = 4000,
                             noise_halfwidth: float = 1.0):
    """Bootstrap particle filter for the bounded second-order system (the near-optimal reference).

    Uniform likelihood ``1{|z - c.x| <= c_v}`` (000 eq. 3.3), systematic resampling every step.
    ``w_sampler(rng, shape)`` draws inputs, ``x0_sampler(rng, shape)`` draws ``x_0`` (..., 2).
    Returns posterior means (R, T, 2).
    """
    zs = np.asarray(zs, dtype=float)
    R, T = zs.shape
    P = int(particles)
    x = x0_sampler(rng, (R, P))
    A = np.asarray(A, float)
    b = np.asarray(b, float)
    c = np.asarray(c, float)
    out = np.empty((R, T, 2))
    ar = np.arange(P)
    for k in range(T):
        if k > 0:
            x = x @ A.T + w_sampler(rng, (R, P))[..., None] * b
        lik = (np.abs(zs[:, k, None] - x @ c) <= noise_halfwidth).astype(float)
        s = lik.sum(axis=1)
        if np.any(s == 0):  # every particle excluded: keep the nearest ones (rare, logged by caller)
            dist = np.abs(zs[:, k, None] - x @ c)
            lik = np.where(s[:, None] == 0, (dist <= dist.min(axis=1, keepdims=True) + 1e-9), lik)
            s = lik.sum(axis=1)
        wts = lik / s[:, None]
        out[:, k] = np.einsum("rp,rpi->ri", wts, x)
        cdf = np.cumsum(wts, axis=1)
        cdf[:, -1] = 1.0
        u = (rng.random((R, 1)) + ar) / P
        idx = np.minimum(np.array([np.searchsorted(cdf[r], u[r]) for r in range(R)]), P - 1)
        x = np.take_along_axis(x, idx[..., None], axis=1)
    return out
