"""The near-optimal yardsticks: a grid (point-mass) Bayesian filter for 1-D and 2-D states and a
bootstrap particle filter, both batched over Monte Carlo paths.

Every experiment reports the gap of each suboptimal filter to the MSE of one of these.

Grid filter
-----------
The conditional density is kept on a fixed grid ``x_1 .. x_N`` (a regular grid over ``bounds``,
``size`` points per axis), as a probability vector ``p`` per path.

* Discrete model: ``p⁻_j ∝ Σ_i p_i τ(x_j | x_i)`` with the transition density τ of
  ``x' = f(x) + G(x) w`` (any noise law with a density when ``G`` is square and invertible;
  Gaussian ``N(f, G Q Gᵀ)`` otherwise), then ``p⁺ ∝ p⁻ · p_v(y − h(x))``.
* SDE model: the Fokker–Planck operator is approximated by Kushner's Markov chain on the grid
  (central differences where they keep the rates positive, upwind otherwise; reflecting edges),
  its generator ``L`` exponentiated once, ``p⁻ = p · expm(L dt)``; then the Kallianpur–Striebel
  likelihood of the increment ``exp(hᵀ R⁻¹ dy − ½ hᵀ R⁻¹ h dt)`` at the grid points. In 2-D the
  diffusion ``G Q Gᵀ`` must be diagonal.

The mean and covariance of ``p`` are returned as :class:`~nlfilter.filters.base.Estimates`.
Choose ``bounds`` to cover the states with margin and ``size`` so that the grid spacing is small
against the noise: the filter is exact as the grid is refined.

Particle filter
---------------
Bootstrap filter: particles propagated through the model (Euler–Maruyama substeps for SDEs),
weighted by the measurement likelihood, resampled (systematic) when the effective sample size
falls below ``threshold · particles``. The estimate is the weighted mean/covariance before
resampling.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from scipy import sparse

from .. import _validate as V
from ..noise import Gaussian
from .base import Estimates, GaussianState, _Runner, measurement_loglik, observed_precision, screened


def _check_time_step(flt, model, dt, who):
    """SDE models need the measurement step ``dt`` (and use R⁻¹); discrete ones take none and
    need a measurement law with a density."""
    if model.kind == "sde":
        if dt is None:
            raise ValueError("dt: expected the measurement step for an SDEModel, got None")
        flt.dt = float(V.positive("dt", dt))
        flt._Rinv = np.linalg.inv(model.R)
    elif dt is not None:
        raise ValueError(f"dt: a DiscreteModel has no time step; expected None, got {dt!r}")
    elif not model.measurement_noise.has_density:
        raise ValueError(f"measurement_noise: the {who} needs a law with a density (logpdf)")


def _maybe_sparse(K, rel: float = 1e-13):
    """Drop entries below ``rel`` times their row's largest (their mass is far below the grid's
    own error) and return CSR when that leaves the kernel sparse: ``p @ K`` then costs the
    kernel's support, not N²."""
    K = np.where(K >= rel * K.max(axis=1, keepdims=True), K, 0.0)
    nnz = np.count_nonzero(K)
    return sparse.csr_array(K) if nnz < 0.05 * K.size else K


def _apply(p, K):
    """``p @ K`` for a batch ``p (..., N)`` and a dense or sparse kernel."""
    if isinstance(K, np.ndarray):
        return p @ K
    flat = p.reshape(-1, p.shape[-1])
    return np.asarray((K.T @ flat.T).T).reshape(p.shape)


def _moments(p, X):
    """Mean (..., n) and covariance (..., n, n) of probability vectors p (..., N) on points X (N, n)."""
    n = X.shape[-1]
    mean = p @ X
    second = (p @ (X[:, :, None] * X[:, None, :]).reshape(-1, n * n)).reshape(*p.shape[:-1], n, n)
    cov = second - mean[..., :, None] * mean[..., None, :]
    return mean, 0.5 * (cov + np.swapaxes(cov, -1, -2))


class GridFilter:
    """Point-mass Bayesian filter on a regular grid (1-D or 2-D states); see the module docstring.

    Parameters
    ----------
    model : DiscreteModel or SDEModel with ``n ≤ 2``
    bounds : ``(lo, hi)`` for 1-D, or ``[(lo1, hi1), (lo2, hi2)]``
    size : points per axis (int, or one per axis)
    dt : SDE models: the measurement step
    start : discrete models: step convention (see :mod:`nlfilter.filters.base`)
    """

    name = "grid"

    def __init__(self, model, bounds, size=401, *, dt: float | None = None, start: str = "update"):
        if model.n > 2:
            raise ValueError(f"model: the grid filter handles n ≤ 2 states, got n = {model.n}; use ParticleFilter")
        self.model = model
        n = model.n
        b = np.asarray(bounds, dtype=float).reshape(n, 2) if np.size(bounds) == 2 * n else None
        if b is None or np.any(b[:, 1] <= b[:, 0]) or not np.all(np.isfinite(b)):
            raise ValueError(f"bounds: expected {'(lo, hi)' if n == 1 else '[(lo1, hi1), (lo2, hi2)]'} "
                             f"with lo < hi, got {bounds!r}")
        sizes = np.broadcast_to(np.asarray(size), (n,))
        for s in sizes:
            V.positive("size", int(s), integer=True)
            if s < 3:
                raise ValueError(f"size: expected at least 3 points per axis, got {size!r}")
        self.axes = [np.linspace(lo, hi, int(s)) for (lo, hi), s in zip(b, sizes)]
        self.steps = np.array([ax[1] - ax[0] for ax in self.axes])
        mesh = np.meshgrid(*self.axes, indexing="ij")
        self.X = np.stack([g.ravel() for g in mesh], axis=-1)  # (N, n), first axis slowest
        self.start = V.choice("start", start, {"update", "predict"})
        _check_time_step(self, model, dt, "grid filter")
        self._time_varying = not getattr(model, "time_invariant", False)
        self._kernel_cache = None

    # -- transition ------------------------------------------------------------------------
    def _kernel_discrete(self, k):
        md, X = self.model, self.X
        f = md.f(X, k)  # (N, n)
        G = md.G(X, k)  # (N, n, r)
        D = X[None, :, :] - f[:, None, :]  # (from i, to j, n)
        law = md.process_noise
        if md.r == md.n and law.has_density:
            Ginv = np.linalg.inv(G)
            z = np.einsum("iab,ijb->ija", Ginv, D)
            logk = law.logpdf(z) - np.log(np.abs(np.linalg.det(G)))[:, None]
        elif isinstance(law, Gaussian):
            C = np.einsum("iab,bc,idc->iad", G, md.Q, G)
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
            src = idx.take(range(0, sizes[d] - 1), axis=d).ravel()
            dst = idx.take(range(1, sizes[d]), axis=d).ravel()
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

    # -- prior, update ---------------------------------------------------------------------
    def prior(self, m0, P0, batch, initial=None):
        if initial is not None:
            logp = initial.logpdf(self.X)
        else:
            if m0 is None or P0 is None:
                raise ValueError("m0/P0: expected the prior mean and covariance (or initial), got None")
            n = self.model.n
            m0 = V.as_float_array("m0", m0, ndim=1, shape_tail=(n,)) if np.ndim(m0) else np.full(n, float(m0))
            V.finite("m0", m0)
            P0 = V.covariance("P0", P0, n)
            if not np.linalg.eigvalsh(P0)[0] > 0:
                raise ValueError("P0: the grid filter needs a prior density (positive definite P0), got a "
                                 "singular covariance; pass initial= for another law")
            logp = Gaussian(P0).logpdf(self.X - m0)
        p = np.exp(logp - np.max(logp))
        if not np.isfinite(p).all() or p.sum() <= 0:
            raise ValueError("m0/P0: the prior has no mass on the grid; widen bounds")
        return np.broadcast_to(p / p.sum(), (*batch, self.X.shape[0])).copy()

    def _update(self, p, y, k):
        md, X = self.model, self.X
        obs = ~np.isnan(y)
        if not obs.any():
            return p, np.zeros(p.shape[:-1], dtype=bool)
        hX = md.h(X, k)  # (N, m)
        if md.kind == "discrete":
            resid = np.where(obs[..., None, :], y[..., None, :] - hX, 0.0)
            ll = measurement_loglik(md.measurement_noise, resid, obs)
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
        return np.where(dead[..., None], p, w / np.where(s > 0, s, 1.0)), dead

    @screened
    def run(self, ys, m0=None, P0=None, *, initial=None, on_divergence: str = "raise",
            progress: bool = False) -> Estimates:
        """Filter ``ys (..., T, m)`` (increments for SDEs) from N(m0, P0) or the law ``initial``.

        A measurement impossible under every grid point (zero likelihood, e.g. bounded noise
        and a too-narrow grid) is a divergence of that path."""
        md = self.model
        ys = V.as_float_array("ys", ys, ndim_min=2, shape_tail=(None, md.m))
        V.finite("ys", ys, allow_nan=True)  # NaN: missing
        batch, T = ys.shape[:-2], ys.shape[-2]
        p = self.prior(m0, P0, batch, initial)
        out = _Runner(batch, T, md.n, on_divergence, self.name)
        init_p = p.copy()
        offset = 0 if (md.kind == "sde" or self.start == "update") else 1
        from tqdm.auto import tqdm
        for k in tqdm(range(T), disable=not progress, desc="grid", leave=False):
            if md.kind == "sde":
                p = _apply(p, self._kernel(k * self.dt))
                p, dead = self._update(p, ys[..., k, :], (k + 1) * self.dt)
            else:
                if k > 0 or offset:
                    p = _apply(p, self._kernel(k + offset - 1))
                    p = p / p.sum(axis=-1, keepdims=True)
                p, dead = self._update(p, ys[..., k, :], k + offset)
            mean, cov = _moments(p, self.X)
            if dead.any():
                mean = np.where(dead[..., None], np.nan, mean)
            out.record(k, GaussianState(mean, cov), GaussianState(mean * 0, cov * 0 + np.eye(md.n)))
            if out.diverged.any():
                p = np.where(out.diverged[..., None], init_p, p)
        return out.result()


class ParticleFilter:
    """Bootstrap particle filter, batched over paths; see the module docstring.

    Parameters
    ----------
    model : DiscreteModel or SDEModel
    particles : number of particles per path
    dt, substeps : SDE models: measurement step and Euler–Maruyama steps per measurement step
    threshold : resample when ESS < threshold · particles
    start : discrete models: step convention
    """

    name = "particle"

    def __init__(self, model, particles: int = 2000, *, dt: float | None = None, substeps: int = 5,
                 threshold: float = 0.5, start: str = "update"):
        self.model = model
        self.particles = V.positive("particles", particles, integer=True)
        self.threshold = float(threshold)
        if not 0.0 <= self.threshold <= 1.0:
            raise ValueError(f"threshold: expected a number in [0, 1], got {threshold!r}")
        self.start = V.choice("start", start, {"update", "predict"})
        self.substeps = V.positive("substeps", substeps, integer=True)
        _check_time_step(self, model, dt, "particle filter")

    def _propagate(self, x, k, rng):
        md = self.model
        if md.kind == "discrete":
            w = md.process_noise.sample(rng, x.shape[:-1])
            return md.f(x, k) + md.Gw(x, w, k)
        h = self.dt / self.substeps
        L = md.process_noise._sqrt
        for j in range(self.substeps):
            s = k * self.dt + j * h
            dB = rng.standard_normal((*x.shape[:-1], md.r)) @ L.T * np.sqrt(h)
            x = x + md.f(x, s) * h + md.Gw(x, dB, s)
        return x

    def _loglik(self, x, y, k):
        md = self.model
        obs = ~np.isnan(y)
        if md.kind == "discrete":
            resid = np.where(obs[..., None, :], y[..., None, :] - md.h(x, k), 0.0)
            return measurement_loglik(md.measurement_noise, resid, obs)
        hx = md.h(x, k)
        Rinv = observed_precision(md.R, self._Rinv, obs)  # partly missing: the observed marginal
        hR = np.einsum("...pa,...ab->...pb", hx, Rinv)
        yo = np.where(obs, y, 0.0)
        return np.einsum("...a,...pa->...p", yo, hR) - 0.5 * self.dt * np.einsum("...pa,...pa->...p", hR, hx)

    @staticmethod
    def _systematic(w, rng):
        """Systematic resampling of each row of ``w (B, Np)`` (normalized): indices (B, Np)."""
        B, Np = w.shape
        c = np.cumsum(w, axis=1)
        c[:, -1] = 1.0
        u = (rng.random((B, 1)) + np.arange(Np)) / Np
        off = np.arange(B)[:, None]
        idx = np.searchsorted((c + off).ravel(), (u + off).ravel(), side="right")
        return np.minimum(idx.reshape(B, Np) - off * Np, Np - 1)

    @screened
    def run(self, ys, m0=None, P0=None, *, rng=None, initial=None, on_divergence: str = "raise",
            progress: bool = False) -> Estimates:
        """Filter ``ys (..., T, m)`` from N(m0, P0) or the law ``initial``; ``rng`` seeds the
        particles (a Generator or seed)."""
        from ..simulate import initial_states
        md = self.model
        rng = V.rng(rng)
        ys = V.as_float_array("ys", ys, ndim_min=2, shape_tail=(None, md.m))
        V.finite("ys", ys, allow_nan=True)  # NaN: missing
        batch, T = ys.shape[:-2], ys.shape[-2]
        B, Np = int(np.prod(batch)), self.particles
        if initial is None and np.ndim(m0) > 1:
            raise ValueError(f"m0: the particle filter takes one prior mean ({md.n},) for all paths, "
                             f"got shape {np.shape(m0)}")
        yf = ys.reshape(B, T, md.m)
        x = initial_states(md.n, B * Np, rng, m0=m0, P0=P0, initial=initial).reshape(B, Np, md.n)
        logw = np.zeros((B, Np))
        out = _Runner((B,), T, md.n, on_divergence, self.name)
        offset = 0 if (md.kind == "sde" or self.start == "update") else 1
        from tqdm.auto import tqdm
        for k in tqdm(range(T), disable=not progress, desc="particles", leave=False):
            if md.kind == "sde":
                x = self._propagate(x, k, rng)
                tk = (k + 1) * self.dt
            else:
                if k > 0 or offset:
                    x = self._propagate(x, k + offset - 1, rng)
                tk = k + offset
            if not np.all(np.isnan(yf[:, k])):
                logw = logw + self._loglik(x, yf[:, k], tk)
            mx = logw.max(axis=1, keepdims=True)
            dead = ~np.isfinite(mx[:, 0])
            w = np.exp(logw - np.where(np.isfinite(mx), mx, 0.0))
            w /= w.sum(axis=1, keepdims=True)
            w = np.where(dead[:, None], 1.0 / Np, w)
            mean = np.einsum("bp,bpi->bi", w, x)
            d = x - mean[:, None, :]
            cov = np.einsum("bp,bpi,bpj->bij", w, d, d)
            mean = np.where(dead[:, None], np.nan, mean)
            out.record(k, GaussianState(mean, cov), GaussianState(np.zeros(md.n), np.eye(md.n)))
            ess = 1.0 / np.sum(w**2, axis=1)
            rs = ess < self.threshold * Np
            if rs.any():
                idx = self._systematic(w[rs], rng)
                x[rs] = np.take_along_axis(x[rs], idx[..., None], axis=1)
                logw[rs] = 0.0
            logw = np.where(dead[:, None] | out.diverged[:, None], 0.0, logw)
        res = out.result()
        return Estimates(res.means.reshape(*batch, T, md.n), res.covs.reshape(*batch, T, md.n, md.n),
                         res.diverged.reshape(batch), res.diverged_step.reshape(batch))
