"""Moment rules for the Gaussian family: E[g], Cov[x, g], Cov[g, g] under a Gaussian belief.

A rule is a small frozen object. Given a batch of Gaussian beliefs ``x ~ N(m, P)`` (``m (..., n)``,
``P (..., n, n)``) and a batched function ``g(X, t) -> (..., p)`` it returns :class:`GaussMoments`::

    mean  = E[g(x)]                  (..., p)
    cross = Cov[x, g(x)]             (..., n, p)   (None when not asked for)
    cov   = Cov[g(x), g(x)]          (..., p, p)
    jac   = the linearization g_x(m) (..., p, n)   (Taylor rules only, else None)
    bad   = paths whose P has no square root (..., ) bool, or None
    noise = E[G(x) Q G(x)ᵀ] (..., n, n) of ``model`` when asked for (``noise_of=model``), else None
    quartic = the fourth-moment part of Cov[g], kept apart (Taylor-2 under the skeleton), else None
    forcing = the covariance forcing tensor M (..., n, n, p) of seed 004 eq. 33 (Taylor-2), else None

(the noise term uses the same nodes as the moments of ``g``; the skeleton applies every term that is
not None). Two table entries of every rule tell the skeleton what to do with the sums:
``symmetrize`` (the predicted covariance) and ``screen`` (the innovation covariance checked for
positive definiteness, failed paths reported). The skeleton says which function it
asks about (``role="dynamics"`` for f, ``"measurement"`` for h): the forms of seed 004 differ there. The filters of
:mod:`nlfilter.filters.gaussian` configure one predict/condition skeleton over a rule
(:mod:`nlfilter.filters.skeleton`), as in dynamax's
generalized Gaussian filter (its ``EKFIntegrals``, ``UKFIntegrals``, ``GHKFIntegrals``):

=====================  ===========================================================================
rule                   approximation
=====================  ===========================================================================
:class:`Taylor1`       ``g(x) ≈ g(m) + J (x − m)``, ``J = g_x(m)``: E[g] = g(m), Cov[x, g] = P Jᵀ,
                       Cov[g] = J P Jᵀ (the EKF; exact on linear g)
:class:`Taylor2`       second-order expansion in the forms of seed 004 (``form``: truncated,
                       truncated-jazwinski, modified, gaussian, modified-gaussian (default:
                       Gaussian fourth moments, exact on quadratic g), first-order), with the −¼
                       terms and the forcing tensor C of 004 eq. 33 as each form has them
:class:`Unscented`     scaled sigma points of van der Merwe (2n + 1 points), ``(alpha, beta, kappa)``
:class:`Cubature`      the third-degree spherical-radial rule of Arasaratnam & Haykin (2009):
                       2n points ``m ± √n L e_i`` (``P = L Lᵀ``), equal weights ``1/(2n)``
:class:`GaussHermite`  tensor-product Gauss–Hermite rule with ``order`` points per axis
                       (``order**n`` points; exact for polynomials of degree ``2·order − 1`` in
                       each variable; Ito & Xiong 2000)
:class:`Cubature5`     Stroud's fifth-degree rule (``2n² + 1`` points; Jia, Xin & Cheng 2013)
=====================  ===========================================================================

Node rules share one implementation: points ``X_i = m + L z_i`` with mean weights ``w_i`` and
covariance weights ``w^c_i``, then ``E[g] ≈ Σ w_i g(X_i)``, ``Cov[x, g] ≈ Σ w^c_i (X_i − m)(g_i − ĝ)ᵀ``,
``Cov[g] ≈ Σ w^c_i (g_i − ĝ)(g_i − ĝ)ᵀ``, ``E[G Q Gᵀ] ≈ Σ w_i G(X_i) Q G(X_i)ᵀ`` (``G Q Gᵀ`` for
constant G). The square root is the Cholesky factor, the eigen root where P is only semi-definite,
and the identity on paths whose P is not PSD (``bad``: the filter poisons them, so that ``run``
raises or marks them; :func:`~nlfilter.filters.linalg.sqrt_psd`).

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
from .._npcall import einsum as _einsum
from ..angles import node_moments, wrap_components
from ..moments.quadrature import MAX_ENTRIES, cubature5_rule, gauss_hermite_rule
from .contractions import gaussian_quartic, hessian_trace, noise_covariance, quarter_outer  # (re-exported)
from .linalg import axis_gather, matmul, mm, psd_root

__all__ = ["GaussMoments", "Taylor1", "Taylor2", "FORMS", "Form", "FORM_TABLE", "Unscented", "Cubature", "GaussHermite", "NodeRule",
           "sigma_points", "hessian_trace", "quarter_outer", "gaussian_quartic", "noise_covariance"]


MAX_NODES = 100_000  # Gauss–Hermite tensor grids larger than this are refused (order**n nodes)


class GaussMoments(NamedTuple):
    """Moments of ``g(x)`` under a Gaussian belief (see the module docstring)."""

    mean: np.ndarray
    cross: np.ndarray | None
    cov: np.ndarray
    jac: np.ndarray | None = None
    bad: np.ndarray | None = None
    noise: np.ndarray | None = None
    quartic: np.ndarray | None = None
    forcing: np.ndarray | None = None


@dataclass(frozen=True)
class Taylor1:
    """First-order Taylor rule (the EKF's): ``E[g] = g(m)``, ``Cov[x, g] = P Jᵀ``, ``Cov[g] = J P Jᵀ``
    with ``J = g_x(m)``; ``E[G Q Gᵀ] = G(m) Q G(m)ᵀ``. Exact when g is affine (and G constant)."""

    name = "taylor1"
    kind = "taylor1"  # the compiled loop's step kernel (nlfilter.filters.compiled)
    second = False  # no second-order terms (for the continuous skeleton)
    symmetrize = False  # the skeleton's table entries (nlfilter.filters.skeleton): P⁻ as computed,
    screen = False  # S not screened (H P Hᵀ + R is PSD by construction)

    def noise(self, model, m, P, t):
        """``E[G Q Gᵀ] ≈ G(m) Q G(m)ᵀ``."""
        return model.GQGT(m, t)

    def forcing(self, P, A):
        """No forcing tensor (first order)."""
        return None

    def needs(self, model):
        """The model's derivatives this rule evaluates."""
        return ("f_x", "h_x")

    def moments(self, state, g, t, *, jac, hess=None, cross: bool = True, cov: bool = True, noise_of=None,
                role=None, angles=()) -> GaussMoments:
        """``jac``: the Jacobian ``g_x(X, t) -> (..., p, n)``; ``cross``/``cov``: whether
        Cov[x, g] / Cov[g] are wanted (else None); ``noise_of``: a model whose ``E[G Q Gᵀ]`` to add;
        ``angles``: the angular components of g, their mean wrapped (:mod:`nlfilter.angles`)."""
        m, P = state
        J = jac(m, t)
        Q = None if noise_of is None else noise_of.GQGT(m, t)  # G(m) Q G(m)ᵀ
        mean = wrap_components(g(m, t), angles) if angles else g(m, t)
        if cross:
            C = mm(P, J.swapaxes(-1, -2))  # Cov[x, g] = P Jᵀ
            return GaussMoments(mean, C, mm(J, C) if cov else None, J, None, Q)
        S = mm(mm(J, P), J.swapaxes(-1, -2)) if cov else None  # J P Jᵀ
        return GaussMoments(mean, None, S, J, None, Q)


#: the forms of the Taylor-2 rule (:class:`Taylor2`), the ``form=`` of the second-order filters
FORMS = ("truncated", "truncated-jazwinski", "modified", "gaussian", "modified-gaussian", "first-order")


class Form(NamedTuple):
    """One row of :data:`FORM_TABLE`: what a second-order form of seed 004 keeps.

    ``prediction`` / ``innovation``: the fourth-moment term of Cov[f] (the predicted covariance) and
    of Cov[h] (the innovation covariance) — ``"none"``, ``"-quarter"`` (−¼(P g_xx)(P g_xx)ᵀ, 004
    eq. 11 and after eq. 23) or ``"gaussian"`` (½ tr(g_xx⁽ⁱ⁾ P g_xx⁽ʲ⁾ P)); ``forcing``: the
    covariance forcing tensor of the update (004 eq. 33) — ``"none"``, ``"truncated"`` or
    ``"gaussian"``; ``gaussian_noise``: whether E[G V Gᵀ] keeps its Gaussian fourth moments
    (004 eq. 19); ``second``: whether any second-order term is kept (``False``: the EKF's arithmetic)."""

    prediction: str
    innovation: str
    forcing: str
    gaussian_noise: bool
    second: bool = True


#: seed 004's forms as data (Henriksen 1979; :mod:`nlfilter.filters.second_order`): the NumPy
#: skeleton and the compiled loop both read this table
FORM_TABLE = {
    "truncated": Form("none", "none", "none", False),
    "truncated-jazwinski": Form("-quarter", "-quarter", "truncated", False),
    "modified": Form("none", "-quarter", "none", False),
    "gaussian": Form("gaussian", "gaussian", "gaussian", True),
    "modified-gaussian": Form("gaussian", "gaussian", "none", True),
    "first-order": Form("none", "none", "none", False, second=False),
}


@dataclass(frozen=True)
class Taylor2:
    """Second-order Taylor rule in the forms of seed 004 (Henriksen 1979): ``g`` expanded to second
    order about ``m``, third central moments neglected::

        E[g] = g(m) + ½ (P g_xx)                       (004 eqs. 18, 20)
        Cov[x, g] = P Jᵀ,   Cov[g] = J P Jᵀ + [fourth-moment term of the form]
        E[G Q Gᵀ] = G Q Gᵀ + (P Q G_x²) + ½(P Q G_xx G) + ½(·)ᵀ  [+ Gaussian fourth moments]   (eqs. 13-14, 19)

    (``(P g_xx)_i = Σ_jl P_jl ∂²g_i/∂x_j∂x_l``). ``form`` (one of :data:`FORMS`) chooses the
    fourth-moment term, for the dynamics (``role="dynamics"``) and the measurement
    (``role="measurement"``) separately: none (``"truncated"``, 004 eqs. 18-23), −¼(P g_xx)(P g_xx)ᵀ
    (Jazwinski's, 004 eq. 11 and after eq. 23), or ½ tr(g_xx⁽ⁱ⁾ P g_xx⁽ʲ⁾ P) (Gaussian fourth moments);
    and the forcing tensor ``M (..., n, n, p)`` of the covariance update (004 eq. 33; ``forcing``).
    ``"first-order"`` drops every second-order term (the EKF's arithmetic).

    The default ``"modified-gaussian"`` is the Gaussian second-order filter without the C tensor
    (Jazwinski 1970, ch. 9): exact for quadratic g. Standalone (``role=None``), ``cov`` is the whole
    Cov[g]; for the skeleton (``role`` given) the fourth-moment term comes apart in ``quartic`` and is
    added last, and ``jac`` is returned only where ``S = H P Hᵀ + R`` exactly (no measurement
    term: the update may then use the Joseph form, 004 eq. 21). Over the skeletons of
    :mod:`nlfilter.filters.gaussian` this rule *is* :class:`~nlfilter.filters.second_order.SecondOrderFilter`
    and :class:`~nlfilter.filters.second_order.ContinuousDiscreteSecondOrderFilter`.
    ``hess``: the Hessian ``g_xx(X, t) -> (..., p, n, n)``."""

    form: str = "modified-gaussian"
    name = "taylor2"
    kind = "taylor2"  # the compiled loop's step kernel
    symmetrize = True  # the skeleton (nlfilter.filters.skeleton) symmetrizes the predicted covariance (as 004's filters do)
    screen = True  # the skeleton screens the innovation covariance for positive definiteness

    def __post_init__(self):
        object.__setattr__(self, "form", V.choice("form", self.form, set(FORMS)))

    @property
    def second(self) -> bool:
        return FORM_TABLE[self.form].second

    def needs(self, model):
        if not self.second:
            return ("f_x", "h_x")
        return ("f_x", "h_x", "f_xx", "h_xx") + (() if model.G_constant else ("G_x", "G_xx"))

    def noise(self, model, m, P, t):
        """``E[G(x) V G(x)ᵀ]`` to second order (004 eqs. 13-14, 19; :func:`noise_covariance`)."""
        if model.G_constant and not getattr(model, "_per_path_G", True):  # one G for every path: once, broadcast
            GQG = _einsum("...ia,ab,...qb->...iq", G := model.G(np.zeros(model.n), t), model.Q, G)  # (the same sums)
            return np.ndarray((*m.shape[:-1], *GQG.shape), float, GQG, 0, (0,) * (m.ndim - 1) + GQG.strides)
        G = model.G(m, t)
        if model.G_constant or not self.second:
            return _einsum("...ia,ab,...qb->...iq", G, model.Q, G)
        return noise_covariance(P, model.Q, G, model.G_x(m, t), model.G_xx(m, t), gaussian=FORM_TABLE[self.form].gaussian_noise)

    def forcing(self, P, A):
        """The covariance forcing tensor ``M (..., n, n, p)`` with ``dP = Σ_k M_ijk [·]_k``, or None.

        truncated-Jazwinski (004 eq. 33, the retained term): ``M_ijk = −½ P_ij (P h_xx)_k``;
        Gaussian (fourth moments of a Gaussian in eq. 33): ``M_ijk = (P h_xx⁽ᵏ⁾ P)_ij``."""
        kind = FORM_TABLE[self.form].forcing
        if kind == "truncated":
            return -0.5 * P[..., :, :, None] * hessian_trace(P, A)[..., None, None, :]
        if kind == "gaussian":
            return np.einsum("...ia,...kab,...bj->...ijk", P, A, P)  # (P h_xx^(k) P)_ij
        return None

    def moments(self, state, g, t, *, jac, hess=None, cross: bool = True, cov: bool = True, noise_of=None,
                role=None, angles=()) -> GaussMoments:
        m, P = state
        J = jac(m, t)
        mean = g(m, t)
        A = None
        if self.second:
            A = hess(m, t)
            mean = mean + 0.5 * hessian_trace(P, A)  # 004 eqs. 18, 20
        mean = wrap_components(mean, angles)  # angular components in (−π, π] (the Taylor terms at m)
        form = FORM_TABLE[self.form]
        kind = form.prediction if role == "dynamics" else form.innovation if role == "measurement" else "gaussian"
        quartic = None
        if A is not None and cov:
            if kind == "-quarter":
                quartic = -quarter_outer(P, A)  # 004 eq. 11 / after eq. 23 (pre-correction)
            elif kind == "gaussian":
                quartic = gaussian_quartic(P, A)
        Jt = J.swapaxes(-1, -2)
        C = S = None
        if role == "dynamics" and not cov:  # the drift of dP/dt: Cov[x, f] = (F P)ᵀ
            C = matmul(J, P).swapaxes(-1, -2) if cross else None
        elif role == "dynamics":
            S = matmul(matmul(J, P), Jt)  # 004 eq. 19: F X Fᵀ
            C = matmul(P, Jt) if cross else None
        elif cross or cov:
            C = matmul(P, Jt)  # Cov[x, g] = P Jᵀ (third moments neglected)
            S = matmul(J, C) if cov else None
        if role is None and quartic is not None:
            S, quartic = S + quartic, None
        Q = None if noise_of is None else self.noise(noise_of, m, P, t)
        forcing = self.forcing(P, A) if role == "measurement" and A is not None else None
        jac_out = J if role == "measurement" and form.innovation == "none" else None
        return GaussMoments(mean, C if cross else None, S, jac_out, None, Q, quartic, forcing)


class NodeRule:
    """Base of the node rules: a rule *is* its table of unit nodes and weights.

    A subclass gives ``unit_nodes(n) -> (z (N, n), wm (N,), wc (N,))``: the nodes of
    N(0, I_n) with the mean and covariance weights (read-only arrays, cached per n). The points
    under ``N(m, P)`` are ``X_i = m + L z_i`` with ``L`` the square root of P
    (:func:`~nlfilter.filters.linalg.sqrt_psd`); the NumPy skeleton (:meth:`moments`) and the
    compiled loop (``nlfilter.filters.compiled``) both read this one table, so a new node rule
    is a table (and a registry line). ``check(n)``, when defined, refuses a dimension the table
    cannot serve (a ValueError naming the rule's argument)."""

    kind = "nodes"  # the compiled loop's step kernel
    symmetrize = False  # the skeleton's table entries (nlfilter.filters.skeleton): P⁻ as the sums give it,
    screen = False  # S not screened (a weighted sum of outer products plus R)

    def unit_nodes(self, n: int):  # pragma: no cover
        raise NotImplementedError

    def nodes(self, m, P):
        """``(X (..., N, n), wm (N,), wc (N,), bad (...))``: the points ``m + L z_i`` and weights; ``bad``:
        paths whose P has no square root (points from the identity, to discard: the filter poisons them)."""
        X, wm, wc, bad = self._nodes(m, P)
        return X, wm, wc, (np.zeros(P.shape[:-2], bool) if bad is None else bad)

    def _nodes(self, m, P):  # nodes with bad None where every path has its root (no all-False array)
        L, bad = psd_root(P)
        return (*self.points(m, L), bad)

    def points(self, m, L):
        """``(X (..., N, n), wm, wc)``: the points ``m + L z_i`` of any root ``L`` of P (the square-root filters
        pass their propagated factor, :mod:`~nlfilter.filters.square_root`)."""
        z, wm, wc = self.unit_nodes(m.shape[-1])
        Lt = L.swapaxes(-1, -2)  # rows: the columns of L
        axes = axis_gather(z)
        if axes is not None:  # nodes on the axes (unscented, cubature): X_p = m + z_pj L e_j,
            col, zc = axes  # a gather (the same numbers as the product, faster)
            return m[..., None, :] + Lt[..., col, :] * zc, wm, wc
        return m[..., None, :] + z @ Lt, wm, wc  # X_p = m + L z_p: one batched product (an einsum is a naive loop)

    def needs(self, model):
        return ()

    def moments(self, state, g, t, *, jac=None, hess=None, cross: bool = True, cov: bool = True,
                noise_of=None, role=None, angles=()) -> GaussMoments:
        """As :meth:`Taylor1.moments` (``jac``, ``hess``, ``role`` unused); ``angles``: circular means."""
        m, P = state
        X, w, wc, bad = self._nodes(m, P) if type(self).nodes is NodeRule.nodes else self.nodes(m, P)  # (a rule's own)
        GX = g(X, t)
        mean, D = node_moments(GX, w, angles)  # Σ w_i g(X_i), g_i − ĝ (angles: circular, wrapped)
        if m.shape[-1] < 4:  # small states: the einsums cost little (and keep their rounding)
            S = _einsum("i,...ia,...ib->...ab", wc, D, D) if cov else None  # Σ wc_i (g_i − ĝ)(g_i − ĝ)ᵀ
            C = _einsum("i,...ia,...ib->...ab", wc, X - m[..., None, :], D) if cross else None
        else:  # batched matmuls Σ_i A_ia (wc_i D_ib): a three-operand einsum is a naive loop, 5-20x
            Dw = D * wc[:, None]  # slower from n = 4 (the sums differ from it by rounding only)
            S = D.swapaxes(-1, -2) @ Dw if cov else None
            C = (X - m[..., None, :]).swapaxes(-1, -2) @ Dw if cross else None
        Q = None
        if noise_of is not None:  # E[G Q Gᵀ]: G Q Gᵀ for constant G, else Σ w_i G(X_i) Q G(X_i)ᵀ
            Q = (noise_of.GQGT(m, t) if noise_of.G_constant
                 else _einsum("i,...iab->...ab", w, noise_of.GQGT(X, t)))
        return GaussMoments(mean, C, S, None, None if bad is None or not bad.any() else bad, Q)


def sigma_points(m, P, alpha, beta, kappa):
    """Sigma points ``(..., 2n+1, n)``, weights ``(Wm, Wc)`` of shape ``(2n+1,)``, and the paths
    ``(...)`` whose covariance is not PSD: the nodes of :class:`Unscented` ``(alpha, beta, kappa)``
    (:meth:`NodeRule.nodes`)."""
    return Unscented(alpha, beta, kappa).nodes(m, P)


def _frozen(*arrays):
    out = tuple(np.array(a, float) for a in arrays)
    for a in out:
        a.flags.writeable = False
    return out


@functools.lru_cache(maxsize=None)
def _unscented_table(n, alpha, beta, kappa):
    lam = alpha**2 * (n + kappa) - n
    c = math.sqrt(n + lam)
    z = np.concatenate([np.zeros((1, n)), c * np.eye(n), -c * np.eye(n)])
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + 1 - alpha**2 + beta
    return _frozen(z, wm, wc)


@dataclass(frozen=True)
class Unscented(NodeRule):
    """Scaled unscented transform (van der Merwe): ``2n + 1`` sigma points (:meth:`unit_nodes`)."""

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    name = "unscented"

    def __post_init__(self):
        object.__setattr__(self, "alpha", float(V.positive("alpha", self.alpha)))
        object.__setattr__(self, "beta", float(V.positive("beta", self.beta, strict=False)))
        object.__setattr__(self, "kappa", V.real("kappa", self.kappa))

    #: the largest rounding of the weighted sums the weights may cause, ``eps · Σ|Wc_i|``: with
    #: ``s = α²(n + κ)`` the weights are ≈ ``1/s`` with a centre weight ``≈ 1 − n/s``, so the sums
    #: of points cancel and lose ``eps·n/s`` of their relative accuracy (``α = 1e-3``, the usual
    #: small choice, loses ~1e-10 for n = 2)
    ROUNDING = 1e-6

    def check(self, n):
        if n + self.kappa <= 0:
            raise ValueError(f"kappa: expected n + kappa > 0 (n = {n}), got {self.kappa!r}")
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            a2 = np.float64(self.alpha) ** 2
            s = a2 * (n + self.kappa)  # n + λ
            w = np.abs([(s - n) / s + 1 - a2 + self.beta, *[0.5 / s] * (2 * n)])
            loss = np.finfo(float).eps * w.sum()
        if not (s > 0 and np.isfinite(s) and loss <= self.ROUNDING):
            raise ValueError(f"alpha: expected a sigma-point spread α²(n + κ) whose weights lose at most "
                             f"{self.ROUNDING:g} to rounding (eps·Σ|W|), got alpha = {self.alpha!r} "
                             f"(n = {n}, kappa = {self.kappa:g}: α²(n + κ) = {float(s):.3g}, rounding {float(loss):.3g})")

    def unit_nodes(self, n):
        """``z_0 = 0``, ``z_{±i} = ±√(n + λ) e_i`` (``λ = α²(n + κ) − n``); ``Wm_0 = λ/(n + λ)``,
        ``Wc_0 = Wm_0 + 1 − α² + β``, the others ``1/(2(n + λ))`` (van der Merwe 2004)."""
        return _unscented_table(n, self.alpha, self.beta, self.kappa)


@functools.lru_cache(maxsize=None)
def _cubature_table(n):
    return _frozen(math.sqrt(n) * np.concatenate([np.eye(n), -np.eye(n)]), np.full(2 * n, 0.5 / n),
                   np.full(2 * n, 0.5 / n))


@functools.lru_cache(maxsize=None)
def _gh_table(n, order):
    z, w = gauss_hermite_rule(n, order)
    return _frozen(z, w, w)


@dataclass(frozen=True)
class Cubature(NodeRule):
    """Third-degree spherical-radial cubature (Arasaratnam & Haykin 2009, the CKF's rule):
    ``X_{±i} = m ± √n L e_i``, weights ``1/(2n)`` (the unscented points with α = 1, β = κ = 0,
    whose centre point has weight zero)."""

    name = "cubature"

    def unit_nodes(self, n):
        """``z_{±i} = ±√n e_i``, weights ``1/(2n)`` (Arasaratnam & Haykin 2009)."""
        return _cubature_table(n)


@dataclass(frozen=True)
class GaussHermite(NodeRule):
    """Tensor-product Gauss–Hermite rule (Ito & Xiong 2000): ``order`` nodes per axis,
    ``X_p = m + L z_p`` with ``z_p`` the probabilists' Hermite nodes (``order**n`` points)."""

    order: int = 3
    name = "gauss-hermite"

    def __post_init__(self):
        if isinstance(self.order, bool) or not isinstance(self.order, (int, np.integer)) or self.order < 1:
            raise ValueError(f"order: expected a positive integer, got {V.shown(self.order)}")
        object.__setattr__(self, "order", int(self.order))

    def check(self, n):
        if self.order ** n > MAX_NODES:
            raise ValueError(f"order: {self.order}**{n} = {self.order ** n} nodes per expectation exceed "
                             f"{MAX_NODES}; expected a lower order, or the Cubature rule for n = {n}")

    def unit_nodes(self, n):
        """The probabilists' Hermite nodes on a tensor grid, product weights (Ito & Xiong 2000)."""
        return _gh_table(n, self.order)


@functools.lru_cache(maxsize=None)
def _cubature5_table(n):
    z, w = cubature5_rule(n)
    return _frozen(z, w, w)


@dataclass(frozen=True)
class Cubature5(NodeRule):
    """Fifth-degree cubature rule for N(0, I_n) (Stroud 1971, *Approximate calculation of multiple
    integrals*, the fully symmetric degree-5 formula; as the fifth-degree cubature Kalman filter of
    Jia, Xin & Cheng 2013, "High-degree cubature Kalman filter", Automatica 49): ``2n² + 1`` nodes::

        z_0 = 0                          w_0 = 2/(n + 2)
        z = ±√(n + 2) e_i                w = (4 − n)/(2(n + 2)²)      (2n nodes)
        z = √((n + 2)/2)(±e_i ± e_j)     w = 1/(n + 2)²               (i < j: 2n(n − 1) nodes)

    (the nodes and weights of :func:`nlfilter.moments.quadrature.cubature5_rule`). The weights sum to
    1 and the rule is exact for every polynomial of total degree ≤ 5 under N(0, I_n): so ``wc = wm``
    gives the exact mean and covariance of any g of degree ≤ 2 (products of degree ≤ 4) and, like
    every node rule, the Kalman filter on a linear model. For n = 1 it is the 3-point Gauss–Hermite
    rule.

    Negative weights: for n = 4 the axis nodes have weight 0, for n ≥ 5 a negative one. The means
    stay exact to degree 5, but ``Σ w_i (g_i − ĝ)(g_i − ĝ)ᵀ`` is then no sum of PSD terms: for a g
    far from quadratic the predicted or innovation covariance can come out indefinite (it is PSD
    wherever it is exact, e.g. for affine g; in n = 6, ``g = x₁⁴`` under N(0, I) gets the variance
    −57 for 96). The filter does not go on silently: the run loop's PSD check raises or marks a path
    whose predicted covariance is not PSD (``on_divergence``), and the rule asks the skeleton to
    screen the innovation covariance (``screen``; NumPy and compiled loops alike): an S that is not
    positive definite fails that path's update. Use :class:`Cubature` (positive weights, degree 3)
    or :class:`GaussHermite` where that happens.

    >>> z, wm, wc = Cubature5().unit_nodes(2)
    >>> z.shape, float(wm.sum()), bool(wm.flags.writeable)
    ((9, 2), 1.0, False)
    >>> round(float(np.einsum("i,i,i,i,i->", wm, *z.T, *z.T)), 12)    # E[z₁² z₂²] = 1, a degree-4 moment
    1.0
    """

    name = "cubature5"
    screen = True  # negative weights (n ≥ 5): the skeleton checks S for positive definiteness

    def check(self, n):
        """Refuse an n whose ``2n² + 1`` nodes exceed ``MAX_NODES`` per expectation, or whose
        table would exceed the node coordinates :func:`cubature5_rule` builds (n > 215)."""
        nodes = 2 * n * n + 1
        if nodes > MAX_NODES or nodes * n > MAX_ENTRIES:
            raise ValueError(f"rule: Cubature5 in n = {n} dimensions needs 2n² + 1 = {nodes} nodes per expectation; "
                             f"expected at most {MAX_NODES} nodes and {MAX_ENTRIES:.0e} node coordinates, or the "
                             f"third-degree Cubature rule (2n nodes)")

    def unit_nodes(self, n):
        """Stroud's degree-5 nodes and weights (``wc = wm``; cached, read-only)."""
        return _cubature5_table(n)


__all__ += ["Cubature5"]
