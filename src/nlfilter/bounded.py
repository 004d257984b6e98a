"""Bounded-noise linear models of seed 000 (the method-of-moments Bayesian filters' problems).

``x_{k+1} = A x_k + b w_k``, ``z_k = cᵀ x_k + v_k`` with a bounded scalar input ``|w| ≤ w_bound``
and ``v ~ U(−noise_halfwidth, noise_halfwidth)`` (000 eqs. 2.4-2.8; 000 uses a half-width of 1).
The law of ``w`` is *unknown* to the filters except through its bound and (known or learnt)
moments; ``w_law`` (a frozen ``scipy.stats`` law) is only used to simulate.

>>> m = BoundedNoiseModel.first_order(0.5, 1.0)
>>> m.kind, m.n, m.m, m.h
('bounded', 1, 1, 0.5)
"""

from __future__ import annotations

import numpy as np

from . import _validate as V
from .streams import PathRNG


class BoundedNoiseModel:
    """``x_{k+1} = A x_k + b w_k``, ``z_k = c·x_k + v_k``, ``|w| ≤ w_bound``, ``v ~ U(−c_v, c_v)``.

    ``kind = "bounded"`` (the filters that accept it: the seed-000 moment filters), ``n`` the state
    dimension (1 or 2), ``m = 1`` (a scalar measurement, ``ys (..., T, 1)``)."""

    kind = "bounded"
    m = 1

    def __init__(self, A, b, c, w_bound: float, *, noise_halfwidth: float = 1.0, w_law=None):
        self.A = V.as_float_array("A", A, ndim=2)
        n = self.A.shape[0]
        if self.A.shape != (n, n) or n not in (1, 2):
            raise ValueError(f"A: expected shape (1, 1) or (2, 2), got {self.A.shape}")
        self.n = n
        self.b = V.as_float_array("b", b, shape_tail=(n,))
        self.c = V.as_float_array("c", c, shape_tail=(n,))
        self.w_bound = float(V.positive("w_bound", w_bound))
        self.noise_halfwidth = float(V.positive("noise_halfwidth", noise_halfwidth))
        self.w_law = w_law

    @classmethod
    def first_order(cls, h: float, w_bound: float, **kw) -> "BoundedNoiseModel":
        """``x_{k+1} = h x_k + w_k``, ``z_k = x_k + v_k`` (000 eqs. 2.4-2.5)."""
        return cls([[float(h)]], [1.0], [1.0], w_bound, **kw)

    @property
    def h(self) -> float:
        """The scalar ``h`` of a first-order model."""
        if self.n != 1:
            raise ValueError(f"model: h is the coefficient of a first-order model, this one has n = {self.n}")
        return float(self.A[0, 0])

    def simulate(self, steps: int, paths, rng, x0=None, *, burn: int = 0):
        """``(xs (P, steps, n), ys (P, steps, 1))``: ``w`` drawn from ``w_law`` (needed), ``v``
        uniform; the state starts at ``x0 (P, n)`` (default 0) and runs ``burn`` steps before the
        first recorded one (a burn-in from 0 to the stationary law; the experiments use 300).
        ``paths`` an int or a ``range`` of path indices, ``rng`` the root of the per-path streams
        (:func:`nlfilter.simulate.simulate`). Draws of a path: its inputs ``w`` (``burn + steps``),
        then its measurement noises (``steps``)."""
        if self.w_law is None:
            raise ValueError("w_law: simulating needs the input law, got None")
        V.positive("steps", steps, integer=True)
        V.positive("burn", burn, integer=True, strict=False)
        rng = PathRNG.of(rng, paths)
        paths = len(rng)
        c = self.noise_halfwidth
        w, v = rng.draw(lambda g, s: (self.w_law.rvs(size=(burn + steps,), random_state=g),
                                      g.uniform(-c, c, (steps,))))
        x = np.zeros((paths, self.n)) if x0 is None else np.broadcast_to(x0, (paths, self.n)).astype(float)
        xs = np.empty((paths, burn + steps, self.n))
        for k in range(burn + steps):
            xs[:, k] = x
            x = x @ self.A.T + w[:, k, None] * self.b
        xs = xs[:, burn:]
        ys = xs @ self.c + v
        return xs, ys[..., None]


class ZeroOrderModel:
    """The zero-order problem of seed 000, Chapter III: ``x_k`` i.i.d. with density
    ``(J+1)/2 x^J`` on (−1, 1) (J even, 000 eq. 3.18), ``z_k = x_k + (1 + beta x_k) v_k``,
    ``v_k ~ U(−c, c)`` (000 assumption 3: c = 1; ``beta = 0`` is the additive ``z = x + v`` of
    eq. 3.1, ``beta ≠ 0`` the non-additive form ``z = h(x, v)`` of eq. 1.2).

    ``copula_r`` (``None``: x and v independent) couples ``(x_k, v_k)`` by a Gaussian copula of
    correlation r, each keeping its law: ``x = F^{-1}(Φ(g1))``, ``v = c (2 Φ(g2) − 1)``,
    ``corr(g1, g2) = r`` (the robustness study of 000's abstract: input/noise correlation).

    >>> m = ZeroOrderModel(10)
    >>> xs, zs = m.simulate(5, 3, 0)
    >>> xs.shape, zs.shape, bool(np.all(np.abs(zs - xs) <= 1))
    ((3, 5, 1), (3, 5, 1), True)
    """

    kind = "zero-order"
    n = 1
    m = 1

    def __init__(self, J: int, *, beta: float = 0.0, copula_r: float | None = None,
                 noise_halfwidth: float = 1.0):
        if isinstance(J, bool) or not isinstance(J, (int, np.integer)) or J < 0 or J % 2:
            raise ValueError(f"J: expected a non-negative even integer, got {J!r}")
        self.J = int(J)
        self.noise_halfwidth = float(V.positive("noise_halfwidth", noise_halfwidth))
        self.beta = float(beta)
        if not (1 - abs(self.beta) > 0):
            raise ValueError(f"beta: expected |beta| < 1 (1 + beta x > 0 on (-1, 1)), got {beta!r}")
        if copula_r is not None and not 0 <= float(copula_r) < 1:
            raise ValueError(f"copula_r: expected a copula correlation 0 <= r < 1 (or None), got {copula_r!r}")
        self.copula_r = None if copula_r is None else float(copula_r)

    def sample_x(self, rng, shape):
        """Samples of ``(J+1)/2 x^J`` on (−1, 1): ``|x| = U^{1/(J+1)}``, random sign (draws: U, then
        the signs). ``rng`` a Generator (``shape`` the whole shape) or a
        :class:`~nlfilter.streams.PathRNG` (``(B, *shape)``: ``shape`` per path, drawn path by path)."""
        u = rng.random(shape)
        s = rng.random(shape) < 0.5
        return np.where(s, -1.0, 1.0) * u ** (1.0 / (self.J + 1))

    def sample_pair(self, rng, shape):
        """``(x, v)`` of the given shape: independent (draws: x as :meth:`sample_x`, then v), or
        through the Gaussian copula (draws: g1, then the independent normal part of g2); ``rng`` as
        in :meth:`sample_x`."""
        c = self.noise_halfwidth
        if self.copula_r is None:
            x = self.sample_x(rng, shape)
            return x, rng.uniform(-c, c, shape)
        from scipy.special import ndtr
        r = self.copula_r
        g1 = rng.standard_normal(shape)
        g2 = r * g1 + np.sqrt(1.0 - r * r) * rng.standard_normal(shape)
        u1 = ndtr(g1)
        x = np.sign(2 * u1 - 1) * np.abs(2 * u1 - 1) ** (1.0 / (self.J + 1))  # F(x) = (1 + x^{J+1})/2
        v = 2.0 * ndtr(g2) - 1.0
        return x, (v if c == 1.0 else c * v)

    def measure(self, x, v):
        """``z = x + (1 + beta x) v`` (``x + v`` when beta = 0)."""
        return x + v if self.beta == 0.0 else x + (1 + self.beta * x) * v

    def simulate(self, steps: int, paths: int, rng, *, noise: bool = False):
        """``(xs (paths, steps, 1), zs (paths, steps, 1))``, and the noises ``vs (paths, steps)``
        with ``noise=True``; ``paths`` an int or a ``range`` of path indices, ``rng`` the root of the
        per-path streams (:func:`nlfilter.simulate.simulate`); each path draws as :meth:`sample_pair`
        on ``(steps,)`` (one sample per path with ``steps = 1``: an i.i.d. Monte Carlo)."""
        V.positive("steps", steps, integer=True)
        x, v = PathRNG.of(rng, paths).draw(self.sample_pair, (steps,))
        out = (x[..., None], self.measure(x, v)[..., None])
        return (*out, v) if noise else out
