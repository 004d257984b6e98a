"""SymPy to code, written once: NumPy array code for the models' batched functions and the moment
engine, and scalar Python code (``math``) for the compiled loop's numba kernels.

The one float policy of every printer here (:class:`FullPrecisionPrinter`, :class:`ArrayPrinter`,
:class:`ScalarPrinter`): a finite float constant is written as ``repr(float(c))``, the shortest
text that reads back to the same double (up to 17 significant digits; SymPy's own printers write
15, so ``0.1 + 2**-50`` would become ``0.100000000000001``); a non-finite one as SymPy writes it.

>>> import sympy as sp
>>> x = sp.Symbol("x")
>>> c = sp.Float(0.1 + 2**-50)
>>> float_text(0.1 + 2**-50), ArrayPrinter().doprint(c * x**3), ScalarPrinter().doprint(sp.sin(c * x))
('0.1000000000000009', '0.1000000000000009*(x*x*x)', 'math.sin(0.1000000000000009*x)')

Three source generators give the compiled loop its kernels: :func:`array_source`
(``def name(x, t, p, out)`` writing every entry of an array, common subexpressions once, the zeros
of a sparse array in one loop), :func:`trace_source` (``def name(x, t, p, P, out)``: the contraction
``Σ_jl P_jl A_ijl`` of a Hessian over its entries not identically 0) and :func:`scalar_source`
(``def name(x_0, t, p) -> float``, a model with one state). The derivatives every generator is fed (:func:`jacobian`,
:func:`first_derivatives`) are those of ``sp.diff``, entry by entry, computed over the terms of a
sum that contain the variable only.

This module imports NumPy, SciPy and SymPy only: the models, the moment engine and the compiled
loop all stand above it.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.special
import sympy as sp
from sympy.printing.numpy import NumPyPrinter
from sympy.printing.precedence import precedence
from sympy.printing.pycode import PythonCodePrinter

__all__ = ["float_text", "FullPrecisionPrinter", "ArrayPrinter", "ScalarPrinter", "lambdify_numpy",
           "lambdify_arrays", "array_source", "trace_source", "scalar_source", "jacobian", "first_derivatives",
           "gradients", "is_affine", "nothing_to_share", "SCIPY_FUNCTIONS"]

SCIPY_FUNCTIONS = {"_erf": scipy.special.erf, "_erfc": scipy.special.erfc}
"""The names :class:`ArrayPrinter` writes for ``erf``/``erfc`` (SciPy's ufuncs: NumPy has none,
``math.erf`` takes no arrays), the namespace of :func:`lambdify_arrays`."""

_NUMPY_SETTINGS = {"fully_qualified_modules": False, "inline": True, "allow_unknown_functions": True}
_SCALAR_SETTINGS = {"fully_qualified_modules": True, "inline": True, "allow_unknown_functions": False}


def float_text(value: float) -> str | None:
    """The float policy: ``repr(value)`` for a finite double, ``None`` (the printer's own text)
    otherwise."""
    value = float(value)
    return repr(value) if math.isfinite(value) else None


class _FullPrecision:
    """Float constants by :func:`float_text` (mixed into every printer of the module)."""

    def _print_Float(self, expr):
        text = float_text(expr)
        return text if text is not None else super()._print_Float(expr)


class FullPrecisionPrinter(_FullPrecision, NumPyPrinter):
    """NumPy code whose float constants carry full double precision (the module's float policy)."""

    def __init__(self, settings=None):
        super().__init__(dict(_NUMPY_SETTINGS, **(settings or {})))


class ArrayPrinter(FullPrecisionPrinter):
    """NumPy code for batched arrays: small integer powers written as products (``x*x*x`` is several
    times faster than ``x**3`` on arrays), ``erf``/``erfc`` as SciPy's ufuncs
    (:data:`SCIPY_FUNCTIONS`), float constants in full precision."""

    def _print_Pow(self, expr, rational=False):
        if expr.exp.is_Integer and 2 <= int(expr.exp) <= 4:
            base = self.parenthesize(expr.base, precedence(expr))
            return "(" + "*".join([base] * int(expr.exp)) + ")"  # parenthesized: a product, not a power
        return super()._print_Pow(expr, rational=rational)

    def _print_Mul(self, expr):
        # c*s (a finite float times a symbol, the terms of a linear model): the text NumPyPrinter
        # writes, without its general factor ordering (a third of a dense linear model's build)
        if len(expr.args) == 2:
            c, s = expr.args
            if c.is_Float and s.is_Symbol and np.isfinite(float(c)):
                v = float(c)
                return ("-" if v < 0 else "") + float_text(abs(v)) + "*" + self._print(s)
        return super()._print_Mul(expr)

    def _print_erf(self, expr):
        return f"_erf({self._print(expr.args[0])})"

    def _print_erfc(self, expr):
        return f"_erfc({self._print(expr.args[0])})"


class ScalarPrinter(_FullPrecision, PythonCodePrinter):
    """Python scalar code (``math.sin``), float constants in full precision: the compiled loop's
    kernels (numba compiles ``math``)."""

    def __init__(self, settings=None):
        super().__init__(dict(_SCALAR_SETTINGS, **(settings or {})))


def lambdify_numpy(args, exprs, **kw):
    """``sympy.lambdify`` to NumPy with :class:`FullPrecisionPrinter` (``kw`` such as ``cse=True``
    pass through)."""
    return sp.lambdify(args, exprs, modules="numpy", printer=FullPrecisionPrinter(), **kw)


def lambdify_arrays(args, exprs):
    """``sympy.lambdify`` of the list ``exprs`` with :class:`ArrayPrinter` (a model's batched
    functions), common subexpressions eliminated unless :func:`nothing_to_share` says there are none."""
    return sp.lambdify(args, exprs, modules=[SCIPY_FUNCTIONS, "numpy"], cse=not nothing_to_share(exprs),
                       printer=ArrayPrinter())


def nothing_to_share(exprs) -> bool:
    """Whether common-subexpression elimination can find nothing in ``exprs`` (then ``lambdify``
    without it writes the same code, without its cost: seconds for a dense 42-state linear model).

    Decided for sums of terms ``c*s``, ``s`` and ``c`` (``c`` a number, ``s`` a symbol) only: no
    term, up to its sign, may occur twice in the whole list (so no subexpression repeats and no two
    sums, nor their negations, share two terms); anything else answers ``False`` (use CSE)."""
    seen = set()
    for e in exprs:
        for a in (e.args if e.is_Add else (e,)):
            if a.is_Mul:
                if len(a.args) != 2 or not (a.args[0].is_Number and a.args[1].is_Symbol):
                    return False
                key = (abs(a.args[0]), a.args[1])
            elif a.is_Symbol:
                key = (sp.S.One, a)
            elif a.is_Number:
                key = (abs(a), None)
            else:
                return False
            if key in seen:
                return False
            seen.add(key)
    return True


# ---------------------------------------------------------------------------------------------
# scalar source for the compiled loop
# ---------------------------------------------------------------------------------------------
def _renamed(exprs, states, time, psyms) -> tuple:
    """``(xs, ps, flat, used)``: the states and parameters renamed ``x_i``, ``p_j`` (the time ``t_``)
    in ``exprs``, as the generated functions read them, and the names the expressions use."""
    xs = {s: sp.Symbol(f"x_{i}") for i, s in enumerate(states)}
    ps = {s: sp.Symbol(f"p_{j}") for j, s in enumerate(psyms)}
    sub = {**xs, **ps}
    if time is not None:
        sub[time] = sp.Symbol("t_")
    flat = [sp.sympify(e).xreplace(sub) for e in exprs]
    return xs, ps, flat, set().union(*(e.free_symbols for e in flat)) if flat else set()


def array_source(name, exprs, shape, states, time, psyms, block: bool = False, zeros: bool = True) -> str:
    """``def name(x, t, p, out)``: writes ``out[idx] = expr`` for every entry of ``exprs`` (flat,
    row-major over ``shape``), with common subexpressions computed once; the states are read from
    ``x``, the parameters ``psyms`` from ``p`` in their order, ``time`` (or ``None``) is ``t``.
    ``block``: the same function over a block of paths, ``def name(x, t, p, out, nb)`` with the
    paths last (``x (n, ≥nb)``, ``out (*shape, ≥nb)``), the code of one path in a loop over the
    first ``nb`` (the batch-inner loop's, ``nlfilter.filters.compiled.batch_loop``). ``zeros=False``:
    the entries that are identically 0 are not written (the caller's ``out`` holds zeros there).

    >>> import sympy as sp
    >>> x, a = sp.symbols("x a")
    >>> print(array_source("g", [a * sp.sin(x), 0], (2,), [x], None, [a]))
    def g(x, t, p, out):
        x_0 = x[0]
        p_0 = p[0]
        out[1] = 0.0
        out[0] = p_0*math.sin(x_0)
    >>> print(array_source("g", [a * sp.sin(x), 0], (2,), [x], None, [a], block=True))
    def g(x, t, p, out, nb):
        p_0 = p[0]
        for b_ in range(nb):
            x_0 = x[0, b_]
            out[1, b_] = 0.0
            out[0, b_] = p_0*math.sin(x_0)
    """
    xs, ps, flat, used = _renamed(exprs, states, time, psyms)
    pr = ScalarPrinter()
    ind, lane = ("        ", ", b_") if block else ("    ", "")
    xlines = [f"{ind}x_{i} = x[{i}{lane}]" for i, s in enumerate(states) if xs[s] in used]
    plines = [f"    p_{j} = p[{j}]" for j, s in enumerate(psyms) if ps[s] in used]
    if time is not None and sp.Symbol("t_") in used:
        plines.append("    t_ = t")
    if block:
        lines = [f"def {name}(x, t, p, out, nb):", *plines, "    for b_ in range(nb):", *xlines]
    else:
        lines = [f"def {name}(x, t, p, out):", *xlines, *plines]
    body = len(lines)
    nonzero = [(i, e) for i, e in enumerate(flat) if e != 0]
    if nonzero:
        reps, red = sp.cse([e for _, e in nonzero], symbols=sp.numbered_symbols("c_"))
        lines += [f"{ind}{s} = {pr.doprint(v)}" for s, v in reps]
    else:
        red = []
    zeros = [i for i, e in enumerate(flat) if e == 0] if zeros else []
    if len(zeros) > 8:  # a sparse Hessian: one loop of zeros, then the nonzero entries (compact code)
        ix = [f"i{d}" for d in range(len(shape))]
        for d, (v, size) in enumerate(zip(ix, shape)):
            lines.append(ind + "    " * d + f"for {v} in range({size}):")
        lines.append(ind + "    " * len(shape) + f"out[{', '.join(ix)}{lane}] = 0.0")
    else:
        for i in zeros:
            lines.append(f"{ind}out[{', '.join(map(str, np.unravel_index(i, shape)))}{lane}] = 0.0")
    for (i, _), e in zip(nonzero, red):
        lines.append(f"{ind}out[{', '.join(map(str, np.unravel_index(i, shape)))}{lane}] = {pr.doprint(e)}")
    if len(lines) == body:
        lines.append(f"{ind}pass")
    return "\n".join(lines)


def trace_source(name, exprs, shape, states, time, psyms) -> str:
    """``def name(x, t, p, P, out)``: ``out[i] = Σ_jl P[j, l] A[i, j, l]`` for the Hessians ``A``
    of ``exprs`` (flat, row-major over ``shape = (pdim, n, n)``), summed from 0.0 over the entries
    not identically 0 in row-major order, each entry's value that of :func:`array_source` (the same
    substitutions and common subexpressions). The dense sum of every entry in that order gives the
    same numbers for finite ``P``: a skipped term is ``±0.0``, which leaves a sum started at +0.0
    unchanged to the last bit.

    >>> import sympy as sp
    >>> x, y = sp.symbols("x y")
    >>> print(trace_source("tr", [0, sp.cos(y), sp.cos(y), 0, 0, 0, 0, 2], (2, 2, 2), [x, y], None, []))
    def tr(x, t, p, P, out):
        x_1 = x[1]
        c_0 = math.cos(x_1)
        s = 0.0
        s += P[0, 1]*(c_0)
        s += P[1, 0]*(c_0)
        out[0] = s
        s = 0.0
        s += P[1, 1]*(2)
        out[1] = s
    """
    xs, ps, flat, used = _renamed(exprs, states, time, psyms)
    pr = ScalarPrinter()
    lines = [f"def {name}(x, t, p, P, out):"]
    lines += [f"    x_{i} = x[{i}]" for i, s in enumerate(states) if xs[s] in used]
    lines += [f"    p_{j} = p[{j}]" for j, s in enumerate(psyms) if ps[s] in used]
    if time is not None and sp.Symbol("t_") in used:
        lines.append("    t_ = t")
    nonzero = [(i, e) for i, e in enumerate(flat) if e != 0]
    red = []
    if nonzero:  # (the common subexpressions of array_source: the same list, the same cse)
        reps, red = sp.cse([e for _, e in nonzero], symbols=sp.numbered_symbols("c_"))
        lines += [f"    {s} = {pr.doprint(v)}" for s, v in reps]
    terms = {}
    for (i, _), e in zip(nonzero, red):
        a, j, q = np.unravel_index(i, shape)
        terms.setdefault(int(a), []).append(f"    s += P[{j}, {q}]*({pr.doprint(e)})")
    for a in range(shape[0]):
        if a in terms:
            lines += ["    s = 0.0", *terms[a], f"    out[{a}] = s"]
        else:
            lines.append(f"    out[{a}] = 0.0")
    return "\n".join(lines)


def scalar_source(name, expr, state, time, psyms) -> str:
    """``def name(x_0, t, p)`` returning the one entry ``expr`` of a scalar model's function.

    >>> import sympy as sp
    >>> x = sp.Symbol("x")
    >>> print(scalar_source("s", sp.exp(-x) + x**2, x, None, []))
    def s(x_0, t, p):
        return float(x_0**2 + math.exp(-x_0))
    """
    sub = {state: sp.Symbol("x_0"), **{s: sp.Symbol(f"p_{j}") for j, s in enumerate(psyms)}}
    if time is not None:
        sub[time] = sp.Symbol("t_")
    e = sp.sympify(expr).xreplace(sub)
    pr = ScalarPrinter()
    lines = [f"def {name}(x_0, t, p):"]
    lines += [f"    p_{j} = p[{j}]" for j, s in enumerate(psyms) if sp.Symbol(f"p_{j}") in e.free_symbols]
    if time is not None and sp.Symbol("t_") in e.free_symbols:
        lines.append("    t_ = t")
    reps, (red,) = sp.cse([e], symbols=sp.numbered_symbols("c_"))
    lines += [f"    {c} = {pr.doprint(v)}" for c, v in reps]
    lines.append(f"    return float({pr.doprint(red)})")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# derivatives fed to the generators
# ---------------------------------------------------------------------------------------------
def _d(e, s):
    """``∂e/∂s`` as ``sp.diff`` gives it (the same expression), a sum differentiated term by term
    over the terms that contain ``s`` only (``Add._eval_derivative`` differentiates every term: the
    n³ cost of a dense n-state Jacobian)."""
    if e.is_Add:
        return e.func(*[_d(a, s) for a in e.args if s in a.free_symbols])
    if e is s:
        return sp.S.One
    if e.is_Mul and len(e.args) == 2 and e.args[1] is s and e.args[0].is_Number:  # c*s: c, as Mul's rule gives
        return e.args[0]
    return e.diff(s)


def gradients(exprs, states) -> list:
    """``[[∂e/∂s for s in states] for e in exprs]``, each entry the expression ``sp.diff`` gives; a
    sum is differentiated over the terms that contain ``s`` (in the sum's order), an entry free of
    ``s`` is zero."""
    rows = []
    for e in exprs:
        if e.is_Add:
            terms = {}
            for a in e.args:
                for s in a.free_symbols:
                    terms.setdefault(s, []).append(a)
            rows.append([e.func(*[_d(a, s) for a in terms[s]]) if s in terms else sp.S.Zero for s in states])
        else:
            fs = e.free_symbols
            rows.append([_d(e, s) if s in fs else sp.S.Zero for s in states])
    return rows


def jacobian(M, states) -> sp.Matrix:
    """``M.jacobian(states)`` (the same entries).

    >>> import sympy as sp
    >>> x, y = sp.symbols("x y")
    >>> jacobian(sp.Matrix([x * y, 2 * x + y**2]), [x, y])
    Matrix([
    [y,   x],
    [2, 2*y]])
    """
    rows = gradients(M, states)
    return sp.Matrix(len(rows), len(states), [d for row in rows for d in row]) if rows else sp.zeros(0, len(states))


def first_derivatives(M, states) -> list:
    """``[∂e/∂s for e in M for s in states]`` (row-major over ``M``, the states last): G's
    derivatives ``[i, a, j]``, and from first derivatives ``[..., j]`` the Hessian entries
    ``[..., j, k]`` (the same ``sp.diff`` per entry as nested loops)."""
    return [d for row in gradients(list(M), states) for d in row]


def is_affine(e, grad, states) -> bool:
    """Whether ``e`` is a polynomial of total degree ≤ 1 in ``states`` (``grad`` its gradient): a
    polynomial whose gradient is free of the states is affine; otherwise SymPy's ``Poly`` decides."""
    if not e.is_polynomial(*states):
        return False
    ss = frozenset(states)
    if all(g.free_symbols.isdisjoint(ss) for g in grad):
        return True
    return sp.Poly(e, *states).total_degree() <= 1
