"""Extended Kalman filters, discrete and continuous time.

Discrete (``x[k+1] = f + G w``, ``y = h + v``)::

    predict:  m⁻ = f(m),  P⁻ = F P Fᵀ + G Q Gᵀ,            F = f_x(m), G = G(m)
    update:   S = H P Hᵀ + R,  K = P Hᵀ S⁻¹,  m⁺ = m + K (y − h(m)),
              P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ  (Joseph),    H = h_x(m)

Continuous (Itô SDE, measurement increments ``dy``; seed 004 eqs. 35-37 without the second-order
terms)::

    dm = f dt + K (dy − h dt),  K = P Hᵀ R⁻¹
    dP/dt = F P + P Fᵀ + G Q Gᵀ − P Hᵀ R⁻¹ H P

one step per increment: the ``dt`` terms integrated by Euler or RK4, then ``K dy`` added with the
gain at the start of the step (the Itô reading; with Euler this is Euler–Maruyama).

Also here: the iterated EKF (:class:`IteratedEKF`, Bell & Cathey 1993) and the continuous-discrete
EKF and IEKF (:class:`ContinuousDiscreteEKF`, :class:`ContinuousDiscreteIEKF`): SDE dynamics,
discrete measurements. The discrete and continuous-discrete ones are the skeletons of
:mod:`nlfilter.filters.gaussian` with the Taylor-1 rule.
"""

from __future__ import annotations

import numpy as np  # noqa: F401  (the doctests use it)

from .. import _validate as V
from .base import ContinuousFilter, GaussianState  # noqa: F401  (GaussianState: the doctests)
from .diffuse_prior import DiffusePrior
from .gaussian import ContinuousDiscreteGaussianFilter, ContinuousGaussianFilter, GaussianFilter
from .rules import Taylor1
from .skeleton import iterated_update


def _iterations(flt, iterations, tol):
    """The iterated update's options (:func:`~nlfilter.filters.skeleton.iterated_update`)."""
    flt.iterations = V.positive("iterations", iterations, integer=True)
    flt.tol = float(V.positive("tol", tol, strict=False))


def _iterated_condition(flt, state, y, t, R=None):
    """The update step of the iterated filters (their ``_condition``): the iterated update, and the
    likelihood's ``(ŷ, S)`` of the first (EKF) linearization at the predicted mean (the predictive
    law of y is not changed by iterating the posterior mode)."""
    new, moments = iterated_update(flt.model, state, y, t, flt.iterations, flt.tol, info=True)
    return new, None, moments


class EKF(DiffusePrior, GaussianFilter):
    """Extended Kalman filter for a :class:`~nlfilter.models.DiscreteModel` (batched): the
    :class:`~nlfilter.filters.gaussian.GaussianFilter` skeleton with the
    :class:`~nlfilter.filters.rules.Taylor1` rule (equations in the module docstring).

    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0)
    >>> est = EKF(model).run(np.array([[[1.0], [0.5]]]), m0=[0.0], P0=[[1.0]])
    >>> est.means.shape, round(float(est.means[0, 0, 0]), 6)
    ((1, 2, 1), 0.5)
    """

    name = "ekf"
    source = "Jazwinski 1970, Stochastic Processes and Filtering Theory, ch. 8 (extended Kalman filter)"
    compiled = True  # its steps are the family's (backend="numba")
    needs = ("f_x", "h_x")

    def __init__(self, model, *, start: str | None = None):
        super().__init__(model, Taylor1(), start=start)


class IteratedEKF(DiffusePrior, GaussianFilter):
    """Iterated extended Kalman filter (Bell & Cathey 1993).

    The EKF prediction (the skeleton with the Taylor-1 rule), and an update that repeats the
    linearization of h at the latest estimate (Gauss–Newton on the MAP problem)::

        x_0 = m⁻,  H_i = h_x(x_i),  K_i = P⁻ H_iᵀ (H_i P⁻ H_iᵀ + R)⁻¹
        x_{i+1} = m⁻ + K_i (y − h(x_i) − H_i (m⁻ − x_i)),    m⁺ = x_N
        P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ  (last K_i, H_i)

    Parameters
    ----------
    model : DiscreteModel
    iterations : int — the maximum number of Gauss–Newton updates (1: the EKF); default 10
    tol : float — a path stops when ``|x_{i+1} − x_i| ≤ tol (1 + |x_i|)``; default 1e-10
    start : ``"update"`` or ``"predict"``

    Examples
    --------
    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [x], [x**3], Q=0.1, R=0.01)
    >>> s = GaussianState(np.array([1.0]), np.array([[0.5]]))
    >>> y = np.array([8.0])                                  # x = 2 explains it
    >>> round(float(EKF(model).update(s, y, 0).mean[0]), 4), round(float(IteratedEKF(model).update(s, y, 0).mean[0]), 4)
    (3.3282, 1.9999)
    """

    name = "iekf"
    source = "Bell & Cathey 1993, The iterated Kalman filter update as a Gauss-Newton method, IEEE TAC 38(2) 294-297"
    needs = ("f_x", "h_x")
    compiled = False  # the iterated update (its _condition) has no compiled loop

    def __init__(self, model, *, iterations: int = 10, tol: float = 1e-10, start: str | None = None):
        super().__init__(model, Taylor1(), start=start)
        _iterations(self, iterations, tol)

    _condition = _iterated_condition

    @property
    def _diffuse_iterate(self):  # the diffuse prior's update: Gauss–Newton (diffuse_prior.DiffusePrior)
        return self.iterations, self.tol


class ContinuousDiscreteEKF(ContinuousDiscreteGaussianFilter):
    """Continuous-discrete EKF on an :class:`~nlfilter.models.SDEModel` with measurements
    ``y_k = h(x(t_k)) + v_k`` at ``t_k = t0 + k dt`` (Jazwinski 1970, ch. 8)::

        dm/dt = f(m),   dP/dt = F P + P Fᵀ + G Q Gᵀ   (F = f_x(m), between measurements)

    integrated by ``scheme`` with ``substeps`` steps per interval, then the EKF update. The same
    filter as ``ContinuousDiscreteSecondOrderFilter(form="first-order")`` (as a Taylor-1 rule).

    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x], Q=2.0, R=1.0)
    >>> s = ContinuousDiscreteEKF(model, 0.1, substeps=4).predict(GaussianState(np.array([1.0]), np.array([[0.5]])), 0)
    >>> round(float(s.mean[0]), 6), round(float(s.cov[0, 0]), 6)   # e^{-0.1}, 1 − 0.5 e^{-0.2}
    (0.904837, 0.590635)
    """

    name = "cd-ekf"
    source = "Jazwinski 1970, Stochastic Processes and Filtering Theory, ch. 8 (continuous-discrete EKF)"
    needs = ("f_x", "h_x")

    def __init__(self, model, dt: float, *, scheme: str = "rk4", substeps: int = 1, start: str | None = None,
                 t0: float | None = None):
        super().__init__(model, dt, Taylor1(), scheme=scheme, substeps=substeps, start=start, t0=t0)


class ContinuousDiscreteIEKF(ContinuousDiscreteGaussianFilter):
    """Continuous-discrete iterated EKF: the prediction of :class:`ContinuousDiscreteEKF`, the
    iterated update of :class:`IteratedEKF` (Bell & Cathey 1993) at the measurements.

    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x**3], Q=0.2, R=0.01)
    >>> flt = ContinuousDiscreteIEKF(model, 0.1, iterations=20)
    >>> round(float(flt.update(GaussianState(np.array([1.0]), np.array([[0.5]])), np.array([8.0]), 0).mean[0]), 4)
    1.9999
    """

    name = "cd-iekf"
    source = "Bell & Cathey 1993, IEEE TAC 38(2) (iterated update); Jazwinski 1970, ch. 8 (prediction)"
    needs = ("f_x", "h_x")
    compiled = False  # the iterated update has no compiled kernel
    compiled_refusal = "its iterated (Gauss–Newton) update has no compiled kernel; it runs on the NumPy loop"

    def __init__(self, model, dt: float, *, iterations: int = 10, tol: float = 1e-10, scheme: str = "rk4",
                 substeps: int = 1, start: str | None = None, t0: float | None = None):
        super().__init__(model, dt, Taylor1(), scheme=scheme, substeps=substeps, start=start, t0=t0)
        _iterations(self, iterations, tol)

    _condition = _iterated_condition


class ContinuousEKF(ContinuousGaussianFilter):
    """Continuous-time EKF (Kalman–Bucy on the linearization) for an :class:`~nlfilter.models.SDEModel`: the
    :class:`~nlfilter.filters.gaussian.ContinuousGaussianFilter` skeleton (Itô step) with the
    :class:`~nlfilter.filters.rules.Taylor1` rule (equations in the module docstring).

    Parameters
    ----------
    model : SDEModel
    dt : float — the measurement step of the increments ``dy``
    scheme : ``"rk4"`` (default) or ``"euler"`` — integration of the mean/covariance ODE
    substeps : int — integration steps per measurement step
    """

    name = "ekf"
    family = "gaussian"
    source = "seed 004 eqs. 35-37 without the second-order terms (Itô innovation step)"
    needs = ("f_x", "h_x")

    def __init__(self, model, dt, *, scheme="rk4", substeps=1):
        ContinuousFilter.__init__(self, model, dt, scheme=scheme, substeps=substeps)
        self.innovation = "ito"
        self._set_rule(Taylor1(), by="ContinuousEKF")
