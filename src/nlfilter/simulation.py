"""The data a simulator returns: :class:`Simulation` (true states, measurements, initial states,
times) and its :class:`Timing` convention — where the measurements sit in time, which every filter
run on the Simulation reads (:meth:`nlfilter.filters.base.Filter.for_timing`). The simulators are
in :mod:`nlfilter.simulate`; this module sits below both them and the filters."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import _validate as V


class Timing(NamedTuple):
    """Where a :class:`Simulation`'s measurements sit in time: what a filter run on it must assume.

    ``kind``: ``"discrete"`` (a DiscreteModel's samples), ``"increments"`` (an SDE observed
    continuously: ``ys[..., k, :]`` is ``dy`` over ``[t0 + k dt, t0 + (k+1) dt]``) or
    ``"continuous-discrete"`` (an SDE observed at ``t_k``: ``y_k = h(x(t_k)) + v_k``);
    ``start``: ``"update"`` (``ys[..., 0, :]`` measures the state whose prior is ``(m0, P0)``, at
    ``t0``) or ``"predict"`` (it measures the state one step or ``dt`` after the prior), None for
    increments; ``t0``: the prior's time (0 for a discrete model); ``dt``: the measurement
    interval (None for a discrete model); ``substeps``: an SDE's data, the Euler–Maruyama steps
    per interval of :func:`~nlfilter.simulate.simulate` (increments) or of
    :func:`~nlfilter.simulate.simulate_continuous_discrete` (its default ``process="euler-maruyama"``;
    :mod:`nlfilter.sde_step`: the model a particle reference must share to have the simulator's),
    None when not made by them (a 4-field Timing, the exact-transition simulators, the flow). The filters read it (:meth:`nlfilter.filters.base.Filter.for_timing`;
    a ParticleFilter built without ``substeps`` takes these); ``times``: continuous-discrete only,
    the measurement times ``t_1 < t_2 < ...`` (a tuple) when irregular, ``dt`` then None
    (:mod:`nlfilter.filters.irregular`)."""

    kind: str
    start: str | None
    t0: float
    dt: float | None
    substeps: int | None = None
    times: tuple | None = None


def _check_timing(timing) -> None:
    """A :class:`Timing` whose fields agree with each other (named errors otherwise)."""
    if not isinstance(timing, Timing):
        raise TypeError(f"timing: expected a Timing or None, got {type(timing).__name__}")
    V.choice("timing.kind", timing.kind, {"discrete", "increments", "continuous-discrete"})
    if timing.kind == "increments":
        if timing.start is not None:
            raise ValueError(f"timing.start: increments have no step convention; expected None, got {timing.start!r}")
    else:
        V.choice("timing.start", timing.start, {"update", "predict"})
    V.real("timing.t0", timing.t0)
    if timing.times is not None:
        if timing.kind != "continuous-discrete" or timing.dt is not None:
            raise ValueError(f"timing.times: irregular times are for continuous-discrete measurements with dt=None; "
                             f"got kind {timing.kind!r}, dt={timing.dt!r}")
        V.measurement_times("timing.times", timing.times, timing.t0 if timing.start == "predict" else -np.inf)
    elif timing.kind == "discrete":
        if timing.dt is not None:
            raise ValueError(f"timing.dt: a discrete model has no time step; expected None, got {timing.dt!r}")
    else:
        V.positive("timing.dt", timing.dt)
    if timing.substeps is not None:
        if timing.kind == "discrete":
            raise ValueError(f"timing.substeps: only an SDE's measurements are made by Euler–Maruyama substeps; "
                             f"expected None for {timing.kind} measurements, got {timing.substeps!r}")
        V.positive("timing.substeps", timing.substeps, integer=True)


class _SimulationArrays(NamedTuple):
    xs: np.ndarray
    ys: np.ndarray
    x0: np.ndarray
    t: np.ndarray


class Simulation(_SimulationArrays):
    """``xs (paths, T, n)``, ``ys (paths, T, m)`` (increments ``dy`` for SDEs), ``x0 (paths, n)``,
    ``t (T,)`` the times (step indices for discrete models) of ``xs`` — a 4-tuple (``xs, ys, x0, t =
    sim``) — and ``timing``, the :class:`Timing` convention of its measurements (``None`` for
    one built by hand without it): ``Filter.run``/``smooth``, :func:`~nlfilter.evaluate.loglik` and
    :func:`~nlfilter.fitting.fit` take a Simulation in place of ``ys`` and read the step convention
    ``start``, ``t0`` and ``dt`` from it (a filter built with a conflicting one is refused).

    A path whose state or measurement became non-finite (``on_divergence="mark"`` of the
    simulators) has NaN ``xs`` and ``ys`` from that step on: :attr:`diverged` and
    :attr:`diverged_step` read them back."""

    def __new__(cls, xs, ys, x0, t, timing: Timing | None = None):
        self = super().__new__(cls, xs, ys, x0, t)
        if timing is not None:
            _check_timing(timing)
        self.__dict__["timing"] = timing
        return self

    timing: Timing | None = None  # a Simulation made by tuple methods (_make) has none

    def _replace(self, **kw):
        """A copy with some of ``xs, ys, x0, t`` replaced; the timing is kept."""
        return Simulation(*super()._replace(**kw), timing=self.timing)

    def __reduce__(self):
        return Simulation, (*self, self.timing)

    def __repr__(self):
        return f"{super().__repr__()[:-1]}, timing={self.timing!r})"

    @property
    def diverged(self) -> np.ndarray:
        """``(paths,)`` bool: the paths marked as diverged (NaN states)."""
        return np.isnan(self.xs).any(axis=(-2, -1))

    @property
    def diverged_step(self) -> np.ndarray:
        """``(paths,)`` int: the first step of a diverged path (NaN from it on), −1 elsewhere."""
        nan = np.isnan(self.xs).any(axis=-1)
        return np.where(nan.any(axis=-1), nan.argmax(axis=-1), -1)
