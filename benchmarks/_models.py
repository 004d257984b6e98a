"""The benchmarks' problems, one definition each, as nlfilter models, NumPy functions (filterpy)
and jax functions (dynamax). Imports only ``nlfilter.DiscreteModel`` of nlfilter, so that an older
commit's tree can run them too (``bench_history.py``).

* the scalar cubic sensor ``x[k+1] = 0.99 x[k] + w``, ``y = x³ + v`` (Q = 0.01, R = 0.1;
  m0 = 0.5, P0 = 0.1): ``bench_ekf.py`` (its dt = 0.01: 0.99 = 1 − dt), ``bench_single_path.py``;
* the chain of n states, m = ⌈n/2⌉ measurements::

      x_i[k+1] = 0.9 x_i[k] + 0.1 sin(x_{i+1}[k]) + w_i      (x_{n+1} := x_1)
      y_j[k]   = x_j[k] + 0.1 x_{j+m}[k]² + v_j             (x_{j+m} := x_j past n)

  Q = 0.01 I, R = 0.1 I, m0 = 0, P0 = I: ``bench_dimensions.py``, ``bench_single_path.py`` (n = 4).
"""

from __future__ import annotations

import math

import numpy as np
import sympy as sp

from nlfilter import DiscreteModel

A, CUBIC_Q, CUBIC_R, CUBIC_M0, CUBIC_P0 = 0.99, 0.01, 0.1, 0.5, 0.1
Q, R = 0.01, 0.1  # the chain's


def cubic() -> DiscreteModel:
    x = sp.Symbol("x")
    return DiscreteModel([x], [A * x], [x**3], Q=CUBIC_Q, R=CUBIC_R, name="cubic sensor")


def cubic_np():
    """The cubic sensor's ``(fx, hx, F, H)`` for filterpy, on a state ``(1,)``."""
    return (lambda x, dt=None: A * x, lambda x: x**3, lambda x: np.array([[A]]),
            lambda x: np.array([[3 * x[0] ** 2]]))


def cubic_jax(jnp):
    """The cubic sensor's ``(m0, P0, f, Q, h, R)`` in jax."""
    return (jnp.array([CUBIC_M0]), jnp.array([[CUBIC_P0]]), lambda x: A * x, jnp.array([[CUBIC_Q]]),
            lambda x: x**3, jnp.array([[CUBIC_R]]))


def _indices(n):
    m = math.ceil(n / 2)
    return m, [(i + 1) % n for i in range(n)], [(j + m) % n for j in range(m)]


def chain(n: int, a: float = 0.9) -> DiscreteModel:
    """The chain of ``n`` states (``a``: its decay; another value is another model of its shape)."""
    x = sp.symbols(f"x1:{n + 1}")
    m, nxt, sq = _indices(n)
    f = [a * x[i] + 0.1 * sp.sin(x[nxt[i]]) for i in range(n)]
    h = [x[j] + 0.1 * x[sq[j]] ** 2 for j in range(m)]
    return DiscreteModel(list(x), f, h, Q=Q * np.eye(n), R=R * np.eye(m), name=f"chain n={n}")


def chain_np(n):
    """The chain's ``(fx, hx, F, H)`` for filterpy, on a state ``(n,)``."""
    m, nxt, sq = _indices(n)

    def fx(x, dt=None):
        return 0.9 * x + 0.1 * np.sin(x[nxt])

    def hx(x):
        return x[:m] + 0.1 * x[sq] ** 2

    def F(x):
        J = 0.9 * np.eye(n)
        for i in range(n):
            J[i, nxt[i]] += 0.1 * np.cos(x[nxt[i]])
        return J

    def H(x):
        J = np.zeros((m, n))
        for j in range(m):
            J[j, j] += 1.0
            J[j, sq[j]] += 0.2 * x[sq[j]]
        return J

    return fx, hx, F, H


def chain_jax(n, jnp):
    """The chain's ``(m0, P0, f, Q, h, R)`` in jax."""
    m, nxt, sq = _indices(n)
    nxt, sq = jnp.array(nxt), jnp.array(sq)
    return (jnp.zeros(n), jnp.eye(n), lambda x: 0.9 * x + 0.1 * jnp.sin(x[nxt]), Q * jnp.eye(n),
            lambda x: x[:m] + 0.1 * x[sq] ** 2, R * jnp.eye(m))


def simulate_np(name: str, paths: int, steps: int, seed: int = 0):
    """``(ys (paths, steps, m), m0, P0)`` of ``"cubic"`` or ``"chainN"``, simulated in NumPy (seeded;
    no tree's ``simulate``: the same data for every commit)."""
    rng = np.random.default_rng(seed)
    if name == "cubic":
        m0, P0 = np.array([CUBIC_M0]), np.array([[CUBIC_P0]])
        f, h, q, r = (lambda x: A * x), (lambda x: x**3), CUBIC_Q, CUBIC_R
    else:
        n = int(name[5:])
        m, nxt, sq = _indices(n)
        m0, P0 = np.zeros(n), np.eye(n)
        f = lambda x: 0.9 * x + 0.1 * np.sin(x[..., nxt])  # noqa: E731
        h = lambda x: x[..., :m] + 0.1 * x[..., sq] ** 2  # noqa: E731
        q, r = Q, R
    x = m0 + rng.standard_normal((paths, len(m0))) @ np.linalg.cholesky(P0).T
    ys = []
    for k in range(steps):
        if k:
            x = f(x) + math.sqrt(q) * rng.standard_normal(x.shape)
        hx = h(x)
        ys.append(hx + math.sqrt(r) * rng.standard_normal(hx.shape))
    return np.ascontiguousarray(np.stack(ys, axis=1)), m0, P0
