"""Square-root Gaussian filters: the belief carries a factor ``S`` of its covariance (``P = S Sᵀ``).

The standard Gaussian filters (:mod:`nlfilter.filters.gaussian`) propagate P itself, and in finite
precision ``P⁻ − K S Kᵀ`` can lose symmetry and positive definiteness where the filters are needed
most (a near-noiseless measurement, a long run). The square-root forms propagate a lower-triangular
``S`` by orthogonal transformations only, so ``S Sᵀ`` is symmetric PSD by construction and its
condition number is the square root of P's (Bierman 1977; Grewal & Andrews, *Kalman Filtering:
Theory and Practice*, the square-root and triangularization methods). ``tria(A)`` below is the
lower-triangular ``L`` with ``L Lᵀ = A Aᵀ`` from a QR factorization of ``Aᵀ`` (``Aᵀ = Θ Lᵀ``,
Θ orthonormal; :func:`~nlfilter.filters.triangular.tria`); P is never formed in a step.

Taylor-1 (the square-root EKF; the Kalman filter on a linear model, Morf & Kailath 1975)::

    predict:  m⁻ = f(m),  S⁻ = tria([F S,  G(m) Q^½])                      F = f_x(m)
    update:   tria([[H S⁻,  R^½],      = [[S_y,  0 ],                      H = h_x(m⁻)
                    [S⁻,     0  ]])       [K̄,   S⁺]]
              m⁺ = m⁻ + K̄ S_y⁻¹ (y − h(m⁻))        (K = K̄ S_y⁻¹;  S_y S_yᵀ = H P⁻ Hᵀ + R)

Node rules (unscented: van der Merwe & Wan 2001; cubature: Arasaratnam & Haykin 2009;
Gauss–Hermite: Arasaratnam & Haykin 2008, square-root quadrature) with the points
``X_i = m + S z_i`` of the rule's table (:meth:`~nlfilter.filters.rules.NodeRule.points`)::

    predict:  m⁻ = Σ wm_i f(X_i),   S⁻ = tria([√wc_i (f(X_i) − m⁻),  G Q^½])   (wc_i > 0)
              then a Cholesky downdate by √|wc_i| (f(X_i) − m⁻) for every wc_i < 0
    update:   the joint array  tria([[√wc_i (h(X_i) − ŷ),  R^½],   = [[S_y, 0], [K̄, S⁺]]
                                     [√wc_i S⁻ z_i,         0  ]])
              (downdated likewise), ŷ = Σ wm_i h(X_i),  m⁺ = m⁻ + K̄ S_y⁻¹ (y − ŷ)

The joint array's Gram matrix is ``[[S, Cᵀ], [C, Σ wc_i S⁻ z_i z_iᵀ S⁻ᵀ]]`` with the standard rule's
``S = Cov[h] + R`` and ``C = Cov[x, h]``; its lower-right block is P⁻ because ``Σ wc_i z_i z_iᵀ = I``
(a rule exact for second moments: checked at construction), so ``S⁺ S⁺ᵀ = P⁻ − C S⁻¹ Cᵀ``, the
standard update. A state-dependent ``G(x)`` adds the columns ``√wm_i G(X_i) Q^½`` (E[G Q Gᵀ]).

**Negative weights.** The unscented rule with ``α < 1`` (e.g. ``α = 0.5``: ``wc_0 = −0.25``) has a
negative centre weight, which no QR column can carry. Those terms are removed by rank-one Cholesky
downdates (van der Merwe & Wan 2001, ``cholupdate(S, √|wc_0| (X_0 − m), "−")``; the hyperbolic
rotations of :func:`~nlfilter.filters.triangular.downdate`), exact in exact arithmetic. A downdate whose result is not positive
definite (the standard filter's P⁻ would have lost definiteness there too) is *reported*: that path
is poisoned, so ``run`` raises or marks it as diverged, never returns it silently.

The log-likelihood comes from the factor: with ``u = S_y⁻¹ (y − ŷ)``,
``log N(y; ŷ, S) = −½ (uᵀu + 2 Σ_i log (S_y)_ii + m log 2π)``. Missing components of y: their
rows of the measurement columns are zeroed and R is replaced by its observed block (unit diagonal
elsewhere), the exact update on the observed components (as :func:`~nlfilter.filters.linalg.gaussian_update`).

What ``run`` reports is ``covs = S Sᵀ`` (symmetric), so the likelihood, the contract and the plots
read them as any Gaussian filter's. ``smooth`` is the square-root RTS smoother (:func:`sqrt_rts`:
the joint factor of ``(x_{k+1}, x_k)``, ``Sˢ_k = tria([S_c, G Sˢ_{k+1}])``); the fixed-lag
smoother and the posterior sampler run the rule's moment form from the reported moments
(:mod:`~nlfilter.filters.smoothing`). The Taylor-1 and node forms run on the compiled loop too
(``backend="numba"``, or ``"auto"`` by its rule: ``nlfilter.filters.compiled.sqrt_kernels``, the
same steps on one path, a hand-written Householder ``tria``); fading memory, angles, correlated noise
and a state-dependent R stay on the NumPy loop. Correlated process and measurement noise
(``cross_noise``) is decorrelated as in the standard filters (the prediction's dynamics
``f + G K_w (y_k − h)``, the factor of ``Q − K_w Sᵀ``); non-additive noise is refused at construction
(``structures``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _validate as V
from ..angles import angles_of, near, node_moments, residual, wrap_components
from .gaussian import GaussianFilter
from .linalg import LOG_2PI, decorrelation, mm, sqrt_psd, symmetrize
from .triangular import downdate, tria
from .skeleton import _decorrelated
from .smoothing import SINGULAR_RTOL, _solve_right

__all__ = ["SqrtState", "sqrt_predict", "sqrt_rts", "sqrt_condition", "factor_info", "SquareRootFilter"]


class SqrtState(NamedTuple):
    """Mean ``(..., n)`` and a square root ``factor (..., n, n)`` of the covariance
    (``P = factor @ factorᵀ``): lower-triangular with a non-negative diagonal after every step (the
    prior's is its Cholesky factor, or the symmetric root where P0 is only semi-definite). ``y``: with
    correlated noise (``cross_noise``) the measurement ``(..., m)`` the belief was last conditioned on
    (NaN: none), which the next prediction decorrelates (:class:`~nlfilter.filters.skeleton.CrossNoise`);
    else None."""

    mean: np.ndarray
    factor: np.ndarray
    y: np.ndarray | None = None


def _signed_nodes(rule, n):
    """The rule's table for dimension n split by the sign of the covariance weights:
    ``(z, wm, wc, pos, neg)`` (index arrays; zero weights in neither)."""
    z, wm, wc = rule.unit_nodes(n)
    return z, wm, wc, np.flatnonzero(wc > 0), np.flatnonzero(wc < 0)


def _columns(D, w, idx):
    """``(..., p, len(idx))``: the columns ``√|w_i| D_i`` of ``D (..., N, p)`` for the nodes ``idx``."""
    return (D[..., idx, :] * np.sqrt(np.abs(w[idx]))[:, None]).swapaxes(-1, -2)


def _rows(D, w, idx):
    """The vectors ``√|w_i| D_i (..., p)`` for the nodes ``idx`` (the downdates of negative weights)."""
    return [D[..., i, :] * np.sqrt(-w[i]) for i in idx]


def _noise_columns(model, m, X, wm, t, Lq):
    """The factor columns of ``E[G Q Gᵀ]`` and the downdates of its negative weights:
    ``G(m) Q^½`` for a constant G (or the Taylor-1 rule: X None), else ``√wm_i G(X_i) Q^½``."""
    if X is None or model.G_constant:
        return model.G(m, t) @ Lq, []
    GL = model.G(X, t) @ Lq  # (..., N, n, r)
    pos, neg = np.flatnonzero(wm > 0), np.flatnonzero(wm < 0)
    cols = GL[..., pos, :, :] * np.sqrt(wm[pos])[:, None, None]  # (..., Np, n, r) -> (..., n, Np r)
    cols = np.moveaxis(cols, -3, -2).reshape(*cols.shape[:-3], cols.shape[-2], -1)
    return cols, [GL[..., i, :, j] * np.sqrt(-wm[i]) for i in neg for j in range(GL.shape[-1])]


def _broadcast_concat(blocks, axis):
    """``np.concatenate`` of arrays whose leading (batch) axes broadcast."""
    lead = np.broadcast_shapes(*(b.shape[:-2] for b in blocks))
    return np.concatenate([np.broadcast_to(b, (*lead, *b.shape[-2:])) for b in blocks], axis=axis)


def sqrt_predict(rule, model, belief, t, Lq, *, joint: bool = False, f=None, f_x=None, f_xx=None):
    """``(SqrtState at t + 1, failed paths or None)``: the square-root prediction (module docstring)
    of ``belief`` by ``rule`` (Taylor-1 or a node rule); ``Lq``: a square root of the model's Q.
    ``joint``: ``(m⁻, J, failed)`` with ``J (..., 2n, 2n)`` the lower-triangular factor of the joint
    covariance of ``(x_{k+1}, x_k)`` (the smoother's, :func:`sqrt_rts`): the columns of P⁻ over
    ``S`` (Taylor-1) or ``S z_i`` (nodes), the noise's over zeros. ``f``, ``f_x``: dynamics in place
    of the model's (correlated noise: the decorrelated ones, :class:`~nlfilter.filters.skeleton.CrossNoise`);
    ``f_xx`` likewise (a rule with its own columns, ``sqrt_dynamics``: the second-order filters of
    :mod:`~nlfilter.filters.square_root_second_order`)."""
    m, S = belief[0], belief[1]
    n = m.shape[-1]
    f, f_x = model.f if f is None else f, model.f_x if f_x is None else f_x
    ang = angles_of(model).states
    if hasattr(rule, "sqrt_dynamics"):  # the rule's own columns (square_root_second_order)
        mean, cols, low, neg, noise, nneg = rule.sqrt_dynamics(model, m, S, t, Lq, f, f_x, f_xx, joint)
        mean = wrap_components(mean, ang)
    elif rule.kind == "taylor1":
        mean = wrap_components(f(m, t), ang)
        cols, low, neg = mm(f_x(m, t), S), S, []  # F S over S
        noise, nneg = _noise_columns(model, m, None, None, t, Lq)
    else:
        z, wm, wc, pos, negi = _signed_nodes(rule, n)
        X = rule.points(m, S)[0]
        mean, D = node_moments(f(X, t), wm, ang)  # Σ wm_i f(X_i), f_i − m⁻ (angles: nlfilter.angles)
        cols, low = _columns(D, wc, pos), _columns(X - m[..., None, :], wc, pos)
        neg = _rows(np.concatenate([D, X - m[..., None, :]], axis=-1) if joint else D, wc, negi)
        noise, nneg = _noise_columns(model, m, X, wm, t, Lq)
    if not joint:
        L, failed = downdate(tria(_broadcast_concat([cols, noise], -1)), neg + nneg)
        return SqrtState(mean, L), failed
    lead = np.broadcast_shapes(cols.shape[:-2], low.shape[:-2], noise.shape[:-2])
    A = _broadcast_concat([_broadcast_concat([cols, noise], -1),
                           _broadcast_concat([low, np.zeros((*lead, n, noise.shape[-1]))], -1)], -2)
    nneg = [np.concatenate([v, np.zeros(v.shape)], axis=-1) for v in nneg]
    L, failed = downdate(tria(A), neg + nneg)
    return mean, L, failed


def _gain(Gb, Sp):
    """``G = Ḡ S⁻⁻¹`` (``G P⁻ = D``) by a triangular solve; where ``S⁻`` is singular to rounding (a
    diagonal entry at most :data:`~nlfilter.filters.smoothing.SINGULAR_RTOL` times the largest: the
    standard smoother's threshold on P⁻'s eigenvalues, applied to its square root; a known state
    component, Q = 0 and P0 = 0 in it) the standard smoother's gain from ``P⁻ = S⁻ S⁻ᵀ`` and
    ``D = Ḡ S⁻ᵀ`` (the pseudo-inverse on the range of P⁻, :func:`~nlfilter.filters.smoothing._solve_right`)."""
    d = np.abs(np.diagonal(Sp, axis1=-2, axis2=-1))
    sing = ~np.all(d > SINGULAR_RTOL * d.max(axis=-1, keepdims=True), axis=-1)
    safe = np.where(sing[..., None, None], np.eye(Sp.shape[-1]), Sp)
    G = np.linalg.solve(safe.swapaxes(-1, -2), Gb.swapaxes(-1, -2)).swapaxes(-1, -2)  # G S⁻ = Ḡ
    if sing.any():
        Spt = Sp.swapaxes(-1, -2)
        G = np.where(sing[..., None, None], _solve_right(Sp @ Spt, Gb @ Spt), G)
    return G


def sqrt_rts(beliefs, joint_predict, angles=()):
    """The square-root RTS smoother over the filtered beliefs ``beliefs`` (T :class:`SqrtState` of
    ``(B, n)``, ``(B, n, n)``; ``joint_predict(belief, k)``: :func:`sqrt_predict` with ``joint`` from
    run step k, the filter's rule, time and noise): ``(means (B, T, n),
    covs (B, T, n, n), lag (B, T, n, n))``. Each step factors the joint law of ``(x_{k+1}, x_k)``
    given ``y_0..y_k`` (:func:`sqrt_predict` with ``joint``), ``tria = [[S⁻, 0], [Ḡ, S_c]]`` with
    ``Ḡ S⁻ᵀ = Cov[x_k, x_{k+1}]`` and ``S_c S_cᵀ = P − G P⁻ Gᵀ``; then (Särkkä 2013, Thm. 8.2, in
    factored form)::

        G = Ḡ S⁻⁻¹,   mˢ_k = m_k + G (mˢ_{k+1} − m⁻),   Sˢ_k = tria([S_c,  G Sˢ_{k+1}])

    so ``Pˢ_k = P_k + G (Pˢ_{k+1} − P⁻) Gᵀ`` with no difference of covariances formed; ``lag[:, k] =
    G Pˢ_{k+1}`` (NaN at the last step). A path whose downdate fails gets NaN (the caller reports it)."""
    T = len(beliefs)
    B, n = beliefs[-1].mean.shape
    ms, Ss = np.empty((B, T, n)), np.empty((B, T, n, n))
    lag = np.full((B, T, n, n), np.nan)
    ms[:, -1], Ss[:, -1] = beliefs[-1].mean, beliefs[-1].factor
    for k in range(T - 2, -1, -1):
        m = beliefs[k].mean
        mp, J, failed = joint_predict(beliefs[k], k)
        G = _gain(J[..., n:, :n], J[..., :n, :n])
        ms[:, k] = wrap_components(m + np.einsum("...ij,...j->...i", G, residual(ms[:, k + 1], mp, angles)), angles)
        GS = G @ Ss[:, k + 1]
        Ss[:, k] = tria(np.concatenate([J[..., n:, n:], GS], axis=-1))
        lag[:, k] = GS @ Ss[:, k + 1].swapaxes(-1, -2)
        if failed is not None and failed.any():
            ms[failed, k], Ss[failed, k] = np.nan, np.nan
    return ms, symmetrize(Ss @ Ss.swapaxes(-1, -2)), lag


def sqrt_condition(rule, model, belief, y, t, Lr, *, full: bool = False, at=None):
    """The square-root update of ``belief`` on ``y (..., m)`` (NaN components missing; module
    docstring): ``(SqrtState, failed paths or None, (ŷ, S_y, u, S))`` with ``S_y`` the factor of the
    innovation covariance (of its observed block; unit rows where a component is missing),
    ``u = S_y⁻¹ (y − ŷ)`` (0 where missing) and, with ``full``, ``S = Cov[h] + R`` (all components,
    for the likelihood's ``innovation_cov``; else None). ``Lr``: ``(R, a square root of R)`` of a
    constant R, or None (``model.R_of`` at the predicted mean: the EKF convention). ``at``: Taylor-1
    linearized at ``x`` instead of the mean, ``ŷ = h(x) + H (m⁻ − x)`` (an iterated update's step)."""
    m, S = belief[0], belief[1]
    n, p = m.shape[-1], y.shape[-1]
    ang = angles_of(model)
    if hasattr(rule, "sqrt_measurement"):  # the rule's own columns (square_root_second_order)
        yhat, Y, Xc, neg = rule.sqrt_measurement(model, m, S, t)
    elif rule.kind == "taylor1":
        xl = m if at is None else at
        H = model.h_x(xl, t)
        yhat = (model.h(xl, t) if at is None else
                model.h(xl, t) + np.einsum("...ij,...j->...i", H, residual(m, xl, ang.states)))
        Y, Xc, neg = mm(H, S), S, []  # H S⁻ over S⁻
    else:
        z, wm, wc, pos, negi = _signed_nodes(rule, n)
        X = rule.points(m, S)[0]
        yhat, D = node_moments(model.h(X, t), wm, ang.measurements)  # Σ wm_i h(X_i), h_i − ŷ
        Z = X - m[..., None, :]  # Z_i = S⁻ z_i
        Y, Xc = _columns(D, wc, pos), _columns(Z, wc, pos)
        neg = _rows(np.concatenate([D, np.broadcast_to(Z, (*D.shape[:-1], n))], axis=-1), wc, negi)
    R, LR = Lr if Lr is not None else (model.R_of(m, t), None)
    Sfull = None
    if full:
        Sfull = mm(Y, Y.swapaxes(-1, -2)) + R - sum(np.einsum("...i,...j->...ij", v[..., :p], v[..., :p]) for v in neg)
    miss = np.isnan(y)
    if miss.any():  # the observed block of R (unit diagonal elsewhere), the missing rows of h dropped
        Y = np.where(miss[..., :, None], 0.0, Y)
        neg = [np.concatenate([np.where(miss, 0.0, v[..., :p]), v[..., p:]], axis=-1) for v in neg]
        both = miss[..., :, None] | miss[..., None, :]
        R = np.where(both, np.where(np.eye(p, dtype=bool), 1.0, 0.0), R)
        LR = None
    LR, bad = sqrt_psd(R) if LR is None else (LR, None)
    lead = np.broadcast_shapes(Y.shape[:-2], Xc.shape[:-2], LR.shape[:-2])
    A = _broadcast_concat([_broadcast_concat([Y, LR], -1),
                           _broadcast_concat([Xc, np.zeros((*lead, n, p))], -1)], -2)
    L, failed = downdate(tria(A), neg)
    Sy, Kb, Sp = L[..., :p, :p], L[..., p:, :p], L[..., p:, p:]
    diag = np.diagonal(Sy, axis1=-2, axis2=-1)
    sing = ~np.all(diag > 0, axis=-1)  # a singular (or non-finite) innovation factor
    for more in (failed, bad):
        if more is not None and np.ndim(more):
            sing = sing | more
    yhat = near(yhat, y, ang.measurements)  # angles: the wrapped innovation (nlfilter.angles)
    e = np.where(miss, 0.0, y - yhat)
    safe = np.where(sing[..., None, None], np.eye(p), Sy)
    u = e / safe[..., 0, :] if p == 1 else np.linalg.solve(safe, e[..., None])[..., 0]  # S_y⁻¹ e
    mean = wrap_components(m + np.einsum("...ij,...j->...i", Kb, u), ang.states)  # m⁻ + K̄ S_y⁻¹ (y − ŷ)
    return SqrtState(mean, Sp), (sing if sing.any() else None), (yhat, Sy, u, Sfull)


def factor_info(y, yhat, Sy, u, S) -> dict:
    """The step's likelihood output (as :func:`~nlfilter.filters.linalg.innovation_info`) from the
    innovation factor: ``loglik = −½ (uᵀu + 2 Σ log (S_y)_ii + m_obs log 2π)`` (0 with nothing
    measured; NaN where ``S_y`` is singular), ``innovation = y − ŷ`` (NaN where missing),
    ``innovation_cov = S`` (NaN on a path with nothing measured)."""
    miss = np.isnan(y)
    diag = np.diagonal(Sy, axis1=-2, axis2=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        logdet = 2.0 * np.sum(np.log(np.where(diag > 0, diag, np.nan)), axis=-1)
    ll = -0.5 * (np.sum(u * u, axis=-1) + logdet + (~miss).sum(axis=-1) * LOG_2PI)
    none = miss.all(axis=-1)
    return {"loglik": ll, "innovation": np.where(miss, np.nan, y - yhat),
            "innovation_cov": np.where(none[..., None, None], np.nan, S)}


def _poison(state: SqrtState, bad) -> SqrtState:
    """NaN on the paths in ``bad`` (``run`` then raises or marks them)."""
    if bad is None or not np.any(bad):
        return state
    return SqrtState(np.where(bad[..., None], np.nan, state.mean), np.where(bad[..., None, None], np.nan, state.factor),
                     state.y)


def _second_moments_exact(rule, n) -> bool:
    """Whether the node rule's table gives ``Σ wc_i z_i z_iᵀ = I`` (its points carry P exactly)."""
    z, _, wc = rule.unit_nodes(n)
    return bool(np.allclose(np.einsum("i,ij,ik->jk", wc, z, z), np.eye(n), rtol=0, atol=1e-12))


class SquareRootFilter(GaussianFilter):
    """Discrete-time square-root Gaussian filter over a moment ``rule`` (Taylor-1 or a node rule
    exact for second moments): the steps of the module docstring on a :class:`SqrtState` belief.

    Parameters
    ----------
    model : DiscreteModel (additive noise, uncorrelated; R constant or state-dependent)
    rule : :class:`~nlfilter.filters.rules.Taylor1`, :class:`~nlfilter.filters.rules.Unscented`,
        :class:`~nlfilter.filters.rules.Cubature` or :class:`~nlfilter.filters.rules.GaussHermite`
        (order ≥ 2)
    start : ``"update"`` or ``"predict"`` (see :mod:`nlfilter.filters.base`)

    Notes
    -----
    ``summary`` reports ``(mean, S Sᵀ)``; ``predict``/``update`` take and return a :class:`SqrtState`
    (:meth:`SquareRootFilter.init` makes the first from ``(m0, P0)``, :meth:`SquareRootFilter.belief`
    from a mean and a factor). ``smooth`` is the square-root RTS smoother (:func:`sqrt_rts`).

    Examples
    --------
    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> from nlfilter.filters.rules import Unscented
    >>> x = sp.Symbol("x")
    >>> flt = SquareRootFilter(DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0), Unscented(alpha=0.5))
    >>> b = flt.predict(flt.init([1.0], [[2.0]], (1,)), 0)     # the centre weight −0.25: a downdate
    >>> round(float(b.factor[0, 0, 0] ** 2), 12), round(float(flt.summary(b)[1][0, 0, 0]), 12)   # 0.81 · 2 + 1
    (2.62, 2.62)
    """

    name = "square-root"
    source = ("Morf & Kailath 1975, Square-root algorithms for least-squares estimation, IEEE TAC 20(4); "
              "Bierman 1977, Factorization Methods for Discrete Sequential Estimation")
    structures = ("state-dependent R", "cross noise", "angles")
    compiled = True  # Taylor-1 and node rules: the compiled loop's square-root kinds (compiled.sqrt_kernels)

    @property
    def compiled_kind(self):
        """The compiled loop's kernels: ``"sqrt-taylor1"``, ``"sqrt-nodes"`` (a rule with its own
        square-root columns has none: ``"sqrt-own"``, refused)."""
        if hasattr(self.rule, "sqrt_dynamics"):
            return "sqrt-own"
        return f"sqrt-{getattr(self.rule, 'kind', None)}"

    def __init__(self, model, rule, *, start: str | None = None):
        super().__init__(model, rule, start=start)
        self._square_root_rule(rule)

    def _square_root_rule(self, rule):
        """Refuse a rule without a square-root form (the continuous-discrete forms call it too)."""
        kind = getattr(rule, "kind", None)
        if kind not in ("taylor1", "nodes") and not hasattr(rule, "sqrt_dynamics"):
            raise TypeError(f"rule: the square-root filters take Taylor1 or a node rule (Unscented, Cubature, "
                            f"GaussHermite), got {rule!r}")
        if kind == "nodes" and not _second_moments_exact(rule, self.model.n):
            raise ValueError(f"rule: the square-root update needs a rule whose points carry the covariance "
                             f"(Σ wc_i z_i z_iᵀ = I), got {rule!r}; e.g. GaussHermite(order ≥ 2)")
        self._roots = {}

    def _root(self, key, M):
        """A square root of the constant matrix ``M`` (``model.Q``, ``model.R``), kept while M is."""
        hit = self._roots.get(key)
        if hit is None or hit[0] is not M:
            hit = self._roots[key] = (M, sqrt_psd(np.asarray(M, dtype=float))[0])
        return hit[1]

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        """The prior ``N(m0, P0)`` (checked as every Gaussian filter's) as a :class:`SqrtState`: the
        Cholesky factor of P0 (the symmetric root of a semi-definite one)."""
        st = super().init(m0, P0, batch, initial=initial, rng=rng)  # a MeasuredState with cross noise
        return SqrtState(st.mean, sqrt_psd(st.cov)[0], getattr(st, "y", None))

    def belief(self, mean, factor) -> SqrtState:
        """A :class:`SqrtState` for the step functions (``predict``/``update``) from a mean ``(..., n)``
        and a factor ``(..., n, n)`` of its covariance (``P = factor factorᵀ``): finite,
        lower-triangular with a non-negative diagonal (the form every step keeps; a covariance goes to
        :meth:`SquareRootFilter.init`), broadcast together; anything else is a ValueError naming the argument."""
        n = self.model.n
        mean = V.mean("mean", mean, n)
        S = V.finite("factor", V.as_float_array("factor", factor, shape_tail=(n, n)))
        above = np.triu(S, 1)
        if np.any(above != 0):
            i, j = np.argwhere(above != 0)[0][-2:]
            raise ValueError(f"factor: expected a lower-triangular factor (zeros above the diagonal), got the entry "
                             f"{float(above[..., i, j].ravel()[np.flatnonzero(above[..., i, j])[0]])!r} at ({i}, {j})")
        if np.any(np.diagonal(S, axis1=-2, axis2=-1) < 0):
            raise ValueError("factor: expected a non-negative diagonal (the Cholesky convention), got a negative entry")
        try:
            lead = np.broadcast_shapes(mean.shape[:-1], S.shape[:-2])
        except ValueError:
            raise ValueError(f"mean/factor: shapes {mean.shape}, {S.shape} do not broadcast") from None
        return SqrtState(np.broadcast_to(mean, (*lead, n)).copy(), np.broadcast_to(S, (*lead, n, n)).copy())

    def summary(self, belief):
        S = belief[1]
        return belief[0], symmetrize(mm(S, S.swapaxes(-1, -2)))

    @staticmethod
    def _check_belief(state):
        """A step's belief must carry a factor: a covariance passed for one would be read as one."""
        if not isinstance(state, SqrtState):
            raise TypeError(f"belief: the square-root filters step a SqrtState (mean, factor), made by init(m0, P0, "
                            f"batch) or belief(mean, factor); got {type(state).__name__}")

    def predict(self, state, k):
        """The prediction from step ``k``, from ``N(m, α² P)`` with fading memory (factor ``α S``)."""
        return self._predict(self._inflate(state), k)

    def _inflate(self, state):
        """The belief a prediction starts from: with fading memory α a factor times α; a moment
        belief (of the moment-based backward passes) as every Gaussian filter's
        (:class:`~nlfilter.filters.fading.FadingMemory`)."""
        if isinstance(state, SqrtState) and self.fading != 1.0:
            return state._replace(factor=state.factor * self.fading)
        return super()._inflate(state)

    def _predict(self, state, k):
        self._check_belief(state)
        return self._sqrt_predict(state, k)

    def _sqrt_predict(self, state, k, joint: bool = False):
        """:func:`sqrt_predict` from step ``k``; correlated noise (``cross_noise``, the belief's ``y``):
        the decorrelated dynamics ``f + G K_w (y_k − h)`` and the factor of ``Q − K_w Sᵀ``
        (:class:`~nlfilter.filters.skeleton.CrossNoise`, Anderson & Moore 1979, §5.5)."""
        md, cr = self.model, self._cross
        Q, f = md.Q, (None, None, None)
        if cr.S is not None and state.y is not None:
            obs = ~np.isnan(state.y)
            Kw, KS = decorrelation(cr.S, md.R, cr._Rinv, obs)  # K_w = S_o R_oo⁻¹, K_w Sᵀ
            f = _decorrelated(md, md.G(np.zeros(md.n), k) @ Kw, np.where(obs, state.y, 0.0))
            Q = Q - KS  # Cov[w̃] = Q − K_w Sᵀ
        Lq = self._root("Q", Q) if f[0] is None else sqrt_psd(Q)[0]
        out = sqrt_predict(self.rule, md, state, self._time(k), Lq, joint=joint, f=f[0], f_x=f[1], f_xx=f[2])
        if joint:
            return out
        new, failed = out
        if cr.S is not None:  # predicted: conditioned on no measurement yet
            new = new._replace(y=np.full((*new.mean.shape[:-1], md.m), np.nan))
        return _poison(new, failed)

    smoother_keeps = True  # the backward pass reads the filtered factors (sqrt_rts)

    def _smooth(self, est, beliefs, ys, t0):
        """The square-root RTS backward pass over the filtered factors (:func:`sqrt_rts`); after the
        compiled forward pass, which keeps none, the Cholesky factors of its ``S Sᵀ`` (S itself, to rounding)."""
        if beliefs is None and est.means.shape[1]:
            beliefs = [SqrtState(est.means[:, k], sqrt_psd(est.covs[:, k])[0]) for k in range(est.means.shape[1])]
        if not beliefs:  # no step: nothing to smooth
            return est.means.copy(), est.covs.copy(), {"lag_one_cov": np.full_like(est.covs, np.nan)}
        off = 0 if self.start == "update" else 1
        ms, Ps, lag = sqrt_rts(beliefs, lambda b, k: self._joint(b, k + off), angles_of(self.model).states)
        return ms, Ps, {"lag_one_cov": lag}

    def _joint(self, belief, k):
        """:func:`sqrt_predict` with ``joint`` from step ``k``. With fading memory α the joint law is
        the one that reads the inflation as added process noise (:mod:`nlfilter.filters.fading`): from
        the inflated belief's ``[[S⁻, 0], [Ḡ, S_c]]``, ``D = Ḡ S⁻ᵀ / α²`` and
        ``P − D P⁻⁻¹ Dᵀ = S_c S_cᵀ / α² + (1/α² − 1/α⁴) Ḡ Ḡᵀ`` (a sum of PSD terms: its factor by ``tria``)."""
        mp, J, failed = self._sqrt_predict(self._inflate(belief), k, joint=True)
        a = self.fading
        if a != 1.0:
            n = mp.shape[-1]
            Gb, Sc = J[..., n:, :n], J[..., n:, n:]
            J = J.copy()
            J[..., n:, n:] = tria(np.concatenate([Sc / a, np.sqrt(1.0 / a**2 - 1.0 / a**4) * Gb], axis=-1))
            J[..., n:, :n] = Gb / a**2
        return mp, J, failed

    def _predict_cross(self, state, k):
        """The prediction (the rule's, from moments) and ``Cov[x_k, f(x_k)]`` of the moment-based backward
        passes: the fixed-lag smoother and the posterior sampler (:mod:`~nlfilter.filters.sampling`)."""
        pred, D = GaussianFilter._predict(self, self._inflate(state), k, cross=True)
        return pred, self._deflate(D)

    def _measurement_root(self):
        md = self.model
        return (md.R, self._root("R", md.R)) if getattr(md, "R_constant", True) else None

    def _conditioned(self, state, y, k, full: bool = False):
        self._check_belief(state)
        y = np.asarray(y, dtype=float)
        new, bad, info = sqrt_condition(self.rule, self.model, state, y, self._time(k), self._measurement_root(),
                                        full=full)
        return self._carry(_poison(new, bad), y), bad, info

    def _carry(self, new, y):
        """The updated belief with the measurement it saw, when the noise is correlated."""
        if self._cross.S is None:
            return new
        return new._replace(y=np.broadcast_to(y, new.mean.shape[:-1] + y.shape[-1:]))

    def _update_info(self, state, y, k):
        """``run(..., loglik=True)``: the update with the step's log-likelihood from the innovation
        factor (:func:`factor_info`)."""
        y = np.asarray(y, dtype=float)
        new, bad, (yhat, Sy, u, S) = self._conditioned(state, y, k, full=True)
        return new, bad, factor_info(y, yhat, Sy, u, S)
