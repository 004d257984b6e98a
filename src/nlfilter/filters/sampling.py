"""Posterior trajectory samples: draws of the whole state path ``x_0..x_{T-1}`` given all the
measurements, by forward filtering, backward sampling (Carter & Kohn 1994; Frühwirth-Schnatter
1994; Särkkä 2013, *Bayesian Filtering and Smoothing*, §8.3 for the Gaussian form).

The forward pass is the filter's own run (its filtered moments ``m_k, P_k``); the backward pass
draws, from the last step down, with the same rule-based prediction as the Rauch–Tung–Striebel
smoother (:func:`~nlfilter.filters.smoothing.rts`: ``m⁻_{k+1}``, ``P⁻_{k+1}``,
``D_{k+1} = Cov[x_k, x_{k+1} | y_0..y_k]``, ``G_k = D_{k+1} (P⁻_{k+1})⁻¹``)::

    x_{T-1} ~ N(m_{T-1}, P_{T-1})
    x_k | x_{k+1} ~ N(m_k + G_k (x_{k+1} − m⁻_{k+1}),  P_k − G_k D_{k+1}ᵀ)

On a linear-Gaussian model (every Gaussian filter then is the Kalman filter) the draws are exact
samples of the posterior ``p(x_0..x_{T-1} | y_0..y_{T-1})``: at each step their mean and
covariance are the RTS smoother's, their lag-one covariance its ``lag_one_cov``. On a nonlinear
model they are samples of the Gaussian approximation that the filter's rule makes of that
posterior (the one whose marginals its RTS smoother reports) — not of the exact posterior.

The reference filters draw through their own backward kernels
(:mod:`~nlfilter.filters.reference.forward_backward`): ``x_k | x_{k+1} ∝ p(x_k | y_0..y_k)
τ(x_{k+1} | x_k)`` — on the grid filter, forward filtering backward sampling with the filtered grid
weights times the column of the filter's transition kernel at the drawn point (exact draws of the
grid chain's posterior: grid points, whose marginals are its forward–backward smoother's); on the
particle filter, backward simulation (Godsill, Doucet & West 2004), the filtered particles
reweighted by the transition density to the drawn ``x_{k+1}`` (draws of its clouds, whose
marginals given the clouds are its FFBSm smoother's). These hold any posterior the filter
represents — several modes included, which a Gaussian smoother's draws cannot show. The forward
pass keeps every step's belief: ``B × T × N`` floats on the grid (``N`` grid points),
``B × T × Np × (n + 1)`` for the particles; pass fewer paths at a time to bound it.

From a diffuse prior (``P0`` with ``inf``; the filters with ``diffuse_prior``: KF, EKF, IEKF) the
draws come from the exact diffuse smoother's marginals and lag-one covariances
(:func:`~nlfilter.filters.diffuse_prior.diffuse_smooth`): the posterior of a linear-Gaussian model
is a Gauss–Markov chain given the data, so ``x_{T-1} ~ N(x̂_{T-1}, V_{T-1})`` and
``x_k | x_{k+1} ~ N(x̂_k + C_k V_{k+1}⁺ (x_{k+1} − x̂_{k+1}), V_k − C_k V_{k+1}⁺ C_kᵀ)``,
``C_k = Cov[x_k, x_{k+1} | y]`` (the same law as the backward pass above in the limit ``κ → ∞``).
Where the data leave a diffuse direction unidentified the posterior is improper: refused, naming
``P0``.

Each path draws from a stream of its own (:mod:`nlfilter.streams`, sub-stream :data:`SAMPLE` of
the root of ``rng``): path ``p``'s samples are the same in any batch or chunk. The particle
filter's forward pass draws from that stream too (its clouds are those of
``flt.run(ys, rng=PathRNG(rng, B, key=SAMPLE))``), then the backward pass's uniforms.
"""

from __future__ import annotations

import copy

import numpy as np

from .. import _validate as V
from ..angles import angles_of, residual, wrap_components
from ..errors import DivergenceError
from ..simulation import Simulation
from ..streams import PathRNG
from .base import Filter
from .beliefs import GaussianState
from .checks import is_diffuse
from .linalg import PSD_TOL, sqrt_psd, symmetrize
from .smoothing import _solve_right, backward_steps

__all__ = ["sample_posterior", "SAMPLE"]

SAMPLE = 1
"""The key of the posterior sampler's per-path sub-stream (:mod:`nlfilter.streams`): distinct
from the simulation's (None) and a random filter's (:data:`~nlfilter.streams.FILTER`), so that
sampling with the simulation's seed does not reuse its noise."""


def sample_posterior(flt, ys, m0=None, P0=None, n: int = 1, rng=None, *, initial=None,
                     backend: str = "auto") -> np.ndarray:
    """``n`` draws of the state trajectory given all of ``ys``, for every path (module docstring).

    Parameters
    ----------
    flt : Filter
        A discrete-time Gaussian filter with an RTS smoother (KF, EKF, IEKF, UKF, CKF, GHKF, SLF,
        the second-order filters; continuous-discrete ones too), a :class:`~nlfilter.filters.reference.grid.GridFilter` or a
        :class:`~nlfilter.filters.reference.particle.ParticleFilter` (on an SDEModel: built with ``substeps=1``, whose step has a
        transition density).
    ys : array (..., T, m)
        Measurements, NaN where missing (as :meth:`~nlfilter.filters.base.Filter.run`).
    m0, P0, initial, backend
        The prior and the loop of the forward pass, as :meth:`~nlfilter.filters.base.Filter.run`
        (the reference filters: the NumPy loop).
    n : int
        Draws per path.
    rng : int, SeedSequence, Generator or PathRNG
        The root of the per-path streams (sub-stream :data:`SAMPLE`); a ``PathRNG`` is used as it is.

    Returns
    -------
    ndarray (..., n, T, state dim)
        ``out[..., i, k, :]`` is draw ``i`` of ``x_k``.

    Raises
    ------
    DivergenceError
        Where the forward pass diverges, or a conditional covariance of the backward pass is not
        positive semi-definite, or a reference filter's backward kernel has no mass
        (``what="sampler"``).

    >>> import sympy as sp; from nlfilter import DiscreteModel; from nlfilter.filters import KalmanFilter
    >>> x = sp.Symbol("x")
    >>> kf = KalmanFilter(DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.5, R=1.0))
    >>> sample_posterior(kf, np.zeros((2, 5, 1)), 0.0, 1.0, n=3, rng=0).shape
    (2, 3, 5, 1)
    """
    reference = callable(getattr(flt, "_sample", None))
    if not reference and (getattr(flt, "smoother", None) != "rts" or not hasattr(flt, "_predict_cross")):
        raise TypeError(f"flt: sample_posterior draws through a discrete-time Gaussian filter's RTS backward "
                        f"pass (KF, EKF, UKF, CKF, GHKF, IEKF, SLF, the second-order filters) or the backward "
                        f"kernel of GridFilter or ParticleFilter; got {type(flt).__name__}")
    n = V.positive("n", n, integer=True)
    t0 = None
    if isinstance(ys, Simulation):
        flt, t0 = flt.for_timing(ys.timing)
        ys = ys.ys
    if reference:
        return _reference(flt, ys, m0, P0, n, rng, initial, t0, backend)
    if is_diffuse(P0) and getattr(flt, "diffuse_prior", False):
        return _from_diffuse(flt, ys, m0, P0, n, rng)
    est = flt.run(ys, m0, P0, initial=initial, backend=backend)  # raises where it diverges
    ys = flt.check_data(ys)
    batch, T = ys.shape[:-2], ys.shape[-2]
    B = int(np.prod(batch, dtype=int))
    nx = est.means.shape[-1]
    means, covs = est.means.reshape(B, T, nx), est.covs.reshape(B, T, nx, nx)
    z = PathRNG.of(rng, B, key=SAMPLE).standard_normal((T, n, nx))  # path by path: one call each
    predict_cross, off = backward_steps(flt, ys.reshape(B, T, ys.shape[-1]))
    out = np.empty((B, n, T, nx))
    ang = angles_of(flt.model).states  # angular states: wrapped residuals and draws (nlfilter.angles)
    x = wrap_components(_draw(means[:, T - 1][:, None], covs[:, T - 1], z[:, T - 1], T - 1), ang)
    out[:, :, T - 1] = x
    for k in range(T - 2, -1, -1):
        m, P = means[:, k], covs[:, k]
        pred, D = predict_cross(GaussianState(m, P), k + off)
        G = _solve_right(pred.cov, D)  # G_k = D_{k+1} (P⁻_{k+1})⁻¹
        mean = m[:, None] + residual(x, pred.mean[:, None], ang) @ np.swapaxes(G, -1, -2)
        x = wrap_components(_draw(mean, symmetrize(P - G @ np.swapaxes(D, -1, -2)), z[:, k], k), ang)
        out[:, :, k] = x
    return out.reshape(*batch, n, T, nx)


def _from_diffuse(flt, ys, m0, P0, n, rng):
    """Draws from a diffuse prior (module docstring): at a step whose filtered belief is proper the
    backward pass above (its conditional ``P_k − G_k D_{k+1}ᵀ``, better conditioned than the
    smoothed one); within the diffuse period the Gauss–Markov conditional of the exact diffuse
    smoother's moments. A forward or backward divergence raises."""
    sm, est = flt.smooth(ys, m0, P0), flt.run(ys, m0, P0)
    ys = flt.check_data(ys)
    batch, T, nx = sm.means.shape[:-2], sm.means.shape[-2], sm.means.shape[-1]
    B = int(np.prod(batch, dtype=int))
    if T == 0:
        return np.empty((*batch, n, 0, nx))
    flat = lambda a: a.reshape(B, T, *a.shape[len(batch) + 1:])  # noqa: E731
    means, covs, C, fm, fP = (flat(a) for a in (sm.means, sm.covs, sm.extras["lag_one_cov"], est.means, est.covs))
    unknown = np.isinf(covs).any(axis=(1, 2, 3))
    if unknown.any():
        idx = np.flatnonzero(unknown)
        raise ValueError(f"P0: the data do not identify every diffuse direction of P0 = {V.shown(P0)} on {idx.size} "
                         f"path(s), first {idx[:5].tolist()}: the posterior is improper (an infinite smoothed "
                         "variance), nothing to draw; give a finite variance where no measurement reaches")
    z = PathRNG.of(rng, B, key=SAMPLE).standard_normal((T, n, nx))
    predict_cross, off = backward_steps(flt, ys.reshape(B, T, ys.shape[-1]))
    out = np.empty((B, n, T, nx))
    x = _draw(np.broadcast_to(means[:, T - 1][:, None], (B, n, nx)), covs[:, T - 1], z[:, T - 1], T - 1)
    out[:, :, T - 1] = x
    tp = lambda a: np.swapaxes(a, -1, -2)  # noqa: E731
    for k in range(T - 2, -1, -1):
        proper = np.isfinite(fP[:, k]).all(axis=(-1, -2))
        P = np.where(proper[:, None, None], fP[:, k], np.eye(nx))
        pred, D = predict_cross(GaussianState(fm[:, k], P), k + off)
        G = _solve_right(pred.cov, D)  # the filtered belief's kernel (proper paths)
        G2 = _solve_right(covs[:, k + 1], C[:, k])  # C_k V_{k+1}⁺ (the diffuse period)
        mean = np.where(proper[:, None, None], fm[:, k][:, None] + (x - pred.mean[:, None]) @ tp(G),
                        means[:, k][:, None] + (x - means[:, k + 1][:, None]) @ tp(G2))
        cov = np.where(proper[:, None, None], P - G @ tp(D), covs[:, k] - G2 @ tp(C[:, k]))
        x = _draw(mean, _rounded(cov, np.where(proper[:, None, None], P, covs[:, k])), z[:, k], k)
        out[:, :, k] = x
    return out.reshape(*batch, n, T, nx)


def _rounded(cov, minuend):
    """The conditional covariance ``cov = minuend − G Cᵀ`` (paths ``B``) with its eigenvalues in
    ``[−PSD_TOL·max(1, |minuend|), 0)`` set to 0: the rounding of the difference is relative to
    the terms subtracted, not to their (possibly singular) difference; a more negative eigenvalue
    stays, for :func:`_draw` to refuse."""
    cov = symmetrize(cov)
    if not np.isfinite(cov).all():
        return cov
    w, U = np.linalg.eigh(cov)
    tol = PSD_TOL * np.maximum(1.0, np.abs(minuend).max(axis=(-1, -2)))[:, None]
    w = np.where((w < 0) & (w >= -tol), 0.0, w)
    return symmetrize((U * w[:, None, :]) @ np.swapaxes(U, -1, -2))


def _reference(flt, ys, m0, P0, n, rng, initial, t0, backend):
    """The grid or particle filter's draws (module docstring): its forward pass keeping every
    step's belief (the loop of ``Filter.smooth``, on a copy whose backward pass only keeps them),
    then its ``_sample`` over the uniforms ``(B, T, n)`` of each path's stream."""
    if flt.smoother is None:
        raise TypeError(f"flt: {type(flt).__name__} here has no transition density for its backward kernel "
                        f"(an SDEModel with substeps={getattr(flt, 'substeps', None)}: build it with substeps=1, "
                        "or sample with GridFilter)")
    ys = flt.check_data(ys)
    batch, T, m = ys.shape[:-2], ys.shape[-2], ys.shape[-1]
    B = int(np.prod(batch, dtype=int))
    streams = PathRNG.of(rng, B, key=SAMPLE)
    kept = []

    def keep(est, beliefs, yf, t0):
        kept.append(beliefs)
        return est.means, est.covs
    twin = copy.copy(flt)
    twin._smooth = keep
    Filter.smooth(twin, ys, m0, P0, initial=initial, rng=streams, t0=t0, backend=backend)  # raises where the forward pass diverges
    u = streams.random((T, n))  # path by path, after the forward pass's draws (the particle filter's)
    out = flt._sample(kept[0], ys.reshape(B, T, m), 0.0 if t0 is None else t0, u)
    return out.reshape(*batch, n, T, out.shape[-1])


def _draw(mean, cov, z, k):
    """``mean (B, n, nx) + z (B, n, nx) Lᵀ``, ``L Lᵀ = cov (B, nx, nx)``; a covariance that is not
    PSD (or not finite) raises :class:`DivergenceError` naming its paths and step."""
    L, bad = sqrt_psd(cov)
    bad = bad | ~np.all(np.isfinite(mean), axis=(-1, -2))
    if bad.any():
        idx = np.flatnonzero(bad)
        raise DivergenceError(f"sample_posterior: the backward pass's conditional law is not finite or its "
                              f"covariance not positive semi-definite at step {k} on {idx.size} path(s), first "
                              f"{idx[:5].tolist()}", step=k, paths=idx, what="sampler")
    return mean + z @ np.swapaxes(L, -1, -2)
