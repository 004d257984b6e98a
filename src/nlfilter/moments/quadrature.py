"""Expectations under a Gaussian for non-polynomial functions (sin, cos, exp, ...).

``E[g(x)]``, ``x ~ N(m, P)``, by a rule ``Σ_p w_p g(m + L z_p)`` with ``P = L Lᵀ`` and nodes
``z_p`` of N(0, I):

* ``"gauss-hermite"`` — tensor product of the 1-D Gauss-Hermite rule with ``points`` nodes
  (exact for polynomials of degree ``2·points − 1`` in each variable); default up to
  ``points**n ≤ 4096`` nodes; at most :data:`MAX_POINTS` nodes per axis (NumPy's ``hermegauss``
  underflows beyond 370: zero, then NaN weights) and :data:`MAX_NODES` nodes in all, refused up
  front with a ``ValueError``;
* ``"cubature5"`` — Stroud's fully symmetric degree-5 rule with ``2n² + 1`` nodes, for higher
  dimensions (nodes 0, ±√(n+2) e_i, ±√((n+2)/2)(e_i ± e_j); weights 2/(n+2), (4−n)/(2(n+2)²),
  1/(n+2)²).

This is what makes statistical linearization (003 eqs. 3-5) work for every model under the
Gaussian closure.

>>> import numpy as np
>>> round(float(expect_gaussian(np.cos, np.array([0.0]), np.array([[1.0]]), points=20)[0]), 10)   # e^{-1/2}
0.6065306597
"""

from __future__ import annotations

import numpy as np

from .. import _validate as V

__all__ = ["gauss_hermite_rule", "cubature5_rule", "expect_gaussian", "gaussian_rule", "MAX_POINTS", "MAX_NODES",
           "MAX_ENTRIES"]

#: Largest 1-D Gauss-Hermite rule built: ``hermegauss`` gives finite, positive weights summing to
#: 1 within 1e-12 (and E z², E z⁴ to 1e-11) up to 370 nodes, zero or NaN weights from 371 on.
MAX_POINTS = 300
#: Largest rule built, in nodes (Gauss-Hermite ``points**n``, cubature ``2n² + 1``) and in node
#: coordinates (nodes times n, 160 MB): the integrand is evaluated on every node.
MAX_NODES = 10 ** 6
MAX_ENTRIES = 2 * 10 ** 7


def _check_size(nodes: int, n: int, what: str):
    if nodes > MAX_NODES or nodes * n > MAX_ENTRIES:
        raise ValueError(f"{what}: the rule would have {nodes:.3g} nodes in {n} dimension(s), expected at most "
                         f"{MAX_NODES:.0e} nodes and {MAX_ENTRIES:.0e} node coordinates")


def gauss_hermite_rule(n: int, points: int = 7):
    """Tensor Gauss-Hermite nodes ``(P, n)`` and weights ``(P,)`` (sum 1) for N(0, I_n),
    ``P = points**n``.

    Raises ``ValueError`` (before computing anything) for ``points > MAX_POINTS`` (300: the 1-D
    weights underflow beyond 370 nodes) or ``points**n > MAX_NODES`` (10⁶ nodes; or more than
    ``MAX_ENTRIES`` = 2·10⁷ node coordinates); use :func:`cubature5_rule` in high dimension.
    """
    V.positive("n", n, integer=True)
    V.positive("points", points, integer=True)
    if points > MAX_POINTS:
        raise ValueError(f"points: expected at most {MAX_POINTS} Gauss-Hermite nodes per axis (the weights "
                         f"underflow beyond 370), got {points}")
    _check_size(points ** n, n, f"points, n: points**n = {points}**{n}")
    z, w = np.polynomial.hermite_e.hermegauss(points)
    total = w.sum() / np.sqrt(2 * np.pi)
    if not (np.all(np.isfinite(w)) and np.all(w > 0) and abs(total - 1) < 1e-12):  # guard, never seen <= MAX_POINTS
        raise ValueError(f"points: the {points}-node Gauss-Hermite weights are not finite and positive "
                         f"summing to 1 (sum {total:.3g}); use fewer points")
    w = w / w.sum()
    grids = np.meshgrid(*([z] * n), indexing="ij")
    nodes = np.stack([g.ravel() for g in grids], axis=-1)
    wg = np.meshgrid(*([w] * n), indexing="ij")
    weights = np.prod(np.stack([g.ravel() for g in wg], axis=-1), axis=-1)
    return nodes, weights


def cubature5_rule(n: int):
    """Stroud's degree-5 rule for N(0, I_n): ``2n² + 1`` nodes (see module docstring); a
    ``ValueError`` above ``MAX_NODES`` nodes or ``MAX_ENTRIES`` node coordinates (n > 215)."""
    V.positive("n", n, integer=True)
    _check_size(2 * n * n + 1, n, f"n: 2n² + 1 = {2 * n * n + 1}")
    r = np.sqrt(n + 2.0)
    nodes = [np.zeros(n)]
    weights = [2.0 / (n + 2)]
    for i in range(n):
        for s in (1, -1):
            e = np.zeros(n)
            e[i] = s * r
            nodes.append(e)
            weights.append((4.0 - n) / (2.0 * (n + 2) ** 2))
    rr = r / np.sqrt(2.0)
    for i in range(n):
        for j in range(i + 1, n):
            for si in (1, -1):
                for sj in (1, -1):
                    e = np.zeros(n)
                    e[i], e[j] = si * rr, sj * rr
                    nodes.append(e)
                    weights.append(1.0 / (n + 2) ** 2)
    return np.array(nodes), np.array(weights)


def gaussian_rule(n: int, rule: str = "auto", points: int = 7):
    """Nodes and weights of the chosen rule (``"auto"``: Gauss-Hermite while ``points**n ≤ 4096``).

    ``n`` and ``points`` must be positive integers for every rule; rules too large to build are
    refused up front (:func:`gauss_hermite_rule`, :func:`cubature5_rule`)."""
    V.choice("rule", rule, {"auto", "gauss-hermite", "cubature5"})
    V.positive("n", n, integer=True)
    V.positive("points", points, integer=True)
    if rule == "auto":
        rule = "gauss-hermite" if points ** n <= 4096 else "cubature5"
    return gauss_hermite_rule(n, points) if rule == "gauss-hermite" else cubature5_rule(n)


def _sqrt(P):
    w, U = np.linalg.eigh(0.5 * (P + np.swapaxes(P, -1, -2)))
    return U * np.sqrt(np.clip(w, 0.0, None))[..., None, :]


def expect_gaussian(func, mean, cov, *, rule: str = "auto", points: int = 7, nodes=None, check: bool = True):
    """``E[func(x)]`` for ``x ~ N(mean, cov)``, batched: ``mean (..., n)``, ``cov (..., n, n)``;
    ``func`` maps ``(..., P, n)`` to ``(..., P, *out)``; returns ``(..., *out)``.

    ``nodes``: a precomputed ``(z, w)`` pair (from :func:`gaussian_rule`); ``check``: refuse a
    non-finite mean or a negative variance (the filters' inner loops, which screen their own
    moments, pass False)."""
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    n = mean.shape[-1]
    if cov.shape[-2:] != (n, n):
        raise ValueError(f"cov: expected trailing shape ({n}, {n}), got {cov.shape}")
    diag = np.diagonal(cov, axis1=-2, axis2=-1)
    if check and not (np.all(np.isfinite(mean)) and np.all(np.isfinite(diag))):
        raise ValueError("mean/cov: expected finite values, got NaN or inf")
    if check and np.any(diag < 0):
        raise ValueError(f"cov: expected a covariance (non-negative variances), got a variance {float(diag.min()):.3g}")
    z, w = gaussian_rule(n, rule, points) if nodes is None else nodes
    L = _sqrt(cov)
    x = mean[..., None, :] + np.einsum("...ij,pj->...pi", L, z)  # x_p = m + L z_p
    vals = np.asarray(func(x))
    if vals.shape[:x.ndim - 1] != x.shape[:-1]:
        raise ValueError(f"func: expected an output with leading shape {x.shape[:-1]} (batch, nodes), "
                         f"got {vals.shape}")
    return np.moveaxis(vals, x.ndim - 2, -1) @ w  # Σ_p w_p func(x_p)
