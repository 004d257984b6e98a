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

    def simulate(self, steps: int, paths: int, rng, x0=None, *, burn: int = 0):
        """``(xs (paths, steps, n), ys (paths, steps, 1))``: ``w`` drawn from ``w_law`` (needed),
        ``v`` uniform; the state starts at ``x0 (paths, n)`` (default 0) and runs ``burn`` steps
        before the first recorded one (a burn-in from 0 to the stationary law; the experiments use
        300). Draws: all inputs ``w (paths, burn + steps)`` at once, then all measurement noises."""
        if self.w_law is None:
            raise ValueError("w_law: simulating needs the input law, got None")
        V.positive("steps", steps, integer=True)
        V.positive("paths", paths, integer=True)
        V.positive("burn", burn, integer=True, strict=False)
        rng = np.random.default_rng(rng)
        w = self.w_law.rvs(size=(paths, burn + steps), random_state=rng)
        x = np.zeros((paths, self.n)) if x0 is None else np.broadcast_to(x0, (paths, self.n)).astype(float)
        xs = np.empty((paths, burn + steps, self.n))
        for k in range(burn + steps):
            xs[:, k] = x
            x = x @ self.A.T + w[:, k, None] * self.b
        xs = xs[:, burn:]
        ys = xs @ self.c + rng.uniform(-self.noise_halfwidth, self.noise_halfwidth, (paths, steps))
        return xs, ys[..., None]
