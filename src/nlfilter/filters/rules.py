"""Moment rules for the Gaussian family: E[g], Cov[x, g], Cov[g, g] under a Gaussian belief.

A rule is a small frozen object. Given a batch of Gaussian beliefs ``x ~ N(m, P)`` (``m (..., n)``,
``P (..., n, n)``) and a batched function ``g(X, t) -> (..., p)`` it returns :class:`GaussMoments`::

    mean  = E[g(x)]                  (..., p)
    cross = Cov[x, g(x)]             (..., n, p)   (None when not asked for)
    cov   = Cov[g(x), g(x)]          (..., p, p)
    jac   = the linearization g_x(m) (..., p, n)   (Taylor rules only, else None)
    bad   = paths whose P has no square root (..., ) bool, or None
    noise = E[G(x) Q G(x)ᵀ] (..., n, n) of ``model`` when asked for (``noise_of=model``), else None

(the noise term uses the same nodes as the moments of ``g``). The filters of
:mod:`nlfilter.filters.gaussian` are one predict/update skeleton over a rule, as in dynamax's
generalized Gaussian filter (its ``EKFIntegrals``, ``UKFIntegrals``, ``GHKFIntegrals``):

=====================  ===========================================================================
rule                   approximation
=====================  ===========================================================================
:class:`Taylor1`       ``g(x) ≈ g(m) + J (x − m)``, ``J = g_x(m)``: E[g] = g(m), Cov[x, g] = P Jᵀ,
                       Cov[g] = J P Jᵀ (the EKF; exact on linear g)
:class:`Taylor2`       second-order expansion with Gaussian fourth moments (the Gaussian
                       second-order filter; exact on quadratic g)
:class:`Unscented`     scaled sigma points of van der Merwe (2n + 1 points), ``(alpha, beta, kappa)``
:class:`Cubature`      the third-degree spherical-radial rule of Arasaratnam & Haykin (2009):
                       2n points ``m ± √n L e_i`` (``P = L Lᵀ``), equal weights ``1/(2n)``
:class:`GaussHermite`  tensor-product Gauss–Hermite rule with ``order`` points per axis
                       (``order**n`` points; exact for polynomials of degree ``2·order − 1`` in
                       each variable; Ito & Xiong 2000)
=====================  ===========================================================================

Node rules share one implementation: points ``X_i = m + L z_i`` with mean weights ``w_i`` and
covariance weights ``w^c_i``, then ``E[g] ≈ Σ w_i g(X_i)``, ``Cov[x, g] ≈ Σ w^c_i (X_i − m)(g_i − ĝ)ᵀ``,
``Cov[g] ≈ Σ w^c_i (g_i − ĝ)(g_i − ĝ)ᵀ``, ``E[G Q Gᵀ] ≈ Σ w_i G(X_i) Q G(X_i)ᵀ`` (``G Q Gᵀ`` for
constant G). The square root is the Cholesky factor, the eigen root where P is only semi-definite,
and the identity on paths whose P is not PSD (``bad``: the filter poisons them, so that ``run``
raises or marks them; :func:`~nlfilter.filters.base.sqrt_psd`).

>>> import numpy as np
>>> from nlfilter.filters.base import GaussianState
>>> s = GaussianState(np.array([1.0]), np.array([[0.5]]))
>>> sq = lambda X, t: X**2                                   # E[x²] = m² + P = 1.5
>>> round(float(GaussHermite(3).moments(s, sq, 0).mean[0]), 12), float(Cubature().moments(s, sq, 0).mean[0])
(1.5, 1.5)
>>> float(Taylor1().moments(s, sq, 0, jac=lambda X, t: 2 * X[..., None]).mean[0])   # g(m)
1.0
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .. import _validate as V
from ..moments.quadrature import gauss_hermite_rule
from .linalg import mm, sqrt_psd
from .second_order import gaussian_quartic, hessian_trace, noise_covariance

__all__ = ["GaussMoments", "Taylor1", "Taylor2", "Unscented", "Cubature", "GaussHermite", "NodeRule",
           "sigma_points"]


MAX_NODES = 100_000  # Gauss–Hermite tensor grids larger than this are refused (order**n nodes)


class GaussMoments(NamedTuple):
    """Moments of ``g(x)`` under a Gaussian belief (see the module docstring)."""

    mean: np.ndarray
    cross: np.ndarray | None
    cov: np.ndarray
    jac: np.ndarray | None = None
    bad: np.ndarray | None = None
    noise: np.ndarray | None = None


@dataclass(frozen=True)
class Taylor1:
    """First-order Taylor rule (the EKF's): ``E[g] = g(m)``, ``Cov[x, g] = P Jᵀ``, ``Cov[g] = J P Jᵀ``
    with ``J = g_x(m)``; ``E[G Q Gᵀ] = G(m) Q G(m)ᵀ``. Exact when g is affine (and G constant)."""

    name = "taylor1"

    def needs(self, model):
        """The model's derivatives this rule evaluates."""
        return ("f_x", "h_x")

    def moments(self, state, g, t, *, jac, hess=None, cross: bool = True, cov: bool = True, noise_of=None
                ) -> GaussMoments:
        """``jac``: the Jacobian ``g_x(X, t) -> (..., p, n)``; ``cross``/``cov``: whether
        Cov[x, g] / Cov[g] are wanted (else None); ``noise_of``: a model whose ``E[G Q Gᵀ]`` to add."""
        m, P = state
        J = jac(m, t)
        Q = None if noise_of is None else noise_of.GQGT(m, t)  # G(m) Q G(m)ᵀ
        if cross:
            C = mm(P, np.swapaxes(J, -1, -2))  # Cov[x, g] = P Jᵀ
            return GaussMoments(g(m, t), C, mm(J, C) if cov else None, J, None, Q)
        S = mm(mm(J, P), np.swapaxes(J, -1, -2)) if cov else None  # J P Jᵀ
        return GaussMoments(g(m, t), None, S, J, None, Q)


@dataclass(frozen=True)
class Taylor2:
    """Gaussian second-order rule: ``g`` expanded to second order about ``m``, moments of a Gaussian::

        E[g] = g(m) + ½ (P g_xx),   Cov[x, g] = P Jᵀ,
        Cov[g]_ij = (J P Jᵀ)_ij + ½ tr(g_xx⁽ⁱ⁾ P g_xx⁽ʲ⁾ P)

    (``(P g_xx)_i = Σ_jl P_jl ∂²g_i/∂x_j∂x_l``; third moments vanish, fourth are Gaussian) and
    ``E[G Q Gᵀ]`` to second order with its Gaussian fourth-moment term (seed 004 eqs. 13-14). Exact
    for quadratic g. Over the skeleton it is the Gaussian second-order filter without the C tensor,
    ``SecondOrderFilter(form="modified-gaussian")`` (Jazwinski 1970, ch. 9; seed 004).
    ``hess``: the Hessian ``g_xx(X, t) -> (..., p, n, n)``."""

    name = "taylor2"

    def needs(self, model):
        return ("f_x", "f_xx", "h_x", "h_xx") + (() if model.G_constant else ("G_x", "G_xx"))

    def moments(self, state, g, t, *, jac, hess, cross: bool = True, cov: bool = True, noise_of=None
                ) -> GaussMoments:
        m, P = state
        J, A = jac(m, t), hess(m, t)
        mean = g(m, t) + 0.5 * hessian_trace(P, A)  # 004 eqs. 18, 20
        C = P @ np.swapaxes(J, -1, -2) if (cross or cov) else None  # Cov[x, g] = P Jᵀ
        S = J @ C + gaussian_quartic(P, A) if cov else None
        Q = None
        if noise_of is not None:
            md = noise_of
            Q = noise_covariance(P, md.Q, md.G(m, t), None if md.G_constant else md.G_x(m, t),
                                 None if md.G_constant else md.G_xx(m, t), gaussian=True)
        return GaussMoments(mean, C if cross else None, S, None, None, Q)


class NodeRule:
    """Base of the node rules: subclasses give ``nodes(m, P) -> (X (..., N, n), w (N,), wc (N,), bad)``."""

    def nodes(self, m, P):  # pragma: no cover
        raise NotImplementedError

    def needs(self, model):
        return ()

    def moments(self, state, g, t, *, jac=None, hess=None, cross: bool = True, cov: bool = True,
                noise_of=None) -> GaussMoments:
        """As :meth:`Taylor1.moments` (``jac``, ``hess`` are not used)."""
        m, P = state
        X, w, wc, bad = self.nodes(m, P)
        GX = g(X, t)
        mean = np.einsum("i,...ij->...j", w, GX)  # Σ w_i g(X_i)
        D = GX - mean[..., None, :]
        S = np.einsum("i,...ia,...ib->...ab", wc, D, D) if cov else None  # Σ wc_i (g_i − ĝ)(g_i − ĝ)ᵀ
        C = np.einsum("i,...ia,...ib->...ab", wc, X - m[..., None, :], D) if cross else None
        Q = None
        if noise_of is not None:  # E[G Q Gᵀ]: G Q Gᵀ for constant G, else Σ w_i G(X_i) Q G(X_i)ᵀ
            Q = (noise_of.GQGT(m, t) if noise_of.G_constant
                 else np.einsum("i,...iab->...ab", w, noise_of.GQGT(X, t)))
        return GaussMoments(mean, C, S, None, bad if bad.any() else None, Q)


def sigma_points(m, P, alpha, beta, kappa):
    """Sigma points ``(..., 2n+1, n)``, weights ``(Wm, Wc)`` of shape ``(2n+1,)``, and the paths
    ``(...)`` whose covariance is not PSD (their points are drawn from the identity and must be
    discarded: the filter poisons them so that ``run`` raises or marks them). The square root is the
    Cholesky factor, or the eigen root where P is only semi-definite (:func:`sqrt_psd`)."""
    n = m.shape[-1]
    lam = alpha**2 * (n + kappa) - n
    L, bad = sqrt_psd((n + lam) * P)
    Lt = np.swapaxes(L, -1, -2)  # rows = columns of L
    X = np.concatenate([m[..., None, :], m[..., None, :] + Lt, m[..., None, :] - Lt], axis=-2)
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + 1 - alpha**2 + beta
    return X, Wm, Wc, bad



@dataclass(frozen=True)
class Unscented(NodeRule):
    """Scaled unscented transform (van der Merwe), nodes of :func:`~nlfilter.filters.ukf.sigma_points`."""

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    name = "unscented"

    def __post_init__(self):
        object.__setattr__(self, "alpha", float(V.positive("alpha", self.alpha)))
        object.__setattr__(self, "beta", float(V.positive("beta", self.beta, strict=False)))
        if not np.isfinite(self.kappa):
            raise ValueError(f"kappa: expected a finite number, got {self.kappa!r}")
        object.__setattr__(self, "kappa", float(self.kappa))

    def check(self, n):
        if n + self.kappa <= 0:
            raise ValueError(f"kappa: expected n + kappa > 0 (n = {n}), got {self.kappa!r}")

    def nodes(self, m, P):
        return sigma_points(m, P, self.alpha, self.beta, self.kappa)


def _weights(w):
    w = np.asarray(w, float)
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=None)
def _cubature_weights(n):
    return _weights(np.full(2 * n, 0.5 / n))


@functools.lru_cache(maxsize=None)
def _gh_rule(n, order):
    z, w = gauss_hermite_rule(n, order)
    z.flags.writeable = False
    return z, _weights(w)


@dataclass(frozen=True)
class Cubature(NodeRule):
    """Third-degree spherical-radial cubature (Arasaratnam & Haykin 2009, the CKF's rule):
    ``X_{±i} = m ± √n L e_i``, weights ``1/(2n)`` (the unscented points with α = 1, β = κ = 0,
    whose centre point has weight zero)."""

    name = "cubature"

    def nodes(self, m, P):
        n = m.shape[-1]
        L, bad = sqrt_psd(P)
        Lt = math.sqrt(n) * np.swapaxes(L, -1, -2)  # rows: √n × the columns of L
        X = np.concatenate([m[..., None, :] + Lt, m[..., None, :] - Lt], axis=-2)
        w = _cubature_weights(n)
        return X, w, w, bad


@dataclass(frozen=True)
class GaussHermite(NodeRule):
    """Tensor-product Gauss–Hermite rule (Ito & Xiong 2000): ``order`` nodes per axis,
    ``X_p = m + L z_p`` with ``z_p`` the probabilists' Hermite nodes (``order**n`` points)."""

    order: int = 3
    name = "gauss-hermite"

    def __post_init__(self):
        if isinstance(self.order, bool) or not isinstance(self.order, (int, np.integer)) or self.order < 1:
            raise ValueError(f"order: expected a positive integer, got {self.order!r}")
        object.__setattr__(self, "order", int(self.order))

    def check(self, n):
        if self.order ** n > MAX_NODES:
            raise ValueError(f"order: {self.order}**{n} = {self.order ** n} nodes per expectation exceed "
                             f"{MAX_NODES}; expected a lower order, or the Cubature rule for n = {n}")

    def nodes(self, m, P):
        z, w = _gh_rule(m.shape[-1], self.order)
        L, bad = sqrt_psd(P)
        X = m[..., None, :] + np.einsum("...ij,pj->...pi", L, z)  # X_p = m + L z_p
        return X, w, w, bad
