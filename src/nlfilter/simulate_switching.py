"""Sample paths of a jump-Markov model (:class:`~nlfilter.switching.SwitchingModel`): the modes
drawn from its Markov chain, the states and measurements from each step's mode.

Each path draws from a stream of its own (:mod:`nlfilter.streams`, as :func:`~nlfilter.simulate.simulate`),
in this order: the initial state, then ``steps`` uniforms (``steps + 1`` with ``start="predict"``,
the first for the prior's mode) for the modes (the first from ``μ0``, then
each from its predecessor's row of ``Π``, by inversion of the cumulative probabilities), then for each
mode ``j`` in turn its process and measurement noises for every step (every mode's, whichever
mode is active: the draws of a path do not depend on its modes, so two switching models with the
same noise laws share their noises). ``paths=range(a, b)`` gives the rows ``a..b−1`` of the run
on all paths, bitwise.
"""

from __future__ import annotations

import numpy as np

from . import _validate as V
from .angles import angles_of, wrap_components
from .simulate import _Screen, _start
from .simulation import Simulation, Timing
from .switching import SwitchingModel

__all__ = ["SwitchingSimulation", "simulate_switching", "draw_modes"]


class SwitchingSimulation(Simulation):
    """A :class:`~nlfilter.simulation.Simulation` with the true modes ``modes (paths, T)`` (ints)."""

    def __new__(cls, xs, ys, x0, t, timing=None, modes=None):
        self = super().__new__(cls, xs, ys, x0, t, timing)
        self.__dict__["modes"] = modes
        return self

    def __reduce__(self):
        return SwitchingSimulation, (*self, self.timing, self.modes)


def draw_modes(u, transition, mode_probs0):
    """``(B, T)`` modes of Markov chains from uniforms ``u (B, T)``: ``r_0`` from ``mode_probs0``,
    ``r_k`` from row ``r_{k−1}`` of ``transition`` (inversion: the first ``j`` whose cumulative
    probability exceeds ``u``)."""
    M = len(mode_probs0)
    c0, cP = np.cumsum(mode_probs0), np.cumsum(transition, axis=1)
    r = np.empty(u.shape, dtype=np.intp)
    r[:, 0] = np.minimum((u[:, 0, None] >= c0).sum(-1), M - 1)
    for k in range(1, u.shape[1]):
        r[:, k] = np.minimum((u[:, k, None] >= cP[r[:, k - 1]]).sum(-1), M - 1)
    return r


def simulate_switching(model, steps: int, *, paths=1, rng=None, m0=None, P0=None, x0=None, start: str = "update",
                       on_divergence: str = "raise") -> SwitchingSimulation:
    """Paths of the jump-Markov ``model``: ``xs (P, T, n)``, ``ys (P, T, m)`` and the modes
    ``modes (P, T)`` (``modes[:, k]`` the mode of the step measured by ``ys[:, k]``: it drove the
    transition into ``xs[:, k]`` and measures it; module docstring for the draws).

    Parameters
    ----------
    model : SwitchingModel
    steps, paths, rng, m0, P0, x0, on_divergence : as :func:`~nlfilter.simulate.simulate`
    start : ``"update"`` (``ys[:, 0]`` measures the initial state, under the mode ``r_0 ~ μ0``) or
        ``"predict"`` (``μ0`` is the mode's law at the prior, one step before: ``r_0 ~ μ0 Π``, and
        the transition into ``xs[:, 0]`` is under ``r_0``; the IMM's and the particle filter's
        convention); additive Gaussian or non-additive
        process noise, additive measurement noise with a constant covariance per mode

    Examples
    --------
    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> x = sp.Symbol("x")
    >>> sw = SwitchingModel([DiscreteModel([x], [x], [x], Q=0.01, R=0.1), DiscreteModel([x], [x + 1], [x], Q=0.01, R=0.1)],
    ...                     [[0.9, 0.1], [0.1, 0.9]])
    >>> sim = simulate_switching(sw, 5, paths=3, rng=0, m0=[0.0], P0=[[1.0]])
    >>> sim.xs.shape, sim.modes.shape, set(sim.modes.ravel().tolist()) <= {0, 1}
    ((3, 5, 1), (3, 5), True)
    """
    if not isinstance(model, SwitchingModel):
        raise TypeError(f"model: expected a SwitchingModel, got {type(model).__name__}")
    V.choice("start", start, {"update", "predict"})
    offset = 1 if start == "predict" else 0
    for j, md in enumerate(model.models):
        if not getattr(md, "R_constant", True) or getattr(md, "cross_noise", None) is not None \
                or not getattr(md, "additive_measurement", True):
            raise ValueError(f"model: mode {j}: the switching simulator takes additive measurement noise of constant "
                             f"covariance without correlated process noise")
    first = model.models[0]
    rng, x, x_init, xs = _start(first, steps, paths, rng, m0, P0, x0, None, width=3 * first.m + first.r + 1)
    screen = _Screen(on_divergence, rng, "simulate_switching")
    u = rng.random((steps + offset,))
    noises = [rng.draw(lambda g, s, md=md: (md.process_noise.sample(g, s), md.measurement_noise.sample(g, s)), (steps,))
              for md in model.models]
    modes = draw_modes(u, model.transition, model.mode_probs0)[:, offset:]  # predict: μ0 is the prior's, one step before
    P = len(rng)
    ys = np.empty((P, steps, first.m))
    ang = angles_of(first)
    x = wrap_components(x, ang.states)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for k in range(steps):
            r = modes[:, k]
            if k > 0 or offset:
                j = k + offset - 1
                new = np.empty_like(x)
                for i, md in enumerate(model.models):
                    sel = r == i
                    if sel.any():
                        new[sel] = md.transition(x[sel], noises[i][0][sel, k], j)
                x = screen.check(k, wrap_components(new, ang.states), x=wrap_components(new, ang.states),
                                 restart=x_init)
            xs[:, k] = x
            y = np.empty((P, first.m))
            for i, md in enumerate(model.models):
                sel = r == i
                if sel.any():
                    y[sel] = md.h(x[sel], k + offset) + noises[i][1][sel, k]
            ys[:, k] = wrap_components(y, ang.measurements)
            screen.check(k, ys[:, k])
    screen.finish(xs, ys)
    return SwitchingSimulation(xs, ys, x_init, np.arange(steps) + offset, Timing("discrete", start, 0.0, None), modes)


