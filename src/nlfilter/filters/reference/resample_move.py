"""Resample-move particle filter for deterministic continuous dynamics and discrete measurements
(see :mod:`nlfilter.filters.reference`).

With no process noise a bootstrap particle filter degenerates: resampling copies particles and
nothing spreads them again. Resample-move (Gilks & Berzuini 2001) follows each resampling by
``moves`` random-walk Metropolis–Hastings sweeps on the *initial* state ``x0`` of each particle,
whose posterior given ``y_1 .. y_k`` is known exactly,

    p(x0 | y_1..y_k) ∝ N(x0; m0, P0) · Π_j N(y_j; h(Φ_j(x0)), R),

``Φ_j`` the RK4 flow (:func:`~nlfilter.ode.ode_step`) of the drift to the j-th
measurement. The moves restore the diversity without changing the target. The proposal is
``x0' = x0 + scale · L z`` with ``L Lᵀ`` the cloud's covariance of ``x0`` (in prior-scaled units,
regularized by 1e-12); a move at step k re-integrates the proposal over k intervals, so the
belief keeps the measurements seen so far.

The belief is a :class:`ResampleMoveBelief`. The estimate of a step is the weighted mean and
covariance of the particles *before* the resample-move that ends ``update`` (stored in the
belief); after ``predict`` it is the weighted mean and covariance of the propagated particles.
Particles whose flow blows up (non-finite) get zero weight.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ... import _validate as V
from ...streams import FILTER, PathRNG
from ..base import Filter, check_structure, ode_step, set_start, set_t0
from ..checks import refuse_infinite
from ..linalg import observed_precision
from ..pointmass import cloud_moments
from .particle import systematic_resample


class ResampleMoveBelief(NamedTuple):
    """Per path: initial states ``x0 (B, Np, n)`` and current states ``x (B, Np, n)`` of the
    particles, ``cum (B, Np)`` the log-likelihood of all measurements along each particle's path,
    ``logw (B, Np)`` log-weights, ``ys (B, K, m)`` the K measurements so far, ``mean (B, n)``,
    ``cov (B, n, n)`` the estimate, ``alive (B,)`` (False: a diverged path, left alone),
    ``accepted``/``proposed (B,)`` cumulative Metropolis counts. Shared: ``ks`` (the step index of
    each stored measurement), ``prior`` ``(m0, P0⁻¹, √diag P0)``, the per-path generators ``rng``
    (a :class:`~nlfilter.streams.PathRNG`)."""

    x0: np.ndarray
    x: np.ndarray
    cum: np.ndarray
    logw: np.ndarray
    ys: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    alive: np.ndarray
    accepted: np.ndarray
    proposed: np.ndarray
    ks: tuple
    prior: tuple
    rng: PathRNG

    _shared = ("ks", "prior", "rng")


def _weighted(x, logw):
    """Weighted mean ``(B, n)`` and covariance ``(B, n, n)``; non-finite particles get weight 0."""
    fin = np.all(np.isfinite(x), axis=-1)
    logw = np.where(fin, logw, -np.inf)
    mx = logw.max(axis=1, keepdims=True)
    w = np.exp(logw - np.where(np.isfinite(mx), mx, 0.0))
    w /= w.sum(axis=1, keepdims=True)
    xz = np.where(fin[..., None], x, 0.0)
    mu = np.einsum("bp,bpi->bi", w, xz)
    d = np.where(fin[..., None], xz - mu[:, None, :], 0.0)
    return mu, np.einsum("bp,bpi,bpj->bij", w, d, d), w


class ResampleMoveParticleFilter(Filter):
    """Resample-move particle filter (module docstring) on an :class:`~nlfilter.models.SDEModel`
    **without process noise** (``Q = 0``) read as continuous-discrete: ``dx/dt = f(x, t)``,
    ``y_k = h(x(t_k)) + v_k``, ``v_k ~ N(0, R)``, ``t_k = t0 + k dt`` (``predict``/``update``, as
    :class:`~nlfilter.filters.second_order.ContinuousDiscreteSecondOrderFilter`). The prior is
    N(m0, P0), one for all paths; ``run(..., rng=)`` seeds the particles and the moves (path ``p``
    from the stream ``FILTER`` of path ``p``, :mod:`nlfilter.streams`, or a PathRNG over the paths).

    Parameters
    ----------
    model : SDEModel with Q = 0
    particles : number of particles per path
    dt : measurement interval
    substeps : RK4 steps per interval
    moves : Metropolis sweeps after each resampling
    scale : proposal scale
    threshold : resample when ESS < threshold · particles
    start : ``"predict"`` (default: ``ys[..., 0, :]`` at ``t0 + dt``) or ``"update"`` (at ``t0``); None: the
        default, or a Simulation's
    t0 : float (None: 0.0, or a Simulation's)

    Notes
    -----
    ``Estimates.extras``: ``accepted``, ``proposed (..., T)`` the cumulative numbers of accepted and
    proposed moves per path (the acceptance rate is ``accepted[..., -1].sum() / proposed[..., -1].sum()``).
    """

    name = "resample-move"
    family = "reference"
    source = ("resample-move particle filter (Gilks & Berzuini 2001): bootstrap filter with exact "
              "Metropolis moves on the initial state, for noise-free continuous dynamics")
    accepts = ("sde",)
    needs = ("no process noise",)
    time = "discrete"
    random = True
    start = "predict"  # the default: the prior at t0, y_0 at t0 + dt (as simulate_continuous_discrete)

    def __init__(self, model, particles: int = 1000, *, dt: float, substeps: int = 20, moves: int = 2,
                 scale: float = 1.0, threshold: float = 0.5, start: str | None = None, t0: float | None = None):
        if getattr(model, "kind", None) != "sde":
            raise TypeError(f"model: {type(self).__name__} expects an SDEModel, got {type(model).__name__}")
        if np.any(model.Q != 0):
            raise ValueError("model: the resample-move filter assumes no process noise (Q = 0), got a nonzero Q")
        self.model = check_structure(self, model)  # angles: refused, naming them
        self.particles = V.positive("particles", particles, integer=True)
        self.dt = float(V.positive("dt", dt))
        self.substeps = V.positive("substeps", substeps, integer=True)
        self.moves = V.positive("moves", moves, integer=True, strict=False)
        self.scale = float(V.positive("scale", scale))
        self.threshold = V.real("threshold", threshold)
        if not 0.0 <= self.threshold <= 1.0:
            raise ValueError(f"threshold: expected a number in [0, 1], got {threshold!r}")
        set_start(self, start)
        set_t0(self, t0)
        self._Rinv = np.linalg.inv(model.R)

    def _time(self, k):
        return self.t0 + k * self.dt

    def _flow(self, x, k):
        return ode_step(self.model.f, x, self._time(k), self.dt, substeps=self.substeps, scheme="rk4")

    def _loglik(self, x, y, k):
        """``log N(y; h(x), R)`` up to a constant, ``(B, Np)``; −inf where ``x`` or it is not finite.
        NaN components of ``y (B, m)`` are missing (the observed marginal)."""
        obs = ~np.isnan(y)
        r = np.where(obs[:, None, :], y[:, None, :] - self.model.h(x, self._time(k)), 0.0)
        if obs.all():
            ll = -0.5 * np.einsum("bpi,ij,bpj->bp", r, self._Rinv, r)
        else:
            Rinv = observed_precision(self.model.R, self._Rinv, obs)
            ll = -0.5 * np.einsum("bpi,bij,bpj->bp", r, Rinv, r)
        return np.where(np.all(np.isfinite(x), axis=-1) & np.isfinite(ll), ll, -np.inf)

    # -- the belief functions ----------------------------------------------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None) -> ResampleMoveBelief:
        """``particles`` draws per path from N(m0, P0) (one prior for all paths, all paths from
        its own stream), equal weights, no measurement yet."""
        if initial is not None:
            raise ValueError(f"initial: {type(self).__name__} starts from a Gaussian prior (m0, P0); "
                             f"expected None, got {type(initial).__name__}")
        n, m = self.model.n, self.model.m
        if np.ndim(m0) > 1 or np.ndim(P0) > 2:
            raise ValueError(f"{'m0' if np.ndim(m0) > 1 else 'P0'}: the resample-move filter takes one prior ({n},), "
                             f"({n}, {n}) for all paths, "
                             f"got shapes {np.shape(m0)}, {np.shape(P0)}")
        m0 = V.mean("m0", m0, n)
        refuse_infinite(P0, type(self).__name__)
        P0 = V.covariance("P0", P0, n)
        if not np.linalg.eigvalsh(P0)[0] > 1e-12 * max(1.0, float(np.max(np.abs(P0)))):
            raise ValueError(f"P0: the moves need the prior density, expected a positive definite matrix, "
                             f"got {P0.tolist()}")
        D = np.sqrt(np.diag(P0))
        B, Np = int(np.prod(batch)), self.particles
        rng = PathRNG.of(rng, B, key=FILTER)
        z = rng.standard_normal((Np, n))
        if np.count_nonzero(P0 - np.diag(np.diag(P0))) == 0:
            x0 = m0 + z * D
        else:
            x0 = m0 + z @ np.linalg.cholesky(P0).T
        mean, cov, _ = _weighted(x0, np.zeros((B, Np)))
        return ResampleMoveBelief(x0, x0.copy(), np.zeros((B, Np)), np.zeros((B, Np)), np.zeros((B, 0, m)),
                                  mean, cov, np.ones(B, bool), np.zeros(B, np.int64), np.zeros(B, np.int64),
                                  (), (m0, np.linalg.inv(P0), D), rng)

    def predict(self, belief: ResampleMoveBelief, k) -> ResampleMoveBelief:
        """The particles flown (RK4) from ``t_k`` to ``t_{k+1}``; the estimate is their weighted
        mean and covariance."""
        with np.errstate(over="ignore", invalid="ignore"):  # blown-up trajectories get zero weight
            x = self._flow(belief.x, k)
            mean, cov, _ = _weighted(x, belief.logw)
        return belief._replace(x=x, mean=mean, cov=cov)

    def update(self, belief: ResampleMoveBelief, y, k) -> ResampleMoveBelief:
        """Weight by the likelihood of ``y (B, m)`` at ``t_k``; the estimate is the weighted mean
        and covariance; then resample (systematic) the paths whose ESS < threshold · particles and
        move their particles (module docstring). Raises
        :class:`~nlfilter.errors.DivergenceError` where every particle has zero likelihood."""
        belief, bad = self._update_unchecked(belief, y, k)
        if bad is not None:
            from ...errors import DivergenceError
            idx = np.flatnonzero(bad)
            raise DivergenceError(f"{self.name}: the measurement has zero likelihood for every particle at step {k} "
                                  f"on {idx.size} path(s), first {idx[:5].tolist()}", paths=idx, what="likelihood")
        return belief

    def summary(self, belief: ResampleMoveBelief):
        """The estimate stored in the belief (module docstring)."""
        return belief.mean, belief.cov

    def reset(self, belief: ResampleMoveBelief, paths, start):
        """Diverged paths are not restarted: they stop taking part in resampling and moves (their
        outputs are NaN, flagged by the run loop)."""
        alive = belief.alive & ~paths
        return belief._replace(alive=alive, logw=np.where(alive[:, None], belief.logw, 0.0))

    def extras(self, belief: ResampleMoveBelief):
        return {"accepted": belief.accepted, "proposed": belief.proposed}

    def _update_unchecked(self, belief, y, k):
        with np.errstate(over="ignore", invalid="ignore"):
            return self._update(belief, y, k)

    def _update(self, belief, y, k):
        m0, P0inv, D = belief.prior
        rng, Np, n = belief.rng, self.particles, self.model.n
        alive = belief.alive
        ll = self._loglik(belief.x, y, k)
        x = np.where(np.isfinite(ll)[..., None], belief.x, m0)
        cum = belief.cum + ll
        logw = belief.logw + ll
        gone = ~np.any(np.isfinite(logw), axis=1) & alive
        logw = np.where((alive & ~gone)[:, None], logw, 0.0)
        w = np.exp(logw - logw.max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        mu, cov = cloud_moments(w, x)
        ys = np.concatenate([belief.ys, y[:, None, :]], axis=1)
        ks = belief.ks + (int(k),)
        x0 = belief.x0
        accepted, proposed = belief.accepted.copy(), belief.proposed.copy()
        res = (1.0 / np.sum(w**2, axis=1) < self.threshold * Np) & alive & ~gone
        if res.any():
            rows = np.flatnonzero(res)
            sub = rng.take(rows)  # the resampled paths' generators
            idx = systematic_resample(w[rows], sub)
            take = lambda a: np.take_along_axis(a[rows], idx[..., None] if a.ndim == 3 else idx, axis=1)  # noqa: E731
            z0, zk, zc = take(x0), take(x), take(cum)
            logw[rows] = 0.0

            def logprior(z):
                dz = z - m0
                return -0.5 * np.einsum("...i,ij,...j->...", dz, P0inv, dz)

            at = dict(zip(ks, range(len(ks))))
            for _ in range(self.moves):
                c = z0 - z0.mean(axis=1, keepdims=True)
                C = np.einsum("bpi,bpj->bij", c, c) / Np / np.outer(D, D)  # in prior-scaled units
                L = np.linalg.cholesky(C + 1e-12 * np.eye(n)) * D[:, None]
                prop = z0 + self.scale * sub.standard_normal(z0.shape[1:]) @ np.swapaxes(L, -1, -2)
                xt, llp = prop.copy(), np.zeros(z0.shape[:2])
                for j in range(k + 1):  # x(t_j) from x0 = x(t_0); the measurements at their steps
                    if j > 0:
                        xt = self._flow(xt, j - 1)
                    if j in at:
                        llp = llp + self._loglik(xt, ys[rows, at[j]], j)
                log_a = logprior(prop) + llp - logprior(z0) - zc
                acc = np.log(sub.random(llp.shape[1:])) < log_a
                accepted[rows] += acc.sum(axis=1)
                proposed[rows] += acc.shape[1]
                z0 = np.where(acc[..., None], prop, z0)
                zk = np.where(acc[..., None], xt, zk)
                zc = np.where(acc, llp, zc)
            x0, x, cum = x0.copy(), x.copy(), cum.copy()
            x0[rows], x[rows], cum[rows] = z0, zk, zc
        new = ResampleMoveBelief(x0, x, cum, logw, ys, mu, cov, alive, accepted, proposed, ks, belief.prior, rng)
        return new, (gone if gone.any() else None)
