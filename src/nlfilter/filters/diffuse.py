"""The exact diffuse initialisation of the Kalman filter: a prior with infinite variance in some
directions (``P0`` with ``inf`` on those diagonal entries), the state's level there unknown,
handled exactly rather than by a large finite variance (Koopman & Durbin 2000, "Fast filtering
and smoothing for multivariate state space models", J. Time Series Anal. 21; Durbin & Koopman
2012, *Time Series Analysis by State Space Methods*, 2nd ed., §5.2 and §6.4 univariate form).

The prior covariance is ``P = κ P∞ + P*`` with ``κ → ∞``: ``P∞`` the diagonal indicator of the
infinite entries, ``P*`` the finite rest (the rows and columns of an infinite entry are zero). The
measurement is taken in component by component after whitening by the Cholesky factor ``L`` of
the observed block of ``R`` (``ỹ = L⁻¹ (y − d)``, ``z = (L⁻¹ H)_i``, unit variance); for each
component ``v = ỹ_i − z a``, ``M∞ = P∞ zᵀ``, ``M* = P* zᵀ``, ``F∞ = z P∞ zᵀ``, ``F* = z P* zᵀ + 1``:

- ``F∞ > 0`` (the component sees a diffuse direction: the univariate form, D&K 2012 §6.4.3, of
  the exact initial Kalman filter of §5.2)::

      a ← a + M∞ v / F∞
      P∞ ← P∞ − M∞ M∞ᵀ / F∞
      P* ← P* + M∞ M∞ᵀ F* / F∞² − (M* M∞ᵀ + M∞ M*ᵀ) / F∞
      log-likelihood term: −½ (log 2π + log F∞)

- ``F∞ = 0``: the ordinary update, ``a ← a + M* v / F*``, ``P* ← P* − M* M*ᵀ / F*``, term
  ``−½ (log 2π + log F* + v² / F*)``;

and every step's terms less ``Σ log L_ii`` (the whitening's Jacobian). The prediction carries both
parts: ``P∞ ← F P∞ Fᵀ``, ``P* ← F P* Fᵀ + G Q Gᵀ``. Once ``P∞`` is zero the recursion is the
Kalman filter. The sum of the terms is the diffuse log-likelihood ``log L_d = lim_{κ→∞} (log L(κ)
+ (q/2) log κ)``, ``q`` the number of diffuse directions (D&K 2012 §7.2.2) — the quantity a
maximum-likelihood fit of a model with unknown initial level maximises (statsmodels'
``initialization="diffuse"``).

The extended and iterated extended Kalman filters run the same recursion on their linearised model
(:mod:`~nlfilter.filters.diffuse_prior`): at each step ``F = f_x(a)``, ``a⁻ = f(a)`` and ``H =
h_x(x)``, ``d = h(x) − H x`` at the predicted mean ``x = a⁻`` (the IEKF: at its Gauss–Newton
iterate, the likelihood's terms from the first linearization); :func:`diffuse_filter` takes the
step's linearization as two callables, and keeps what the exact diffuse smoother needs.

Reported estimates: the mean ``a`` and, while a direction is still diffuse, ``inf`` in the rows and
columns of the covariance that ``P∞`` reaches (not yet identified by the data), ``P*`` elsewhere.
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import NamedTuple

import numpy as np

from .. import _validate as V
from ..errors import DivergenceError
from .checks import is_diffuse
from .estimates import Estimates
from .linalg import symmetrize

__all__ = ["is_diffuse", "diffuse_run", "diffuse_filter", "kalman_steps", "DiffuseTrack", "DIFFUSE_TOL"]

#: ``F∞ = z P∞ zᵀ`` counts as zero at or below this fraction of ``|z|²`` (``P∞``'s entries are
#: O(1): a projected-out direction leaves rounding of ~1e-16 there)
DIFFUSE_TOL = 1e-12
_LOG_2PI = math.log(2.0 * math.pi)


def _split(P0, n):
    """``(P∞, P*)`` from ``P0 (..., n, n)`` with ``inf`` on the diffuse diagonal entries."""
    P = V.as_float_array("P0", P0)  # complex refused (NumPy would drop the imaginary part)
    if P.ndim == 0 and n == 1:
        P = P.reshape(1, 1)
    if P.shape[-2:] != (n, n):
        raise ValueError(f"P0: expected a covariance of shape ({n}, {n}) (or per path), got shape {P.shape}")
    inf = np.isposinf(P)
    diag = np.isposinf(np.diagonal(P, axis1=-2, axis2=-1))
    cross = diag[..., :, None] | diag[..., None, :]
    if np.isnan(P).any() or np.isneginf(P).any() or (inf & ~np.eye(n, dtype=bool)).any() \
            or (cross & ~np.eye(n, dtype=bool) & (P != 0)).any():
        raise ValueError("P0: a diffuse prior has inf on the diagonal entries of the unknown directions and zeros "
                         f"in their rows and columns, finite entries elsewhere; got {V.shown(P0)}")
    Pinf = np.where(np.eye(n, dtype=bool) & cross, 1.0, 0.0)
    Pstar = np.where(cross, 0.0, P)
    V.covariance("P0", Pstar, n, batch=True)  # the finite part: symmetric PSD
    return Pinf, Pstar


class DiffuseTrack(NamedTuple):
    """What the exact diffuse smoother (:func:`~nlfilter.filters.diffuse_prior.diffuse_smooth`)
    reads of a forward pass, paths flattened: the predicted ``a (B, T, n)``, ``Pinf``, ``Pst (B, T,
    n, n)`` of every step, the transition ``F (B, T, n, n)`` into it (step 0's unused), and each
    whitened component's ``z (B, T, m, n)``, ``v``, ``M∞``, ``M*``, ``F∞``, ``F*`` and which update
    it took (``dif``, ``ordinary``; neither: missing)."""

    a: np.ndarray
    Pinf: np.ndarray
    Pst: np.ndarray
    F: np.ndarray
    z: np.ndarray
    v: np.ndarray
    Minf: np.ndarray
    Mst: np.ndarray
    Finf: np.ndarray
    Fst: np.ndarray
    dif: np.ndarray
    ordinary: np.ndarray


class _Updated(NamedTuple):
    """One step's update (its mean first, for :func:`~nlfilter.filters.skeleton.gauss_newton`)."""

    mean: np.ndarray
    Pinf: np.ndarray
    Pst: np.ndarray
    ll: np.ndarray
    z: np.ndarray
    v: np.ndarray
    Minf: np.ndarray
    Mst: np.ndarray
    Finf: np.ndarray
    Fst: np.ndarray
    dif: np.ndarray
    ordinary: np.ndarray


def _outer(p, q):
    return p[:, :, None] * q[:, None, :]


def diffuse_update(a, Pinf, Pst, y, H, d, R) -> _Updated:
    """The update of ``(a, P∞, P*)`` (paths ``B``) by ``y (B, m)`` (NaN: missing) through ``y = H x
    + d + ε``, ``ε ~ N(0, R)``, component by component after whitening (module docstring), with the
    step's log-likelihood term and every component's quantities (:class:`DiffuseTrack`)."""
    B, m, n = a.shape[0], y.shape[-1], a.shape[-1]
    obs = ~np.isnan(y)
    both = obs[:, :, None] & obs[:, None, :]
    L = np.linalg.cholesky(np.where(both, R, np.eye(m)))  # the observed block's factor; 1 elsewhere
    yt = np.linalg.solve(L, np.where(obs, y - d, 0.0)[..., None])[..., 0]
    Zt = np.linalg.solve(L, np.broadcast_to(H, (B, m, n)))
    ll = -np.sum(np.where(obs, np.log(np.diagonal(L, axis1=-2, axis2=-1)), 0.0), axis=-1)
    rec = [np.zeros((B, m)), np.zeros((B, m, n)), np.zeros((B, m, n)), np.zeros((B, m)), np.zeros((B, m)),
           np.zeros((B, m), bool), np.zeros((B, m), bool)]
    for i in range(m):
        z, o = Zt[:, i], obs[:, i]
        v = yt[:, i] - np.einsum("bj,bj->b", z, a)
        Minf, Mst = np.einsum("bij,bj->bi", Pinf, z), np.einsum("bij,bj->bi", Pst, z)
        Finf, Fst = np.einsum("bi,bi->b", z, Minf), np.einsum("bi,bi->b", z, Mst) + 1.0
        dif = o & (Finf > DIFFUSE_TOL * np.einsum("bi,bi->b", z, z))
        ordinary = o & ~dif
        Fi = np.where(dif, Finf, 1.0)
        Fs = np.where(ordinary, Fst, 1.0)
        a = a + np.where(dif[:, None], Minf * (v / Fi)[:, None], 0.0) \
            + np.where(ordinary[:, None], Mst * (v / Fs)[:, None], 0.0)
        Pst_dif = Pst + _outer(Minf, Minf) * (Fst / Fi**2)[:, None, None] \
            - (_outer(Mst, Minf) + _outer(Minf, Mst)) / Fi[:, None, None]
        Pst = symmetrize(np.where(dif[:, None, None], Pst_dif,
                                  np.where(ordinary[:, None, None], Pst - _outer(Mst, Mst) / Fs[:, None, None], Pst)))
        Pinf = symmetrize(np.where(dif[:, None, None], Pinf - _outer(Minf, Minf) / Fi[:, None, None], Pinf))
        ll = ll + np.where(dif, -0.5 * (_LOG_2PI + np.log(Fi)), 0.0) \
            + np.where(ordinary, -0.5 * (_LOG_2PI + np.log(Fs) + v * v / Fs), 0.0)
        for rows, x in zip(rec, (v, Minf, Mst, Finf, Fst, dif, ordinary)):
            rows[:, i] = x
    return _Updated(a, Pinf, Pst, ll, Zt, *rec)


def diffuse_run(kf, ys, m0, P0, *, loglik: bool = False, on_divergence: str = "raise") -> Estimates:
    """The Kalman filter ``kf`` over ``ys (..., T, m)`` from the diffuse prior ``(m0, P0)`` (module
    docstring); ``loglik``: ``extras["loglik"] (..., T)``, the diffuse log-likelihood's terms (and
    ``loglik_failed``). A path whose moments become non-finite raises
    :class:`~nlfilter.errors.DivergenceError` (``on_divergence="raise"``) or is marked (``"mark"``:
    ``diverged``, ``diverged_step``, its outputs NaN from that step on), as the run loop does."""
    return diffuse_filter(kf, ys, m0, P0, *kalman_steps(kf), loglik=loglik, on_divergence=on_divergence)[0]


def kalman_steps(kf):
    """``(predict, measure)`` of :func:`diffuse_filter` for the Kalman filter ``kf``: its model's matrices."""

    def predict(a, k):
        F, b, _, _, GQG = kf._mats if kf._const else kf._matrices(k)
        return a @ F.T + b, F, kf._gqg(GQG, a, k)

    def measure(x, k):
        return (kf._mats if kf._const else kf._matrices(k))[2:4]
    return predict, measure


def diffuse_filter(flt, ys, m0, P0, predict, measure, *, loglik: bool = False, on_divergence: str = "raise",
                   iterate=None, keep: bool = False):
    """The exact diffuse filter (module docstring) of the discrete filter ``flt`` over ``ys``:
    ``predict(a, k) -> (a⁻, F, G Q Gᵀ)`` and ``measure(x, k) -> (H, d)`` give the model index
    ``k``'s (linearized) matrices, batched or not; ``iterate = (iterations, tol)``: the update is
    relinearized at its own mean (the IEKF's Gauss–Newton, :func:`~nlfilter.filters.skeleton.gauss_newton`),
    the likelihood's terms those of the first linearization. Returns ``(Estimates, DiffuseTrack or
    None)`` (``keep``: the track for the smoother)."""
    from .skeleton import gauss_newton
    on = V.choice("on_divergence", on_divergence, {"raise", "mark"})
    md = flt.model
    if flt._cross.S is not None:
        raise ValueError("P0: a diffuse prior (inf entries) with correlated process and measurement noise "
                         "(cross_noise) is not supported; give a finite P0")
    n = md.n
    Pinf0, Pstar0 = _split(P0, n)
    ys = flt.check_data(ys)
    batch, T, m = ys.shape[:-2], ys.shape[-2], ys.shape[-1]
    B = math.prod(batch)
    yf = ys.reshape(B, T, m)
    m0 = V.mean("m0", m0, n)
    try:
        a = np.broadcast_to(m0, (*batch, n)).reshape(B, n).copy()
        Pinf = np.broadcast_to(Pinf0, (*batch, n, n)).reshape(B, n, n).copy()
        Pst = np.broadcast_to(Pstar0, (*batch, n, n)).reshape(B, n, n).copy()
    except ValueError:
        raise ValueError(f"m0/P0: shapes {m0.shape}, {np.shape(P0)} do not broadcast to the batch {batch} of ys") from None
    R = md.R if md.R_constant else None  # R_k given per step: read at each step (md.R_of)
    off = 0 if flt.start == "update" else 1
    means, covs, terms = np.empty((B, T, n)), np.empty((B, T, n, n)), np.zeros((B, T))
    step, failed = np.full(B, -1), np.zeros((B, T), bool)
    track = [[] for _ in DiffuseTrack._fields] if keep else None
    for k in range(T):
        F = np.eye(n)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            if k > 0 or off:
                a, F, GQG = predict(a, k + off - 1)
                Ft = np.swapaxes(F, -1, -2)
                Pinf = F @ Pinf @ Ft
                Pst = symmetrize(F @ Pst @ Ft + GQG)
            Rk = md.R_of(a, k + off) if R is None else R
            H, d = measure(a, k + off)
            new = diffuse_update(a, Pinf, Pst, yf[:, k], H, d, Rk)
            if iterate is not None:
                first = new.ll
                new = gauss_newton(new, lambda x: diffuse_update(a, Pinf, Pst, yf[:, k], *measure(x, k + off), Rk),
                                   *iterate)._replace(ll=first)
            if keep:
                for rows, x in zip(track, (a, Pinf, Pst, np.broadcast_to(F, (B, n, n)), *new[4:])):
                    rows.append(x)
            a, Pinf, Pst, ll = new[:4]
        unknown = np.abs(Pinf) > DIFFUSE_TOL
        reach = unknown.any(axis=-1)
        means[:, k] = a
        covs[:, k] = np.where(reach[:, :, None] | reach[:, None, :], np.inf, Pst)
        terms[:, k] = ll
        moments = np.isfinite(a).all(axis=-1) & np.isfinite(Pst).all(axis=(-1, -2))
        bad = (step < 0) & ~(moments & np.isfinite(ll))
        if bad.any():
            idx = np.flatnonzero(bad)
            if on == "raise":
                raise DivergenceError(f"{flt.name}: the diffuse filter's moments are not finite at step {k} on "
                                      f"{idx.size} path(s), first {idx[:5].tolist()}; pass on_divergence='mark' to "
                                      "record such paths and go on", step=k, paths=idx, what="covariance")
            step[idx] = k
            failed[idx, k] = moments[idx]  # the likelihood term failed first (as the run loop's loglik_failed)
        dead = step >= 0  # marked: NaN from their step on
        if dead.any():
            a, Pinf, Pst = (np.where(dead.reshape(-1, *(1,) * (x.ndim - 1)), np.nan, x) for x in (a, Pinf, Pst))
            means[dead, k], covs[dead, k], terms[dead, k] = np.nan, np.nan, np.nan
    out = lambda x: x.reshape(*batch, *x.shape[1:])  # noqa: E731
    extras = MappingProxyType({"loglik": out(terms), "loglik_failed": out(failed)} if loglik else {})
    est = Estimates(out(means), out(covs), (step >= 0).reshape(batch), step.reshape(batch), extras)
    if not keep:
        return est, None
    shapes = ((n,), (n, n), (n, n), (n, n), (m, n), (m,), (m, n), (m, n), (m,), (m,), (m,), (m,))
    return est, DiffuseTrack(*(np.stack(x, axis=1) if T else np.zeros((B, 0, *s)) for x, s in zip(track, shapes)))
