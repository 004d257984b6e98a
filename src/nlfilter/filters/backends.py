"""The run backends by name, in one plain dict (as the filter registry): ``run(..., backend=NAME)``.

Each entry names, as ``"module:attribute"`` strings imported on first use, the backend's run
function and its ``unsupported(flt) -> reason or None`` (None for a backend that runs every
filter). ``"numpy"`` is the loop of :meth:`~nlfilter.filters.base.Filter.run` (the reference);
``"numba"`` the compiled loop (``nlfilter.filters.compiled``, which imports numba: seconds, so
only when asked for). Named by strings, the backends import nothing here: the compiled loop never
needs :mod:`~nlfilter.filters.base`, and ``base`` never imports the compiled loop.
"""

from __future__ import annotations

from importlib import import_module
from typing import NamedTuple

__all__ = ["Backend", "BACKENDS", "AUTO", "load", "refusal"]


class Backend(NamedTuple):
    """``run``: ``"module:function"`` running ``(flt, yf (B, T, m), batch, m0, P0, on_divergence,
    loglik, progress) -> Estimates`` (the NumPy loop: the method ``Filter._loop``); ``unsupported``:
    ``"module:function"`` of ``flt -> reason or None``, or None."""

    run: str
    unsupported: str | None


BACKENDS = {
    "numpy": Backend("nlfilter.filters.base:Filter._loop", None),
    "numba": Backend("nlfilter.filters.compiled:run_compiled", "nlfilter.filters.compiled:unsupported"),
    "numba-shared": Backend("nlfilter.filters.compiled.run:run_shared", "nlfilter.filters.compiled:unsupported"),
}

#: ``backend="auto"``: ``"module:function"`` of ``(flt, B, T, repeats) -> (backend, why)``
AUTO = "nlfilter.filters.compiled.choice:choose"


def load(path: str):
    """The object named ``"module:attribute.attribute"``, imported."""
    module, _, attr = path.partition(":")
    obj = import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def refusal(name: str, flt) -> str | None:
    """Why backend ``name`` cannot run ``flt`` (its ``unsupported``), or None."""
    check = BACKENDS[name].unsupported
    return None if check is None else load(check)(flt)
