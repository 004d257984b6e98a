"""Exact diffuse priors for the Taylor-1 filters and the exact diffuse smoother (issue 30 item 3).

A prior ``P0`` with ``inf`` on the diagonal entries of unknown directions (``P = κ P∞ + P*``,
``κ → ∞``; :mod:`~nlfilter.filters.diffuse`) runs exactly — no large finite variance — in the
filters that mix in :class:`DiffusePrior`: :class:`~nlfilter.filters.kalman.KalmanFilter`,
:class:`~nlfilter.filters.ekf.EKF` and :class:`~nlfilter.filters.ekf.IteratedEKF`
(``diffuse_prior = True``; the others refuse such a ``P0`` naming these,
:func:`~nlfilter.filters.checks.refuse_infinite`).

The extended filters run Koopman & Durbin's exact initial filter (Durbin & Koopman 2012, *Time
Series Analysis by State Space Methods*, 2nd ed., §5.2, univariate form §6.4.3) on the model
linearized at each step, as the EKF linearizes it::

    a⁻ = f(a),  F = f_x(a),  P∞⁻ = F P∞ Fᵀ,  P*⁻ = F P* Fᵀ + G Q Gᵀ        (G, Q at a)
    y ≈ h(x) + H (x' − x),  H = h_x(x),  x = a⁻  (IEKF: its Gauss–Newton iterate)

with the log-likelihood terms of the diffuse steps ``−½ (log 2π + log F∞)`` (D&K 2012 eq. 7.4's
convention: ``log L_d = lim (log L(κ) + (q/2) log κ)``, the ``log κ`` dropped as statsmodels does);
on a linear model the EKF and IEKF are the Kalman filter exactly. The approximation is the EKF's:
while a direction is diffuse, the linearization point in it is ``m0``'s, as an EKF started from
``P0 = κ I`` (whose estimates approach these as ``O(1/κ)``).

The exact diffuse smoother (:func:`diffuse_smooth`; D&K 2012 §5.3, in the univariate form of
Koopman & Durbin 2000, J. Time Series Anal. 21, §4) runs backwards over each step's components
and transition with ``r = r⁽⁰⁾ + κ⁻¹ r⁽¹⁾``, ``N = N⁽⁰⁾ + κ⁻¹ N⁽¹⁾ + κ⁻² N⁽²⁾`` from zero. A
component with ``F∞ > 0`` (gains ``K⁽⁰⁾ = M∞/F∞``, ``K⁽¹⁾ = (M* − K⁽⁰⁾ F*)/F∞``, ``L⁽ʲ⁾ = δ_{j0} I −
K⁽ʲ⁾ z``)::

    r⁽⁰⁾ ← L⁽⁰⁾ᵀ r⁽⁰⁾,    r⁽¹⁾ ← zᵀ v/F∞ + L⁽⁰⁾ᵀ r⁽¹⁾ + L⁽¹⁾ᵀ r⁽⁰⁾
    N⁽⁰⁾ ← L⁽⁰⁾ᵀ N⁽⁰⁾ L⁽⁰⁾
    N⁽¹⁾ ← zᵀz/F∞ + L⁽⁰⁾ᵀ N⁽¹⁾ L⁽⁰⁾ + L⁽¹⁾ᵀ N⁽⁰⁾ L⁽⁰⁾ + L⁽⁰⁾ᵀ N⁽⁰⁾ L⁽¹⁾
    N⁽²⁾ ← −zᵀz F*/F∞² + L⁽⁰⁾ᵀ N⁽²⁾ L⁽⁰⁾ + L⁽⁰⁾ᵀ N⁽¹⁾ L⁽¹⁾ + L⁽¹⁾ᵀ N⁽¹⁾ L⁽⁰⁾ + L⁽¹⁾ᵀ N⁽⁰⁾ L⁽¹⁾

(D&K 2012 eqs. 5.21-5.23); with ``F∞ = 0`` the ordinary ``r⁽⁰⁾ ← zᵀ v/F* + Lᵀ r⁽⁰⁾``, ``N⁽⁰⁾ ←
zᵀz/F* + Lᵀ N⁽⁰⁾ L`` (``L = I − M* z/F*``; ``r⁽¹⁾``, ``N⁽¹⁾``, ``N⁽²⁾`` by ``L`` alone); a transition
``F``: ``r ← Fᵀ r``, ``N ← Fᵀ N F``. At each step's predicted ``(a, P∞, P*)`` (eqs. 5.24, 5.25)::

    x̂ = a + P* r⁽⁰⁾ + P∞ r⁽¹⁾
    V = P* − P* N⁽⁰⁾ P* − P∞ N⁽¹⁾ P* − P* N⁽¹⁾ P∞ − P∞ N⁽²⁾ P∞

and the lag-one covariance ``Cov[x_k, x_{k+1} | y] = P_k Lᵀ (I − N P_{k+1})`` (D&K 2012 eq. 4.69,
``L = F_{k+1} Π_i L_i`` over the step's components, ``N`` at step ``k + 1``) expanded in ``κ``::

    A L⁽⁰⁾ᵀ (−N⁽¹⁾ D − N⁽²⁾ C) + (A L⁽¹⁾ᵀ + P* L⁽⁰⁾ᵀ) (I − N⁽⁰⁾ D − N⁽¹⁾ C)

(``A = P∞_k``, ``C, D = P∞, P*`` at step ``k + 1``; the ``κ`` terms vanish as ``N⁽⁰⁾ C = 0``).
Once ``P∞ = 0`` this is the Rauch–Tung–Striebel smoother. A direction the data never identify
keeps ``P∞ − P∞ N⁽¹⁾ P∞ ≠ 0``: its variance is reported ``inf``, as the filter reports one.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from .. import _validate as V
from ..errors import DivergenceError
from ..simulation import Simulation
from .checks import check_structure, is_diffuse
from .diffuse import diffuse_filter
from .estimates import Estimates
from .linalg import symmetrize

__all__ = ["DiffusePrior", "diffuse_smooth", "IDENTIFIED_TOL"]

#: a smoothed diffuse part ``P∞ − P∞ N⁽¹⁾ P∞`` (entries O(1), a product of three) counts as zero
#: (the direction identified by the data) at or below this
IDENTIFIED_TOL = 1e-8


class DiffusePrior:
    """The exact diffuse prior of a discrete Gaussian filter (module docstring): ``run`` and
    ``smooth`` with ``P0`` holding ``inf`` run :func:`~nlfilter.filters.diffuse.diffuse_filter` and
    :func:`diffuse_smooth` on the filter's linearization (``_diffuse_steps``: Taylor-1 here; the
    Kalman filter's matrices in :class:`~nlfilter.filters.kalman.KalmanFilter`); a finite ``P0``
    runs the filter's own loop."""

    diffuse_prior = True  # P0 with inf entries: the exact diffuse initialisation
    _diffuse_iterate = None  # (iterations, tol): the IEKF's Gauss–Newton update

    def run(self, ys, m0=None, P0=None, *, loglik: bool = False, **kw):
        """As :meth:`Filter.run <nlfilter.filters.base.Filter.run>`; a ``P0`` with ``inf`` on the
        diagonal entries of unknown directions is a diffuse prior, run by the exact diffuse
        initialisation (:mod:`~nlfilter.filters.diffuse_prior`; NumPy loop; ``loglik``: the
        diffuse log-likelihood)."""
        if not is_diffuse(P0):
            return super().run(ys, m0, P0, loglik=loglik, **kw)
        flt, ys = self._diffuse_setup(ys, kw)
        if not isinstance(loglik, (bool, np.bool_)):
            raise TypeError(f"loglik: expected True or False, got {V.shown(loglik)}")
        return diffuse_filter(flt, ys, m0, P0, *flt._diffuse_steps(), loglik=loglik, iterate=flt._diffuse_iterate,
                              on_divergence=kw.get("on_divergence", "raise"))[0]

    def smooth(self, ys, m0=None, P0=None, **kw):
        """As :meth:`Filter.smooth <nlfilter.filters.base.Filter.smooth>`; from a diffuse ``P0``
        the exact diffuse smoother (:func:`diffuse_smooth`, with ``extras["lag_one_cov"]``)."""
        if not is_diffuse(P0):
            return super().smooth(ys, m0, P0, **kw)
        flt, ys = self._diffuse_setup(ys, kw)
        return diffuse_smooth(flt, ys, m0, P0, on_divergence=kw.get("on_divergence", "raise"))

    def _diffuse_setup(self, ys, kw):
        """``(filter, ys)``: a Simulation's convention applied, the options checked."""
        if getattr(self, "fading", 1.0) != 1.0:
            raise ValueError(f"alpha: the exact diffuse initialisation (P0 with inf) has no fading memory; got "
                             f"alpha = {self.fading!r} (expected 1, or a finite P0)")
        given = {k: v for k, v in kw.items() if k not in ("on_divergence", "backend", "rng") and v not in (None, False)}
        if given:  # any backend (a fit's automatic choice may name the compiled one; the loop is NumPy's), rng ignored
            raise ValueError(f"P0: a diffuse prior (inf entries) runs on the NumPy loop with the default options; "
                             f"got {sorted(given)}")
        flt = self
        if isinstance(ys, Simulation):
            flt, _ = self.for_timing(ys.timing)
            ys = ys.ys
        check_structure(flt, flt.model)
        return flt, ys

    def _diffuse_steps(self):
        """``(predict, measure)`` of :func:`~nlfilter.filters.diffuse.diffuse_filter`: the model
        linearized at the mean (module docstring)."""
        md = self.model

        def predict(a, k):
            t = self._time(k)
            return md.f(a, t), md.f_x(a, t), md.GQGT(a, t)

        def measure(x, k):
            t = self._time(k)
            H = md.h_x(x, t)
            return H, md.h(x, t) - np.einsum("...ij,...j->...i", H, x)
        return predict, measure


def diffuse_smooth(flt, ys, m0, P0, *, on_divergence: str = "raise") -> Estimates:
    """The exact diffuse smoother (module docstring) of ``flt`` over ``ys (..., T, m)`` from the
    diffuse prior ``(m0, P0)``: smoothed means, covariances and ``extras["lag_one_cov"]``
    (``[..., k] = Cov[x_k, x_{k+1} | y]``, NaN at the last step). A path whose forward or backward
    pass is not finite raises :class:`~nlfilter.errors.DivergenceError` or is marked
    (``on_divergence="mark"``: NaN outputs), as :meth:`Filter.smooth <nlfilter.filters.base.Filter.smooth>` does."""
    on = V.choice("on_divergence", on_divergence, {"raise", "mark"})
    est, tr = diffuse_filter(flt, ys, m0, P0, *flt._diffuse_steps(), iterate=flt._diffuse_iterate,
                             on_divergence=on, keep=True)
    batch = est.diverged.shape
    B, T, n = tr.a.shape
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        ms, Ps, lag = _backward(tr)
    dead = est.diverged.reshape(B).copy()
    step = est.diverged_step.reshape(B).copy()
    lost = ~dead & ~(np.isfinite(ms).all(axis=(-1, -2)) & ~np.isnan(Ps).any(axis=(-1, -2, -3)))
    if lost.any():
        idx = np.flatnonzero(lost)
        if on == "raise":
            raise DivergenceError(f"{flt.name}: the diffuse smoother's backward pass is not finite on {idx.size} "
                                  f"path(s), first {idx[:5].tolist()}; pass on_divergence='mark' to record such paths "
                                  "and go on", step=0, paths=idx, what="smoother")
        dead |= lost
        step[idx] = 0
    nan = lambda a: np.where(dead.reshape(-1, *(1,) * (a.ndim - 1)), np.nan, a)  # noqa: E731
    out = lambda a: nan(a).reshape(*batch, *a.shape[1:])  # noqa: E731
    return Estimates(out(ms), out(Ps), dead.reshape(batch), step.reshape(batch),
                     MappingProxyType({"lag_one_cov": out(lag)}))


def _backward(tr):
    """The backward pass over a :class:`~nlfilter.filters.diffuse.DiffuseTrack` (module
    docstring): ``(means, covs, lag)`` ``(B, T, n)``, ``(B, T, n, n)`` twice."""
    B, T, n = tr.a.shape
    m = tr.z.shape[2]
    eye = np.eye(n)
    tp = lambda x: np.swapaxes(x, -1, -2)  # noqa: E731
    mv = lambda M, x: np.einsum("bij,bj->bi", M, x)  # noqa: E731
    outer = lambda p, q: p[:, :, None] * q[:, None, :]  # noqa: E731
    r0, r1 = np.zeros((B, n)), np.zeros((B, n))
    N0, N1, N2 = np.zeros((B, n, n)), np.zeros((B, n, n)), np.zeros((B, n, n))
    ms, Ps, lag = np.empty((B, T, n)), np.empty((B, T, n, n)), np.full((B, T, n, n), np.nan)
    after = None  # (N⁽⁰⁾, N⁽¹⁾, N⁽²⁾) at step k + 1's predicted belief
    for k in range(T - 1, -1, -1):
        if k < T - 1:  # through the transition into step k + 1
            F = tr.F[:, k + 1]
            r0, r1 = mv(tp(F), r0), mv(tp(F), r1)
            N0, N1, N2 = (tp(F) @ N @ F for N in (N0, N1, N2))
        Ls = []
        for i in range(m - 1, -1, -1):  # the step's components, last first
            z, v = tr.z[:, k, i], tr.v[:, k, i]
            dif, ordn = tr.dif[:, k, i], tr.ordinary[:, k, i]
            Fi = np.where(dif, tr.Finf[:, k, i], 1.0)
            Fs = np.where(ordn | dif, tr.Fst[:, k, i], 1.0)
            K0 = np.where(dif[:, None], tr.Minf[:, k, i] / Fi[:, None],
                          np.where(ordn[:, None], tr.Mst[:, k, i] / Fs[:, None], 0.0))
            K1 = np.where(dif[:, None], (tr.Mst[:, k, i] - K0 * Fs[:, None]) / Fi[:, None], 0.0)
            L0, L1 = eye - outer(K0, z), -outer(K1, z)
            f1, f2 = np.where(dif, 1.0 / Fi, 0.0), np.where(dif, -Fs / Fi**2, 0.0)
            fo = np.where(ordn, 1.0 / Fs, 0.0)
            zz = outer(z, z)
            r0, r1 = mv(tp(L0), r0) + z * (fo * v)[:, None], mv(tp(L0), r1) + mv(tp(L1), r0) + z * (f1 * v)[:, None]
            N0, N1, N2 = (tp(L0) @ N0 @ L0 + zz * fo[:, None, None],
                          tp(L0) @ N1 @ L0 + tp(L1) @ N0 @ L0 + tp(L0) @ N0 @ L1 + zz * f1[:, None, None],
                          tp(L0) @ N2 @ L0 + tp(L0) @ N1 @ L1 + tp(L1) @ N1 @ L0 + tp(L1) @ N0 @ L1
                          + zz * f2[:, None, None])
            Ls.append((L0, L1))
        a, A, Bs = tr.a[:, k], tr.Pinf[:, k], tr.Pst[:, k]
        ms[:, k] = a + mv(Bs, r0) + mv(A, r1)
        V_ = symmetrize(Bs - Bs @ N0 @ Bs - A @ N1 @ Bs - Bs @ N1 @ A - A @ N2 @ A)
        As = A - A @ N1 @ A  # the smoothed diffuse part: zero where the data identify the state
        reach = (np.abs(As) > IDENTIFIED_TOL).any(axis=-1)
        Ps[:, k] = np.where(reach[:, :, None] | reach[:, None, :], np.inf, V_)
        if k < T - 1:
            P0_, P1_ = np.broadcast_to(eye, (B, n, n)), np.zeros((B, n, n))
            for L0, L1 in reversed(Ls):  # L = F Π_i L_i, components in their order, to O(1/κ)
                P0_, P1_ = L0 @ P0_, L0 @ P1_ + L1 @ P0_
            F = tr.F[:, k + 1]
            L0c, L1c = F @ P0_, F @ P1_
            C, D = tr.Pinf[:, k + 1], tr.Pst[:, k + 1]
            M0, M1, M2 = after
            X0, Xm = eye - M0 @ D - M1 @ C, -M1 @ D - M2 @ C
            lk = A @ tp(L0c) @ Xm + (A @ tp(L1c) + Bs @ tp(L0c)) @ X0
            nxt = np.isinf(Ps[:, k + 1]).any(axis=-1)
            lag[:, k] = np.where(reach[:, :, None] | nxt[:, None, :], np.inf, lk)
        after = (N0, N1, N2)
    return ms, Ps, lag
