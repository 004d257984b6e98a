"""The model's functions as numba scalar code: f, h, G and their derivatives generated from the
model's SymPy expressions (``fn(x, t, p, out)`` for one path; ``fn(x, t, p) -> float`` for the
scalar batch loop), with common subexpressions computed once and float constants printed in full
double precision. Generated once per model and shared by its
:meth:`~nlfilter.models.Model.with_params` copies (:data:`KERNELS`); the loops bind them as
globals (:mod:`.build`).
"""

from __future__ import annotations

import math
import weakref

import numpy as np
import sympy as sp
from sympy.printing.pycode import PythonCodePrinter

from .support import jit

__all__ = ["KERNELS", "model_kernels", "scalar_kernels"]


class _ScalarPrinter(PythonCodePrinter):
    """Python scalar code (``math.sin``) with float constants in full double precision."""

    def _print_Float(self, expr):
        value = float(expr)
        return repr(value) if math.isfinite(value) else super()._print_Float(expr)


def _source(name, exprs, shape, states, time, psyms) -> str:
    """``def name(x, t, p, out)``: writes ``out[idx] = expr`` for every entry of ``exprs`` (flat,
    row-major over ``shape``), with common subexpressions computed once."""
    xs = {s: sp.Symbol(f"x_{i}") for i, s in enumerate(states)}
    ps = {s: sp.Symbol(f"p_{j}") for j, s in enumerate(psyms)}
    sub = {**xs, **ps}
    if time is not None:
        sub[time] = sp.Symbol("t_")
    flat = [sp.sympify(e).xreplace(sub) for e in exprs]
    pr = _ScalarPrinter({"fully_qualified_modules": True, "inline": True, "allow_unknown_functions": False})
    used = set().union(*(e.free_symbols for e in flat)) if flat else set()
    lines = [f"def {name}(x, t, p, out):"]
    lines += [f"    x_{i} = x[{i}]" for i, s in enumerate(states) if xs[s] in used]
    lines += [f"    p_{j} = p[{j}]" for j, s in enumerate(psyms) if ps[s] in used]
    if time is not None and sp.Symbol("t_") in used:
        lines.append("    t_ = t")
    nonzero = [(i, e) for i, e in enumerate(flat) if e != 0]
    if nonzero:
        reps, red = sp.cse([e for _, e in nonzero], symbols=sp.numbered_symbols("c_"))
        lines += [f"    {s} = {pr.doprint(v)}" for s, v in reps]
    else:
        red = []
    zeros = [i for i, e in enumerate(flat) if e == 0]
    if len(zeros) > 8:  # a sparse Hessian: one loop of zeros, then the nonzero entries (compact code)
        ix = [f"i{d}" for d in range(len(shape))]
        for d, (v, size) in enumerate(zip(ix, shape)):
            lines.append("    " + "    " * d + f"for {v} in range({size}):")
        lines.append("    " + "    " * len(shape) + f"out[{', '.join(ix)}] = 0.0")
    else:
        for i in zeros:
            lines.append(f"    out[{', '.join(map(str, np.unravel_index(i, shape)))}] = 0.0")
    for (i, _), e in zip(nonzero, red):
        lines.append(f"    out[{', '.join(map(str, np.unravel_index(i, shape)))}] = {pr.doprint(e)}")
    if len(lines) == 1:
        lines.append("    pass")
    return "\n".join(lines)


def _scalar_source(name, expr, state, time, psyms) -> str:
    """``def name(x_0, t, p)`` returning the one entry ``expr`` of a scalar model's function."""
    sub = {state: sp.Symbol("x_0"), **{s: sp.Symbol(f"p_{j}") for j, s in enumerate(psyms)}}
    if time is not None:
        sub[time] = sp.Symbol("t_")
    e = sp.sympify(expr).xreplace(sub)
    pr = _ScalarPrinter({"fully_qualified_modules": True, "inline": True, "allow_unknown_functions": False})
    lines = [f"def {name}(x_0, t, p):"]
    lines += [f"    p_{j} = p[{j}]" for j, s in enumerate(psyms) if sp.Symbol(f"p_{j}") in e.free_symbols]
    if time is not None and sp.Symbol("t_") in e.free_symbols:
        lines.append("    t_ = t")
    reps, (red,) = sp.cse([e], symbols=sp.numbered_symbols("c_"))
    lines += [f"    {c} = {pr.doprint(v)}" for c, v in reps]
    lines.append(f"    return float({pr.doprint(red)})")
    return "\n".join(lines)


def scalar_kernels(model) -> dict:
    """``{"f", "f_x", "h", "h_x", "G"}`` of a model with one state, one measurement and one noise
    as numba functions ``fn(x, t, p) -> float`` (the scalar batch loop's)."""
    from ...models import _jacobian
    key = model._kernels["f"]
    store = KERNELS.setdefault(key, {})
    if "scalar" not in store:
        ex = model.expressions
        (x,), time, psyms = model.states, model.time, model._psyms
        exprs = {"f": ex["f"][0], "f_x": _jacobian(ex["f"], [x])[0, 0], "h": ex["h"][0],
                 "h_x": _jacobian(ex["h"], [x])[0, 0], "G": ex["G"][0, 0]}
        out = {}
        for w, e in exprs.items():
            name = "s_" + w.replace("_", "")
            ns = {"math": math}
            exec(compile(_scalar_source(name, e, x, time, psyms), f"<nlfilter.compiled scalar {w}>", "exec"), ns)  # noqa: S102
            out[w] = jit(ns[name], _nrt=False, inline="always")
        store["scalar"] = out
    return store["scalar"]


KERNELS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def model_kernels(model, *, second: bool = False) -> dict:
    """``{"f", "f_x", "h", "h_x", "G"[, "f_xx", "h_xx"]}``: the model's functions compiled by numba
    as ``fn(x (n,), t, p, out)`` writing ``out`` (shape as the model's function, one path), the
    parameters read from ``p`` in the order of the model's parameter symbols. Generated once per
    model (shared by its :meth:`~nlfilter.models.Model.with_params` copies); ``second`` adds the
    Hessians (the Taylor-2 rule)."""
    from ...models import _first, _jacobian  # the model's own differentiation (the same entries)
    key = model._kernels["f"]  # shared by every with_params copy
    store = KERNELS.setdefault(key, {})
    want = ("f", "f_x", "h", "h_x", "G") + (("f_xx", "h_xx") if second else ())
    missing = [w for w in want if w not in store]
    if missing:
        ex = model.expressions
        states, time, psyms = model.states, model.time, model._psyms
        n, m, r = model.n, model.m, model.r
        fM, hM, GM = ex["f"], ex["h"], ex["G"]
        if "_fx" not in store:
            store["_fx"], store["_hx"] = _jacobian(fM, states), _jacobian(hM, states)
        fx, hx = store["_fx"], store["_hx"]
        specs = {"f": (list(fM), (n,)), "f_x": (list(fx), (n, n)), "h": (list(hM), (m,)),
                 "h_x": (list(hx), (m, n)), "G": (list(GM), (n, r))}
        if second:
            specs["f_xx"] = (_first(list(fx), states), (n, n, n))
            specs["h_xx"] = (_first(list(hx), states), (m, n, n))
        for w in missing:
            exprs, shape = specs[w]
            name = "g_" + w.replace("_", "")
            src = _source(name, exprs, shape, states, time, psyms)
            ns = {"math": math}
            exec(compile(src, f"<nlfilter.compiled {w}>", "exec"), ns)  # noqa: S102 - code we generated
            # scalar code: no reference counting; small functions inlined into the loops (a
            # Hessian of 16 states, 4096 entries, inlined took 18 minutes to compile)
            store[w] = jit(ns[name], _nrt=False, inline="always" if len(exprs) <= 64 else "never")
            store["src_" + w] = src
    return {w: store[w] for w in want}


# ---------------------------------------------------------------------------------------------
