"""Second-order problem (000 eqs. 2.6-2.8): ``x_{k+1} = A x_k + b w_k`` (2-vector), ``z_k = c.x_k + v_k``.

The four steps of the first-order filter in 2-D:

1. mixed moments ``E[x0^i x1^j]`` (total order <= N) propagate exactly through the linear map by
   a multinomial expansion (:func:`moment_map_tensor`, eq. 3.13 in two dimensions);
2. the reachable set (Schweppe) is bounded by a convex *template polygon*
   ``{x : d_j.x <= beta_j}`` over fixed directions ``d_j`` (evenly spaced, plus ``+-c``): its
   prediction is the exact support function of ``A P (+) b [-w_b, w_b]`` on those directions,
   ``beta_j' = max_{v in P} d_j.(A v) + w_b |d_j.b|`` (``bounding="box"`` keeps only the axes);
3. the predicted density is the tensor Legendre polynomial of total degree N on the polygon's
   bounding box, restricted to the polygon;
4. the update integrates it exactly over the polygon cut by the slab ``|z - c.x| <= c_v``
   (fan of triangles, collapsed Gauss–Legendre rules exact for degree 2N) — posterior moments,
   mean, fallback to the uniform law on the cut polygon as in 1-D, and also when the posterior
   covariance is not positive semi-definite (the degree-N polynomial is negative over much of the
   cut, as on a loose bounding box: its "moments" are no law's);
5. adaptation uses ``kappa_i(w) = kappa_i(y) / sum_j (c^T A^j b)^i`` with ``y = c.x``; a refresh
   at step k comes before the estimate of step k (000's Fig. 7), so the prediction into step k
   is redone with the new input moments (the belief keeps the previous posterior's moments).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ... import _validate as V
from ...moments.densities import LegendreDensity2D, pdf_batched_2d
from ...moments.polygons import clip_halfplane, pad_polygons, polygon_quadrature, trim_polygon
from ..beliefs import where_paths
from ._moment_base import BOX_AND_LEARNER, REFRESH, MomentFilter, configure_input, impulse_power_sums, observed
from .first_order import _raw_model


PolygonBelief = NamedTuple("PolygonBelief", [("M", np.ndarray), ("verts", np.ndarray), *BOX_AND_LEARNER,
                                              ("prev", np.ndarray), *REFRESH])
PolygonBelief.__doc__ = """Per path: posterior mixed moments ``M (B, N+1, N+1)`` (``M[i, j] = E[x0^i x1^j]``, total
    order <= N), the reachable polygon ``verts (B, V, 2)`` (``bounding="polygon"``; a common vertex
    capacity V, padded with repeated vertices) and bounding box ``lo``/``hi (B, 2)``, the
    ``fallback (B,)`` flag, the input moments in use ``mw (B, N)``, the learner's power sums
    ``acc (B, N)`` and ``count (B,)``, the previous posterior ``prev (B, N+1, N+1)``,
    ``predicted (B,)`` (whether ``M`` is its prediction, to redo after a refresh) and the flags
    ``refreshed``/``refresh_failed (B,)`` of this step's refresh (:data:`~nlfilter.filters.moment_bayes.INVALID_MOMENTS`)."""


def _merge(paths, new, old):
    """``where_paths`` for polygon beliefs whose vertex capacities differ."""
    cap = max(new.verts.shape[-2], old.verts.shape[-2])
    return where_paths(paths, new._replace(verts=pad_polygons(new.verts, cap)),
                       old._replace(verts=pad_polygons(old.verts, cap)))


def _monomial_index(N):
    """Exponent pairs (i, j) with i + j <= N, and a mask on the (N+1, N+1) array."""
    mask = np.add.outer(np.arange(N + 1), np.arange(N + 1)) <= N
    return mask


def moment_map_tensor(A, b, N: int) -> np.ndarray:
    """``C[i, j, p, q, r]``: ``E[y0^i y1^j] = sum C[i,j,p,q,r] E[x0^p x1^q] E[w^r]`` for ``y = A x + b w``.

    Built once per filter (multinomial expansion of ``(A00 x0 + A01 x1 + b0 w)^i (A10 x0 + A11 x1 + b1 w)^j``).
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)

    def powers(a0, a1, bw):
        out = [np.zeros((N + 1, N + 1, N + 1))]
        out[0][0, 0, 0] = 1.0
        for _ in range(N):
            prev = out[-1]
            nxt = np.zeros_like(prev)
            nxt[1:, :, :] += a0 * prev[:-1, :, :]
            nxt[:, 1:, :] += a1 * prev[:, :-1, :]
            nxt[:, :, 1:] += bw * prev[:, :, :-1]
            out.append(nxt)
        return out

    P0 = powers(A[0, 0], A[0, 1], b[0])
    P1 = powers(A[1, 0], A[1, 1], b[1])
    C = np.zeros((N + 1,) * 5)
    for i in range(N + 1):
        for j in range(N + 1 - i):
            a, c = P0[i], P1[j]
            for p, q, r in zip(*np.nonzero(a)):
                sub = c[: N + 1 - p, : N + 1 - q, : N + 1 - r]
                C[i, j, p:p + sub.shape[0], q:q + sub.shape[1], r:r + sub.shape[2]] += a[p, q, r] * sub
    return C


def linear_map_moments(M, A, b, mw, C=None) -> np.ndarray:
    """Mixed moments of ``A x + b w`` (x independent of the scalar w), total order <= N.

    ``M[..., i, j] = E[x0^i x1^j]`` (M[0,0] = 1), ``A`` (2, 2), ``b`` (2,), ``mw`` (..., N) moments of w.
    Exact (eq. 3.13 in two dimensions).  ``C`` = :func:`moment_map_tensor` if precomputed.
    """
    M = np.asarray(M, dtype=float)
    N = M.shape[-1] - 1
    C = moment_map_tensor(A, b, N) if C is None else C
    mw = np.concatenate([np.ones((*np.shape(mw)[:-1], 1)), np.asarray(mw, dtype=float)], axis=-1)
    return np.einsum("ijpqr,...pq,...r->...ij", C, M, mw)


class SecondOrderMomentFilter(MomentFilter):
    """Moment Bayesian filter for ``x_{k+1} = A x_k + b w_k``, ``z_k = c.x_k + v_k`` (000 eqs. 2.6-2.8).

    ``SecondOrderMomentFilter(model, N, ...)`` with a 2-state
    :class:`~nlfilter.bounded.BoundedNoiseModel` (or the raw ``(A, b, c, w_bound, N, ...)``).
    000 writes the second-order system in modal form ``A = diag(h1, h2)``, ``b = c = (d1, d2)``
    (eqs. 2.6-2.7 as the OCR reads them); any stable 2x2 ``A`` works here. See the module
    docstring for the derivation.

    ``run(ys)``, ``ys (..., T, 1)``: ``means (..., T, 2)`` the posterior means, ``covs`` the posterior
    covariances from the second moments (NaN when N = 1: none carried); ``extras``: ``fallback``,
    ``lower``/``upper (..., T, 2)`` the posterior's bounding box and, adaptive, ``w_moments`` and
    the refresh flags ``refreshed``/``refresh_failed (..., T)``. ``invalid_moments`` as in
    :class:`~nlfilter.filters.moment_bayes.FirstOrderMomentFilter` (default "warn").
    A missing measurement: predict only, nothing learnt.

    >>> import numpy as np
    >>> from nlfilter.bounded import BoundedNoiseModel
    >>> from nlfilter.moments.densities import uniform_moments
    >>> md = BoundedNoiseModel(np.diag([0.6, -0.5]), [1.0, 1.0], [1.0, 1.0], 1.0)
    >>> SecondOrderMomentFilter(md, 2, w_moments=uniform_moments(2)).run(np.array([[0.3], [-0.2], [0.9]])).means.shape
    (3, 2)
    """

    name = "second-order-moment"
    source = "seed 000 eqs. 2.6-2.8, 2.27-2.29, 3.3, 3.13-3.16 (two-dimensional form derived here)"
    n = 2

    def __init__(self, model, *args, w_moments=None, adaptive: bool = False,
                 initial_w_moments=None, n0: float = 100.0, window: int = 20, noise_halfwidth: float | None = None,
                 eps: float = 1e-9, outside: str = "raise", bounding: str = "polygon", directions: int = 16,
                 invalid_moments: str = "warn"):
        self.bounding = V.choice("bounding", bounding, {"box", "polygon"})
        model, rest = _raw_model(model, args, 2)
        if model.n != 2:
            raise ValueError(f"A: expected shape (2, 2), got {model.A.shape}")
        if len(rest) != 1:
            raise TypeError(f"N: expected SecondOrderMomentFilter(model, N, ...), got {len(rest)} positional N")
        self.model = model
        self.A, self.b, self.cv = model.A, model.b, model.c
        if not np.max(np.abs(np.linalg.eigvals(self.A))) < 1:
            raise ValueError(f"A: expected a stable matrix (spectral radius < 1), got {self.A.tolist()}")
        if self.cv[1] == 0:
            raise ValueError("c: expected c[1] != 0 (swap the states otherwise)")
        configure_input(self, model.w_bound, rest[0], w_moments, adaptive, initial_w_moments, n0, window,
                        model.noise_halfwidth if noise_halfwidth is None else noise_halfwidth, eps, outside,
                        invalid_moments)
        self._powers = np.arange(1, self.N + 1)
        # stationary bounding box and impulse response g_j = c^T A^j b
        Ab = [self.b]
        for _ in range(50000):
            Ab.append(self.A @ Ab[-1])
            if np.max(np.abs(Ab[-1])) < 1e-17:
                break
        Ab = np.array(Ab)
        self.bound = self.wb * np.sum(np.abs(Ab), axis=0)
        self.S = impulse_power_sums(Ab @ self.cv, self.N)
        self.z_bound = self.wb * float(np.sum(np.abs(Ab @ self.cv))) + self.c  # largest possible |z|
        self._K = self.N + 2  # Gauss-Legendre nodes per direction: exact for the degree-2N integrands
        self._gl = np.polynomial.legendre.leggauss(self._K)
        self._mask = _monomial_index(self.N)
        self._C = moment_map_tensor(self.A, self.b, self.N)
        # template directions for the polygon bound: evenly spaced, plus the measurement's +-c
        m = int(V.positive("directions", directions, integer=True))
        ang = 2 * np.pi * np.arange(m) / m
        cn = self.cv / np.linalg.norm(self.cv)
        self.D = np.concatenate([np.stack([np.cos(ang), np.sin(ang)], axis=-1), cn[None], -cn[None]])
        self.beta_stat = self.wb * np.sum(np.abs(Ab @ self.D.T), axis=0)  # support of the stationary set
        self._DAb = np.abs(self.D @ self.b) * self.wb
        tt, ww = np.polynomial.legendre.leggauss(self.N + 2)
        self._tri = (0.5 * (tt + 1), 0.5 * ww)

    # -- building blocks --------------------------------------------------------------------
    def stationary(self, mw, steps: int | None = None):
        """Stationary mixed moments and box, by iterating the exact prediction from x = 0
        (``steps`` default: until the spectral radius^steps < 1e-15)."""
        if steps is None:
            rho = float(np.max(np.abs(np.linalg.eigvals(self.A))))
            steps = 1 if rho == 0 else int(min(50000, np.ceil(np.log(1e-15) / np.log(rho)) + 1))
        M = np.zeros((*np.shape(mw)[:-1], self.N + 1, self.N + 1))
        M[..., 0, 0] = 1.0
        for _ in range(steps):
            M = linear_map_moments(M, self.A, self.b, mw, self._C)
        return M, np.broadcast_to(-self.bound, (*M.shape[:-2], 2)), np.broadcast_to(self.bound, (*M.shape[:-2], 2))

    def predict_box(self, M, lo, hi, mw):
        Mp = linear_map_moments(M, self.A, self.b, mw, self._C)
        Al = self.A * lo[..., None, :]
        Ah = self.A * hi[..., None, :]
        bw = np.abs(self.b) * self.wb
        lp = np.maximum(np.sum(np.minimum(Al, Ah), axis=-1) - bw, -self.bound)
        hp = np.minimum(np.sum(np.maximum(Al, Ah), axis=-1) + bw, self.bound)
        return Mp, lp, hp

    def _slab_nodes(self, lo, hi, s_lo, s_hi):
        """Quadrature nodes/weights on {box} ∩ {s_lo <= c.x <= s_hi}: returns x (..., Q, 2), w (..., Q),
        and the polygon's candidate vertices (..., V, 2) with a validity mask."""
        c0, c1 = self.cv
        corners = np.stack([c0 * lo[..., 0] + c1 * lo[..., 1], c0 * lo[..., 0] + c1 * hi[..., 1],
                            c0 * hi[..., 0] + c1 * lo[..., 1], c0 * hi[..., 0] + c1 * hi[..., 1]], axis=-1)
        a = np.maximum(s_lo, corners.min(axis=-1))
        bnd = np.minimum(s_hi, corners.max(axis=-1))
        bps = np.sort(np.concatenate([corners, a[..., None], bnd[..., None]], axis=-1), axis=-1)
        bps = np.clip(bps, a[..., None], np.maximum(a, bnd)[..., None])  # (..., 6)
        t, w = self._gl
        sa, sb = bps[..., :-1, None], bps[..., 1:, None]  # (..., 5, 1)
        s = 0.5 * (sa + sb) + 0.5 * (sb - sa) * t  # (..., 5, K)
        ws = 0.5 * (sb - sa) * w

        def x0_range(s):
            e1 = s - c1 * lo[..., None, None, 1]
            e2 = s - c1 * hi[..., None, None, 1]
            if c0 != 0:
                r1, r2 = e1 / c0, e2 / c0
                l0 = np.maximum(lo[..., None, None, 0], np.minimum(r1, r2))
                u0 = np.minimum(hi[..., None, None, 0], np.maximum(r1, r2))
            else:
                l0 = np.broadcast_to(lo[..., None, None, 0], s.shape)
                u0 = np.broadcast_to(hi[..., None, None, 0], s.shape)
            return l0, np.maximum(u0, l0)

        l0, u0 = x0_range(s)  # (..., 5, K)
        x0 = 0.5 * (l0 + u0)[..., None] + 0.5 * (u0 - l0)[..., None] * t  # (..., 5, K, K)
        wx = 0.5 * (u0 - l0)[..., None] * w
        x1 = (s[..., None] - c0 * x0) / c1
        W = (ws[..., None] * wx) / abs(c1)
        shp = W.shape[:-3] + (-1,)
        X = np.stack([x0.reshape(shp), x1.reshape(shp)], axis=-1)
        # polygon vertices: the x0-range ends at every breakpoint
        vb = bps[..., None, :]
        vl0, vu0 = x0_range(vb)
        vl0, vu0 = vl0[..., 0, :], vu0[..., 0, :]
        vx0 = np.concatenate([vl0, vu0], axis=-1)
        vs = np.concatenate([bps, bps], axis=-1)
        verts = np.stack([vx0, (vs - c0 * vx0) / c1], axis=-1)
        return X, W.reshape(shp), verts, bnd >= a

    def update_box(self, M, lo, hi, z):
        z = np.asarray(z, dtype=float)
        X, W, verts, ok = self._slab_nodes(lo, hi, z - self.c, z + self.c)
        if np.any(~ok):
            if self.outside == "raise":
                i = tuple(int(j) for j in np.argwhere(~ok)[0])
                raise ValueError(f"ys: measurement {float(z[i] if z.ndim else z)!r} (path {i}) is inconsistent "
                                 f"with the reachable box and |v| <= {self.c}")
            # clip: use the nearest reachable value of c.x as the measurement
            c0, c1 = self.cv
            corners = np.stack([c0 * lo[..., 0] + c1 * lo[..., 1], c0 * hi[..., 0] + c1 * hi[..., 1],
                                c0 * lo[..., 0] + c1 * hi[..., 1], c0 * hi[..., 0] + c1 * lo[..., 1]], axis=-1)
            zc = np.clip(z, corners.min(-1) - self.c, corners.max(-1) + self.c)
            X, W, verts, ok = self._slab_nodes(lo, hi, zc - self.c, zc + self.c)
        d = LegendreDensity2D.from_moments(M, lo, hi)
        p = d.pdf(X) if X.ndim == 2 else pdf_batched_2d(d, X)
        N = self.N
        e = np.arange(N + 1)
        P0 = X[..., 0, None] ** e  # (..., Q, N+1)
        P1 = X[..., 1, None] ** e
        I = np.einsum("...q,...qi,...qj->...ij", W * p, P0, P1)
        U = np.einsum("...q,...qi,...qj->...ij", W, P0, P1)  # uniform on the polygon (fallback)
        with np.errstate(divide="ignore", invalid="ignore"):
            post = I / I[..., :1, :1]
            uni = U / U[..., :1, :1]
        # new bounding box of the polygon box ∩ slab
        nlo = np.min(verts, axis=-2)
        nhi = np.max(verts, axis=-2)
        mean = np.stack([post[..., 1, 0], post[..., 0, 1]], axis=-1)
        fb = (~(I[..., 0, 0] >= self.eps) | ~np.all((mean >= nlo) & (mean <= nhi), axis=-1)
              | ~np.all(np.isfinite(post[..., self._mask]), axis=-1) | _not_psd(post))
        area = U[..., 0, 0]
        tiny = ~(area > 1e-14 * np.prod(self.bound))
        post = np.where(fb[..., None, None], uni, post)
        # a degenerate polygon (zero area): point mass at the centre of its vertices
        cen = 0.5 * (nlo + nhi)
        pt = cen[..., 0, None, None] ** e[:, None] * cen[..., 1, None, None] ** e[None, :]
        post = np.where(tiny[..., None, None], pt, post)
        post = np.where(self._mask, post, 0.0)
        width = np.maximum(nhi - nlo, 1e-9 * (1 + self.bound))
        nhi = nlo + width
        return post, nlo, nhi, fb & ~tiny

    # -- polygon (template) bound ------------------------------------------------------------
    def _polygon(self, beta):
        """Vertices of {x : D x <= beta} (clipping the stationary box), (..., P, 2), CCW."""
        B = self.bound
        box = np.array([[-B[0], -B[1]], [B[0], -B[1]], [B[0], B[1]], [-B[0], B[1]]])
        P = np.broadcast_to(box, (*beta.shape[:-1], 4, 2))
        for j in range(self.D.shape[0]):
            P = clip_halfplane(P, self.D[j], beta[..., j])
            if P.shape[-2] > 8:
                P = trim_polygon(P)
        return trim_polygon(P)

    def predict_polygon(self, M, verts, mw):
        """Exact moments of A x + b w; template bound: support of A P (+) b [-w_b, w_b] on D."""
        Mp = linear_map_moments(M, self.A, self.b, mw, self._C)
        AV = verts @ self.A.T
        beta = np.max(np.einsum("jk,...pk->...pj", self.D, AV), axis=-2) + self._DAb
        beta = np.minimum(beta, self.beta_stat)
        P = self._polygon(beta)
        return Mp, P

    def update_polygon(self, M, verts, z):
        z = np.asarray(z, dtype=float)
        cn = self.cv / np.linalg.norm(self.cv)
        scale = 1.0 / np.linalg.norm(self.cv)
        lo_b = np.min(verts, axis=-2)
        hi_b = np.max(verts, axis=-2)
        Q = clip_halfplane(verts, cn, (z + self.c) * scale)
        Q = trim_polygon(clip_halfplane(Q, -cn, -(z - self.c) * scale))
        X, W = polygon_quadrature(Q, *self._tri)
        area = W.sum(-1)
        tiny = ~(area > 1e-12 * np.prod(self.bound))
        if np.any(tiny):
            # measurement (nearly) inconsistent with the reachable polygon
            proj = np.einsum("k,...pk->...p", self.cv, verts)
            gap = np.maximum(proj.min(-1) - (z + self.c), (z - self.c) - proj.max(-1))
            bad = gap > 1e-9 * (1 + np.max(self.bound))
            if np.any(bad) and self.outside == "raise":
                i = tuple(int(j) for j in np.argwhere(bad)[0])
                raise ValueError(f"ys: measurement {float(z[i] if z.ndim else z)!r} (path {i}) is inconsistent "
                                 f"with the reachable polygon and |v| <= {self.c}")
        d = LegendreDensity2D.from_moments(M, lo_b, np.maximum(hi_b, lo_b + 1e-12))
        p = pdf_batched_2d(d, X) if X.ndim > 2 else d.pdf(X)
        e = np.arange(self.N + 1)
        P0 = X[..., 0, None] ** e
        P1 = X[..., 1, None] ** e
        I = np.einsum("...q,...qi,...qj->...ij", W * p, P0, P1)
        U = np.einsum("...q,...qi,...qj->...ij", W, P0, P1)
        with np.errstate(divide="ignore", invalid="ignore"):
            post = I / I[..., :1, :1]
            uni = U / U[..., :1, :1]
        nlo, nhi = np.min(Q, axis=-2), np.max(Q, axis=-2)
        mean = np.stack([post[..., 1, 0], post[..., 0, 1]], axis=-1)
        fb = (~(I[..., 0, 0] >= self.eps) | ~np.all((mean >= nlo) & (mean <= nhi), axis=-1)
              | ~np.all(np.isfinite(post[..., self._mask]), axis=-1) | _not_psd(post))
        post = np.where(fb[..., None, None], uni, post)
        # degenerate / inconsistent (clip mode): point mass at the polygon point nearest the slab
        proj = np.einsum("k,...pk->...p", self.cv, verts)
        near = np.take_along_axis(verts, np.argmin(np.abs(proj - z[..., None]), axis=-1)[..., None, None], axis=-2)[..., 0, :]
        pt = near[..., 0, None, None] ** e[:, None] * near[..., 1, None, None] ** e[None, :]
        post = np.where(tiny[..., None, None], pt, post)
        Q = np.where(tiny[..., None, None], near[..., None, :], Q)
        post = np.where(self._mask, post, 0.0)
        return post, Q, np.min(Q, axis=-2), np.max(Q, axis=-2), fb & ~tiny

    # -- the protocol --------------------------------------------------------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None):
        self._no_prior(m0, P0, initial)
        B = math.prod(batch)
        M, lo, hi = self.stationary(self.w_moments if not self.adaptive else self.initial_w_moments)
        M = np.broadcast_to(M, (B, self.N + 1, self.N + 1)).copy()
        mw = np.broadcast_to(self.w_moments if not self.adaptive else self.initial_w_moments, (B, self.N)).copy()
        if self.bounding == "polygon":
            verts = self._polygon(np.broadcast_to(self.beta_stat, (B, self.D.shape[0])))
        else:
            verts = np.zeros((B, 1, 2))
        no = np.zeros(B, bool)
        return PolygonBelief(M, verts, np.broadcast_to(lo, (B, 2)).copy(), np.broadcast_to(hi, (B, 2)).copy(),
                             no, mw, np.zeros((B, self.N)), np.zeros(B, int), np.zeros_like(M), no.copy(), no.copy(),
                             no.copy())

    def predict(self, belief, k):
        B = belief.M.shape[0]
        if self.bounding == "box":
            M, lo, hi = self.predict_box(belief.M, belief.lo, belief.hi, belief.mw)
            verts = belief.verts
        else:
            M, verts = self.predict_polygon(belief.M, belief.verts, belief.mw)
            lo, hi = belief.lo, belief.hi
        no = np.zeros(B, bool)
        return belief._replace(M=M, verts=verts, lo=lo, hi=hi, fallback=no, prev=belief.M,
                               predicted=np.ones(B, bool), refreshed=no, refresh_failed=no)

    def update(self, belief, y, k):
        z, obs = observed(y)
        if not obs.all():  # a consistent value on missing paths: c.x at a point of the reachable set
            inner = (np.mean(belief.verts, axis=-2) if self.bounding == "polygon"
                     else 0.5 * (belief.lo + belief.hi))
            z = np.where(obs, z, inner @ self.cv)
        M = belief.M
        mw, acc, count, redo, refreshed, failed = self._refresh_input(belief, z, obs)
        if redo is not None:
            M = np.where(redo[:, None, None], linear_map_moments(belief.prev, self.A, self.b, mw, self._C), M)
        if self.bounding == "box":
            post, lo, hi, fb = self.update_box(M, belief.lo, belief.hi, z)
            verts = belief.verts
        else:
            post, verts, lo, hi, fb = self.update_polygon(M, belief.verts, z)
        new = PolygonBelief(post, verts, lo, hi, fb, mw, acc, count, belief.prev, np.zeros_like(belief.predicted),
                            refreshed, failed)
        return new if obs.all() else _merge(obs, new, belief)

    def reset(self, belief, paths, start):
        return _merge(paths, start, belief)

    def summary(self, belief):
        M = belief.M
        mean = np.stack([M[:, 1, 0], M[:, 0, 1]], axis=-1)
        if self.N < 2:
            return mean, None
        c01 = M[:, 1, 1] - M[:, 1, 0] * M[:, 0, 1]
        cov = np.empty((M.shape[0], 2, 2))
        cov[:, 0, 0] = M[:, 2, 0] - M[:, 1, 0] ** 2
        cov[:, 1, 1] = M[:, 0, 2] - M[:, 0, 1] ** 2
        cov[:, 0, 1] = cov[:, 1, 0] = c01
        return mean, cov

    def extras(self, belief):
        return {"fallback": belief.fallback, "lower": belief.lo, "upper": belief.hi, **self._learner_extras(belief)}


def _not_psd(post):
    """Boolean ``(...)``: mixed moments ``post (..., N+1, N+1)`` (N ≥ 2) whose covariance is not
    positive semi-definite (False for N < 2: no second moments)."""
    if post.shape[-1] < 3:
        return np.zeros(post.shape[:-2], bool)
    m0, m1 = post[..., 1, 0], post[..., 0, 1]
    v0, v1 = post[..., 2, 0] - m0 * m0, post[..., 0, 2] - m1 * m1
    c = post[..., 1, 1] - m0 * m1
    return ~((v0 >= 0) & (v1 >= 0) & (v0 * v1 >= c * c))


