"""The registered square-root filters (``sr-kf``, ``sr-ekf``, ``sr-iekf``, ``sr-ukf``, ``sr-ckf``,
``sr-ghkf``, ``sr-slf``): configurations of :class:`~nlfilter.filters.square_root.SquareRootFilter` by a rule,
as the standard ones configure :class:`~nlfilter.filters.gaussian.GaussianFilter`; the steps and the
equations are in :mod:`nlfilter.filters.square_root`.

The square-root iterated EKF (:class:`SquareRootIEKF`): the Gauss–Newton update of
:class:`~nlfilter.filters.ekf.IteratedEKF` (Bell & Cathey 1993) with every linearization's update in
array form (:func:`~nlfilter.filters.square_root.sqrt_condition`)::

    x_0 = m⁻,   H_i = h_x(x_i),   tria([[H_i S⁻, R^½], [S⁻, 0]]) = [[S_y,i, 0], [K̄_i, S⁺_i]]
    x_{i+1} = m⁻ + K̄_i S_y,i⁻¹ (y − h(x_i) − H_i (m⁻ − x_i)),    m⁺ = x_N,   S⁺ = S⁺_N

(the last linearization's factor: the standard filter's Joseph form with the last K_i, H_i). A path
stops when ``|x_{i+1} − x_i| ≤ tol (1 + |x_i|)`` componentwise, or after ``iterations`` updates; the
likelihood's factor is the first (EKF) linearization's, at the predicted mean.
"""

from __future__ import annotations

import numpy as np

from .checks import check_structure
from .cubature import exact_order
from .ekf import _iterations
from .kalman import _require_linear
from .rules import Cubature, GaussHermite, Taylor1, Unscented
from .skeleton import gauss_newton
from .square_root import SquareRootFilter, _poison, sqrt_condition

__all__ = ["SquareRootKF", "SquareRootEKF", "SquareRootIEKF", "SquareRootUKF", "SquareRootCKF", "SquareRootGHKF",
           "SquareRootSLF", "sqrt_iterated_condition"]


class SquareRootEKF(SquareRootFilter):
    """Square-root extended Kalman filter: the Taylor-1 rule's steps in array form
    (:mod:`nlfilter.filters.square_root`; the same estimates as :class:`~nlfilter.filters.ekf.EKF` in
    exact arithmetic).

    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> from nlfilter.filters.ekf import EKF
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [0.9 * x + 0.1 * sp.sin(x)], [x**3], Q=0.1, R=0.01)
    >>> ys = np.array([[[0.5], [0.2], [0.9]]])
    >>> a, b = SquareRootEKF(model).run(ys, [0.5], [[0.3]]), EKF(model).run(ys, [0.5], [[0.3]])
    >>> float(np.abs(a.means - b.means).max()) < 1e-12, float(np.abs(a.covs - b.covs).max()) < 1e-12
    (True, True)
    """

    name = "sr-ekf"
    source = ("Morf & Kailath 1975, IEEE TAC 20(4) (array form); Grewal & Andrews, Kalman Filtering: Theory and "
              "Practice (square-root filtering); Jazwinski 1970, ch. 8 (the EKF)")
    needs = ("f_x", "h_x")

    def __init__(self, model, *, start: str | None = None):
        super().__init__(model, Taylor1(), start=start)


class SquareRootKF(SquareRootFilter):
    """Square-root Kalman filter on a linear model (f, h affine, G constant): :class:`SquareRootEKF`'s
    array steps, exact there (Morf & Kailath 1975; Bierman 1977). The same estimates as
    :class:`~nlfilter.filters.kalman.KalmanFilter` in exact arithmetic, PSD covariances in any."""

    name = "sr-kf"
    source = ("Morf & Kailath 1975, Square-root algorithms for least-squares estimation, IEEE TAC 20(4); "
              "Bierman 1977, Factorization Methods for Discrete Sequential Estimation")
    needs = ("linear",)

    def __init__(self, model, *, start: str | None = None):
        super().__init__(model, Taylor1(), start=start)  # a structure it does not take is named first
        _require_linear(model, "SquareRootKF")


class SquareRootUKF(SquareRootFilter):
    """Square-root unscented Kalman filter (van der Merwe & Wan 2001): the scaled sigma points
    ``(alpha, beta, kappa)`` of :class:`~nlfilter.filters.rules.Unscented` drawn from the factor; a
    negative centre weight (``α < 1``) by Cholesky downdates, a failed one reported
    (:mod:`nlfilter.filters.square_root`).
    Additive noise only (the augmented form of :class:`~nlfilter.filters.ukf.UKF` is not here)."""

    name = "sr-ukf"
    source = ("van der Merwe & Wan 2001, The square-root unscented Kalman filter for state and parameter-estimation, "
              "ICASSP 2001, vol. 6, 3461-3464")

    def __init__(self, model, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 start: str | None = None):
        super().__init__(model, Unscented(alpha, beta, kappa), start=start)
        self.alpha, self.beta, self.kappa = self.rule.alpha, self.rule.beta, self.rule.kappa


class SquareRootCKF(SquareRootFilter):
    """Square-root cubature Kalman filter (Arasaratnam & Haykin 2009, its square-root form): the
    points ``m ± √n S e_i``, weights ``1/(2n)``, all positive (QR steps only)."""

    name = "sr-ckf"
    source = "Arasaratnam & Haykin 2009, Cubature Kalman filters, IEEE TAC 54(6) 1254-1269 (square-root CKF)"

    def __init__(self, model, *, start: str | None = None):
        super().__init__(model, Cubature(), start=start)


class SquareRootGHKF(SquareRootFilter):
    """Square-root Gauss–Hermite (quadrature) Kalman filter: ``order ≥ 2`` nodes per axis from the
    factor (Arasaratnam & Haykin 2008, Square-root quadrature Kalman filtering, IEEE TSP 56(6); Ito &
    Xiong 2000 for the rule)."""

    name = "sr-ghkf"
    source = ("Arasaratnam & Haykin 2008, Square-root quadrature Kalman filtering, IEEE TSP 56(6) 2589-2593; "
              "Ito & Xiong 2000, IEEE TAC 45(5) (the rule)")

    def __init__(self, model, *, order: int = 3, start: str | None = None):
        rule = GaussHermite(order)  # a bad order named by the rule
        if rule.order < 2:  # one node at the mean: its points carry no covariance
            raise ValueError(f"order: the square-root GHKF needs order ≥ 2 (a rule exact for second moments), "
                             f"got {order!r}")
        super().__init__(model, rule, start=start)
        self.order = self.rule.order


class SquareRootSLF(SquareRootFilter):
    """Square-root statistically linearized filter for a polynomial model: the square-root
    Gauss–Hermite filter at :func:`~nlfilter.filters.cubature.exact_order` (the rule then computes the
    Gaussian moments of polynomial f, h, G exactly; Gelb 1974, §6.2), as
    :class:`~nlfilter.filters.cubature.StatisticallyLinearizedFilter` is the GHKF's (order at least 2,
    whose points carry P, where f and h do not depend on the state at all)."""

    name = "sr-slf"
    source = ("Gelb 1974, Applied Optimal Estimation §6.2 (statistical linearization); Arasaratnam & Haykin 2008, "
              "IEEE TSP 56(6) (square-root quadrature)")
    needs = ("polynomial",)

    def __init__(self, model, *, start: str | None = None):
        check_structure(self, model)  # a structure it does not take is named before the degrees are read
        super().__init__(model, GaussHermite(max(2, exact_order(model))), start=start)
        self.order = self.rule.order


def sqrt_iterated_condition(model, belief, y, t, Lr, iterations: int, tol: float, *, full: bool = False):
    """``(SqrtState, failed paths of the first update or None, its (ŷ, S_y, u, S))``: the iterated
    update of ``belief`` on ``y`` (module docstring); a later linearization that fails poisons its
    path (``run`` then raises or marks it)."""
    rule = Taylor1()
    first, bad, info = sqrt_condition(rule, model, belief, y, t, Lr, full=full)

    def relinearized(x):
        cand, failed, _ = sqrt_condition(rule, model, belief, y, t, Lr, at=x)
        return _poison(cand, failed)

    return gauss_newton(_poison(first, bad), relinearized, iterations, tol), bad, info


class SquareRootIEKF(SquareRootFilter):
    """Square-root iterated extended Kalman filter (Bell & Cathey 1993, the Gauss–Newton update, in
    the array form of Morf & Kailath 1975): the square-root EKF's prediction, the update of the
    module docstring; the same estimates as :class:`~nlfilter.filters.ekf.IteratedEKF` in exact
    arithmetic.

    Parameters
    ----------
    model : DiscreteModel
    iterations : int — the maximum number of Gauss–Newton updates (1: the square-root EKF); default 10
    tol : float — a path stops when ``|x_{i+1} − x_i| ≤ tol (1 + |x_i|)``; default 1e-10
    start : ``"update"`` or ``"predict"``
    """

    name = "sr-iekf"
    source = ("Bell & Cathey 1993, The iterated Kalman filter update as a Gauss-Newton method, IEEE TAC 38(2); "
              "Morf & Kailath 1975, IEEE TAC 20(4) (array form)")
    needs = ("f_x", "h_x")

    compiled = False
    compiled_refusal = "its iterated (Gauss–Newton) update has no compiled kernel; it runs on the NumPy loop"

    def __init__(self, model, *, iterations: int = 10, tol: float = 1e-10, start: str | None = None):
        super().__init__(model, Taylor1(), start=start)
        _iterations(self, iterations, tol)

    def _conditioned(self, state, y, k, full: bool = False):
        self._check_belief(state)
        y = np.asarray(y, dtype=float)
        new, bad, info = sqrt_iterated_condition(self.model, state, y, self._time(k), self._measurement_root(),
                                                 self.iterations, self.tol, full=full)
        return self._carry(_poison(new, bad), y), bad, info
