"""The square-root iterated EKF: the Gauss–Newton update of :class:`~nlfilter.filters.ekf.IteratedEKF`
(Bell & Cathey 1993) with every linearization's update in array form
(:func:`~nlfilter.filters.square_root.sqrt_condition`)::

    x_0 = m⁻,   H_i = h_x(x_i),   tria([[H_i S⁻, R^½], [S⁻, 0]]) = [[S_y,i, 0], [K̄_i, S⁺_i]]
    x_{i+1} = m⁻ + K̄_i S_y,i⁻¹ (y − h(x_i) − H_i (m⁻ − x_i)),    m⁺ = x_N,   S⁺ = S⁺_N

(the last linearization's factor: the standard filter's Joseph form with the last K_i, H_i). A path
stops when ``|x_{i+1} − x_i| ≤ tol (1 + |x_i|)`` componentwise, or after ``iterations`` updates; the
likelihood's factor is the first (EKF) linearization's, at the predicted mean.
"""

from __future__ import annotations

import numpy as np

from .ekf import _iterations
from .rules import Taylor1
from .skeleton import gauss_newton
from .square_root import SquareRootFilter, _poison, sqrt_condition

__all__ = ["SquareRootIEKF", "sqrt_iterated_condition"]


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

    def __init__(self, model, *, iterations: int = 10, tol: float = 1e-10, start: str | None = None):
        super().__init__(model, Taylor1(), start=start)
        _iterations(self, iterations, tol)

    def _conditioned(self, state, y, k, full: bool = False):
        self._check_belief(state)
        y = np.asarray(y, dtype=float)
        new, bad, info = sqrt_iterated_condition(self.model, state, y, self._time(k), self._measurement_root(),
                                                 self.iterations, self.tol, full=full)
        return _poison(new, bad), bad, info
