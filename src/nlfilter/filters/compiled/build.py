"""Assembling and caching the compiled loops: the loop of a rule kind (:mod:`.loops`) compiled with
the model's functions (:mod:`.kernels`) bound as globals, once per model and kind.

The loops are compiled from their source text in a namespace built here, explicitly, from the
kernels of :mod:`.path_linalg` and :mod:`.step_kernels` (:func:`namespace`); the specialized
loops (:data:`~nlfilter.filters.compiled.run.SPECIALIZE_UP_TO`) get the dimensions as constants
and every kernel compiled again ``inline="always"`` (:func:`inlined`). The sources are read once,
at import: later edits of the files cannot skew the compiled code.
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from . import loops, path_linalg, step_kernels
from .kernels import KERNELS
from .support import jit

__all__ = ["FUNCTION_ARGS", "namespace", "inlined", "steps", "unused3"]

#: the model's functions each loop takes first (bound as globals by :func:`steps`)
FUNCTION_ARGS = {"taylor1": ("f", "fx", "h", "hx", "G"), "nodes": ("f", "h", "G"),
                 "taylor2": ("f", "fx", "fxx", "h", "hx", "hxx")}

_KERNEL_MODULES = (path_linalg, step_kernels)
_SOURCE = {f.__name__: inspect.getsource(f)  # read once, at import
           for f in (*path_linalg.SOURCES, *step_kernels.SOURCES, *loops.SOURCES.values())}


def namespace() -> dict:
    """The globals the loops and kernels are compiled in: ``math``, ``np``, ``LOG_2PI`` and every
    compiled kernel of :mod:`.path_linalg` and :mod:`.step_kernels` by name."""
    ns = {"math": math, "np": np, "LOG_2PI": step_kernels.LOG_2PI}
    for mod in _KERNEL_MODULES:
        ns.update({f.__name__[:-1]: getattr(mod, f.__name__[:-1]) for f in mod.SOURCES})
    return ns


def inlined() -> dict:
    """:func:`namespace` with every kernel compiled ``inline="always"`` (calling each other inlined)."""
    ns = namespace()
    names = [f.__name__ for mod in _KERNEL_MODULES for f in mod.SOURCES]
    for h in names:
        exec(compile(_SOURCE[h], f"<nlfilter.compiled {h}>", "exec"), ns)  # noqa: S102 - this package's code
    for h in names:
        ns[h[:-1]] = jit(ns[h], _nrt=False, inline="always")
    return ns


def steps(kind: str, fns: dict, key, scalar: bool = False, dims=None):
    """The raw steps of ``kind`` with the model's functions bound as globals (numba then calls
    them directly and can inline them; passed as arguments they would be first-class function
    pointers), compiled once per model (``key``: its kernel store) and kind. ``dims``: ``(n, m,
    r, N)`` compiled in as constants (``N`` None: read from the nodes), with the helpers inlined
    (:data:`~nlfilter.filters.compiled.run.SPECIALIZE_UP_TO`)."""
    store = KERNELS[key]
    name = ("steps", kind, fns["fxx"] is unused3 if kind == "taylor2" else scalar, dims)
    if name not in store:
        py = loops.SOURCES["scalar" if scalar else kind].__name__
        src = _SOURCE[py]
        head, rest = src.split("(", 1)
        params, body = rest.split("):\n", 1)
        plist = [x.strip() for x in params.replace("\n", " ").split(",") if x.strip()]
        drop = FUNCTION_ARGS[kind]
        if tuple(plist[:len(drop)]) != drop:  # pragma: no cover - a guard on this package's own code
            raise RuntimeError(f"steps: {py} does not start with {drop}")
        if dims is not None:
            n, m, r, N = dims
            for old, new in (("    B, T, mdim = ys.shape\n", f"    B, T = ys.shape[0], ys.shape[1]\n    mdim = {m}\n"),
                             ("    n = m0.shape[1]\n", f"    n = {n}\n"), ("    r = Q.shape[0]\n", f"    r = {r}\n"),
                             ("    N = z.shape[0]\n", f"    N = {N}\n" if N is not None else "    N = z.shape[0]\n")):
                body = body.replace(old, new, 1)
        src = head + "(" + ", ".join(plist[len(drop):]) + "):\n" + body
        ns = inlined() if dims is not None else namespace()
        ns.update({a: fns[{"fx": "f_x", "hx": "h_x"}.get(a, a)] if scalar else fns[a] for a in drop})
        exec(compile(src, f"<nlfilter.compiled steps {kind}>", "exec"), ns)  # noqa: S102 - this package's code
        store[name] = jit(ns[py], _nrt=False)
    return store[name]


def unused3_(x, t, p, out):  # pragma: no cover - never called (first-order form)
    pass


#: the Hessian slots of a first-order Taylor-2 form: never called, a compiled no-op fills them
unused3 = jit(unused3_, _nrt=False)
