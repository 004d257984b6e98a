"""A filter's timing convention and the data's (:class:`~nlfilter.simulation.Timing`): ``start``
and ``t0`` as built (``set_start``, ``set_t0``: stated or the default), and :func:`for_timing`,
which adapts a filter built without them to a Simulation's and refuses a conflicting one naming
both."""

from __future__ import annotations

import copy
import math

from .. import _validate as V


def set_start(flt, start) -> None:
    """``flt.start``: ``start`` checked, or the class's default when None; ``flt.start_stated``
    records which (a filter built without ``start`` takes a Simulation's, :meth:`~nlfilter.filters.base.Filter.for_timing`)."""
    flt.start_stated = start is not None
    flt.start = type(flt).start if start is None else V.choice("start", start, {"update", "predict"})


def set_t0(flt, t0) -> None:
    """``flt.t0`` of a continuous-discrete filter: ``t0`` checked, or 0.0 when None (``t0_stated``)."""
    flt.t0_stated = t0 is not None
    flt.t0 = 0.0 if t0 is None else V.real("t0", t0)


def same_dt(flt, timing) -> None:
    """Refuse data measured every ``timing.dt`` for a filter built with another ``dt``."""
    dt = getattr(flt, "dt", None)
    if dt is not None and timing.dt is not None and not math.isclose(dt, timing.dt, rel_tol=1e-12):
        raise ValueError(f"dt: {type(flt).__name__} was built with dt={dt!r}, but the Simulation's measurement "
                         f"step is dt={timing.dt!r}")


def for_timing(flt, timing, *, t0=None):
    """:meth:`Filter.for_timing <nlfilter.filters.base.Filter.for_timing>` of ``flt``: ``(filter,
    t0)`` for data of the convention ``timing`` (None: no check) and ``run``'s ``t0``."""
    name = type(flt).__name__
    if timing is None:
        return flt, t0
    kind = timing.kind
    if flt.time == "continuous":
        if kind != "increments":
            raise ValueError(f"ys: the Simulation holds {kind} measurements; {name} reads the increments dy "
                             "of a continuously observed SDE (simulate(sde_model, ..., dt=...))")
        same_dt(flt, timing)
        if t0 is None:
            return flt, timing.t0
        if V.real("t0", t0) != timing.t0:
            raise ValueError(f"t0: run was given t0={t0!r}, but the Simulation's prior is at t0={timing.t0!r}; "
                             "leave t0 unset to take the data's")
        return flt, t0
    cd = getattr(getattr(flt, "model", None), "kind", None) == "sde"
    if kind == "increments" or (kind == "continuous-discrete") != cd:
        reads = "an SDE measured at discrete times" if cd else "a discrete model's measurements"
        raise ValueError(f"ys: the Simulation holds {kind} measurements; {name} reads {reads}")
    changes = {}
    if timing.start != flt.start:
        if getattr(flt, "start_stated", True):
            where = {"update": "at the prior's time", "predict": "one step after the prior"}[timing.start]
            raise ValueError(f"start: {name} was built with start={flt.start!r}, but the Simulation's first "
                             f"measurement is {where} (start={timing.start!r}); build it with "
                             f"start={timing.start!r}, or without start to take the data's")
        changes["start"] = timing.start
    if cd:
        from .irregular import for_times
        flt = for_times(flt, timing)  # the data's times, or its dt for a filter built with dt=None
        same_dt(flt, timing)
        if getattr(flt, "t0", timing.t0) != timing.t0:
            if getattr(flt, "t0_stated", True):
                raise ValueError(f"t0: {name} was built with t0={flt.t0!r}, but the Simulation's prior is at "
                                 f"t0={timing.t0!r}; build it with that t0, or without t0 to take the data's")
            changes["t0"] = timing.t0
    if not changes:
        return flt, t0
    flt = copy.copy(flt)  # (a copy already when for_times made one: copying again is harmless)
    flt.__dict__.update(changes)
    return flt, t0
