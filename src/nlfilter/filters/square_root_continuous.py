"""Continuous-discrete square-root Gaussian filters (``sr-continuous-discrete-ekf``, ``-ukf``,
``-ckf``): the prediction of :class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter`
propagated on a lower-triangular factor ``S`` of the covariance (``P = S Sᵀ``), the discrete
square-root update of :mod:`nlfilter.filters.square_root` at the measurements.

Between measurements the moment equations of the Gaussian closure (Särkkä 2007, IEEE TAC 52(9))
``dP/dt = Cov[x, f] + Cov[f, x] + E[G Q Gᵀ]`` become the square-root moment ODE (Särkkä 2007, §IV,
the square-root continuous-discrete UKF; Arasaratnam, Haykin & Hurd 2010, IEEE TSP 58(10), the
square-root continuous-discrete CKF; Morf, Lévy & Kailath 1978 for the Riccati equation)::

    dm/dt = E[f],    dS/dt = S Φ(M),    M = S⁻¹ (dP/dt) S⁻ᵀ
    Φ(M) = the strictly lower triangle of M plus half its diagonal

so that ``dS Sᵀ + S dSᵀ = S (Φ(M) + Φ(M)ᵀ) Sᵀ = dP/dt`` and S stays lower-triangular (a product of
lower-triangular matrices; every RK stage a sum of them). P is never formed: with the rule's points
``X_i = m + S z_i`` (the factor itself as their square root, as the standard filter's Cholesky
factor of ``S Sᵀ`` is ``S``), ``S⁻¹ Cov[x, f] S⁻ᵀ = Σ wc_i z_i (S⁻¹ (f(X_i) − ḟ))ᵀ``; Taylor-1 (the
EKF), ``S⁻¹ Cov[f, x] S⁻ᵀ = S⁻¹ F S``; the noise, ``W Wᵀ`` with ``W = S⁻¹ G Q^½`` (or
``Σ wm_i (S⁻¹ G(X_i) Q^½)(·)ᵀ`` for a state-dependent G). The triangular solves need S invertible
(P positive definite): a path whose factor is singular is poisoned, so ``run`` raises or marks it.

Integrated by ``scheme`` (``"rk4"`` default, or ``"euler"``) with ``substeps`` steps per interval:
the defaults of the standard continuous-discrete filters. The two ODEs are the same flow in exact
arithmetic but not the same discretisation: RK4 applied to ``(m, S)`` and to ``(m, P)`` differ by
``O(h⁴)`` (the difference of the two global errors; ``tests/filters/test_square_root_continuous.py``
measures it falling ~16x per halving of h). Accuracy: RK4's error on the factor ODE grows with
``h ‖Φ(M)‖``, and ``‖M‖ ≈ ‖G Q Gᵀ‖ / λ_min(P)`` exceeds the covariance ODE's rate ``‖F‖`` wherever
the process noise is large against the covariance (after an informative update): on
``tests/filters/test_rule_tables.py``'s linear model (rate ~40 against ~1) at dt = 0.01 and one
substep the square-root form is within 1.2e-6 of the exact discretisation, the covariance form
within 1.2e-11; 8 substeps bring it to 2.6e-10 — give such problems more ``substeps``.
``smooth`` is the standard filter's moment-form RTS smoother (the continuous-discrete
cross-covariance ``dC/dt = C P⁻¹ Cov[x, f]``) from the reported moments, as the fixed-lag smoother
of every square-root filter.
"""

from __future__ import annotations

import numpy as np

from ..ode import ode_step
from .gaussian import ContinuousDiscreteGaussianFilter, GaussianFilter
from .base import Filter, GaussianState
from .irregular import belief_time, check_length, interval
from .linalg import mm, sqrt_psd
from .skeleton import propagate
from .triangular import tria
from .rules import Cubature, Taylor1, Unscented
from .square_root import SqrtState, SquareRootFilter, _poison, sqrt_predict

__all__ = ["STIFF", "sqrt_moment_rhs", "sqrt_propagate", "continuous_discrete",
           "SquareRootContinuousDiscreteEKF",
           "SquareRootContinuousDiscreteUKF", "SquareRootContinuousDiscreteCKF"]


def _phi(M):
    """``Φ(M)``: the strictly lower triangle of ``M`` plus half its diagonal."""
    return np.tril(M, -1) + 0.5 * np.tril(np.triu(M))


def _rhs(rule, model, m, S, t, Lq):
    """``(dm/dt, Φ(M))`` at ``(m, S)`` (``dS/dt = S Φ(M)``; module docstring)."""
    n = m.shape[-1]
    sing = ~np.all(np.diagonal(S, axis1=-2, axis2=-1) > 0, axis=-1)
    Ss = np.where(sing[..., None, None], np.eye(n), S)  # the solves stay finite; those paths are poisoned
    if rule.kind == "taylor1":
        dm = model.f(m, t)
        A = np.linalg.solve(Ss, mm(model.f_x(m, t), S)).swapaxes(-1, -2)  # (S⁻¹ F S)ᵀ = S⁻¹ Cov[x, f] S⁻ᵀ
        W = np.linalg.solve(Ss, model.G(m, t) @ Lq)
        N = mm(W, W.swapaxes(-1, -2))
    else:
        z, wm, wc = rule.unit_nodes(n)
        X = rule.points(m, S)[0]
        FX = model.f(X, t)
        dm = np.einsum("i,...ij->...j", wm, FX)  # Σ wm_i f(X_i)
        SD = np.linalg.solve(Ss, (FX - dm[..., None, :]).swapaxes(-1, -2))  # columns S⁻¹ (f(X_i) − ḟ)
        A = (z.T * wc) @ SD.swapaxes(-1, -2)  # Σ wc_i z_i (S⁻¹ D_i)ᵀ
        if model.G_constant:
            W = np.linalg.solve(Ss, model.G(m, t) @ Lq)
            N = mm(W, W.swapaxes(-1, -2))
        else:  # Σ wm_i (S⁻¹ G(X_i) Q^½)(·)ᵀ
            W = np.linalg.solve(Ss[..., None, :, :], model.G(X, t) @ Lq)
            N = np.einsum("i,...iab,...icb->...ac", wm, W, W)
    M = A + A.swapaxes(-1, -2) + N  # S⁻¹ (dP/dt) S⁻ᵀ
    if sing.any():
        dm = np.where(sing[..., None], np.nan, dm)
    return dm, _phi(M)


def sqrt_moment_rhs(rule, model, m, S, t, Lq):
    """``(dm/dt, dS/dt)`` of the square-root moment ODE (module docstring) at ``(m, S)``, time ``t``,
    ``Lq`` a square root of ``model.Q``; a path whose lower-triangular ``S`` has a diagonal entry that
    is not positive gets NaN (it is reported by the caller)."""
    dm, Phi = _rhs(rule, model, m, S, t, Lq)
    return dm, mm(S, Phi)


#: the largest ``h·max|Φ(M)|`` (the factor's relative change over one substep) integrated in
#: square-root form; beyond it (a singular or nearly singular factor: P0 = 0, a rank-deficient P0,
#: a near-noiseless update before a noisy interval) that path's interval is integrated in
#: covariance form instead (the standard filter's ODE, linear in P) and re-factored
STIFF = 1.0


def _array_substeps(rule, model, m, S, t, dt, Lq, substeps, scheme) -> SqrtState:
    """The interval in ``substeps`` discrete square-root predictions (:func:`~nlfilter.filters.square_root.sqrt_predict`,
    a triangularised array: a factor by construction) of the flow over ``h = dt / substeps``
    (one ``scheme`` step of ``f``; Taylor-1: its Jacobian ``I + h f_x``) with the noise ``h G Q Gᵀ``:
    first order in ``h``, the fallback where both ODE forms fail (a near-singular factor whose
    covariance-form stages turn indefinite)."""
    h, n = dt / substeps, m.shape[-1]
    state = SqrtState(m, S)
    for j in range(substeps):
        s = t + j * h
        flow = lambda x, k: ode_step(model.f, x, k, h, scheme=scheme)  # noqa: E731
        jac = lambda x, k: np.eye(n) + h * model.f_x(x, k)  # noqa: E731
        state = sqrt_predict(rule, model, state, s, np.sqrt(h) * Lq, f=flow,
                             f_x=jac if rule.kind == "taylor1" else None)[0]
    return state


def sqrt_propagate(rule, model, belief, t, dt, Lq, *, substeps: int = 1, scheme: str = "rk4") -> SqrtState:
    """The continuous-discrete square-root prediction: :func:`sqrt_moment_rhs` integrated from ``t``
    to ``t + dt`` (:func:`~nlfilter.ode.ode_step`: ``scheme``, ``substeps``), the belief at ``t + dt``.
    A path whose factor is not lower-triangular with a positive diagonal, or changes by more than
    :data:`STIFF` of itself in a substep, is integrated in covariance form
    (:func:`~nlfilter.filters.skeleton.propagate`, the standard filter's step) and re-factored by
    ``tria``; where that fails too (its RK stages turn the covariance indefinite: a near-noiseless
    update before a noisy interval), by discrete square-root array steps of the flow; a path that
    fails every way is NaN (``run`` raises or marks it)."""
    m, S = belief[0], belief[1]
    n = m.shape[-1]
    tri = np.all(np.triu(S, 1) == 0, axis=(-2, -1)) & np.all(np.diagonal(S, axis1=-2, axis2=-1) > 0, axis=-1)
    Ss = np.where(tri[..., None, None], S, np.eye(n))
    with np.errstate(over="ignore", invalid="ignore"):
        Phi = _rhs(rule, model, m, Ss, t, Lq)[1]
        fall = ~tri | ~(dt / substeps * np.abs(Phi).max(axis=(-2, -1)) <= STIFF)
    Ss = np.where(fall[..., None, None], np.eye(n), Ss)
    mp, Sp = ode_step(lambda x, s: sqrt_moment_rhs(rule, model, x[0], x[1], s, Lq), (m, Ss), t, dt,
                      substeps=substeps, scheme=scheme)
    if fall.any():  # covariance form on those paths, re-factored
        P = mm(S, S.swapaxes(-1, -2))
        cov = propagate(rule, model, GaussianState(m, P), t, dt, substeps=substeps, scheme=scheme)
        L, bad = sqrt_psd(cov.cov)
        bad = bad | ~np.isfinite(cov.mean).all(axis=-1)
        L = np.where(bad[..., None, None], np.nan, tria(np.where(bad[..., None, None], 0.0, L)))
        mp = np.where(fall[..., None], cov.mean, mp)
        Sp = np.where(fall[..., None, None], L, Sp)
        last = fall & bad & tri  # where that fails too: the array form, a factor by construction
        if last.any():
            arr = _array_substeps(rule, model, m, S, t, dt, Lq, substeps, scheme)
            mp = np.where(last[..., None], arr.mean, mp)
            Sp = np.where(last[..., None, None], arr.factor, Sp)
    failed = ~np.all(np.diagonal(Sp, axis1=-2, axis2=-1) > 0, axis=-1) & ~fall
    return _poison(SqrtState(mp, Sp), failed | ~np.isfinite(mp).all(axis=-1))


class _ContinuousDiscreteSteps:
    """The continuous-discrete part of a square-root filter, copied onto each class by
    :func:`continuous_discrete` (not a base class: the filters stay configurations of
    :class:`~nlfilter.filters.square_root.SquareRootFilter`, ``Filter`` at most 4 places down their MRO)."""

    compiled = False  # continuous dynamics: no compiled loop
    compiled_refusal = "its continuous-time prediction (an ODE of the factor) has no compiled kernel"
    accepts = ("sde",)
    start = "predict"  # the prior at t0, y_0 at t0 + dt (as simulate_continuous_discrete)
    structures = ("state-dependent R",)
    smoother_keeps = False  # the moment-form RTS pass reads the reported moments
    times = None  # the measurement times t_1 < t_2 < ... when irregular (at_times)
    at_times = ContinuousDiscreteGaussianFilter.at_times  # nlfilter.filters.irregular

    def _continuous_discrete(self, model, dt, rule, scheme, substeps, start, t0):
        # the standard filter's set-up (model kind, start, dt, scheme, substeps, t0, the rule's needs)
        ContinuousDiscreteGaussianFilter.__init__(self, model, dt, rule, scheme=scheme, substeps=substeps, start=start,
                                                  t0=t0, by=type(self).__name__)
        self._square_root_rule(rule)

    def _time(self, k):
        return belief_time(self, k)

    def check_data(self, ys):
        ys = Filter.check_data(self, ys)
        check_length(self, ys.shape[-2])
        return ys

    def _predict(self, state, k):
        self._check_belief(state)
        return sqrt_propagate(self.rule, self.model, state, self._time(k), interval(self, k), self._root("Q", self.model.Q),
                              substeps=self.substeps, scheme=self.scheme)

    def _predict_cross(self, state, k):
        """The standard filter's prediction with ``Cov[x(t_k), x(t_{k+1})]`` from moments (the smoothers)."""
        pred, D = ContinuousDiscreteGaussianFilter._predict(self, self._inflate(state), k, cross=True)
        return pred, self._deflate(D)

    _smooth = GaussianFilter._smooth


def continuous_discrete(cls):
    """Class decorator: a :class:`~nlfilter.filters.square_root.SquareRootFilter` subclass made
    continuous-discrete — the model, ``dt``, ``scheme``, ``substeps``, ``start`` and ``t0`` as
    :class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter` takes them (its
    ``__init__`` calls ``self._continuous_discrete(model, dt, rule, scheme, substeps, start, t0)``),
    the prediction by :func:`sqrt_propagate`, the standard filter's moment-form RTS smoother from
    the reported moments."""
    for key, value in vars(_ContinuousDiscreteSteps).items():
        if not key.startswith("__"):
            setattr(cls, key, value)
    return cls


_PARAMS = """
    Parameters
    ----------
    model : SDEModel; its ``h`` and ``R`` are read as the discrete measurement ``y_k = h(x(t_k)) + v_k``
    dt : float — the measurement interval
    scheme : ``"rk4"`` (default) or ``"euler"``
    substeps : int — integration steps per interval (default 1)
    start : ``"predict"`` (default: ``ys[..., 0, :]`` at ``t0 + dt``) or ``"update"``
    t0 : float — the prior's time (None: 0.0)
"""


@continuous_discrete
class SquareRootContinuousDiscreteEKF(SquareRootFilter):
    __doc__ = """Square-root continuous-discrete EKF: ``dm/dt = f(m)``, ``dS/dt = S Φ(S⁻¹ F S + (S⁻¹ F S)ᵀ
    + W Wᵀ)``, ``W = S⁻¹ G Q^½`` (module docstring), the square-root EKF update at the measurements;
    :class:`~nlfilter.filters.ekf.ContinuousDiscreteEKF` in square-root form.
    """ + _PARAMS + """
    Examples
    --------
    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> flt = SquareRootContinuousDiscreteEKF(SDEModel([x], [-x], [x], Q=2.0, R=1.0), 0.1, substeps=4)
    >>> b = flt.predict(flt.init([1.0], [[0.5]], (1,)), 0)
    >>> round(float(b.mean[0, 0]), 6), round(float(b.factor[0, 0, 0] ** 2), 6)   # e^{-0.1}, 1 − 0.5 e^{-0.2}
    (0.904837, 0.590635)
    """

    name = "sr-cd-ekf"
    source = ("Jazwinski 1970, ch. 8 (continuous-discrete EKF); Särkkä 2007, IEEE TAC 52(9) (square-root moment "
              "ODE); Morf & Kailath 1975, IEEE TAC 20(4) (array update)")
    needs = ("f_x", "h_x")

    def __init__(self, model, dt: float, *, scheme: str = "rk4", substeps: int = 1, start: str | None = None,
                 t0: float | None = None):
        self._continuous_discrete(model, dt, Taylor1(), scheme, substeps, start, t0)


@continuous_discrete
class SquareRootContinuousDiscreteUKF(SquareRootFilter):
    __doc__ = """Square-root continuous-discrete unscented Kalman filter (Särkkä 2007, §IV): the sigma
    points ``m + S z_i`` of :class:`~nlfilter.filters.rules.Unscented` ``(alpha, beta, kappa)`` in the
    square-root moment ODE (a negative centre weight is only a coefficient there), the square-root
    UKF update at the measurements; :class:`~nlfilter.filters.ukf.ContinuousDiscreteUKF` in
    square-root form.
    """ + _PARAMS

    name = "sr-cd-ukf"
    source = ("Särkkä 2007, On unscented Kalman filtering for state estimation of continuous-time nonlinear "
              "systems, IEEE TAC 52(9) (square-root form); van der Merwe & Wan 2001 (square-root update)")

    def __init__(self, model, dt: float, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 scheme: str = "rk4", substeps: int = 1, start: str | None = None, t0: float | None = None):
        self._continuous_discrete(model, dt, Unscented(alpha, beta, kappa), scheme, substeps, start, t0)
        self.alpha, self.beta, self.kappa = self.rule.alpha, self.rule.beta, self.rule.kappa


@continuous_discrete
class SquareRootContinuousDiscreteCKF(SquareRootFilter):
    __doc__ = """Square-root continuous-discrete cubature Kalman filter (Arasaratnam, Haykin & Hurd 2010,
    IEEE TSP 58(10)): the points ``m ± √n S e_i`` in the square-root moment ODE, the square-root CKF
    update at the measurements; :class:`~nlfilter.filters.cubature.ContinuousDiscreteCKF` in
    square-root form.
    """ + _PARAMS

    name = "sr-cd-ckf"
    source = ("Arasaratnam, Haykin & Hurd 2010, Cubature Kalman filtering for continuous-discrete systems, "
              "IEEE TSP 58(10) (square-root form)")

    def __init__(self, model, dt: float, *, scheme: str = "rk4", substeps: int = 1, start: str | None = None,
                 t0: float | None = None):
        self._continuous_discrete(model, dt, Cubature(), scheme, substeps, start, t0)
