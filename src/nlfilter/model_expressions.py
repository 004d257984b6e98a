"""What a model's expressions may be, checked once: symbols, vectors and matrices, the supported
functions (:data:`SUPPORTED_FUNCTIONS`) and the code-generation forms of the piecewise-smooth ones
with their derivative convention (:mod:`nlfilter.models`, "Functions").

>>> import sympy as sp
>>> x = sp.Symbol("x")
>>> e = code_form(sp.Abs(x) + sp.Max(x, 1))
>>> sp.diff(e, x).subs(x, 2.0), sp.diff(e, x).subs(x, -2.0)
(2, -1)
"""

from __future__ import annotations

import numpy as np
import sympy as sp
from sympy.core.function import AppliedUndef

class _PiecewiseFn(sp.Function):
    """A piecewise-smooth function in the generated code, with the derivative convention of
    :mod:`nlfilter.models` ("Functions"): derivatives taken almost everywhere (``fdiff``; zero, that of a
    step function, unless a subclass says otherwise), printed as the NumPy ufunc ``ufunc``. Used
    only for code generation (:func:`code_form`); the model's own expressions keep SymPy's
    ``Abs``, ``sign``, ..."""

    ufunc = ""

    @classmethod
    def eval(cls, *args):
        if all(a.is_Number for a in args):  # numbers: SymPy's own function evaluates them
            return cls.sympy(*args)

    def fdiff(self, argindex=1):
        return sp.S.Zero

    def _numpycode(self, printer):
        return f"{self.ufunc}({', '.join(printer._print(a) for a in self.args)})"


def _piecewise_fn(name, nargs, ufunc, sympy_fn, base=_PiecewiseFn, **attrs):
    return type(name, (base,), {"nargs": nargs, "ufunc": ufunc, "sympy": sympy_fn, **attrs})


_Sign = _piecewise_fn("_Sign", 1, "sign", sp.sign)
_Floor = _piecewise_fn("_Floor", 1, "floor", sp.floor)
_Ceiling = _piecewise_fn("_Ceiling", 1, "ceil", sp.ceiling)
_Step = _piecewise_fn("_Step", 2, "heaviside", sp.Heaviside)  # Heaviside(u, H0): H0 at u = 0


class _Abs(_PiecewiseFn):
    nargs, ufunc, sympy = 1, "absolute", sp.Abs

    def fdiff(self, argindex=1):
        return _Sign(self.args[0])


class _Extremum(_PiecewiseFn):
    """max(a, b) (``side`` 1) or min(a, b) (``side`` -1): the derivative 1 in the argument that
    wins, 0 in the other, 1/2 in each at a tie."""

    def fdiff(self, argindex=1):
        a, b = self.args
        return _Step(self.side * (a - b if argindex == 1 else b - a), sp.S.Half)


_Max = _piecewise_fn("_Max", 2, "maximum", sp.Max, _Extremum, side=1)
_Min = _piecewise_fn("_Min", 2, "minimum", sp.Min, _Extremum, side=-1)


def _pairwise(cls, args):
    out = args[0]
    for a in args[1:]:
        out = cls(out, a)
    return out


PIECEWISE = {sp.Abs: _Abs, sp.sign: _Sign, sp.floor: _Floor, sp.ceiling: _Ceiling,
             sp.Heaviside: lambda u, h0=sp.S.Half: _Step(u, sp.S.Half if h0 is None else h0),
             sp.Max: lambda *a: _pairwise(_Max, a), sp.Min: lambda *a: _pairwise(_Min, a)}
SMOOTH = (sp.exp, sp.log, sp.sin, sp.cos, sp.tan, sp.cot, sp.sec, sp.csc, sp.asin, sp.acos, sp.atan,
          sp.atan2, sp.sinh, sp.cosh, sp.tanh, sp.asinh, sp.acosh, sp.atanh, sp.erf, sp.erfc)
SUPPORTED_FUNCTIONS = tuple(f.__name__ for f in SMOOTH + tuple(PIECEWISE))
"""The SymPy functions a model's f, h, G (and symbolic Q, R) may use (:mod:`nlfilter.models`,
"Functions"); powers, ``sqrt`` included, and the constants ``pi``, ``E`` too."""


def code_form(e):
    """``e`` with SymPy's piecewise functions replaced by their code-generation forms
    (``_PiecewiseFn``: derivatives by the stated convention); ``e`` itself when it has none."""
    if not e.has(*PIECEWISE):
        return e
    return e.replace(lambda a: type(a) in PIECEWISE, lambda a: PIECEWISE[type(a)](*a.args))


def code_matrix(M):
    """:func:`code_form` of every entry of the matrix ``M`` (``M`` itself when none changes)."""
    return M.applyfunc(code_form) if any(e.has(*PIECEWISE) for e in M) else M


def check_expressions(name: str, M, shape_index: bool = False) -> None:
    """Refuse, naming ``name`` and the entry, an entry of ``M`` that is not a real, finite
    expression of supported functions (:data:`SUPPORTED_FUNCTIONS`)."""
    allowed = set(SMOOTH) | set(PIECEWISE)
    for k, e in enumerate(M):
        where = f"{name}[{k}]" if not shape_index else f"{name}[{k // M.shape[1]}, {k % M.shape[1]}]"
        if not isinstance(e, sp.Expr):
            raise TypeError(f"{name}: expected real expressions, got {e!r} ({type(e).__name__}) in {where}")
        for a in sp.preorder_traversal(e):
            if a.is_Symbol or a.is_NumberSymbol:
                continue
            if a.is_Number or a is sp.I or a in (sp.zoo, sp.oo, -sp.oo, sp.nan):
                if not (a.is_extended_real and a.is_finite):
                    raise ValueError(f"{name}: {where} = {e} is not real/finite (it contains {a}); expected "
                                     "real, finite expressions")
                continue
            if isinstance(a, (sp.Add, sp.Mul, sp.Pow)):
                continue
            if isinstance(a, AppliedUndef):
                raise ValueError(f"{name}: undefined function {a} in {where}; a model's functions must be "
                                 f"SymPy's, one of {', '.join(SUPPORTED_FUNCTIONS)}")
            if type(a) in allowed:
                continue
            raise ValueError(f"{name}: unsupported {'function' if isinstance(a, sp.Function) else 'expression'} "
                             f"{a} in {where}; supported: {', '.join(SUPPORTED_FUNCTIONS)} (and +, *, powers, "
                             "sqrt, pi, E)")


def matrix(name, value, rows=None, cols=None) -> sp.Matrix:
    """A SymPy matrix from ``value`` (``rows`` x ``cols`` when given), refused naming ``name``."""
    try:
        M = sp.Matrix(value)
    except (TypeError, ValueError, sp.SympifyError) as exc:
        raise TypeError(f"{name}: expected a list or SymPy Matrix of expressions, got {type(value).__name__}") from exc
    if rows is not None and M.shape[0] != rows:
        raise ValueError(f"{name}: expected {rows} row(s), got shape {M.shape}")
    if cols is not None and M.shape[1] != cols:
        raise ValueError(f"{name}: expected {cols} column(s), got shape {M.shape}")
    return M


def vector(name, value, n=None) -> sp.Matrix:
    """A column of expressions from a list, a row or a column (``n`` entries when given)."""
    M = matrix(name, value)
    if 1 not in M.shape or (n is not None and M.shape[0] * M.shape[1] != n):
        want = f"{n} expressions" if n is not None else "a list of expressions"
        raise ValueError(f"{name}: expected {want} (a vector), got shape {M.shape}")
    return M.reshape(M.shape[0] * M.shape[1], 1)


def is_symbolic(value) -> bool:
    """Whether a Q or R argument holds SymPy expressions with free symbols."""
    if isinstance(value, (sp.Basic, sp.MatrixBase)):
        return bool(value.free_symbols)
    if isinstance(value, (list, tuple)):
        return any(is_symbolic(v) for v in value)
    if isinstance(value, np.ndarray) and value.dtype == object:
        return any(is_symbolic(v) for v in value.ravel())
    return False


def piecewise_names(matrices) -> frozenset:
    """The names of SymPy's piecewise-smooth functions (``Abs``, ``Max``, ...) used in ``matrices``."""
    return frozenset(type(a).__name__ for M in matrices for e in M if e.has(*PIECEWISE)
                     for a in sp.preorder_traversal(e) if type(a) in PIECEWISE)


def model_symbols(states, time, params, inputs):
    """``(states, params, inputs)`` of a model checked: distinct SymPy symbols, the time distinct
    from the states, no symbol in two roles, no two names alike; ``states`` a list, ``params`` a dict,
    ``inputs`` a tuple."""
    if isinstance(states, sp.Symbol):
        states = [states]
    states = list(states)
    if not states or not all(isinstance(s, sp.Symbol) for s in states):
        raise TypeError(f"states: expected a non-empty list of SymPy symbols, got {states!r}")
    if len(set(states)) != len(states):
        raise ValueError(f"states: expected distinct symbols, got {states!r}")
    if time is not None and not isinstance(time, sp.Symbol):
        raise TypeError(f"time: expected a SymPy symbol or None, got {type(time).__name__}")
    if time is not None and time in states:
        raise ValueError(f"time: the time symbol {time} is also a state (states {[str(s) for s in states]}); "
                         "expected a symbol distinct from the states")
    params = dict(params or {})
    for p in params:
        if not isinstance(p, sp.Symbol):
            raise TypeError(f"params: expected SymPy symbols as keys, got {p!r}")
    if isinstance(inputs, sp.Symbol):
        inputs = [inputs]
    inputs = tuple(inputs or ())
    if not all(isinstance(u, sp.Symbol) for u in inputs) or len(set(inputs)) != len(inputs):
        raise TypeError(f"inputs: expected a list of distinct SymPy symbols, got {list(inputs)!r}")
    clash = (set(inputs) & set(params)) | ((set(inputs) | set(params)) & (set(states) | {time}))
    if clash:
        roles = {s: [nm for nm, group in (("a state", states), ("the time", [time]), ("a parameter", params),
                                          ("an input", inputs)) if s in group] for s in clash}
        raise ValueError(f"params/inputs: symbol(s) {sorted(map(str, clash))} are used twice ("
                         + "; ".join(f"{s} is {' and '.join(r)}" for s, r in sorted(roles.items(), key=str))
                         + "); expected states, the time, parameters and inputs disjoint")
    names = [str(p) for p in list(params) + list(inputs)]
    if len(set(names)) != len(names):
        raise ValueError(f"params/inputs: expected distinct names, got {names}")
    return states, params, inputs


def noise_symbols(noise, meas_noise, states, time, psyms):
    """``(noise, meas_noise)`` as tuples of SymPy symbols (the non-additive noises of f and h),
    checked distinct from the states, the time, the parameters and inputs ``psyms`` and each other."""
    # non-additive noise: x[k+1] = f(x[k], w[k]), y[k] = h(x[k], v[k]) with the noise symbols in f, h
    noise, meas_noise = (tuple([a] if isinstance(a, sp.Symbol) else (a or ())) for a in (noise, meas_noise))
    for nm, syms, other in (("noise", noise, meas_noise), ("meas_noise", meas_noise, noise)):
        if not syms:
            continue
        if not all(isinstance(w, sp.Symbol) for w in syms) or len(set(syms)) != len(syms):
            raise TypeError(f"{nm}: expected a list of distinct SymPy symbols (the "
                            f"{'process noise in f' if nm == 'noise' else 'measurement noise in h'}), got {list(syms)!r}")
        used = set(syms) & (set(states) | set(psyms) | {time} | set(other))
        if used:
            raise ValueError(f"{nm}: symbol(s) {sorted(map(str, used))} are already states, the time, parameters, "
                             "inputs or the other noise")
    return noise, meas_noise


def check_free_symbols(fM, hM, GM, states, time, psyms, noise, meas_noise) -> None:
    """Refuse a symbol of f, h (with its measurement noise) or G that is neither a state, the time,
    a parameter or input, nor (in f, h) the non-additive noise."""
    allowed = set(states) | ({time} if time is not None else set()) | set(psyms)
    for nm, M in (("f", fM), ("h", hM), ("G", GM)):
        own = set(noise) if nm == "f" else set(meas_noise) if nm == "h" else set()
        extra = M.free_symbols - allowed - own
        if extra:
            raise ValueError(f"{nm}: uses symbol(s) {sorted(map(str, extra))} that are neither states "
                             f"{[str(s) for s in states]}, the time symbol, nor given in params or inputs"
                             + (" (nor noise)" if nm == "f" and noise else "")
                             + (" (nor meas_noise)" if nm == "h" and meas_noise else ""))
