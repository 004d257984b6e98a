"""Point-mass and weighted-cloud beliefs: the geometry the reference filters share.

A point-mass belief is a probability vector ``p (..., N)`` over fixed points ``X (N, n)``: the
grid filter's mesh (:class:`~nlfilter.filters.reference.grid.GridFilter`, :func:`axis_points`),
the cells of the bounded-noise grid (:class:`~nlfilter.filters.reference.bounded.BoundedGridFilter1D`,
:func:`cells`) and the points on the circle of the optimal phase filter
(:class:`~nlfilter.filters.phase.CircleGridFilter`, :func:`circle_points`, with ``X = (sin θ, cos θ)``).
A weighted cloud holds points per path, ``x (B, Np, n)`` with weights ``w (B, Np)`` (the particle
filters and the particle smoother). This module is below all of them and their smoothers
(:mod:`nlfilter.filters.reference.forward_backward`), which is what breaks the grid/particle/smoother
import cycle; it imports nothing of nlfilter.
"""

from __future__ import annotations

import numpy as np

__all__ = ["axis_points", "cells", "circle_points", "normalize", "moments", "apply_kernel", "weights",
           "cloud_moments"]


def axis_points(lo: float, hi: float, size: int) -> np.ndarray:
    """``size`` equally spaced points from ``lo`` to ``hi``, both included (a grid filter's axis;
    spacing ``(hi − lo) / (size − 1)``)."""
    return np.linspace(lo, hi, int(size))


def cells(lo: float, hi: float, size: int):
    """``(edges (size + 1,), centres (size,))`` of ``size`` equal cells covering ``[lo, hi]``."""
    edges = np.linspace(lo, hi, int(size) + 1)
    return edges, 0.5 * (edges[1:] + edges[:-1])


def circle_points(size: int) -> np.ndarray:
    """The angles ``θ_i = 2π i / size``, ``i = 0..size−1``: ``size`` equally spaced points on the
    circle (spacing ``2π / size``; the FFT's grid)."""
    return 2 * np.pi * np.arange(int(size)) / int(size)


def normalize(w: np.ndarray) -> np.ndarray:
    """``w / Σ w`` along the last axis (the caller handles paths without mass)."""
    return w / w.sum(axis=-1, keepdims=True)


def moments(p: np.ndarray, X: np.ndarray):
    """Mean ``(..., n)`` and covariance ``(..., n, n)`` (symmetrized) of probability vectors
    ``p (..., N)`` over the points ``X (N, n)``.

    >>> m, P = moments(np.array([[0.25, 0.75]]), np.array([[0.0], [2.0]]))
    >>> m.tolist(), P.tolist()             # mean 1.5, variance 4·0.75 − 1.5² = 0.75
    ([[1.5]], [[[0.75]]])
    """
    n = X.shape[-1]
    mean = p @ X
    second = (p @ (X[:, :, None] * X[:, None, :]).reshape(-1, n * n)).reshape(*p.shape[:-1], n, n)
    cov = second - mean[..., :, None] * mean[..., None, :]
    return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def apply_kernel(p: np.ndarray, K) -> np.ndarray:
    """``p @ K`` for a batch ``p (..., N)`` and a dense or scipy-sparse kernel ``K (N, N)``."""
    if isinstance(K, np.ndarray):
        return p @ K
    flat = p.reshape(-1, p.shape[-1])
    return np.asarray((K.T @ flat.T).T).reshape(p.shape)


def weights(logw: np.ndarray) -> np.ndarray:
    """Normalized weights ``(B, Np)`` from log-weights ``(B, Np)``; uniform on a path without a
    finite log-weight."""
    Np = logw.shape[1]
    mx = logw.max(axis=1, keepdims=True)
    if np.isfinite(mx).all():  # the usual case, every path with mass: the same numbers without the masks
        w = np.subtract(logw, mx)
        w /= np.exp(w, out=w).sum(axis=1, keepdims=True)
        return w
    dead = ~np.isfinite(mx[:, 0])
    w = np.exp(logw - np.where(np.isfinite(mx), mx, 0.0))
    w /= w.sum(axis=1, keepdims=True)
    return np.where(dead[:, None], 1.0 / Np, w)


def cloud_moments(w: np.ndarray, x: np.ndarray, cov: bool = True):
    """Weighted mean ``(B, n)`` and covariance ``(B, n, n)`` of the clouds ``x (B, Np, n)`` with
    normalized weights ``w (B, Np)``: ``m = Σ_p w_p x_p`` and ``Σ_p w_p (x_p − m)(x_p − m)ᵀ``, two
    matrix products per path (BLAS; the deviations laid out ``(B, n, Np)``, so that every
    elementwise pass runs along the particles). ``cov`` False: ``(mean, None)``."""
    B, Np, n = x.shape
    mean = np.matmul(w[:, None, :], x)[:, 0]
    if not cov:
        return mean, None
    d = np.subtract(np.swapaxes(x, 1, 2), mean[:, :, None], out=np.empty((B, n, Np)))
    return mean, np.matmul(d * w[:, None, :], np.swapaxes(d, 1, 2))
