"""Benchmark problems of the papers as ready models (a flat module of functions).

Each function returns a :class:`Problem`: the model, the filters' prior ``(m0, P0)``, the true
initial state (``x0``; ``None`` means "drawn from the prior"), the step ``dt`` and a default number
of ``steps``. Parameters are keyword arguments with the defaults the experiments use.

Seed 004 problems (``nlfilter reproduce second-order``):

* :func:`quadratic` — scalar discrete, strong quadratic measurement (the setting of Andrade Netto
  et al., where the pre-correction truncated filter loses positive definiteness);
* :func:`state_noise` — scalar Itô SDE with state-dependent noise gain, where the G_x (and G_xx)
  terms of 004 eqs. 13-14, 36 matter;
* :func:`falling_body` — the falling body / re-entry problem of Athans, Wishner and Bertolini
  (1968): continuous dynamics, discrete range measurements.

Seed 001 problem: :func:`cubic_sensor` (Vallot's cubic sensor; ``nlfilter reproduce cubic-sensor``
and ``cubic-sensor-closures``).

>>> p = quadratic()
>>> p.model.n, p.model.m, p.model.kind
(1, 1, 'discrete')
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import sympy as sp

from . import _validate as V
from .models import DiscreteModel, SDEModel


class Problem(NamedTuple):
    """A benchmark: ``model``, prior ``m0 (n,)``, ``P0 (n, n)``, true ``x0 (n,)`` or ``None`` (drawn
    from the prior), measurement step ``dt`` (``None`` for a discrete model), default ``steps``."""

    model: object
    m0: np.ndarray
    P0: np.ndarray
    x0: np.ndarray | None
    dt: float | None
    steps: int
    name: str


def quadratic(*, a: float = 0.7, b: float = 0.02, c: float = 0.3, q: float = 1.0, r: float = 0.2,
              p0: float = 1.0, steps: int = 50) -> Problem:
    """``x[k+1] = a x + b x² + w``, ``y = x + c x² + v``, ``w ~ N(0, q)``, ``v ~ N(0, r)``,
    ``x[0] ~ N(0, p0)``.

    The measurement curvature ``c`` is "strong" when ``c² X² ≳ r``: Jazwinski's innovation variance
    ``(1 + 2cm)² X + r − ¼(2cX)²`` then turns negative near ``m = −1/(2c)``, where the measurement is
    uninformative. The drift keeps its fixed point at 0 stable (the other, at ``(1 − a)/b``, is far
    out in the tail for the defaults).
    """
    for nm, v in (("q", q), ("r", r), ("p0", p0)):
        V.positive(nm, v)
    V.positive("steps", steps, integer=True)
    x = sp.Symbol("x")
    model = DiscreteModel([x], [a * x + b * x**2], [x + c * x**2], Q=q, R=r, name="quadratic")
    return Problem(model, np.zeros(1), np.array([[p0]]), None, None, steps, "quadratic")


def state_noise(*, a: float = 1.0, s0: float = 0.3, s1: float = 0.8, s2: float = 0.1, c: float = 0.5,
                r: float = 0.2, p0: float = 0.25, m0: float = 0.5, dt: float = 0.01,
                steps: int = 200) -> Problem:
    """Itô ``dx = −a x dt + (s0 + s1 x + s2 x²) dβ``, ``dy = (x + c x²) dt + dη``, ``E dβ² = dt``,
    ``E dη² = r dt``, ``x(0) ~ N(m0, p0)``; measurement increments every ``dt``.

    With ``s1 ≠ 0`` the noise intensity depends on the state: the EKF's ``G(m)² `` misses
    ``s1² X`` (the ``(X V G_x²)`` term of 004 eq. 36); ``s2 ≠ 0`` adds the G_xx terms.
    """
    for nm, v in (("r", r), ("p0", p0), ("dt", dt)):
        V.positive(nm, v)
    V.positive("a", a, strict=False)
    V.positive("steps", steps, integer=True)
    x = sp.Symbol("x")
    model = SDEModel([x], [-a * x], [x + c * x**2], G=[[s0 + s1 * x + s2 * x**2]], Q=1.0, R=r,
                     name="state-noise")
    return Problem(model, np.array([m0]), np.array([[p0]]), None, dt, steps, "state-noise")


def falling_body(*, gamma: float = 5e-5, M: float = 1e5, Z: float = 1e5, r: float = 1e4,
                 x0=(3e5, 2e4, 1e-3), m0=(3e5, 2e4, 3e-5), P0=(1e6, 4e6, 1e-4), q: float = 0.0,
                 dt: float = 1.0, steps: int = 60) -> Problem:
    """Falling body of Athans, Wishner and Bertolini (1968), in the form commonly restated (e.g. by
    Julier and Uhlmann): altitude ``x1`` (ft), downward speed ``x2`` (ft/s), ballistic coefficient
    ``x3``::

        dx1/dt = −x2,  dx2/dt = −exp(−γ x1) x2² x3,  dx3/dt = 0      (+ √q dβ on each, q = 0 default)
        y_k = √(M² + (x1(t_k) − Z)²) + v_k,  v_k ~ N(0, r),  t_k = k dt, k = 1..steps

    The radar sits at altitude ``Z`` at horizontal distance ``M``; when the body passes ``Z`` the
    range is insensitive to altitude (h_x1 = 0), where second-order terms matter. The model is an
    :class:`~nlfilter.models.SDEModel` whose ``h``/``R`` are the *discrete* measurement (use
    :class:`~nlfilter.filters.second_order.ContinuousDiscreteSecondOrderFilter`). The true initial
    state ``x0`` is fixed and the prior ``(m0, diag(P0))`` is deliberately off in ``x3``.
    """
    V.positive("r", r)
    V.positive("q", q, strict=False)
    V.positive("dt", dt)
    V.positive("steps", steps, integer=True)
    x1, x2, x3 = sp.symbols("x1 x2 x3")
    f = [-x2, -sp.exp(-gamma * x1) * x2**2 * x3, 0]
    h = [sp.sqrt(M**2 + (x1 - Z) ** 2)]
    model = SDEModel([x1, x2, x3], f, h, G=sp.eye(3), Q=q * np.eye(3), R=r, name="falling-body")
    return Problem(model, np.asarray(m0, float), np.diag(np.asarray(P0, float)), np.asarray(x0, float),
                   dt, steps, "falling-body")


def cubic_sensor(q: float = 2.0, r: float = 1.0, *, dt: float = 0.01, steps: int = 2000) -> Problem:
    """The cubic sensor of seed 001 ch. 5 (Vallot 1981, 001 eqs. 5.1-5.4): ``dx = −x dt + dw``
    (``E dw² = q dt``), ``dy = x³ dt + dv`` (``E dv² = r dt``), started in the stationary law
    ``x(0) ~ N(0, q/2)`` (the prior). Simulate it exactly with :func:`nlfilter.simulate.simulate_ou`.

    >>> p = cubic_sensor(2.0, 1.0)
    >>> p.model.kind, float(p.P0[0, 0])
    ('sde', 1.0)
    """
    V.positive("q", q)
    V.positive("r", r)
    V.positive("dt", dt)
    V.positive("steps", steps, integer=True)
    x = sp.Symbol("x")
    model = SDEModel([x], [-x], [x**3], Q=float(q), R=float(r), name="cubic-sensor")
    return Problem(model, np.zeros(1), np.array([[q / 2]]), None, dt, steps, "cubic-sensor")


def euler_discretization(model: SDEModel, dt: float) -> DiscreteModel:
    """The Euler–Maruyama discretization of an Itô :class:`~nlfilter.models.SDEModel` on the measurement grid, as a
    :class:`~nlfilter.models.DiscreteModel`: ``x[k+1] = x + f dt + G √dt w``, ``y_k = dy_k/dt = h(x_k) + v_k`` with
    ``w ~ (0, Q)``, ``v ~ (0, R/dt)``. Used to run discrete-only filters (the UKF) on SDE problems.

    >>> m = euler_discretization(state_noise().model, 0.01)
    >>> float(m.R[0, 0]) == 0.2 / 0.01
    True
    """
    if getattr(model, "kind", None) != "sde" or model.sym is None:
        raise TypeError(f"model: expected an SDEModel stated in SymPy, got {type(model).__name__}")
    V.positive("dt", dt)
    X = sp.Matrix(model.states)
    f = X + model.sym["f"] * dt
    G = model.sym["G"] * sp.sqrt(sp.Float(dt))
    return DiscreteModel(model.states, f, model.sym["h"], G=G, Q=model.Q, R=model.R / dt,
                         time=model.time, name=f"{model.name} (Euler, dt={dt})")


__all__ = ["Problem", "quadratic", "state_noise", "falling_body", "cubic_sensor", "euler_discretization"]
