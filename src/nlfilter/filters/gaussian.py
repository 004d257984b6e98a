"""One discrete and one continuous-discrete skeleton for the Gaussian filters, over a moment rule.

The EKF, UKF, cubature (CKF) and Gauss–Hermite (GHKF) Kalman filters differ only in the rule of
:mod:`nlfilter.filters.rules` that computes the moments of f and h under the Gaussian belief
``N(m, P)`` (the shape of dynamax's generalized Gaussian filter)::

    predict:  m⁻ = E[f(x)],   P⁻ = Cov[f(x)] + E[G(x) Q G(x)ᵀ]
    update:   ŷ = E[h(x)],  S = Cov[h(x)] + R,  C = Cov[x, h(x)],  K = C S⁻¹,
              m⁺ = m⁻ + K (y − ŷ),  P⁺ = P⁻ − K S Kᵀ

(:func:`~nlfilter.filters.base.gaussian_update`: missing components, partly missing measurements
with correlated R, singular S poisoned).

A state-dependent measurement noise ``v_k ~ N(0, R(x_k))`` (``DiscreteModel(..., R=<expression in
the states>)``) enters as ``R(m⁻)``, R at the predicted mean: ``S = Cov[h] + R(m⁻)`` (the EKF
convention, as filterpy's radar example passes ``R=`` at each update; the exact term would be
``E[R(x)]``, which the reference filters use implicitly). The log-likelihood output uses this S.
Correlated process and measurement noise (``cross_noise``, ``E[w_k v_kᵀ] = S``): the prediction
from step k uses the decorrelated dynamics ``f(x) + G S R⁻¹ (y_k − h(x))`` and the noise
``Q − S R⁻¹ Sᵀ`` (:class:`_CrossNoise`; the belief, a :class:`MeasuredState`, carries ``y_k``). A linearizing rule (Taylor-1) also hands its ``H = h_x(m)``
to the update, which then uses the Joseph form ``(I − K H) P (I − K H)ᵀ + K R Kᵀ``.

Continuous-discrete time (an :class:`~nlfilter.models.SDEModel` ``dx = f dt + G dβ`` measured at
``t_k = t0 + k dt`` by ``y_k = h(x(t_k)) + v_k``, ``v_k ~ N(0, R)``): between measurements the
moment equations of the Gaussian closure (Särkkä 2007, IEEE TAC 52(9); Jazwinski 1970, ch. 9)::

    dm/dt = E[f(x)],    dP/dt = Cov[x, f(x)] + Cov[f(x), x] + E[G(x) Q G(x)ᵀ]

with the expectations taken by the rule, integrated by RK4 or Euler with ``substeps`` steps per
interval (as :class:`~nlfilter.filters.second_order.ContinuousDiscreteSecondOrderFilter`); the same
discrete update at the measurements. With Taylor-1, ``Cov[x, f] = P Fᵀ``: the continuous-discrete EKF.

Continuous time (increments ``dy``, the Itô filter of seed 004 eqs. 35-37): :class:`ContinuousGaussianFilter`
over a Taylor rule (Taylor-1: :class:`~nlfilter.filters.ekf.ContinuousEKF`; Taylor-2 in a form of
seed 004: :class:`~nlfilter.filters.second_order.ContinuousSecondOrderFilter`).

Seed 004's second-order filters are these skeletons with the rule ``Taylor2(form)``: its
fourth-moment term is added last (``quartic``), the predicted covariance symmetrized, the innovation
covariance screened for positive definiteness (``screen``), and the forcing tensor of the forms
that have one added to the updated covariance.

The iterated update (:func:`iterated_update`, Bell & Cathey 1993) is the Gauss–Newton
maximization of the posterior density in place of the single Taylor-1 update.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _validate as V
from .base import ContinuousFilter, DiscreteFilter, GaussianState, continuous_precision, ode_step, set_start, set_t0
from .rules import hessian_trace
from .smoothing import _solve_right, continuous_rts, rts
from .linalg import decorrelation, gaussian_update, innovation_info, mm, observed_precision, poison, symmetrize

__all__ = ["GaussianFilter", "ContinuousDiscreteGaussianFilter", "ContinuousGaussianFilter", "iterated_update",
           "MeasuredState"]


class MeasuredState(NamedTuple):
    """A Gaussian belief with the measurement ``y (..., m)`` it was last conditioned on (NaN:
    none, as after a prediction): the belief of the filters on a model with correlated process
    and measurement noise (``cross_noise``), whose prediction from step k needs ``y_k``."""

    mean: np.ndarray
    cov: np.ndarray
    y: np.ndarray


class _CrossNoise:
    """Correlated noise ``E[w_k v_kᵀ] = S`` (``model.cross_noise``) for a discrete Gaussian filter,
    the standard decorrelation (Anderson & Moore 1979, §5.5; Simon 2006, §7.1): with ``y_k``
    measuring ``x_k`` and ``w_k`` driving ``x_{k+1}``, write ``w_k = K_w v_k + w̃_k``,
    ``K_w = S R⁻¹``, ``w̃_k ⊥ v_k``::

        x_{k+1} = f(x_k) + G K_w (y_k − h(x_k)) + G w̃_k,    Cov[w̃] = Q − S R⁻¹ Sᵀ

    a model without correlation whose dynamics depend on ``y_k``: the prediction from the
    filtered belief of step k takes the moments of ``f̃(x) = f(x) + G K_w (y_k − h(x))`` (its
    Jacobian ``f_x − G K_w h_x``, Hessian ``f_xx − G K_w h_xx``) by the filter's rule, and the noise
    ``E[G Q Gᵀ] − G K_w Sᵀ Gᵀ`` (G does not depend on the state). The belief carries ``y_k``
    (:class:`MeasuredState`, frozen: the update returns it, the prediction reads it); with
    components of ``y_k`` missing only the observed ones decorrelate (``S_o R_oo⁻¹``), with none
    (the first prediction of ``start="predict"``, a step missing on a path, a plain
    :class:`GaussianState`) the prediction is the uncorrelated one."""

    def _set_cross(self):
        self._cross = getattr(self.model, "cross_noise", None)
        if self._cross is not None:
            self._Rinv_c = np.linalg.inv(self.model.R)

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        s = super().init(m0, P0, batch, initial=initial, rng=rng)
        if self._cross is None:
            return s
        return MeasuredState(s.mean, s.cov, np.full((*s.mean.shape[:-1], self.model.m), np.nan))

    def _carry(self, new, y):
        """The updated belief, with the measurement it saw when the noise is correlated."""
        if self._cross is None:
            return new
        return MeasuredState(new.mean, new.cov, np.broadcast_to(y, new.mean.shape[:-1] + y.shape[-1:]))

    def _predicted(self, new):
        return new if self._cross is None else MeasuredState(
            new.mean, new.cov, np.full((*new.mean.shape[:-1], self.model.m), np.nan))

    def _decorrelation(self, state, k):
        """``(D = G K_w, e, G K_w Sᵀ Gᵀ)``: the gain of ``y_k − h``, the observed ``y_k`` (0 where
        missing), the noise covariance removed; ``None`` without a measurement."""
        y = getattr(state, "y", None)
        if y is None:
            return None
        md = self.model
        obs = ~np.isnan(y)
        Kw, KS = decorrelation(self._cross, md.R, self._Rinv_c, obs)
        G = md.G(np.zeros(md.n), k)
        return G @ Kw, np.where(obs, y, 0.0), G @ KS @ G.T

    def _smooth_predict(self, ys, offset):
        """The smoother's prediction from step ``j`` (model index) with that step's measurement."""
        if self._cross is None:
            return self._predict_cross
        return lambda st, j: self._predict_cross(MeasuredState(st.mean, st.cov, ys[:, j - offset]), j)


def as_belief(state):
    """A Gaussian belief from a ``(mean, cov)`` pair (a :class:`MeasuredState` as it is)."""
    return state if isinstance(state, MeasuredState) else GaussianState(*state)


def _lift(A, nb, X, tail):
    """``A (*batch, *tail)`` viewed against ``X (*batch, *nodes, n)`` (nodes of a rule); a shared
    ``A (*tail)`` as is."""
    if A.ndim == tail:
        return A
    return A.reshape(A.shape[:nb] + (1,) * (X.ndim - 1 - nb) + A.shape[nb:])


class GaussianFilter(_CrossNoise, DiscreteFilter):
    """Discrete-time Gaussian filter over a moment ``rule`` (see the module docstring).

    Parameters
    ----------
    model : DiscreteModel
    rule : a rule of :mod:`nlfilter.filters.rules` (``Taylor1()``, ``Taylor2()``, ``Unscented(...)``,
        ``Cubature()``, ``GaussHermite(order)``)
    start : ``"update"`` or ``"predict"`` (see :mod:`nlfilter.filters.base`)

    ``predict``/``update`` return NaN on the paths whose covariance has no square root (poisoned:
    ``run`` raises or marks them).

    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> from nlfilter.filters.rules import Cubature
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0)
    >>> est = GaussianFilter(model, Cubature()).run(np.array([[[1.0], [0.5]]]), m0=[0.0], P0=[[1.0]])
    >>> round(float(est.means[0, 0, 0]), 6)   # linear model: every rule is the Kalman filter
    0.5
    """

    name = "gaussian"
    family = "gaussian"
    source = "Ito & Xiong 2000 (Gaussian filters); Särkkä 2013, Bayesian Filtering and Smoothing, ch. 6"
    accepts = ("discrete",)
    structures = ("state-dependent R", "cross noise")
    needs: tuple = ()
    time = "discrete"
    compiled = True  # its steps run on the compiled loop (backend="numba"; a subclass changing one loses it)

    def __init__(self, model, rule, *, start: str | None = None):
        super().__init__(model, start=start)
        self._set_rule(rule)

    def _set_rule(self, rule, by=None):
        if not callable(getattr(rule, "moments", None)):
            raise TypeError(f"rule: expected a moment rule (Taylor1, Taylor2, Unscented, Cubature, GaussHermite), "
                            f"got {type(rule).__name__}")
        check = getattr(rule, "check", None)
        if check is not None:
            check(self.model.n)
        self.rule = rule
        self.model.require("f", "h", "G", *rule.needs(self.model), by=by or type(self).__name__)
        self._set_cross()

    def _time(self, k):
        return k

    def _predict(self, state, k, cross: bool = False):
        """``m⁻ = E[f]``, ``P⁻ = Cov[f] + E[G Q Gᵀ]`` (+ the rule's fourth-moment term, added last;
        symmetrized for a rule that asks), poisoned where the rule's nodes failed; with ``cross``
        also ``Cov[x_k, f(x_k)]`` (the smoother's cross-covariance)."""
        md = self.model
        f, f_x, f_xx, sub = md.f, md.f_x, md.f_xx, None
        if self._cross is not None:  # correlated noise: the decorrelated dynamics f̃ (_CrossNoise)
            dec = self._decorrelation(state, k)
            state = GaussianState(state.mean, state.cov)
            if dec is not None:
                D, e, sub = dec
                nb = e.ndim - 1

                def f(X, t):
                    return md.f(X, t) + np.einsum("...ij,...j->...i", _lift(D, nb, X, 2), _lift(e, nb, X, 1) - md.h(X, t))

                def f_x(X, t):
                    return md.f_x(X, t) - _lift(D, nb, X, 2) @ md.h_x(X, t)

                def f_xx(X, t):
                    return md.f_xx(X, t) - np.einsum("...ij,...jkl->...ikl", _lift(D, nb, X, 2), md.h_xx(X, t))
        mo = self.rule.moments(state, f, self._time(k), jac=f_x, hess=f_xx, cross=cross, noise_of=md,
                               role="dynamics")
        P = mo.cov + mo.noise  # P⁻ = Cov[f] + E[G Q Gᵀ]
        if sub is not None:  # Cov[w̃] = Q − S R⁻¹ Sᵀ
            P = P - sub
        if mo.quartic is not None:
            P = P + mo.quartic
        if getattr(self.rule, "symmetrize", False):
            P = symmetrize(P)
        new = GaussianState(mo.mean, P)
        new = self._predicted(new if mo.bad is None else poison(new, mo.bad))
        return (new, mo.cross) if cross else new

    smoother = "rts"

    def _predict_cross(self, state, k):
        return self._predict(state, k, cross=True)

    def _smooth(self, est, beliefs, ys, t0):
        """The RTS backward pass through the rule (:func:`~nlfilter.filters.smoothing.rts`)."""
        off = 0 if self.start == "update" else 1
        ms, Ps, lag = rts(est.means, est.covs, self._smooth_predict(ys, off), off)
        return ms, Ps, {"lag_one_cov": lag}

    def predict(self, state, k):
        return self._predict(state, k)

    def _update(self, state, y, t, R=None, info: bool = False):
        """``(updated belief, failed paths or None)`` at time ``t``; ``R`` defaults to the model's;
        with ``info``, also the predicted measurement moments ``(ŷ, S)``.

        ``S = Cov[h] + R`` (+ the rule's fourth-moment term); a rule with ``screen`` has S checked
        for positive definiteness (failed paths get a harmless S and are reported); a rule's forcing
        tensor adds ``Σ_k M_k [S⁻¹(y − ŷ)]_k`` to the covariance (the discrete C tensor of seed 004
        eq. 17, see :mod:`nlfilter.filters.second_order`)."""
        md = self.model
        if R is None:  # a state-dependent R(x) at the predicted mean (the EKF convention)
            R = md.R if getattr(md, "R_constant", True) else md.R_of(state.mean, t)
        mo = self.rule.moments(state, md.h, t, jac=md.h_x, hess=md.h_xx, role="measurement")
        S = mo.cov + R
        if mo.quartic is not None:
            S = S + mo.quartic
        bad = mo.bad
        if getattr(self.rule, "screen", False):
            nd = _pd_mask(S)
            if nd.any():  # keep the algebra finite; these paths are reported as diverged
                S = np.where(nd[..., None, None], np.eye(S.shape[-1]) * np.abs(S).max(initial=1.0) + R, S)
            bad = nd if bad is None else bad | nd
        if mo.jac is not None:  # S = H P Hᵀ + R exactly: Joseph form with the linearization
            new = gaussian_update(state, y, mo.mean, S, mo.cross, H=mo.jac, R=R)
        else:
            new = gaussian_update(state, y, mo.mean, S, mo.cross)
        if mo.forcing is not None:  # P⁺ += Σ_k M_k [S⁻¹(y − ŷ)]_k
            miss = np.isnan(y)
            e = np.where(miss, 0.0, y - mo.mean)
            Sm = np.where(miss[..., :, None] | miss[..., None, :], np.eye(S.shape[-1]), S)
            u = np.linalg.solve(Sm, e[..., None])[..., 0]
            new = GaussianState(new.mean, symmetrize(new.cov + np.einsum("...ijk,...k->...ij", mo.forcing, u)))
        return (new, bad, (mo.mean, S)) if info else (new, bad)

    def update(self, state, y, k):
        if self._cross is not None:
            state = GaussianState(state.mean, state.cov)
        new, bad = self._update(state, y, self._time(k))
        return self._carry(new if bad is None else poison(new, bad), y)

    likelihood = "prediction-error"

    def _update_info(self, state, y, k):
        """``run(..., loglik=True)``: the update with the step's log N(y; ŷ, S) and innovation
        (:func:`~nlfilter.filters.linalg.innovation_info`; S with the rule's fourth-moment term)."""
        new, bad, (yhat, S) = self._update(GaussianState(state[0], state[1]), y, self._time(k), info=True)
        return self._carry(new if bad is None else poison(new, bad), y), bad, innovation_info(y, yhat, S)


def _pd_mask(S):
    """Boolean ``(...)``: innovation covariances that are not positive definite."""
    if S.shape[-1] == 1:
        return ~(S[..., 0, 0] > 0)
    return ~np.all(np.linalg.eigvalsh(symmetrize(S)) > 0, axis=-1)


class ContinuousDiscreteGaussianFilter(GaussianFilter):
    """Continuous dynamics, discrete measurements, over a moment ``rule`` (see the module docstring).

    Parameters
    ----------
    model : SDEModel; its ``h`` and ``R`` are read as the *discrete* measurement
        ``y_k = h(x(t_k)) + v_k``, ``v_k ~ N(0, R)``, ``t_k = t0 + k dt``
    dt : float — the measurement interval
    rule : a rule of :mod:`nlfilter.filters.rules`
    scheme : ``"rk4"`` (default) or ``"euler"``;  substeps : int — integration steps per interval
    start : ``"predict"`` (default: ``ys[..., 0, :]`` at ``t0 + dt``, the prior at ``t0``, as
        :func:`~nlfilter.simulate.simulate_continuous_discrete`) or ``"update"`` (at ``t0``); None:
        the default, or a Simulation's (:meth:`~nlfilter.filters.base.Filter.for_timing`)
    t0 : float — the prior's time (None: 0.0, or a Simulation's)

    >>> import sympy as sp; from nlfilter import SDEModel
    >>> from nlfilter.filters.rules import Cubature
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x], Q=2.0, R=1.0)       # stationary variance Q / 2 = 1
    >>> flt = ContinuousDiscreteGaussianFilter(model, 0.1, Cubature(), substeps=4)
    >>> s = flt.predict(GaussianState(np.array([1.0]), np.array([[1.0]])), 0)
    >>> round(float(s.mean[0]), 6), round(float(s.cov[0, 0]), 6)   # e^{-0.1}, 1 (RK4)
    (0.904837, 1.0)
    """

    name = "cd-gaussian"
    compiled = False  # continuous dynamics: no compiled loop
    accepts = ("sde",)
    start = "predict"  # the default: the prior at t0, y_0 at t0 + dt (as simulate_continuous_discrete)

    def __init__(self, model, dt: float, rule, *, scheme: str = "rk4", substeps: int = 1,
                 start: str | None = None, t0: float | None = None, by: str | None = None):
        if getattr(model, "kind", None) != "sde":
            raise TypeError(f"model: {type(self).__name__} expects an SDEModel, got {type(model).__name__}")
        self.model = model
        set_start(self, start)
        self.dt = float(V.positive("dt", dt))
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        self.substeps = V.positive("substeps", substeps, integer=True)
        set_t0(self, t0)
        self._set_rule(rule, by=by)

    def _time(self, k):
        return self.t0 + k * self.dt

    def _rhs(self, m, P, z, s):
        md = self.model
        mo = self.rule.moments(GaussianState(m, P), md.f, s, jac=md.f_x, hess=md.f_xx, cov=False, noise_of=md,
                               role="dynamics")
        dP = mo.cross + np.swapaxes(mo.cross, -1, -2) + mo.noise  # Cov[x, f] + Cov[f, x] + E[G Q Gᵀ]
        dm = mo.mean if mo.bad is None else np.where(mo.bad[..., None], np.nan, mo.mean)  # poisoned paths
        return dm, dP

    def _predict(self, state, k):
        """The belief at ``t_{k+1}`` from the belief at ``t_k = t0 + k dt`` (no measurement)."""
        return ContinuousFilter.integrate(self, self._rhs, GaussianState(*state), None, self._time(k))

    def _predict_cross(self, state, k):
        """The prediction and ``C(t_{k+1}) = Cov[x(t_k), x(t_{k+1})]``: the moment equations with
        ``dC/dt = C P⁻¹ Cov[x, f]`` (:mod:`~nlfilter.filters.smoothing`), ``C(t_k) = P_k``."""
        md = self.model

        def rhs(x, s):
            m, P, C = x
            mo = self.rule.moments(GaussianState(m, P), md.f, s, jac=md.f_x, hess=md.f_xx, cov=False,
                                   noise_of=md, role="dynamics")
            dP = mo.cross + np.swapaxes(mo.cross, -1, -2) + mo.noise
            return mo.mean, dP, C @ _solve_right(P, np.swapaxes(mo.cross, -1, -2)).swapaxes(-1, -2)

        state = GaussianState(*state)
        m, P, C = ode_step(rhs, (state.mean, state.cov, state.cov), self._time(k), self.dt, substeps=self.substeps,
                           scheme=self.scheme, finish=lambda x: (x[0], symmetrize(x[1]), x[2]))
        return GaussianState(m, P), C


class ContinuousGaussianFilter(ContinuousFilter):
    """Continuous-time (Itô) skeleton over a Taylor rule, for an :class:`~nlfilter.models.SDEModel`
    observed through increments ``dy`` (seed 004 eqs. 35-37; with Taylor-1 the continuous EKF)::

        dm = [f + ½(P f_xx)] dt + K {dy − ĥ dt},   ĥ = h + ½(P h_xx),   K = P Hᵀ R⁻¹
        dP = [F P + P Fᵀ + E[G Q Gᵀ] − K R Kᵀ] dt  [+ Σ_k M_k [R⁻¹(dy − ĥ dt)]_k, the rule's forcing]

    (the ½ terms and the forcing only for a second-order rule). ``rule``: :class:`~nlfilter.filters.rules.Taylor1`
    or :class:`~nlfilter.filters.rules.Taylor2` (``form``); it gives ``E[G Q Gᵀ]`` (``noise``) and the
    forcing tensor. Node rules are refused: their E[f] does not split into f and ½(P f_xx) as
    these equations are integrated.

    One step, ``innovation="ito"`` (default): the ``dt`` terms are integrated by ``scheme`` (Euler or
    RK4, ``substeps`` per step), then the ``dy`` terms are added as an Itô increment with the gain at
    the start of the step (with Euler: the Euler–Maruyama step; holding ``dy/dt`` constant inside RK4
    stages would converge to the Stratonovich reading whenever the gain depends on the state).
    ``innovation="update"``: the increment is first absorbed by the discrete update of the rule
    (:meth:`GaussianFilter._update` with ``y = dy/dt``, ``R = R/dt``), then the moments are propagated
    over ``dt`` without measurement terms. Missing components of ``dy`` do not update.

    >>> import sympy as sp; from nlfilter import SDEModel
    >>> from nlfilter.filters.rules import Taylor1
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x], Q=1.0, R=1.0)
    >>> s = ContinuousGaussianFilter(model, 0.01, Taylor1(), scheme="euler").step(
    ...     GaussianState(np.array([0.0]), np.array([[1.0]])), np.array([0.1]), 0.0)
    >>> round(float(s.mean[0]), 6), round(float(s.cov[0, 0]), 6)   # K dy; P + (−2P + 1 − P²) dt
    (0.1, 0.98)
    """

    name = "continuous-gaussian"
    family = "gaussian"
    source = "seed 004 eqs. 35-37 (Henriksen 1979); Jazwinski 1970, ch. 9"

    def __init__(self, model, dt, rule, *, scheme: str = "rk4", substeps: int = 1, innovation: str = "ito"):
        super().__init__(model, dt, scheme=scheme, substeps=substeps)
        self.innovation = V.choice("innovation", innovation, {"ito", "update"})
        self._set_rule(rule)

    def _set_rule(self, rule, by=None):
        if not (callable(getattr(rule, "noise", None)) and callable(getattr(rule, "forcing", None))):
            raise TypeError(f"rule: {type(self).__name__} expects a Taylor rule (Taylor1, Taylor2), "
                            f"got {type(rule).__name__}")
        self.rule = rule
        self.model.require("f", "h", "G", *rule.needs(self.model), by=by or type(self).__name__)
        self._second = rule.second
        self._Rinv = continuous_precision(self.model)

    def _gain_parts(self, m, P, s, obs, Rinv):
        """Gain, P Hᵀ, ĥ and the forcing tensor M R⁻¹; ``Rinv``: the precision of the observed
        components (:func:`~nlfilter.filters.linalg.observed_precision`; missing ones do not update)."""
        md = self.model
        H = md.h_x(m, s) * obs[..., :, None]
        PHt = mm(P, np.swapaxes(H, -1, -2))
        K = mm(PHt, Rinv)  # 004 eq. 37
        hhat = md.h(m, s)
        M = None
        if self._second:
            h_xx = md.h_xx(m, s)
            hhat = hhat + 0.5 * hessian_trace(P, h_xx)  # 004 eq. 35
            M = self.rule.forcing(P, h_xx)
            if M is not None:
                M = np.einsum("...ijk,...kl->...ijl", M * obs[..., None, None, :], Rinv)  # M R⁻¹
        return K, PHt, hhat * obs, M

    def _rhs_factory(self, obs, Rinv):
        md = self.model

        def rhs(m, P, z, s):
            F = md.f_x(m, s)
            K, PHt, hhat, M = self._gain_parts(m, P, s, obs, Rinv)
            dm = md.f(m, s) - np.einsum("...ij,...j->...i", K, hhat)
            if self._second:
                dm = dm + 0.5 * hessian_trace(P, md.f_xx(m, s))  # 004 eq. 35, drift part
            FP = mm(F, P)
            dP = FP + np.swapaxes(FP, -1, -2) + self.rule.noise(md, m, P, s) - mm(K, np.swapaxes(PHt, -1, -2))
            if M is not None:
                dP = dP - np.einsum("...ijk,...k->...ij", M, hhat)  # forcing term, its dt part
            return dm, dP

        return rhs

    likelihood = "prediction-error"

    def _step_info(self, state, dy, t):
        """``run(..., loglik=True)``: the step with the density of the increment under the
        discretised measurement ``dy = h dt + dη``: ``dy/dt ~ N(ŷ, S)``, ``S = Cov[h] + R/dt``
        from the belief at the step's start (the rule's moments; exact as dt → 0 on a linear
        model), reported for ``dy`` (innovation ``dy − ŷ dt``, covariance ``S dt²``)."""
        state = GaussianState(*state)
        dy = np.asarray(dy, dtype=float)
        new, bad, info = self._step(state, dy, t, info=True)
        return new, bad, info

    def _step(self, state, dy, t, info: bool = False):
        """``(state at t + dt, bad paths or None)`` (and the step's likelihood output with ``info``)."""
        obs = ~np.isnan(dy)
        if self.innovation == "update" or info:
            new, bad, (yhat, S) = GaussianFilter._update(self, state, dy / self.dt, t, R=self.model.R / self.dt,
                                                         info=True)
            out = innovation_info(dy / self.dt, yhat, S, scale=self.dt) if info else None
        if self.innovation == "update":
            new = new if bad is None else poison(new, bad)
            none = np.zeros_like(obs)
            new = self.integrate(self._rhs_factory(none, np.zeros_like(self._Rinv)), new, None, t)
            return (new, bad, out) if info else (new, bad)
        dy0 = np.where(obs, dy, 0.0)
        m, P = state
        Rinv = observed_precision(self.model.R, self._Rinv, obs)
        K, _, _, M = self._gain_parts(m, P, t, obs, Rinv)  # Itô: gain at the start of the step
        new = self.integrate(self._rhs_factory(obs, Rinv), GaussianState(m, P), None, t)
        mean = new.mean + np.einsum("...ij,...j->...i", K, dy0)
        cov = new.cov
        if M is not None:
            cov = symmetrize(cov + np.einsum("...ijk,...k->...ij", M, dy0))
        return (GaussianState(mean, cov), None, out) if info else (GaussianState(mean, cov), None)

    def step(self, state, dy, t):
        """The belief at ``t + dt`` from the belief at ``t`` and the increment ``dy (..., m)``."""
        new, bad = self._step(GaussianState(*state), np.asarray(dy, dtype=float), t)
        return new if bad is None else poison(new, bad)

    smoother = "rts"

    def _smooth(self, est, beliefs, ys, t0):
        """The continuous RTS smoother (:func:`~nlfilter.filters.smoothing.continuous_rts`)."""
        return continuous_rts(self, est.means, est.covs, t0)

    def _step_unchecked(self, state, dy, t):
        return self._step(state, dy, t)


def iterated_update(model, state, y, t, iterations: int, tol: float) -> GaussianState:
    """Iterated EKF update (Bell & Cathey 1993, IEEE TAC 38(2): Gauss–Newton on the MAP problem)::

        x_0 = m⁻,   H_i = h_x(x_i),   S_i = H_i P⁻ H_iᵀ + R,   K_i = P⁻ H_iᵀ S_i⁻¹
        x_{i+1} = m⁻ + K_i (y − h(x_i) − H_i (m⁻ − x_i))
        P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ   with the last K_i, H_i (Joseph form)

    Each path stops when ``|x_{i+1} − x_i| ≤ tol (1 + |x_i|)`` componentwise, or after
    ``iterations`` updates (one iteration is the EKF update, exactly). Missing components of ``y``
    take no part (their rows of the innovation and gain are zero, :func:`gaussian_update`), so only
    the observed components are iterated. A path's result does not depend on the other paths.
    """
    md = model
    m, P = state
    R = md.R if getattr(md, "R_constant", True) else md.R_of(m, t)  # R(x) at the predicted mean, as the first update

    def linear_update(x, first):
        H = md.h_x(x, t)
        C = mm(P, np.swapaxes(H, -1, -2))
        S = mm(H, C) + R
        y_pred = md.h(x, t) if first else md.h(x, t) + np.einsum("...ij,...j->...i", H, m - x)
        return gaussian_update(state, y, y_pred, S, C, H=H, R=R)

    new = linear_update(m, True)
    done = np.zeros(m.shape[:-1], bool)
    for _ in range(iterations - 1):
        x = new.mean
        cand = linear_update(x, False)
        step_small = np.all(np.abs(cand.mean - x) <= tol * (1.0 + np.abs(x)), axis=-1)
        new = GaussianState(np.where(done[..., None], new.mean, cand.mean),
                            np.where(done[..., None, None], new.cov, cand.cov))
        done = done | step_small
        if done.all():
            break
    return new


class _Iterated:
    """The iterated update for a Taylor-1 skeleton (``IteratedEKF``, ``ContinuousDiscreteIEKF``)."""
    compiled = False  # the iterated update has no compiled loop

    def _set_iterations(self, iterations, tol):
        self.iterations = V.positive("iterations", iterations, integer=True)
        self.tol = float(V.positive("tol", tol, strict=False))

    def update(self, state, y, k):
        new = iterated_update(self.model, GaussianState(state[0], state[1]), y, self._time(k), self.iterations, self.tol)
        return self._carry(new, y)

    def _update_info(self, state, y, k):
        """The iterated update, with the likelihood of the first (EKF) linearization at the
        predicted mean: the predictive law of y is not changed by iterating the posterior mode."""
        state = GaussianState(state[0], state[1])
        _, _, (yhat, S) = GaussianFilter._update(self, state, y, self._time(k), info=True)
        return self.update(state, y, k), None, innovation_info(y, yhat, S)
