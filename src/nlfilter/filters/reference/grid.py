"""Grid (point-mass) Bayesian filter for 1-D and 2-D states (see :mod:`nlfilter.filters.reference`).

The belief is a :class:`GridBelief`: one probability vector ``p (B, N)`` per path over the grid
points ``GridFilter.X (N, n)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg as sla
from scipy import sparse

from ... import _validate as V
from ...angles import angles_of, near, residual, weighted_moments
from ...noise import Gaussian
from ...sde_step import END_POINT
from ..base import gaussian_prior
from ..pointmass import apply_kernel, axis_points, moments, normalize
from ..linalg import gaussian_loglik, innovation_info, measurement_loglik, no_information, observed_precision
from ._reference_base import _ReferenceFilter
from .forward_backward import grid_ffbs, grid_smoother


EDGE_LIMIT = 0.9
"""The default ``edge_limit`` of :class:`GridFilter`: a path whose density at an outermost grid
point reaches 0.9 of its peak has left the grid (its mode is on the edge, or within half a
standard deviation of it; the experiments' grids stay below 0.1)."""


class GridBelief(NamedTuple):
    """Probability vectors ``p (B, N)`` over the grid points ``GridFilter.X (N, n)``."""

    p: np.ndarray


def _maybe_sparse(K, rel: float = 1e-13):
    """Drop entries below ``rel`` times their row's largest (their mass is far below the grid's
    own error) and return CSR when that leaves the kernel sparse: ``p @ K`` then costs the
    kernel's support, not N²."""
    K = np.where(K >= rel * K.max(axis=1, keepdims=True), K, 0.0)
    nnz = np.count_nonzero(K)
    return sparse.csr_array(K) if nnz < 0.05 * K.size else K


def _invertible(det, X, k, what):
    """Refuse, naming G, a transition whose ``what`` (determinants ``det (N,)`` at the grid points
    ``X``) is singular somewhere on the grid: the transition has no density there."""
    bad = ~(np.abs(det) > 0)
    if bad.any():
        raise ValueError(f"G: the grid filter's transition density needs {what} invertible at every grid point, "
                         f"got a singular one at x = {X[np.argmax(bad)].tolist()} (step {k}); move the grid off "
                         "it (bounds, size) or use ParticleFilter")


class GridFilter(_ReferenceFilter):
    """Point-mass Bayesian filter on a regular grid (1-D or 2-D states); see
    :mod:`nlfilter.filters.reference`. Discrete models: ``predict``/``update``; SDE models: ``step``
    (``time`` is ``"continuous"``). ``run`` takes the prior N(m0, P0) (P0 positive definite: a
    density) or any law ``initial`` with a ``logpdf``.

    Parameters
    ----------
    model : DiscreteModel or SDEModel with ``n ≤ 2``
    bounds : ``(lo, hi)`` for 1-D, or ``[(lo1, hi1), (lo2, hi2)]``
    size : points per axis (int, or one per axis)
    dt : SDE models: the measurement step
    start : discrete models: step convention (see :mod:`nlfilter.filters.base`)
    edge_limit : a path has *left the grid* when, after an update (a step for SDEs), the
        probability of one of the outermost grid points is at least ``edge_limit`` times the
        largest probability of the path's density (:meth:`edge_ratio`): the bounds cut the density
        near its mode and the mean sits at the edge. The run loop reports such a path as diverged
        (``on_divergence="raise"``: :class:`~nlfilter.errors.DivergenceError` naming the paths and
        the step, ``what="edge"``; ``"mark"``: flagged in ``Estimates.diverged``, NaN from that
        step on). Default :data:`EDGE_LIMIT` (0.9: a Gaussian cut within 0.46 standard deviations
        of its mode, or a mode on the edge as when the state is outside); None: never. A ratio,
        not a mass, so that the rule does not depend on the number of points: the mass on the
        outermost points of a density cut at its mode shrinks as the grid is refined (two of 101
        points hold 1-10 % of it), while the ratio stays near 1.

    Notes
    -----
    Measurement convention (SDEs): a density on the grid carries no path within the interval, so
    not the simulator's ``∫ h ds`` (:mod:`nlfilter.sde_step`): ``dy`` is weighed with ``h`` at the
    interval's end point, ``exp(h(x)ᵀ R⁻¹ dy − ½ dt h(x)ᵀ R⁻¹ h(x))`` at each grid point after
    the transition — first order in ``dt``: its error per interval grows with the movement of ``h``
    within the interval against the measurement noise ``√(R/dt)`` (the automatic reference of
    :func:`~nlfilter.comparison.compare` takes particles where that movement is not small,
    :func:`~nlfilter.yardstick.endpoint_error`).

    ``Estimates.extras["edge_mass"] (..., T)``: the posterior mass on the outermost grid points
    at each step (:meth:`edge_mass`): when it is not small, the bounds cut the density off (the
    automatic reference of :func:`~nlfilter.comparison.compare` widens them above 1e-3).
    """

    blas_threads = 1  # small dense products per step: one BLAS thread (base.Filter.blas_threads)
    name = "grid"
    source = ("point-mass filter (Bucy & Senne); SDEs: Kushner's Markov-chain approximation of the "
              "Fokker–Planck operator and the Kallianpur–Striebel likelihood")
    needs = ("n ≤ 2", "noise density")
    structures = ("state-dependent R", "time-varying R", "angles")
    # SDEs: a grid density carries no path, so no ∫ h ds: the increment is read with h at the
    # interval's end point after the chain's transition (the simulator's left-point sum to first order)
    measurement_convention = END_POINT

    def __init__(self, model, bounds, size=401, *, dt: float | None = None, start: str | None = None,
                 edge_limit: float | None = EDGE_LIMIT):
        if model.n > 2:
            raise ValueError(f"model: the grid filter handles n ≤ 2 states, got n = {model.n}; use ParticleFilter")
        n = model.n
        try:
            b = np.asarray(bounds, dtype=float)
        except (TypeError, ValueError):
            b = None
        b = b.reshape(n, 2) if b is not None and b.size == 2 * n else None
        if b is None or np.any(b[:, 1] <= b[:, 0]) or not np.all(np.isfinite(b)):
            raise ValueError(f"bounds: expected {'(lo, hi)' if n == 1 else '[(lo1, hi1), (lo2, hi2)]'} "
                             f"with lo < hi, got {bounds!r}")
        sizes = [size] * n if np.ndim(size) == 0 else list(np.asarray(size, dtype=object).ravel())
        if len(sizes) != n or np.ndim(size) > 1:
            raise ValueError(f"size: expected points per axis, an int or {n} of them (one per state), got {size!r}")
        for s in sizes:
            V.positive("size", s.item() if isinstance(s, np.generic) else s, integer=True)
            if s < 3:
                raise ValueError(f"size: expected at least 3 points per axis, got {size!r}")
        self._angles = angles_of(model).states  # periodic axes: the circle (−π, π] (nlfilter.angles)
        for d in self._angles:
            if not np.allclose(b[d], (-np.pi, np.pi), rtol=0, atol=1e-12):
                raise ValueError(f"bounds: state {d} is an angle, its axis the circle; expected (-pi, pi) for it, "
                                 f"got {tuple(b[d].tolist())}")
        self.axes = [(-np.pi + 2 * np.pi * np.arange(1, s + 1) / s) if d in self._angles else axis_points(lo, hi, s)
                     for d, ((lo, hi), s) in enumerate(zip(b, sizes))]  # an angle: size points in (−π, π]
        self.steps = np.array([ax[1] - ax[0] for ax in self.axes])
        mesh = np.meshgrid(*self.axes, indexing="ij")
        self.X = np.stack([g.ravel() for g in mesh], axis=-1)  # (N, n), first axis slowest
        self._setup(model, dt, start, "grid filter")
        if edge_limit is not None:
            if isinstance(edge_limit, bool) or not isinstance(edge_limit, (int, float, np.floating, np.integer)) \
                    or not 0.0 < float(edge_limit) <= 1.0:
                raise ValueError(f"edge_limit: expected a number in (0, 1] or None, got {edge_limit!r}")
            edge_limit = float(edge_limit)
        self.edge_limit = edge_limit
        self._time_varying = not getattr(model, "time_invariant", False)
        self._kernel_cache = None

    # -- transition ------------------------------------------------------------------------
    def _kernel_discrete(self, k):
        md, X = self.model, self.X
        f = md.f(X, k)  # (N, n)
        G = md.G(X, k)  # (N, n, r)
        D = residual(X[None, :, :], f[:, None, :], self._angles)  # (from i, to j, n); angles wrapped
        law = md.process_noise
        if md.r == md.n and law.has_density:
            det = np.linalg.det(G)
            _invertible(det, X, k, "G(x)")
            Ginv = np.linalg.inv(G)
            z = np.einsum("iab,ijb->ija", Ginv, D)
            logk = law.logpdf(z) - np.log(np.abs(det))[:, None]
        elif isinstance(law, Gaussian):
            C = np.einsum("iab,bc,idc->iad", G, md.Q, G)
            _invertible(np.linalg.det(C), X, k, "G(x) Q G(x)ᵀ")
            Ci = np.linalg.inv(C)
            logk = (-0.5 * np.einsum("ija,iab,ijb->ij", D, Ci, D)
                    - 0.5 * np.log(np.linalg.det(2 * np.pi * C))[:, None])
        else:
            raise ValueError("process_noise: the grid filter needs a Gaussian law, or a law with a "
                             "density and a square G")
        return _maybe_sparse(np.exp(logk) * np.prod(self.steps))

    def _kernel_sde(self, t):
        md, X, n = self.model, self.X, self.model.n
        N = X.shape[0]
        f = md.f(X, t)
        D = md.GQGT(X, t)
        if n == 2 and np.any(np.abs(D[:, 0, 1]) > 1e-12 * (np.abs(D[:, 0, 0]) + np.abs(D[:, 1, 1]) + 1e-300)):
            raise ValueError("model: the 2-D grid filter for SDEs needs a diagonal diffusion G Q Gᵀ")
        sizes = [len(a) for a in self.axes]
        idx = np.arange(N).reshape(sizes)
        rows, cols, vals = [], [], []
        for d in range(n):
            h = self.steps[d]
            diff = 0.5 * D[:, d, d] / h**2
            drift = f[:, d] / h
            up = diff + 0.5 * drift
            down = diff - 0.5 * drift
            bad = (up < 0) | (down < 0)  # central differences would give a negative rate: upwind
            up = np.where(bad, diff + np.maximum(drift, 0.0), up)
            down = np.where(bad, diff + np.maximum(-drift, 0.0), down)
            last = sizes[d] if d in self._angles else sizes[d] - 1  # periodic: the last point's neighbour is the first
            src = idx.take(range(0, last), axis=d).ravel()
            dst = np.roll(idx, -1, axis=d).take(range(0, last), axis=d).ravel()
            rows += [src, dst]
            cols += [dst, src]
            vals += [up[src], down[dst]]
        rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
        L = sparse.coo_matrix((vals, (rows, cols)), shape=(N, N)).toarray()
        L[np.diag_indices(N)] = -L.sum(axis=1)
        return _maybe_sparse(sla.expm(L * self.dt))

    def _kernel(self, k):
        if self._kernel_cache is not None and not self._time_varying:
            return self._kernel_cache
        K = self._kernel_discrete(k) if self.model.kind == "discrete" else self._kernel_sde(k)
        self._kernel_cache = K
        return K

    # -- the belief functions ----------------------------------------------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None) -> GridBelief:
        """The prior on the grid for ``prod(batch)`` paths: N(m0, P0) (one prior for all paths,
        P0 positive definite) or the law ``initial`` (its ``logpdf`` at the grid points)."""
        if initial is not None:
            if not callable(getattr(initial, "logpdf", None)):
                raise TypeError(f"initial: expected a law with a logpdf, got {type(initial).__name__}")
            logp = initial.logpdf(self.X)
        else:
            prior = gaussian_prior(m0, P0, self.model.n, (), one=True, who=type(self).__name__)
            m0, P0 = prior.mean[0], prior.cov[0]
            law = Gaussian(P0)
            if law._singular:  # the test of Gaussian.logpdf, named here
                raise ValueError(f"P0: the grid filter needs a prior density (positive definite P0: smallest "
                                 f"eigenvalue > 1e-14 · max(1, largest)), got smallest eigenvalue "
                                 f"{np.linalg.eigvalsh(P0)[0]:.3g}; pass initial= for another law")
            logp = law.logpdf(residual(self.X, m0, self._angles))
        p = np.exp(logp - np.max(logp))
        if not np.isfinite(p).all() or p.sum() <= 0:
            raise ValueError("m0/P0: the prior has no mass on the grid; widen bounds")
        B = int(np.prod(batch))
        return GridBelief(np.broadcast_to(p / p.sum(), (B, self.X.shape[0])).copy())

    def predict(self, belief: GridBelief, k) -> GridBelief:
        """Discrete time: ``p⁻ ∝ p · τ(k)``, the belief of step ``k + 1``."""
        self._need("discrete", "predict")
        return GridBelief(normalize(apply_kernel(belief.p, self._kernel(k))))

    def update(self, belief: GridBelief, y, k) -> GridBelief:
        """Discrete time: ``p⁺ ∝ p · p_v(y − h(x, k))`` for ``y (B, m)`` (NaN components missing);
        raises :class:`~nlfilter.errors.DivergenceError` where ``y`` is impossible at every grid point."""
        belief, bad = self._update_unchecked(belief, y, k)
        self._raise_bad(belief, bad, f"step {k}")
        return belief

    def step(self, belief: GridBelief, dy, t) -> GridBelief:
        """SDE: ``p · expm(L dt)`` over ``[t, t + dt]``, then the likelihood of the increment ``dy (B, m)``."""
        belief, bad = self._step_unchecked(belief, dy, t)
        self._raise_bad(belief, bad, f"t = {t}")
        return belief

    def summary(self, belief: GridBelief):
        """Mean and covariance of the grid density (angular axes: circular, :mod:`nlfilter.angles`)."""
        return weighted_moments(belief.p, self.X, self._angles) if self._angles else moments(belief.p, self.X)

    def edge_mass(self, p) -> np.ndarray:
        """The probability ``(B,)`` on the grid's outermost points (any axis at its first or last
        point): mass the bounds may be cutting off. Near 0 when the bounds hold the density;
        ``compare`` checks it at every step (its reference certificate)."""
        q = p.reshape(p.shape[0], *(len(a) for a in self.axes))
        inner = q[(slice(None), *self._inner())]
        return 1.0 - inner.reshape(p.shape[0], -1).sum(axis=-1)

    def edge_ratio(self, p) -> np.ndarray:
        """``(B,)``: the largest probability of an outermost grid point over the largest
        probability of all points, for probability vectors ``p (B, N)``: 1 when the density's mode
        is on the edge, ``exp(-d²/2)`` for a Gaussian cut ``d`` standard deviations from its mode
        (``edge_limit`` in the class docstring)."""
        q = p.reshape(p.shape[0], *(len(a) for a in self.axes))
        edge = np.ones(q.shape[1:], bool)
        edge[self._inner()] = False
        if not edge.any():  # every axis periodic: no edge
            return np.zeros(p.shape[0])
        with np.errstate(divide="ignore", invalid="ignore"):
            return q[:, edge].max(axis=-1) / p.max(axis=-1)

    def _inner(self):
        """The index of the grid's inner points: all points along a periodic (angular) axis."""
        return tuple(slice(None) if d in self._angles else slice(1, -1) for d in range(len(self.axes)))

    def _left(self, p):
        """``(B,)`` the paths whose density reaches ``edge_limit`` of its peak on the edge, or None."""
        if self.edge_limit is None:
            return None
        out = self.edge_ratio(p) >= self.edge_limit
        return out if out.any() else None

    def _bad(self, p, dead):
        """The paths to report: ``dead`` (zero likelihood everywhere) or left the grid; None if none."""
        left = self._left(p)
        if left is None:
            return dead
        return left if dead is None else (dead | left)

    def _divergence_reason(self, belief, paths):
        """The run loop's message for the paths that left the grid (``edge_limit``); None for others."""
        left = self._left(belief.p)
        if left is None or not (left & paths).any():
            return None
        idx = np.flatnonzero(left & paths)
        r = self.edge_ratio(belief.p[idx])
        return (f"the posterior left the grid (bounds {self._bounds_text()}): its probability at an outermost point is "
                f"{r.min():.3g}{'' if idx.size == 1 else f'-{r.max():.3g}'} of its peak (edge_limit = {self.edge_limit:g}), "
                "the mean sits at the edge; widen bounds", "edge", idx)

    def _bounds_text(self):
        b = [f"({a[0]:g}, {a[-1]:g})" for a in self.axes]
        return b[0] if len(b) == 1 else "[" + ", ".join(b) + "]"

    def _raise_bad(self, belief, bad, where):
        """``update``/``step`` called on their own: raise for the dead paths or those that left the grid."""
        if bad is None:
            return
        why = self._divergence_reason(belief, bad)
        if why is not None:
            from ...errors import DivergenceError
            text, what, idx = why
            raise DivergenceError(f"{self.name}: {text} at {where} on {idx.size} path(s), first {idx[:5].tolist()}",
                                  paths=idx, what=what)
        self._raise_dead(bad, where)

    def extras(self, belief: GridBelief):
        """``edge_mass (B,)`` per step (:meth:`edge_mass`)."""
        return {"edge_mass": self.edge_mass(belief.p)}

    def _update_unchecked(self, belief, y, k):
        self._need("discrete", "update")
        p, bad = self._update(belief.p, y, k)
        return GridBelief(p), self._bad(p, bad)

    def _step_unchecked(self, belief, dy, t):
        self._need("continuous", "step")
        p = apply_kernel(belief.p, self._kernel(t))
        p, bad = self._update(p, dy, t + self.dt)
        return GridBelief(p), self._bad(p, bad)

    likelihood = "exact"

    def _update_info(self, belief, y, k):
        """``run(..., loglik=True)``: the update and ``log Σ_i p⁻_i p(y | x_i)``, the log-evidence of
        the step under the grid density, with the innovation ``y − Σ p⁻_i h(x_i)`` and its covariance
        ``Cov_{p⁻}[h] + R``."""
        self._need("discrete", "update")
        p, bad, info = self._update(belief.p, y, k, info=True)
        return GridBelief(p), self._bad(p, bad), info

    def _step_info(self, belief, dy, t):
        """``run(..., loglik=True)``: the step and the log-density of ``dy`` given the past,
        ``log Σ_i p⁻_i N(dy; h(x_i) dt, R dt)`` (the Kallianpur–Striebel ratio times the density of
        ``dη``), with the innovation ``dy − E[h] dt`` and its covariance ``(Cov[h] dt + R) dt``."""
        self._need("continuous", "step")
        p = apply_kernel(belief.p, self._kernel(t))
        p, bad, info = self._update(p, dy, t + self.dt, info=True)
        return GridBelief(p), self._bad(p, bad), info

    def _update(self, p, y, k, info: bool = False):
        """``(p⁺, dead paths or None)``; a dead path (zero likelihood everywhere) keeps ``p``; with
        ``info`` also the step's likelihood output (see :meth:`_update_info`)."""
        md, X = self.model, self.X
        obs = ~np.isnan(y)
        if not obs.any():
            return (p, None, no_information(*y.shape)) if info else (p, None)
        hX = md.h(X, k)  # (N, m)
        RX = None
        if md.kind == "discrete":
            resid = np.where(obs[..., None, :], residual(y[..., None, :], hX, angles_of(md).measurements), 0.0)
            if md.R_constant:
                ll = measurement_loglik(md.measurement_noise, resid, obs)
            else:  # v ~ N(0, R(x)) exactly at each point (observed components: their marginal)
                RX = md.R_of(X, k)  # (N, m, m)
                ll = gaussian_loglik(resid, RX, obs[..., None, :])
        else:
            Rinv = observed_precision(md.R, self._Rinv, obs)  # partly missing: the observed marginal
            yo = np.where(obs, y, 0.0)
            hR = np.einsum("ka,...ab->...kb", hX, Rinv)  # Rinv (m, m), or (..., m, m) if partly missing
            ll = np.einsum("...a,...ka->...k", yo, hR) - 0.5 * self.dt * np.einsum("...ka,ka->...k", hR, hX)
        with np.errstate(divide="ignore"):
            lp = np.log(p) + ll
        mx = np.max(lp, axis=-1, keepdims=True)
        dead = ~np.isfinite(mx[..., 0])
        w = np.exp(lp - np.where(np.isfinite(mx), mx, 0.0))
        s = w.sum(axis=-1, keepdims=True)
        dead |= ~(s[..., 0] > 0)
        out = np.where(dead[..., None], p, w / np.where(s > 0, s, 1.0)), (dead if dead.any() else None)
        if not info:
            return out
        with np.errstate(divide="ignore"):  # log Σ p_i exp(ll_i) / Σ p_i (a continuous step's p⁻ may lose mass)
            ll = mx[..., 0] + np.log(s[..., 0]) - np.log(p.sum(axis=-1))
        if md.kind != "discrete":  # times the density of dy under pure noise, N(dy; 0, R dt)
            ll = ll + innovation_info(y, np.zeros_like(y), md.R * self.dt)["loglik"]
        scale = 1.0 if md.kind == "discrete" else self.dt
        ang = angles_of(md).measurements
        Eh, Ch = weighted_moments(p / p.sum(axis=-1, keepdims=True), hX, ang) if ang else moments(p, hX)  # of h
        Eh = near(Eh, y / scale, ang)  # angles: the wrapped innovation
        # dy/dt: Cov[h] + R/dt, times dt² below; a state-dependent R: Cov[h] + E[R(x)]
        S = Ch * scale + (md.R if RX is None else np.einsum("...k,kij->...ij", p, RX) / p.sum(axis=-1)[..., None, None])
        ll = np.where(dead, -np.inf, np.where(obs.any(axis=-1), ll, 0.0))  # nothing measured: exactly 0
        res = innovation_info(y / scale, Eh, S / scale, scale=scale)
        res["loglik"] = ll
        return (*out, res)

    # -- the smoother ------------------------------------------------------------------------------
    smoother = "forward-backward"
    smoother_keeps = True

    def _smooth(self, est, beliefs, ys, t0):
        """The forward–backward smoother on the grid with the filter's own kernel
        (:func:`~nlfilter.filters.reference.forward_backward.grid_smoother`): exact for the grid's chain.
        Keeps every step's density: ``B × T × N`` floats (``smooth(..., chunk=)`` bounds B)."""
        if not beliefs:  # T = 0: nothing to smooth
            return est.means, est.covs
        return grid_smoother([b.p for b in beliefs], self._step_kernel(t0), self.X, angles=self._angles)

    def _step_kernel(self, t0):
        """``k ↦`` the kernel from step ``k`` to step ``k + 1`` of a run from ``t0``."""
        if self.time == "continuous":  # step k's density is at t0 + (k + 1) dt; the next step starts there
            return lambda k: self._kernel(t0 + (k + 1) * self.dt)
        offset = 0 if self.start == "update" else 1  # step k + 1 is predicted from step k at model index k + offset (base.run)
        return lambda k: self._kernel(k + offset)

    def _sample(self, beliefs, ys, t0, u):
        """Trajectory draws ``(B, d, T, n)`` by forward filtering, backward sampling on the grid
        (:func:`~nlfilter.filters.reference.forward_backward.grid_ffbs`; ``u (B, T, d)`` uniforms):
        exact draws of the grid chain's posterior, grid points (:func:`nlfilter.sample_posterior`)."""
        return grid_ffbs([b.p for b in beliefs], self._step_kernel(t0), self.X, u)
