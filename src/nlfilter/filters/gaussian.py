"""One discrete and one continuous-discrete skeleton for the Gaussian filters, over a moment rule.

The EKF, UKF, cubature (CKF) and Gauss–Hermite (GHKF) Kalman filters differ only in the rule of
:mod:`nlfilter.filters.rules` that computes the moments of f and h under the Gaussian belief
``N(m, P)`` (the shape of dynamax's generalized Gaussian filter)::

    predict:  m⁻ = E[f(x)],   P⁻ = Cov[f(x)] + E[G(x) Q G(x)ᵀ]
    update:   ŷ = E[h(x)],  S = Cov[h(x)] + R,  C = Cov[x, h(x)],  K = C S⁻¹,
              m⁺ = m⁻ + K (y − ŷ),  P⁺ = P⁻ − K S Kᵀ

(:func:`~nlfilter.filters.linalg.gaussian_update`: missing components, partly missing measurements
with correlated R, singular S poisoned).

A state-dependent measurement noise ``v_k ~ N(0, R(x_k))`` (``DiscreteModel(..., R=<expression in
the states>)``) enters as ``R(m⁻)``, R at the predicted mean: ``S = Cov[h] + R(m⁻)`` (the EKF
convention, as filterpy's radar example passes ``R=`` at each update; the exact term would be
``E[R(x)]``, which the reference filters use implicitly). The log-likelihood output uses this S.
Correlated process and measurement noise (``cross_noise``, ``E[w_k v_kᵀ] = S``): the prediction
from step k uses the decorrelated dynamics ``f(x) + G S R⁻¹ (y_k − h(x))`` and the noise
``Q − S R⁻¹ Sᵀ`` (:class:`~nlfilter.filters.skeleton.CrossNoise`; the belief, a :class:`MeasuredState`, carries ``y_k``). A linearizing rule (Taylor-1) also hands its ``H = h_x(m)``
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

The iterated update (:func:`~nlfilter.filters.skeleton.iterated_update`, Bell & Cathey 1993) is
the Gauss–Newton maximization of the posterior density in place of the single Taylor-1 update.

The steps themselves are the pure functions of :mod:`nlfilter.filters.skeleton` (``predict``,
``condition``, ``moment_rhs``, ``propagate``); the classes here and their subclasses (EKF, UKF,
CKF, GHKF, SLF, IEKF, the second-order filters) are configurations of them: a rule, a time
setting, and two switches — ``raises`` (the step functions raise
:class:`~nlfilter.errors.DivergenceError` on a failed path instead of returning it poisoned: the
second-order filters) and the update a configuration may replace (``_condition``: the iterated
update, the UKF's augmented points).
"""

from __future__ import annotations

import numpy as np

from .. import _validate as V
from .._npcall import einsum as _einsum
from ..angles import angles_of
from .base import ContinuousFilter, DiscreteFilter, GaussianState, continuous_precision, set_start, set_t0
from .fading import FadingMemory
from .irregular import at_times, belief_time, check_length, interval
from .linalg import innovation_info, observed_precision, poison, symmetrize
from .skeleton import (CrossNoise, MeasuredState, as_belief, as_gaussian, check_paths, condition, ito_gain, ito_rhs,
                       iterated_update, predict, propagate)
from .smoothing import backward_steps, continuous_rts, rts

__all__ = ["GaussianFilter", "ContinuousDiscreteGaussianFilter", "ContinuousGaussianFilter", "iterated_update",
           "MeasuredState", "as_belief"]


class GaussianFilter(DiscreteFilter, FadingMemory):
    """Discrete-time Gaussian filter over a moment ``rule`` (see the module docstring).

    Parameters
    ----------
    model : DiscreteModel
    rule : a rule of :mod:`nlfilter.filters.rules` (``Taylor1()``, ``Taylor2()``, ``Unscented(...)``,
        ``Cubature()``, ``GaussHermite(order)``)
    start : ``"update"`` or ``"predict"`` (see :mod:`nlfilter.filters.base`)

    Notes
    -----
    ``fading_memory(alpha)``: the filter with fading memory, its prediction from ``N(m, α² P)``
    (:mod:`~nlfilter.filters.fading`; every subclass, the continuous-discrete ones included).

    ``predict``/``update`` return NaN on the paths whose covariance has no square root (poisoned:
    ``run`` raises or marks them); with ``raises`` (a configuration's class attribute) they raise
    :class:`~nlfilter.errors.DivergenceError` instead.

    Examples
    --------
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
    structures = ("state-dependent R", "time-varying R", "cross noise", "angles")
    needs: tuple = ()
    time = "discrete"
    raises = False  # True: predict/update raise DivergenceError on a failed path (the second-order filters)
    smoother = "rts"
    likelihood = "prediction-error"
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
        self._cross = CrossNoise(self.model)

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        return self._cross.unmeasured(super().init(m0, P0, batch, initial=initial, rng=rng))

    def _time(self, k):
        return k

    # -- the steps: the skeleton's functions with this configuration's rule and time ---------------
    def _predict(self, state, k, cross: bool = False):
        """:func:`~nlfilter.filters.skeleton.predict` from step ``k`` (correlated noise: with the
        decorrelation of the belief's measurement); with ``cross`` also ``Cov[x_k, f(x_k)]``."""
        cr = self._cross
        if cr.S is None:  # uncorrelated noise: the belief is a plain GaussianState
            return predict(self.rule, self.model, state, self._time(k), cross=cross)
        out = predict(self.rule, self.model, state, self._time(k), decorrelation=cr.decorrelation(state, k),
                      cross=cross)
        return (cr.unmeasured(out[0]), out[1]) if cross else cr.unmeasured(out)

    def _predict_cross(self, state, k):
        pred, D = self._predict(self._inflate(state), k, cross=True)  # fading memory: from α² P (fading.py)
        return pred, self._deflate(D)

    def _condition(self, state, y, t, R=None):
        """``(updated, failed paths or None, (ŷ, S))``: :func:`~nlfilter.filters.skeleton.condition`
        (the step a configuration may replace: the iterated update, the UKF's augmented points)."""
        return condition(self.rule, self.model, state, y, t, R=R)

    def _conditioned(self, state, y, k):
        """The update of step ``k``: ``(belief poisoned on the failed paths, with its measurement,
        failed paths, (ŷ, S))``."""
        y = np.asarray(y, dtype=float)
        new, bad, moments = self._condition(as_gaussian(state), y, self._time(k))
        if bad is not None:
            new = poison(new, bad)
        return (new if self._cross.S is None else self._cross.carry(new, y)), bad, moments

    def predict(self, state, k):
        new = self._predict(self._inflate(state), k)  # fading memory: from α² P (fading.py)
        return check_paths(self, new, None, "predicted covariance", k) if self.raises else new

    def update(self, state, y, k):
        new, bad, _ = self._conditioned(state, y, k)
        return check_paths(self, new, bad, "updated (or innovation) covariance", k) if self.raises else new

    # the run loop's steps: ``predict``/``update`` themselves (so that a subclass redefining one is
    # run with it), except where they raise (``raises``): then the failed paths come back as data
    def _predict_unchecked(self, state, k):
        return (self._predict(self._inflate(state), k) if self.raises else self.predict(state, k)), None

    def _update_unchecked(self, state, y, k):
        if not self.raises:
            return self.update(state, y, k), None
        new, bad, _ = self._conditioned(state, y, k)
        return new, bad

    def _run_steps(self):
        """The run loop's steps (:meth:`~nlfilter.filters.base.Filter._run_steps`): without fading
        memory and correlated noise, :meth:`_predict` and :meth:`_condition` (the skeleton's
        ``predict`` and ``condition`` unless a configuration replaces them) with the failed paths
        of the update poisoned — what ``_predict_unchecked``/``_update_unchecked`` do, their layers
        for those options skipped once per run. A subclass redefining one of those layers runs
        through it (the base's steps)."""
        cls, base = type(self), GaussianFilter
        if self.fading != 1.0 or self._cross.S is not None or any(getattr(cls, a) is not getattr(base, a)
                                                                   for a in _LAYERS):
            return super()._run_steps()
        rule, md, raises, plain_time = self.rule, self.model, self.raises, cls._time is base._time
        if cls._predict is base._predict and plain_time:  # the step's time is k
            def predict_step(state, k):
                return predict(rule, md, state, k), None
        else:
            own_predict = self._predict

            def predict_step(state, k):
                return own_predict(state, k), None
        own_condition, time = (None if cls._condition is base._condition else self._condition), self._time

        def update_step(state, y, k):  # y: a float row of the run's data
            t = k if plain_time else time(k)
            new, bad, _ = (condition(rule, md, state, y, t) if own_condition is None
                           else own_condition(as_gaussian(state), y, t))
            if bad is None:
                return new, None
            return poison(new, bad), (bad if raises else None)
        return predict_step, update_step

    def _update_info(self, state, y, k):
        """``run(..., loglik=True)``: the update with the step's log N(y; ŷ, S) and innovation
        (:func:`~nlfilter.filters.linalg.innovation_info`; S with the rule's fourth-moment term)."""
        new, bad, (yhat, S) = self._conditioned(state, y, k)
        return new, bad, innovation_info(np.asarray(y, dtype=float), yhat, S)

    def _smooth(self, est, beliefs, ys, t0):
        """The RTS backward pass through the rule (:func:`~nlfilter.filters.smoothing.rts`)."""
        ms, Ps, lag = rts(est.means, est.covs, *backward_steps(self, ys), angles=angles_of(self.model).states)
        return ms, Ps, {"lag_one_cov": lag}


#: the layers of a step that :meth:`GaussianFilter._run_steps` skips (a subclass redefining one keeps them)
_LAYERS = ("_predict_unchecked", "_update_unchecked", "predict", "update", "_conditioned", "_inflate")


class ContinuousDiscreteGaussianFilter(GaussianFilter):
    """Continuous dynamics, discrete measurements, over a moment ``rule`` (see the module docstring).

    Parameters
    ----------
    model : SDEModel; its ``h`` and ``R`` are read as the *discrete* measurement
        ``y_k = h(x(t_k)) + v_k``, ``v_k ~ N(0, R)``, ``t_k = t0 + k dt``
    dt : float — the measurement interval; None: the data's (a Simulation's ``dt`` or its
        irregular ``times``), or given by :meth:`at_times` (:mod:`nlfilter.filters.irregular`)
    rule : a rule of :mod:`nlfilter.filters.rules`
    scheme : ``"rk4"`` (default) or ``"euler"``
    substeps : int — integration steps per interval
    start : ``"predict"`` (default: ``ys[..., 0, :]`` at ``t0 + dt``, the prior at ``t0``, as
        :func:`~nlfilter.simulate.simulate_continuous_discrete`) or ``"update"`` (at ``t0``); None:
        the default, or a Simulation's (:meth:`~nlfilter.filters.base.Filter.for_timing`)
    t0 : float — the prior's time (None: 0.0, or a Simulation's)

    Examples
    --------
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
    compiled = True  # the compiled loop runs it too (backend="numba"; nlfilter.filters.compiled.cd_kernels)
    accepts = ("sde",)
    start = "predict"  # the default: the prior at t0, y_0 at t0 + dt (as simulate_continuous_discrete)

    times = None  # the measurement times t_1 < t_2 < ... when irregular (at_times)

    def __init__(self, model, dt: float | None, rule, *, scheme: str = "rk4", substeps: int = 1,
                 start: str | None = None, t0: float | None = None, by: str | None = None):
        if getattr(model, "kind", None) != "sde":
            raise TypeError(f"model: {type(self).__name__} expects an SDEModel, got {type(model).__name__}")
        self.model = model
        set_start(self, start)
        self.dt = None if dt is None else float(V.positive("dt", dt))
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        self.substeps = V.positive("substeps", substeps, integer=True)
        set_t0(self, t0)
        self._set_rule(rule, by=by)

    @property
    def compiled_kind(self):
        """The compiled loop's kind of this filter's rule: ``"cd-taylor1"``, ``"cd-taylor2"``,
        ``"cd-nodes"`` (``nlfilter/filters/compiled/cd_kernels.py``: the prediction; the update the
        discrete rule's), or None."""
        kind = getattr(self.rule, "kind", None)
        return f"cd-{kind}" if kind in ("taylor1", "taylor2", "nodes") else None

    def _time(self, k):
        return belief_time(self, k)

    at_times = at_times  # flt.at_times(times): a copy measuring at t_1 < t_2 < ... (nlfilter.filters.irregular)

    def check_data(self, ys):
        ys = super().check_data(ys)
        check_length(self, ys.shape[-2])
        return ys

    def _predict(self, state, k, cross: bool = False):
        """The belief at ``t_{k+1}`` from the belief at ``t_k = t0 + k dt`` (no measurement):
        :func:`~nlfilter.filters.skeleton.propagate`; with ``cross`` also
        ``C(t_{k+1}) = Cov[x(t_k), x(t_{k+1})]`` (``dC/dt = C P⁻¹ Cov[x, f]``, ``C(t_k) = P_k``)."""
        return propagate(self.rule, self.model, state, self._time(k), interval(self, k), substeps=self.substeps,
                         scheme=self.scheme, cross=cross)


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
    (:func:`~nlfilter.filters.skeleton.condition` with ``y = dy/dt``, ``R = R/dt``), then the moments are propagated
    over ``dt`` without measurement terms. Missing components of ``dy`` do not update.
    ``step`` returns NaN on a failed path, or raises with ``raises`` (the second-order filters).

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
    raises = False  # True: step raises DivergenceError on a failed path (the second-order filters)
    likelihood = "prediction-error"
    smoother = "rts"
    compiled = True  # the Itô step runs on the compiled loop too (backend="numba"; nlfilter.filters.compiled)
    compiled_kind = "ito"  # its kernel there (compiled/ito_kernels.py)

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
        self._Rinv = continuous_precision(self.model)

    def _drift(self, obs, Rinv):
        """``rhs(m, P, z, s)`` of the ``dt`` terms for the run loop's integrator (:func:`ito_rhs`)."""
        return lambda m, P, z, s: ito_rhs(self.rule, self.model, m, P, s, obs, Rinv)

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
            new, bad, (yhat, S) = condition(self.rule, self.model, state, dy / self.dt, t, R=self.model.R / self.dt)
            out = innovation_info(dy / self.dt, yhat, S, scale=self.dt) if info else None
        if self.innovation == "update":
            new = new if bad is None else poison(new, bad)
            none = np.zeros_like(obs)
            new = self.integrate(self._drift(none, np.zeros_like(self._Rinv)), new, None, t)
            return (new, bad, out) if info else (new, bad)
        dy0 = np.where(obs, dy, 0.0)
        m, P = state
        Rinv = observed_precision(self.model.R, self._Rinv, obs)
        K, _, _, M = ito_gain(self.rule, self.model, m, P, t, obs, Rinv, measure=False)  # Itô: gain at the start
        new = self.integrate(self._drift(obs, Rinv), GaussianState(m, P), None, t)
        mean = new.mean + _einsum("...ij,...j->...i", K, dy0)
        cov = new.cov
        if M is not None:
            cov = symmetrize(cov + _einsum("...ijk,...k->...ij", M, dy0))
        return (GaussianState(mean, cov), None, out) if info else (GaussianState(mean, cov), None)

    def step(self, state, dy, t):
        """The belief at ``t + dt`` from the belief at ``t`` and the increment ``dy (..., m)`` (NaN on
        a failed path; with ``raises``, a :class:`~nlfilter.errors.DivergenceError`)."""
        if not self.raises:
            new, bad = self._step_unchecked(state, dy, t)
            return poison(new, bad)
        with np.errstate(over="ignore", invalid="ignore"):
            new, bad = self._step_unchecked(state, dy, t)
        return check_paths(self, new, bad, "covariance", t)

    def _smooth(self, est, beliefs, ys, t0):
        """The continuous RTS smoother (:func:`~nlfilter.filters.smoothing.continuous_rts`)."""
        return continuous_rts(self, est.means, est.covs, t0)

    def _step_unchecked(self, state, dy, t):
        return self._step(GaussianState(*state), np.asarray(dy, dtype=float), t)
