"""Assembling and caching the compiled loops: the one loop template (:mod:`.loops`) compiled with
the predict and update kernels of the rule's kind (:mod:`.rule_kernels`), and those with the
model's functions (:mod:`.kernels`), bound as globals; once per model and kind.

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

from . import loops, path_linalg, rule_kernels, step_kernels
from .kernels import KERNELS
from .support import jit

__all__ = ["FUNCTION_ARGS", "namespace", "inlined", "steps", "unused3"]

#: the functions a source takes first (bound as globals by :func:`steps`): the model's functions
#: of each kernel, the kernels of the template
FUNCTION_ARGS = {"steps_scalar_": ("f", "fx", "h", "hx", "G"), "steps_": ("predict", "update"),
                 "predict_taylor1_": ("f", "fx", "G"), "update_taylor1_": ("h", "hx"),
                 "predict_nodes_": ("f", "G"), "update_nodes_": ("h",),
                 "predict_taylor2_": ("f", "fx", "fxx"), "update_taylor2_": ("h", "hx", "hxx")}

_KERNEL_MODULES = (path_linalg, step_kernels)
_SOURCE = {f.__name__: inspect.getsource(f)  # read once, at import
           for f in (*path_linalg.SOURCES, *step_kernels.SOURCES, *loops.SOURCES.values(),
                     *(k for pair in rule_kernels.KERNELS_BY_KIND.values() for k in pair))}


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
    ns["jacobi"] = path_linalg.jacobi  # called: only where the Cholesky screens cannot decide (rare, long code)
    return ns


def _bind(name, fns, dims):
    """The source of ``name`` with its leading parameters that name entries of ``fns`` dropped (they
    are bound as globals) and, with ``dims = (n, m, r, N)``, the dimensions read from the arrays
    replaced by constants (``N`` None: read from the nodes). Returns ``(source, dropped names)``."""
    head, rest = _SOURCE[name].split("(", 1)
    params, body = rest.split("):\n", 1)
    plist = [x.strip() for x in params.replace("\n", " ").split(",") if x.strip()]
    drop = []
    while plist[len(drop)] in fns:
        drop.append(plist[len(drop)])
    if dims is not None:
        n, m, r, N = dims
        for old, new in (("    B, T, mdim = ys.shape\n", f"    B, T = ys.shape[0], ys.shape[1]\n    mdim = {m}\n"),
                         ("    n = m0.shape[1]\n", f"    n = {n}\n"), ("    r = Q.shape[0]\n", f"    r = {r}\n"),
                         ("    N = z.shape[0]\n", f"    N = {N}\n" if N is not None else "    N = z.shape[0]\n")):
            body = body.replace(old, new, 1)
    return head + "(" + ", ".join(plist[len(drop):]) + "):\n" + body, drop


def _compile(name, fns, dims, ns, **kw):
    """``name``'s source compiled in ``ns`` with ``fns`` bound as its globals (:func:`_bind`)."""
    src, drop = _bind(name, fns, dims)
    missing = [a for a in FUNCTION_ARGS.get(name, ()) if a not in drop]
    if missing:  # pragma: no cover - a guard on this package's own code
        raise RuntimeError(f"steps: {name} does not start with {missing}")
    ns.update({a: fns[a] for a in drop})
    exec(compile(src, f"<nlfilter.compiled {name}>", "exec"), ns)  # noqa: S102 - this package's code
    return jit(ns[name], _nrt=False, **kw)


def steps(kind: str, fns: dict, key, scalar: bool = False, dims=None):
    """The raw loop of rule ``kind``: the template (:func:`.loops.steps_`) with the kind's predict
    and update kernels (:mod:`.rule_kernels`) bound as globals, and in those the model's functions
    ``fns`` (``{"f", "fx", "h", "hx", "G"[, "fxx", "hxx"]}``; numba then calls them directly and can
    inline them; passed as arguments they would be first-class function pointers); ``scalar``: the
    scalar batch loop. Compiled once per model (``key``: its kernel store) and kind. ``dims``:
    ``(n, m, r, N)`` compiled in as constants (``N`` None: read from the nodes), with the helpers
    inlined (:data:`~nlfilter.filters.compiled.run.SPECIALIZE_UP_TO`); the kernels are always
    inlined into the template (one call site each)."""
    store = KERNELS[key]
    name = ("steps", kind, fns["fxx"] is unused3 if kind == "taylor2" else scalar, dims)
    if name not in store:
        ns = inlined() if dims is not None else namespace()
        if scalar:
            fns = {{"f_x": "fx", "h_x": "hx"}.get(w, w): fn for w, fn in fns.items()}  # scalar_kernels' names
            store[name] = _compile(loops.steps_scalar_.__name__, fns, dims, ns)
        else:
            predict, update = (f.__name__ for f in rule_kernels.KERNELS_BY_KIND[kind])
            ns["predict"] = _compile(predict, fns, dims, ns, inline="always")
            ns["update"] = _compile(update, fns, dims, ns, inline="always")
            store[name] = _compile(loops.steps_.__name__, {"predict": ns["predict"], "update": ns["update"]}, dims, ns)
    return store[name]


def unused3_(x, t, p, out):  # pragma: no cover - never called (first-order form)
    pass


#: the Hessian slots of a first-order Taylor-2 form: never called, a compiled no-op fills them
unused3 = jit(unused3_, _nrt=False)
