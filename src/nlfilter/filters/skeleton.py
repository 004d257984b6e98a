"""The Gaussian skeleton as pure functions over a moment rule (the filter classes configure them).

As dynamax's generalized Gaussian filter (its ``_predict`` / ``_condition_on`` over an integrals
object), the steps are functions of ``(rule, model, belief, ...)``: the rule
(:mod:`nlfilter.filters.rules`) knows nothing of the loop and the loop nothing of the rule. Every
term a rule returns in its :class:`~nlfilter.filters.rules.GaussMoments` is applied the same way
(an absent term is None), and the rule's table entries ``symmetrize`` (the predicted covariance)
and ``screen`` (the innovation covariance checked for positive definiteness) are read by one code
path::

    predict:    m⁻ = E[f],   P⁻ = Cov[f] + E[G Q Gᵀ] [− G K_w Sᵀ Gᵀ] [+ quartic]   [symmetrized]
    condition:  ŷ = E[h],    S = Cov[h] + R [+ quartic]   [screened],   C = Cov[x, h],   K = C S⁻¹,
                m⁺ = m⁻ + K (y − ŷ),   P⁺ = P⁻ − K S Kᵀ (Joseph with the rule's H)  [+ Σ_k M_k [S⁻¹(y − ŷ)]_k]
    moment_rhs: dm/dt = E[f],   dP/dt = Cov[x, f] + Cov[f, x] + E[G Q Gᵀ]   (Särkkä 2007)
    ito_rhs:    dm = [f + ½(P f_xx)] dt + K {dy − ĥ dt},  dP = [F P + P Fᵀ + E[G Q Gᵀ] − K R Kᵀ] dt   (seed 004
                eqs. 35-37: the continuous-time filter over a Taylor rule; its dt terms)

(:func:`~nlfilter.filters.linalg.gaussian_update` conditions on the observed components of a partly
missing ``y``; the forcing tensor M is the discrete C tensor of seed 004 eq. 17, see
:mod:`nlfilter.filters.second_order`). The order of the additions is the one the compiled loop
reproduces (``nlfilter.filters.compiled``, agreement to 1e-12): covariance + noise, then the
decorrelation, then the fourth-moment term, then the symmetrization.

>>> import sympy as sp; from nlfilter import DiscreteModel
>>> from nlfilter.filters.rules import Cubature
>>> x = sp.Symbol("x")
>>> model = DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0)
>>> b = predict(Cubature(), model, GaussianState(np.array([1.0]), np.array([[1.0]])), 0)
>>> round(float(b.mean[0]), 12), round(float(b.cov[0, 0]), 12)      # 0.9 m, 0.81 P + Q
(0.9, 1.81)
>>> new, bad, (yhat, S) = condition(Cubature(), model, b, np.array([2.0]), 1)
>>> round(float(new.mean[0]), 6), round(float(S[0, 0]), 6), bad     # m + P/S (y − m), S = P + R
(1.608541, 2.81, None)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..angles import angles_of, near, residual, wrap_components
from .._npcall import einsum as _einsum, quiet as _quiet
from ..errors import DivergenceError
from .base import GaussianState, ode_step
from .beliefs import where_paths
from .linalg import (SCREEN_MAX_N, _cholesky, _total, bad_paths, decorrelation, gaussian_update, mm,
                     poison, symmetrize)
from .contractions import hessian_trace
from .smoothing import _solve_right

__all__ = ["predict", "condition", "moment_rhs", "propagate", "ito_gain", "ito_rhs", "iterated_update", "gauss_newton",
           "CrossNoise",
           "MeasuredState", "as_belief", "as_gaussian", "check_paths"]


class MeasuredState(NamedTuple):
    """A Gaussian belief with the measurement ``y (..., m)`` it was last conditioned on (NaN:
    none, as after a prediction): the belief of the filters on a model with correlated process
    and measurement noise (``cross_noise``), whose prediction from step k needs ``y_k``."""

    mean: np.ndarray
    cov: np.ndarray
    y: np.ndarray


def as_belief(state):
    """A Gaussian belief from a ``(mean, cov)`` pair (a :class:`MeasuredState` as it is)."""
    return state if isinstance(state, MeasuredState) else GaussianState(*state)


class CrossNoise:
    """Correlated noise ``E[w_k v_kᵀ] = S`` (``model.cross_noise``; None: uncorrelated, every
    method the identity), held by a discrete Gaussian filter. The standard decorrelation
    (Anderson & Moore 1979, §5.5; Simon 2006, §7.1): with ``y_k`` measuring ``x_k`` and ``w_k``
    driving ``x_{k+1}``, write ``w_k = K_w v_k + w̃_k``, ``K_w = S R⁻¹``, ``w̃_k ⊥ v_k``::

        x_{k+1} = f(x_k) + G K_w (y_k − h(x_k)) + G w̃_k,    Cov[w̃] = Q − S R⁻¹ Sᵀ

    a model without correlation whose dynamics depend on ``y_k``: the prediction from the
    filtered belief of step k takes the moments of ``f̃(x) = f(x) + G K_w (y_k − h(x))`` (its
    Jacobian ``f_x − G K_w h_x``, Hessian ``f_xx − G K_w h_xx``) by the filter's rule, and the noise
    ``E[G Q Gᵀ] − G K_w Sᵀ Gᵀ`` (G does not depend on the state): :meth:`decorrelation` is the input
    of :func:`predict`. The belief carries ``y_k`` (:class:`MeasuredState`, frozen: the update
    returns it, the prediction reads it); with components of ``y_k`` missing only the observed ones
    decorrelate (``S_o R_oo⁻¹``), with none (the first prediction of ``start="predict"``, a step
    missing on a path, a plain :class:`GaussianState`) the prediction is the uncorrelated one."""

    def __init__(self, model):
        self.model = model
        self.S = getattr(model, "cross_noise", None)
        self._Rinv = None if self.S is None else np.linalg.inv(model.R)

    def unmeasured(self, belief):
        """The belief (the prior, a prediction) marked as conditioned on no measurement yet."""
        if self.S is None:
            return belief
        return MeasuredState(belief.mean, belief.cov, np.full((*belief.mean.shape[:-1], self.model.m), np.nan))

    def carry(self, new, y):
        """The updated belief, with the measurement it saw when the noise is correlated."""
        if self.S is None:
            return new
        return MeasuredState(new.mean, new.cov, np.broadcast_to(y, new.mean.shape[:-1] + y.shape[-1:]))

    def decorrelation(self, state, k):
        """``(D = G K_w, e, G K_w Sᵀ Gᵀ)``: the gain of ``y_k − h``, the observed ``y_k`` (0 where
        missing), the noise covariance removed; ``None`` without correlation or measurement."""
        y = getattr(state, "y", None)
        if self.S is None or y is None:
            return None
        md = self.model
        obs = ~np.isnan(y)
        Kw, KS = decorrelation(self.S, md.R, self._Rinv, obs)
        G = md.G(np.zeros(md.n), k)
        return G @ Kw, np.where(obs, y, 0.0), G @ KS @ G.T

    def smooth_predict(self, predict_cross, ys, offset):
        """The smoother's prediction from step ``j`` (model index) with that step's measurement."""
        if self.S is None:
            return predict_cross
        return lambda st, j: predict_cross(MeasuredState(st.mean, st.cov, ys[:, j - offset]), j)


def _lift(A, nb, X, tail):
    """``A (*batch, *tail)`` viewed against ``X (*batch, *nodes, n)`` (nodes of a rule); a shared
    ``A (*tail)`` as is."""
    if A.ndim == tail:
        return A
    return A.reshape(A.shape[:nb] + (1,) * (X.ndim - 1 - nb) + A.shape[nb:])


def _decorrelated(md, D, e):
    """``f̃ = f + D (e − h)`` with its Jacobian and Hessian (:class:`CrossNoise`)."""
    nb = e.ndim - 1

    def f(X, t):
        e_h = residual(_lift(e, nb, X, 1), md.h(X, t), angles_of(md).measurements)  # e − h (angles wrapped)
        return md.f(X, t) + _einsum("...ij,...j->...i", _lift(D, nb, X, 2), e_h)

    def f_x(X, t):
        return md.f_x(X, t) - _lift(D, nb, X, 2) @ md.h_x(X, t)

    def f_xx(X, t):
        return md.f_xx(X, t) - _einsum("...ij,...jkl->...ikl", _lift(D, nb, X, 2), md.h_xx(X, t))

    return f, f_x, f_xx


def as_gaussian(belief) -> GaussianState:
    """``belief`` as a :class:`GaussianState` (its first two fields; the belief itself when it is one)."""
    return belief if type(belief) is GaussianState else GaussianState(belief[0], belief[1])


def predict(rule, model, belief, t, *, decorrelation=None, cross: bool = False):
    """``m⁻ = E[f]``, ``P⁻ = Cov[f] + E[G Q Gᵀ]`` (+ the rule's fourth-moment term, added last;
    symmetrized where the rule's ``symmetrize`` says), poisoned where the rule's nodes failed.

    ``belief``: ``(mean, cov, ...)`` at time ``t``; ``decorrelation``: ``(D, e, sub)`` of correlated
    noise (:meth:`CrossNoise.decorrelation`: the dynamics ``f + D (e − h)``, the noise less
    ``sub``) or None. Returns the predicted :class:`GaussianState`; with ``cross``, the pair
    ``(prediction, Cov[x_k, f(x_k)])`` (the smoother's cross-covariance)."""
    md = model
    f, f_x, f_xx, sub = md.f, md.f_x, md.f_xx, None
    if decorrelation is not None:  # correlated noise: the decorrelated dynamics f̃ (CrossNoise)
        D, e, sub = decorrelation
        f, f_x, f_xx = _decorrelated(md, D, e)
    idx = angles_of(md).states
    state = belief if type(belief) is GaussianState else as_gaussian(belief)
    if idx:  # (a rule is asked about angles only when there are some)
        mo = rule.moments(state, f, t, jac=f_x, hess=f_xx, cross=cross, noise_of=md, role="dynamics", angles=idx)
    else:
        mo = rule.moments(state, f, t, jac=f_x, hess=f_xx, cross=cross, noise_of=md, role="dynamics")
    P = mo.cov + mo.noise  # P⁻ = Cov[f] + E[G Q Gᵀ]
    if sub is not None:  # Cov[w̃] = Q − S R⁻¹ Sᵀ
        P = P - sub
    P = P if mo.quartic is None else P + mo.quartic
    if rule.symmetrize:
        P = symmetrize(P)
    new = GaussianState(mo.mean, P)
    if mo.bad is not None:
        new = poison(new, mo.bad)
    return (new, mo.cross) if cross else new


def _pd_mask(S):
    """Boolean ``(...)``: innovation covariances whose symmetrized eigenvalues (``eigvalsh``) are
    not all positive. A batch of at most 64 x 64 matrices is first cleared in one call when every
    ``sym(S) − δ I``, ``δ = 1e-8 m max_i S_ii`` (per path), has a Cholesky factor: then λ_min > δ
    less the factorization's backward error (≲ m³ eps max_i S_ii), and eigvalsh, backward stable,
    finds every eigenvalue positive (a non-positive or NaN diagonal fails the factorization)."""
    m = S.shape[-1]
    if m == 1:
        return ~(S[..., 0, 0] > 0)
    Ss = symmetrize(S)
    if m <= SCREEN_MAX_N:
        A = Ss.copy()
        d = A.reshape(*A.shape[:-2], m * m)[..., ::m + 1]  # A's diagonal, a view
        d -= (1e-8 * m) * np.maximum.reduce(d, axis=-1)[..., None]
        if math.isfinite(_total(_quiet(_cholesky, A))):
            return np.zeros(S.shape[:-2], bool)
    return ~np.all(np.linalg.eigvalsh(Ss) > 0, axis=-1)


def condition(rule, model, belief, y, t, R=None):
    """The update of ``belief`` on ``y (..., m)`` at time ``t`` (NaN components missing: the exact
    update on the observed ones): ``(updated GaussianState, failed paths or None, (ŷ, S))``, the
    predicted measurement moments for the likelihood (:func:`~nlfilter.filters.linalg.innovation_info`).

    ``R`` defaults to the model's (a state-dependent ``R(x)`` at the predicted mean: the EKF
    convention). ``S = Cov[h] + R`` (+ the rule's fourth-moment term); a rule with ``screen`` has S
    checked for positive definiteness (failed paths get a harmless S and are reported); a rule's
    linearization ``H`` (``jac``: then ``S = H P Hᵀ + R`` exactly) gives the Joseph form; a rule's
    forcing tensor adds ``Σ_k M_k [S⁻¹(y − ŷ)]_k`` to the covariance (the discrete C tensor of
    seed 004 eq. 17, see :mod:`nlfilter.filters.second_order`). The updated belief is not
    poisoned: the caller decides (a filter that raises, or :func:`~nlfilter.filters.linalg.poison`)."""
    md = model
    state = belief if type(belief) is GaussianState else as_gaussian(belief)
    if R is None:  # a state-dependent R(x) at the predicted mean (the EKF convention)
        R = md.R if getattr(md, "R_constant", True) else md.R_of(state.mean, t)
    ang = angles_of(md)
    if ang.measurements:  # angles: ŷ on the branch of y (the innovation y − ŷ wrapped, nlfilter.angles)
        mo = rule.moments(state, md.h, t, jac=md.h_x, hess=md.h_xx, role="measurement", angles=ang.measurements)
        mo = mo._replace(mean=near(mo.mean, y, ang.measurements))
    else:
        mo = rule.moments(state, md.h, t, jac=md.h_x, hess=md.h_xx, role="measurement")
    S = mo.cov + R if mo.quartic is None else mo.cov + R + mo.quartic
    bad = mo.bad
    if rule.screen:
        nd = _pd_mask(S)
        if nd.any():  # keep the algebra finite; these paths are reported as diverged (none: bad stays None,
            S = np.where(nd[..., None, None], np.eye(S.shape[-1]) * np.abs(S).max(initial=1.0) + R, S)
            bad = nd if bad is None else bad | nd  # and the run loop's check takes its one-call screen)
    new = gaussian_update(state, y, mo.mean, S, mo.cross, H=mo.jac, R=R)  # R is read with H only
    if mo.forcing is not None:  # P⁺ += Σ_k M_k [S⁻¹(y − ŷ)]_k
        miss = np.isnan(y)
        e = np.where(miss, 0.0, y - mo.mean)
        Sm = np.where(miss[..., :, None] | miss[..., None, :], np.eye(S.shape[-1]), S)
        u = np.linalg.solve(Sm, e[..., None])[..., 0]
        new = GaussianState(new.mean, symmetrize(new.cov + _einsum("...ijk,...k->...ij", mo.forcing, u)))
    if ang.states:
        new = GaussianState(wrap_components(new.mean, ang.states), new.cov)
    return new, bad, (mo.mean, S)


def moment_rhs(rule, model, m, P, t, C=None):
    """The moment equations of the Gaussian closure (Särkkä 2007, IEEE TAC 52(9); Jazwinski 1970,
    ch. 9) at ``(m, P)``, time ``t``: ``(dm/dt, dP/dt)`` with ``dm/dt = E[f]`` (NaN on the paths
    whose nodes failed), ``dP/dt = Cov[x, f] + Cov[f, x] + E[G Q Gᵀ]``. With the smoother's
    cross-covariance ``C = Cov[x(t_k), x(t)]`` also ``dC/dt = C P⁻¹ Cov[x, f]``
    (:mod:`~nlfilter.filters.smoothing`): ``(dm/dt, dP/dt, dC/dt)``."""
    mo = rule.moments(GaussianState(m, P), model.f, t, jac=model.f_x, hess=model.f_xx, cov=False, noise_of=model,
                      role="dynamics")
    dP = mo.cross + mo.cross.swapaxes(-1, -2) + mo.noise  # Cov[x, f] + Cov[f, x] + E[G Q Gᵀ]
    if C is not None:
        return mo.mean, dP, C @ _solve_right(P, mo.cross.swapaxes(-1, -2)).swapaxes(-1, -2)
    dm = mo.mean if mo.bad is None else np.where(mo.bad[..., None], np.nan, mo.mean)  # poisoned paths
    return dm, dP


def propagate(rule, model, belief, t, dt, *, substeps: int = 1, scheme: str = "rk4", cross: bool = False):
    """The continuous-discrete prediction: :func:`moment_rhs` integrated from ``t`` to ``t + dt``
    (``scheme`` RK4 or Euler, ``substeps`` steps; P symmetrized after each), the belief at
    ``t + dt``; with ``cross`` the pair ``(belief, Cov[x(t), x(t + dt)])``, ``C(t) = P(t)``."""
    m, P = belief[0], belief[1]
    if not cross:
        m, P = ode_step(lambda x, s: moment_rhs(rule, model, x[0], x[1], s), (m, P), t, dt, substeps=substeps,
                        scheme=scheme, finish=lambda x: (x[0], symmetrize(x[1])))
        return GaussianState(wrap_components(m, angles_of(model).states), P)  # angles wrapped
    m, P, C = ode_step(lambda x, s: moment_rhs(rule, model, x[0], x[1], s, C=x[2]), (m, P, P), t, dt,
                       substeps=substeps, scheme=scheme, finish=lambda x: (x[0], symmetrize(x[1]), x[2]))
    return GaussianState(wrap_components(m, angles_of(model).states), P), C


def ito_gain(rule, model, m, P, t, obs, Rinv, *, measure: bool = True):
    """The measurement terms of the continuous-time (Itô) filter at ``(m, P)`` (seed 004 eqs. 35-37):
    ``(K = P Hᵀ R⁻¹, P Hᵀ, ĥ, M R⁻¹)`` with ``ĥ = h + ½(P h_xx)`` and the forcing tensor M of a
    second-order rule (``rule.second``; else ``ĥ = h``, M None). ``obs (..., m)``: the observed
    components, ``Rinv`` their precision (:func:`~nlfilter.filters.linalg.observed_precision`;
    missing ones do not update). ``measure=False``: ĥ is not wanted (None; the gain of an Itô step)."""
    H = model.h_x(m, t) * obs[..., :, None]
    PHt = mm(P, H.swapaxes(-1, -2))
    K = mm(PHt, Rinv)  # 004 eq. 37
    hhat = model.h(m, t) if measure else None
    M = None
    if rule.second:
        h_xx = model.h_xx(m, t)
        if measure:
            hhat = hhat + 0.5 * hessian_trace(P, h_xx)  # 004 eq. 35
        M = rule.forcing(P, h_xx)
        if M is not None:
            M = _einsum("...ijk,...kl->...ijl", M * obs[..., None, None, :], Rinv)  # M R⁻¹
    return K, PHt, (hhat * obs if measure else None), M


def ito_rhs(rule, model, m, P, t, obs, Rinv):
    """The ``dt`` terms of the continuous-time (Itô) filter (seed 004 eqs. 35-36; Taylor rules):
    ``dm/dt = f [+ ½(P f_xx)] − K ĥ``, ``dP/dt = F P + P Fᵀ + E[G Q Gᵀ] − K R Kᵀ [− Σ_k M_k (R⁻¹ ĥ)_k]``
    (:func:`ito_gain`; ``K R Kᵀ = K (P Hᵀ)ᵀ``)."""
    F = model.f_x(m, t)
    K, PHt, hhat, M = ito_gain(rule, model, m, P, t, obs, Rinv)
    dm = model.f(m, t) - _einsum("...ij,...j->...i", K, hhat)
    if rule.second:
        dm = dm + 0.5 * hessian_trace(P, model.f_xx(m, t))  # 004 eq. 35, drift part
    FP = mm(F, P)
    dP = FP + FP.swapaxes(-1, -2) + rule.noise(model, m, P, t) - mm(K, PHt.swapaxes(-1, -2))
    if M is not None:
        dP = dP - _einsum("...ijk,...k->...ij", M, hhat)  # forcing term, its dt part
    return dm, dP


def iterated_update(model, state, y, t, iterations: int, tol: float, *, info: bool = False):
    """Iterated EKF update (Bell & Cathey 1993, IEEE TAC 38(2): Gauss–Newton on the MAP problem)::

        x_0 = m⁻,   H_i = h_x(x_i),   S_i = H_i P⁻ H_iᵀ + R,   K_i = P⁻ H_iᵀ S_i⁻¹
        x_{i+1} = m⁻ + K_i (y − h(x_i) − H_i (m⁻ − x_i))
        P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ   with the last K_i, H_i (Joseph form)

    Each path stops when ``|x_{i+1} − x_i| ≤ tol (1 + |x_i|)`` componentwise, or after
    ``iterations`` updates (one iteration is the EKF update, exactly). Missing components of ``y``
    take no part (their rows of the innovation and gain are zero, :func:`gaussian_update`), so only
    the observed components are iterated. A path's result does not depend on the other paths.
    With ``info``: ``(belief, (ŷ, S))``, the predicted measurement moments of the first (EKF)
    linearization at the predicted mean (the predictive law of y is not changed by iterating
    the posterior mode): the Taylor-1 rule's, operation for operation.
    """
    md = model
    m, P = state
    R = md.R if getattr(md, "R_constant", True) else md.R_of(m, t)  # R(x) at the predicted mean, as the first update
    first = []

    ang = angles_of(md)

    def linear_update(x, at_mean):
        H = md.h_x(x, t)
        C = mm(P, H.swapaxes(-1, -2))
        S = mm(H, C) + R
        y_pred = md.h(x, t) if at_mean else md.h(x, t) + _einsum("...ij,...j->...i", H, residual(m, x, ang.states))
        y_pred = near(y_pred, y, ang.measurements)  # angles: the wrapped innovation
        if at_mean:
            first.append((y_pred, S))
        new = gaussian_update(state, y, y_pred, S, C, H=H, R=R)
        return GaussianState(wrap_components(new.mean, ang.states), new.cov) if ang.states else new

    new = gauss_newton(linear_update(m, True), lambda x: linear_update(x, False), iterations, tol)
    return (new, first[0]) if info else new


def gauss_newton(new, relinearized, iterations: int, tol: float):
    """The iteration of the iterated updates (:func:`iterated_update`; the square-root IEKF's): from
    the first update ``new`` (a belief whose first field is the mean), ``relinearized(x)`` — the
    update linearized at ``x`` — at the latest mean, path by path until
    ``|x_{i+1} − x_i| ≤ tol (1 + |x_i|)`` componentwise (a path that stopped keeps its belief), at
    most ``iterations`` updates in all."""
    done = np.zeros(new[0].shape[:-1], bool)
    for _ in range(iterations - 1):
        x = new[0]
        cand = relinearized(x)
        step_small = np.all(np.abs(cand[0] - x) <= tol * (1.0 + np.abs(x)), axis=-1)
        new = where_paths(done, new, cand)
        done = done | step_small
        if done.all():
            break
    return new


def check_paths(flt, state, bad, what, t):
    """``state`` when every path is finite and PSD (and not in ``bad``), else a
    :class:`~nlfilter.errors.DivergenceError` naming the filter, the time and the paths (the
    step functions of the filters that raise, ``raises = True``)."""
    now = bad_paths(state.mean, state.cov)
    bad = now if bad is None else bad | now
    if bad.any():
        idx = np.flatnonzero(np.broadcast_to(bad, bad.shape).ravel())
        raise DivergenceError(f"{flt.name}: {what} at {flt.model.time_name}={t} lost positive "
                              f"definiteness or became non-finite on {idx.size} path(s), first "
                              f"{idx[:5].tolist()}", step=None, paths=idx, what="covariance")
    return state
