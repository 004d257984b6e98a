"""The deterministic integrator of every moment equation, flow and RK4 drift step in nlfilter:
:func:`ode_step` (Euler or classical RK4 over one interval in substeps), below both the
simulators and the filters."""

from __future__ import annotations


def ode_step(rhs, x, t: float, dt: float, *, substeps: int = 1, scheme: str = "rk4", finish=None):
    """Integrate ``dx/dt = rhs(x, t)`` over ``[t, t + dt]`` in ``substeps`` steps: ``"euler"``
    (order 1) or classical ``"rk4"`` (order 4). ``x`` is an array or a tuple of arrays (``rhs``
    returns the same structure); ``finish(x)`` is applied after every substep (e.g. symmetrize)."""
    h = dt / substeps
    tup = isinstance(x, tuple)
    add = (lambda a, b, c: tuple(ai + c * bi for ai, bi in zip(a, b))) if tup else (lambda a, b, c: a + c * b)
    for j in range(substeps):
        s = t + j * h
        if scheme == "euler":
            x = add(x, rhs(x, s), h)
        else:
            k1 = rhs(x, s)
            k2 = rhs(add(x, k1, 0.5 * h), s + 0.5 * h)
            k3 = rhs(add(x, k2, 0.5 * h), s + 0.5 * h)
            k4 = rhs(add(x, k3, h), s + h)
            if tup:
                x = tuple(xi + h / 6 * (a + 2 * b + 2 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4))
            else:
                x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if finish is not None:
            x = finish(x)
    return x
