"""A model's parameter values and inputs: numbers, or arrays over time ``(T,)`` / per path
``(..., T)`` read at the step (:meth:`nlfilter.models.Model.with_params`), shared by every
generated function of one model.

>>> import numpy as np
>>> import sympy as sp
>>> a = sp.Symbol("a")
>>> v = Values({a: param_value("a", [0.5, 0.7, 0.9])}, (), None, 0.0)
>>> float(v.at(a, 2, ())), v.scalar([a])
(0.9, False)
"""

from __future__ import annotations

import numpy as np

from . import _validate as V


class Broadcast:
    """A constant array viewed over a batch shape, the last view kept (filters ask for the same
    batch at every step, and ``np.broadcast_to`` costs microseconds)."""

    def __init__(self, value: np.ndarray):
        self.value = value
        self._batch, self._view = None, None

    def __call__(self, batch: tuple) -> np.ndarray:
        if batch != self._batch:
            self._batch, self._view = batch, np.broadcast_to(self.value, (*batch, *self.value.shape))
        return self._view


class Values:
    """The parameter values of one model: ``{Symbol: float | array | None}`` and the grid that
    maps a time to an array entry (shared by every generated function of the model).

    A scalar is used as is. An array ``(T,)`` (shared by all paths) or ``(..., T)`` (one row per
    path) is read at entry ``k`` at step ``k`` (discrete models: the time argument *is* the
    integer step), or for SDE models piecewise constant on the grid ``t0 + i dt``:
    ``i = floor((t - t0) / dt + 1e-9)``, clipped to ``0..T-1``. ``None`` is an input that was
    declared and not given.
    """

    def __init__(self, values: dict, inputs: tuple, dt, t0):
        self.values, self.inputs, self.dt, self.t0 = values, inputs, dt, t0
        self.arrays = {p for p, v in values.items() if isinstance(v, np.ndarray)}
        self.per_path = {p for p in self.arrays if values[p].ndim > 1}
        self.unset = {p for p, v in values.items() if v is None}
        # scalars as NumPy floats: the generated code then follows NumPy's semantics (1/0 is inf,
        # with a RuntimeWarning, for the filters' divergence screening), not Python's ZeroDivisionError
        self._np = {p: np.float64(v) for p, v in values.items() if isinstance(v, float)}

    def scalar(self, syms) -> bool:
        return not any(p in self.arrays or p in self.unset for p in syms)

    def index(self, p, t, T: int) -> int:
        if self.dt is None:  # a discrete model: the step index itself
            k = float(t)
            if k != int(k) or k < 0 or k >= T:
                raise ValueError(f"{p}: its value is an array over {T} step(s); step k = {t!r} is outside "
                                 f"0..{T - 1} (give at least as many entries as steps)")
            return int(k)
        return min(max(int(np.floor((float(t) - self.t0) / self.dt + 1e-9)), 0), T - 1)

    def at(self, p, t, batch: tuple):
        v = self.values[p]
        if v is None:
            raise ValueError(f"inputs: the model declares input(s) {[str(u) for u in self.inputs]} and none "
                             "were given; evaluate model.with_inputs(u) with u of shape (..., T, p)")
        if p not in self.arrays:
            return self._np.get(p, v)
        k = self.index(p, t, v.shape[-1])
        if v.ndim == 1:
            return v[k]
        lead = v.shape[:-1]
        if tuple(batch[:len(lead)]) != lead:
            raise ValueError(f"{p}: a per-path parameter array of shape {v.shape} needs states whose leading "
                             f"axes are the paths {lead}, got a state batch {tuple(batch)}: per-path values "
                             "need a filter that evaluates per path (not a grid filter's points, nor "
                             "Filter.run(chunk=...)); give a (T,) array shared by all paths instead")
        return v[..., k].reshape(*lead, *(1,) * (len(batch) - len(lead)))


NO_VALUES = Values({}, (), None, 0.0)


def param_value(name, value):
    """A parameter value: a finite float, or a float array ``(T,)`` / ``(..., T)`` (read-only)."""
    if np.ndim(value) == 0:
        try:
            v = float(value)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{name}: expected a number or an array over time, got {type(value).__name__}") from exc
        V.finite(name, v)
        return v
    arr = V.as_float_array(name, value).copy()
    if arr.shape[-1] == 0:
        raise ValueError(f"{name}: expected an array over at least one step, got shape {arr.shape}")
    V.finite(name, arr)
    arr.setflags(write=False)
    return arr


def rows_of(model, paths: range):
    """The model for the paths ``paths`` (rows of every per-path parameter array, and of a
    per-path Q or R given per step), or the model itself (``Model._rows``)."""
    vals = getattr(model, "_values", NO_VALUES)
    steps = {nm: a for nm, a in getattr(model, "_steps", {}).items() if a.ndim == 4}
    if not vals.per_path and not steps:
        return model
    new = {}
    for p in vals.per_path:
        v = vals.values[p]
        if v.ndim != 2 or v.shape[0] < paths.stop:
            raise ValueError(f"{p}: a per-path array of shape {v.shape} for paths {paths!r}; expected "
                             f"(P, T) with P >= {paths.stop}")
        new[p] = v[paths.start:paths.stop]
    for nm, a in steps.items():
        if a.shape[0] < paths.stop:
            raise ValueError(f"{nm}: a per-path array of shape {a.shape} for paths {paths!r}; expected "
                             f"(P, T, d, d) with P >= {paths.stop}")
    return model.with_params(new, **{nm: a[paths.start:paths.stop] for nm, a in steps.items()})
