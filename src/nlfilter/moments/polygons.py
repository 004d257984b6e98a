"""Convex polygons for the reachable sets of the seed-000 second-order moment filter: half-plane
clipping (Sutherland–Hodgman) at a fixed vertex capacity, trimming of the padding, and exact
quadrature on a polygon (fan of triangles, collapsed Gauss–Legendre rules). All batched over
leading axes: a polygon batch is ``(..., V, 2)``."""

from __future__ import annotations

import numpy as np

__all__ = ["clip_halfplane", "trim_polygon", "polygon_quadrature", "pad_polygons"]


def clip_halfplane(P, d, beta):
    """Sutherland–Hodgman: the convex polygon P (..., V, 2) cut by {x : d.x <= beta}; (..., V+1, 2).

    Output keeps a fixed capacity: kept vertices first (in order), padded with copies of the last
    one (zero-length edges, harmless for the quadrature and the support function).  An empty
    result collapses to the vertex of P nearest the half-plane.
    """
    beta = np.asarray(beta, dtype=float)
    s = np.einsum("k,...pk->...p", d, P) - beta[..., None]
    Pn = np.roll(P, -1, axis=-2)
    sn = np.roll(s, -1, axis=-1)
    inside = s <= 0
    cross = (s <= 0) != (sn <= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(cross, s / (s - sn), 0.0)
    X = P + t[..., None] * (Pn - P)
    cand = np.stack([P, X], axis=-2).reshape(*P.shape[:-2], 2 * P.shape[-2], 2)
    keep = np.stack([inside, cross], axis=-1).reshape(*s.shape[:-1], 2 * s.shape[-1])
    cap = P.shape[-2] + 1
    order = np.argsort(~keep, axis=-1, kind="stable")[..., :cap]
    out = np.take_along_axis(cand, order[..., None], axis=-2)
    n = keep.sum(-1)
    last = np.take_along_axis(out, np.clip(n - 1, 0, cap - 1)[..., None, None], axis=-2)
    idx = np.arange(cap)
    out = np.where((idx < n[..., None])[..., None], out, last)
    empty = n == 0
    if np.any(empty):
        nearest = np.take_along_axis(P, np.argmin(s, axis=-1)[..., None, None], axis=-2)
        out = np.where(empty[..., None, None], nearest, out)
    return out


def trim_polygon(P, tol=1e-13):
    """Drop repeated consecutive vertices (padding) and cut the capacity to the largest count."""
    d = np.linalg.norm(P - np.roll(P, 1, axis=-2), axis=-1)
    scale = 1.0 + np.max(np.abs(P), axis=(-2, -1))
    keep = d > tol * scale[..., None]
    keep[..., 0] |= ~keep.any(-1)
    n = keep.sum(-1)
    cap = max(int(n.max()), 3)
    order = np.argsort(~keep, axis=-1, kind="stable")[..., :cap]
    out = np.take_along_axis(P, order[..., None], axis=-2)
    last = np.take_along_axis(out, np.clip(n - 1, 0, cap - 1)[..., None, None], axis=-2)
    return np.where((np.arange(cap) < n[..., None])[..., None], out, last)


def polygon_quadrature(P, t, w):
    """Nodes (..., Q, 2) and weights (..., Q) on the convex polygon P (fan of triangles from P[0];
    collapsed Gauss–Legendre on each: exact for polynomials of degree <= 2 len(t) - 2)."""
    v0 = P[..., :1, :]
    a = P[..., 1:-1, :] - v0
    b = P[..., 2:, :] - v0
    area2 = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # signed, (..., V-2)
    S, Tt = np.meshgrid(t, t, indexing="ij")
    Ws = np.outer(w, w) * S  # Jacobian s (collapsed square)
    S, Tt, Ws = S.ravel(), Tt.ravel(), Ws.ravel()
    X = v0[..., None, :] + S[:, None] * ((1 - Tt)[:, None] * a[..., None, :] + Tt[:, None] * b[..., None, :])
    W = np.abs(area2)[..., None] * Ws
    shp = X.shape[:-3] + (-1,)
    return X.reshape(*shp, 2), W.reshape(shp)


def pad_polygons(P, cap: int):
    """Polygons ``P (..., V, 2)`` padded to ``cap >= V`` vertices with copies of the last one
    (zero-length edges: the same set for clipping, the support function and the quadrature)."""
    V = P.shape[-2]
    if V >= cap:
        return P
    return np.concatenate([P, np.repeat(P[..., -1:, :], cap - V, axis=-2)], axis=-2)
