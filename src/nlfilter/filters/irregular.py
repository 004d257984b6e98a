"""Continuous-discrete filters measured at irregular times ``t_1 < t_2 < ...`` (the filters of
:class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter`): ``flt.at_times(times)``, or
a filter built with ``dt=None`` run on a :class:`~nlfilter.simulation.Simulation` whose
:class:`~nlfilter.simulation.Timing` carries the times
(:func:`~nlfilter.simulate.simulate_continuous_discrete` with ``times=``).

Between the measurements at ``t_k`` and ``t_{k+1}`` the moment equations are integrated over
``t_{k+1} − t_k`` (``substeps`` steps of the scheme per interval, whatever its length), from the
prior at ``t0`` to ``t_1`` first (``start="predict"``, the default) or from ``t_1`` itself
(``start="update"``: the prior is the belief at ``t_1``). With equal intervals the numbers are
those of the filter built with that ``dt``."""

from __future__ import annotations

import copy

import numpy as np

from .. import _validate as V


def check_times(flt, times) -> np.ndarray:
    """``times`` checked (finite, strictly increasing, after ``t0`` with ``start="predict"``)."""
    t0 = flt.t0 if flt.start == "predict" else -np.inf
    return V.measurement_times("times", times, t0)


def at_times(flt, times):
    """A copy of ``flt`` that measures at ``times (T,)`` (module docstring)."""
    times = check_times(flt, times)
    new = copy.copy(flt)
    new.times = times
    return new


def belief_time(flt, k: int) -> float:
    """The time of the belief of index ``k`` (the prediction from ``k`` runs to ``k + 1``):
    ``t0 + k dt`` on a regular grid; ``t0, t_1, t_2, ...`` (start "predict") or ``t_1, t_2, ...``
    (start "update") on given times."""
    if flt.times is None:
        if flt.dt is None:
            raise ValueError(f"dt: {type(flt).__name__} was built with dt=None, which takes the measurement times "
                             "of the data: run it on a Simulation (simulate_continuous_discrete), or use "
                             "at_times(times)")
        return flt.t0 + k * flt.dt
    i = k if flt.start == "update" else k - 1
    if i >= len(flt.times):
        raise ValueError(f"ys: more measurements than the {len(flt.times)} times of {type(flt).__name__}.at_times")
    return flt.t0 if i < 0 else float(flt.times[i])


def interval(flt, k: int) -> float:
    """The length of the prediction from belief ``k`` to ``k + 1``."""
    if flt.times is None:
        belief_time(flt, k)  # dt=None: the error naming dt
        return flt.dt
    return belief_time(flt, k + 1) - belief_time(flt, k)


def check_length(flt, T: int) -> None:
    """Data of ``T`` steps for a filter with given times: as many times as measurements."""
    if flt.times is not None and T != len(flt.times):
        raise ValueError(f"ys: got {T} measurement step(s); {type(flt).__name__} measures at {len(flt.times)} "
                         "given times (at_times); expected one measurement per time")


def for_times(flt, timing):
    """``flt`` for data of the Timing ``timing`` (continuous-discrete): the data's times when it has
    them (a filter built with ``dt`` is refused), the data's ``dt`` for a filter built with
    ``dt=None``; otherwise ``flt`` itself."""
    times = getattr(timing, "times", None)
    if times is not None:
        if flt.dt is not None:
            raise ValueError(f"dt: {type(flt).__name__} was built with dt={flt.dt!r}, but the Simulation's "
                             "measurement times are irregular; build it with dt=None to take them")
        if flt.times is not None and not np.array_equal(flt.times, times):
            raise ValueError(f"times: {type(flt).__name__} measures at other times than the Simulation's")
        return flt if flt.times is not None else at_times(flt, times)
    if flt.dt is None and flt.times is None and timing.dt is not None:
        new = copy.copy(flt)
        new.dt = float(timing.dt)
        return new
    return flt


__all__ = ["at_times", "belief_time", "interval", "check_length", "for_times"]
