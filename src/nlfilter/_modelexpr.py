"""A model file's expressions read in bounded time and memory (issue 26, item 1).

:func:`read_expression` turns one string of a model file (:mod:`nlfilter.modelfile`) into the
SymPy expression ``sympy.parse_expr(text, transformations=(auto_number,))`` would give — the same
object, so a file that loaded before builds the same model — but without ever handing SymPy an
operation whose cost is unbounded: Python's :mod:`ast` parses the string (nothing is evaluated),
the tree is checked against the limits below, and the expression is built node by node with each
operation checked *before* SymPy performs it. Every constant subexpression is computed in double
precision alongside (no SymPy ``evalf``, whose precision can grow without bound) and must be a
finite real double.

The limits (module constants; each refusal names the limit and what was found):

``MAX_CHARS``
    characters of one expression: beyond it a file is generated, not written, and Python's
    parser recurses once per operator (a 20,000-term sum exhausts its recursion).
``MAX_NODES``
    numbers, names, operators and calls in one expression (SymPy's work and the generated code
    grow with it).
``MAX_DEPTH``
    nesting of parentheses, calls and operators of different kinds (a chain ``a + b + c`` counts
    once, as SymPy's ``Add`` is flat); Python's parser refuses 200 nested parentheses.
``MAX_EXPONENT``
    ``|p|`` of a constant exponent (its numerator and denominator when a fraction):
    ``2**1023`` is the largest power of two a double holds; ``x**(10**10)`` is no model.
``MAX_BITS``
    an upper bound on the bits of any exact integer or fraction SymPy forms while building (its
    integers are exact: ``((10**300 + 1)/10**300)**1000`` is a fraction of 2 million bits whose
    value is a harmless 1.0).
``MAX_DEGREE``
    a structural upper bound of the total degree in the states (``(x + 1)**100000`` is refused
    before anything expands it).
``MAX_TERMS``
    for a polynomial in the states, ``C(k + d, d)`` (``k`` states, degree bound ``d``) bounds the
    terms of its expansion, which the model's affine check (``sympy.Poly``) computes.

>>> import sympy as sp
>>> x = sp.Symbol("x")
>>> read_expression("0.9*x + 2**10", {"x": x}, {"x"})
0.9*x + 1024
>>> read_expression("9**9**9", {"x": x}, {"x"})
Traceback (most recent call last):
...
nlfilter._modelexpr.ExpressionError: got the power 9**9**9, which has the exponent 387420489; expected |exponent| ≤ 1024
"""

from __future__ import annotations

import ast
import math
import operator

import sympy as sp

MAX_CHARS = 4000
MAX_NODES = 1000
MAX_DEPTH = 40
MAX_EXPONENT = 1024
MAX_BITS = 16384
MAX_DEGREE = 100
MAX_TERMS = 100_000
MAX_DIGITS = 309  # digits of an integer literal: 10**309 > the largest double (1.8e308)

# File-level limits (nlfilter.modelfile). The number of states a file may declare: a model generates code for each of its n² Jacobian
# entries (and n³ second derivatives on first use), so loading grows as n² — 100 states load in
# about 2 s, 200 in 10 s and more; a model file is a small stated model, not generated output.
MAX_STATES = 100
# Σ over the file's expressions of (SymPy nodes × states it uses): the model differentiates each
# expression by each of its states, once for the Jacobians and again on first use for the second
# derivatives, and generates code for each; measured, 8,000 loads in about 2-4 s, 32,000 in 8-17 s.
MAX_WORK = 20_000

FUNCTIONS = {name: getattr(sp, name) for name in
             ("sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "exp", "log",
              "sqrt", "Abs", "sign", "erf", "Min", "Max")}
CONSTANTS = {"pi": sp.pi, "E": sp.E}


def _sign(v):
    return float((v > 0) - (v < 0))


# the functions in doubles (math raises ValueError on a domain error, OverflowError on overflow)
_FLOAT = {"sin": math.sin, "cos": math.cos, "tan": math.tan, "asin": math.asin, "acos": math.acos,
          "atan": math.atan, "atan2": math.atan2, "sinh": math.sinh, "cosh": math.cosh, "tanh": math.tanh,
          "exp": math.exp, "log": math.log, "sqrt": math.sqrt, "Abs": abs, "sign": _sign, "erf": math.erf,
          "Min": min, "Max": max}
_ARITY = {"atan2": (2, 2), "log": (1, 2), "Min": (1, None), "Max": (1, None)}  # others: exactly 1
_OPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}
_FAMILY = {ast.Add: "add", ast.Sub: "add", ast.Mult: "mul", ast.Div: "mul", ast.Pow: "pow"}


class ExpressionError(ValueError):
    """An expression refused; the message says what was found and what is expected (the caller
    adds the file, line and key)."""


def _check_tree(tree: ast.Expression, text: str) -> None:
    """The node kinds, :data:`MAX_NODES` and :data:`MAX_DEPTH`, walked without recursion."""
    nodes = 0
    stack = [(tree.body, 1, None)]
    while stack:
        node, depth, family = stack.pop()
        nodes += 1
        if nodes > MAX_NODES:
            raise ExpressionError(f"got more than {MAX_NODES} numbers, names and operators; expected at most "
                                  f"{MAX_NODES} in one expression")
        if depth > MAX_DEPTH:
            raise ExpressionError(f"got more than {MAX_DEPTH} levels of nesting; expected at most {MAX_DEPTH}")
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            fam = _FAMILY[type(node.op)]
            # a chain of + - (or * /) is one flat SymPy Add (Mul): its left operand stays on this level
            stack.append((node.left, depth if fam == family and fam != "pow" else depth + 1, fam))
            stack.append((node.right, depth + 1, fam))
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.UAdd, ast.USub)):
            stack.append((node.operand, depth + 1, None))
        elif isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS or node.keywords:
                what = ast.get_source_segment(text, node.func) or "?"
                raise ExpressionError(f"got a call of {what!r}; expected one of the functions {' '.join(FUNCTIONS)} "
                                      "with positional arguments")
            lo, hi = _ARITY.get(node.func.id, (1, 1))
            if len(node.args) < lo or (hi is not None and len(node.args) > hi) or \
                    any(isinstance(a, ast.Starred) for a in node.args):
                want = f"{lo}" if lo == hi else f"{lo} to {hi}" if hi else f"at least {lo}"
                raise ExpressionError(f"got {node.func.id}() with {len(node.args)} argument(s); expected {want}")
            stack.extend((a, depth + 1, None) for a in node.args)
        elif isinstance(node, ast.Name):
            pass
        elif isinstance(node, ast.Constant) and type(node.value) in (int, float):
            pass
        else:
            what = ast.get_source_segment(text, node) or type(node).__name__
            raise ExpressionError(f"got {what!r} ({type(node).__name__}); expected a scalar expression of names, "
                                  "numbers, + - * / ** and function calls")


def degree_bound(e, states: frozenset, memo: dict | None = None) -> int:
    """A structural upper bound of the total degree of ``e`` in ``states`` (nothing expanded)."""
    memo = {} if memo is None else memo
    if e in memo:
        return memo[e]
    if e.is_Symbol:
        d = int(e in states)
    elif e.is_Atom:
        d = 0
    elif e.is_Add:
        d = max(degree_bound(a, states, memo) for a in e.args)
    elif e.is_Pow and e.exp.is_Number:
        d = degree_bound(e.base, states, memo) * math.ceil(abs(float(e.exp)))
    else:  # Mul; a symbolic power; a function of its arguments
        d = sum(degree_bound(a, states, memo) for a in e.args)
    memo[e] = d
    return d


def _value(e, memo: dict):
    """``e`` (free of symbols) in double precision: math raises on a domain error or overflow."""
    if e in memo:
        return memo[e]
    if e.is_Rational:
        v = e.p / e.q  # int / int: OverflowError beyond a double
    elif e.is_Number or e.is_NumberSymbol:
        v = float(e)
    elif e.is_Add:
        v = math.fsum(_value(a, memo) for a in e.args)
    elif e.is_Mul:
        v = 1.0
        for a in e.args:
            v *= _value(a, memo)
    elif e.is_Pow:
        v = math.pow(_value(e.base, memo), _value(e.exp, memo))
    elif type(e).__name__ in _FLOAT:
        v = _FLOAT[type(e).__name__](*(_value(a, memo) for a in e.args))
    else:
        raise ValueError(f"{e} has no double value")
    v = float(v)
    if not math.isfinite(v):
        raise OverflowError("beyond the largest double")
    memo[e] = v
    return v


def _refusal(src: str, exc: BaseException) -> ExpressionError:
    reason = ("beyond the largest double" if isinstance(exc, OverflowError) else
              "a division by zero" if isinstance(exc, ZeroDivisionError) else "not a real number")
    return ExpressionError(f"got the constant {src} ({reason}); expected every constant to be a finite real "
                           "number (a double)")


class _Builder:
    """The expression built bottom-up; each node as ``(expr, bits)``, ``bits`` an upper bound of
    the bits of the exact rationals in it (sums and products add them, an integer power ``p``
    multiplies them by ``|p|``)."""

    def __init__(self, text: str, names: dict, states: frozenset):
        self.text, self.names, self.states = text, names, states
        self.values, self.degrees = {}, {}

    def src(self, node) -> str:
        return clip(ast.get_source_segment(self.text, node) or "?")

    def value(self, e, node) -> float | None:
        """``e``'s double if it is a constant (None if it has symbols); a constant that is not a
        finite real double is refused."""
        if e.free_symbols:
            return None
        try:
            return _value(e, self.values)
        except (ValueError, OverflowError, ZeroDivisionError, TypeError) as exc:
            raise _refusal(self.src(node), exc) from None

    def number(self, node):
        lit = ast.get_source_segment(self.text, node) or repr(node.value)
        if isinstance(node.value, int):
            if len(lit) > MAX_DIGITS:
                raise ExpressionError(f"got an integer of {len(lit)} digits; expected at most {MAX_DIGITS} (a finite "
                                      "double)")
            e = sp.Integer(node.value)
            return e, node.value.bit_length() + 1
        if not math.isfinite(float(lit)):
            raise ExpressionError(f"got the number {lit} (beyond the largest double); expected a finite number")
        return sp.Float(lit), 0  # what sympy's auto_number writes: Float of the literal's text

    def power(self, node, base, exp, bits):
        """``base**exp`` once its exponent, exact size, degree and (for a constant) double are
        within bounds; returns ``(expr, bits)``."""
        if exp.is_Number:
            p = abs(exp.p) if exp.is_Rational else abs(float(exp))
            q = exp.q if exp.is_Rational else 1
            if p > MAX_EXPONENT or q > MAX_EXPONENT:
                raise ExpressionError(f"got the power {self.src(node)}, which has the exponent {exp}; expected |exponent| ≤ "
                                      f"{MAX_EXPONENT}" + (f" and a denominator ≤ {MAX_EXPONENT}" if q > 1 else ""))
            if exp.is_Integer and bits * p > MAX_BITS:
                raise ExpressionError(f"got the power {self.src(node)}, which forms exact numbers of up to {bits * p} bits; "
                                      f"expected at most {MAX_BITS} (write decimals for inexact numbers)")
            d = degree_bound(base, self.states, self.degrees) * math.ceil(p)
            if d > MAX_DEGREE:
                raise ExpressionError(f"got the power {self.src(node)}, which has degree {d} in the states; expected at most "
                                      f"{MAX_DEGREE}")
            bits = bits * p if exp.is_Integer else bits
        elif not exp.free_symbols:  # pi, sqrt(2), exp(3): its double bounds it
            v = _value(exp, self.values)
            if abs(v) > MAX_EXPONENT:
                raise ExpressionError(f"got the power {self.src(node)}, which has the exponent {v:.6g}; expected |exponent| ≤ "
                                      f"{MAX_EXPONENT}")
        if not base.free_symbols and not exp.free_symbols:
            try:  # before SymPy: a constant power that is not a finite double is refused unbuilt
                v = math.pow(_value(base, self.values), _value(exp, self.values))
                if not math.isfinite(v):
                    raise OverflowError
            except (ValueError, OverflowError, ZeroDivisionError) as exc:
                raise _refusal(self.src(node), exc) from None
        return base ** exp, bits

    def call(self, node, args):
        name = node.func.id
        if all(not a.free_symbols for a in args):
            try:  # before SymPy (exp(exp(exp(100))) would never finish in SymPy's precision)
                v = _FLOAT[name](*(_value(a, self.values) for a in args))
                if not math.isfinite(v):
                    raise OverflowError
            except (ValueError, OverflowError, ZeroDivisionError, TypeError) as exc:
                raise _refusal(self.src(node), exc) from None
        try:
            return FUNCTIONS[name](*args)
        except (TypeError, ValueError, ArithmeticError) as exc:
            raise ExpressionError(f"got {self.src(node)} ({type(exc).__name__}: {exc}); expected a valid call") from None

    def build(self, root):
        """Post-order over the checked tree, without recursion."""
        out = {}
        stack = [(root, False)]
        while stack:
            node, done = stack.pop()
            if not done:
                stack.append((node, True))
                kids = ([node.left, node.right] if isinstance(node, ast.BinOp) else [node.operand]
                        if isinstance(node, ast.UnaryOp) else list(node.args) if isinstance(node, ast.Call) else [])
                stack.extend((k, False) for k in reversed(kids))
                continue
            if isinstance(node, ast.Constant):
                e, bits = self.number(node)
            elif isinstance(node, ast.Name):
                e = self.names[node.id]
                bits = _bits(e)
            elif isinstance(node, ast.UnaryOp):
                a, bits = out.pop(id(node.operand))
                e = -a if isinstance(node.op, ast.USub) else +a
            elif isinstance(node, ast.BinOp):
                (a, ba), (b, bb) = out.pop(id(node.left)), out.pop(id(node.right))
                if isinstance(node.op, ast.Pow):
                    e, bits = self.power(node, a, b, ba)
                else:
                    if isinstance(node.op, ast.Div) and b == 0:
                        raise ExpressionError(f"got {self.src(node)} (a division by zero); expected a finite expression")
                    e = _BINARY[type(node.op)](a, b)  # Python's operators, as parse_expr evaluates
                    bits = ba + bb + 1
            else:  # a call
                pairs = [out.pop(id(a)) for a in node.args]
                e, bits = self.call(node, [p[0] for p in pairs]), sum(p[1] for p in pairs)
            if not isinstance(e, sp.Expr):
                raise ExpressionError(f"got {self.src(node)} (a {type(e).__name__}); expected a scalar expression")
            if bits > MAX_BITS:
                raise ExpressionError(f"got {self.src(node)}, whose exact numbers may reach {bits} bits; expected at "
                                      f"most {MAX_BITS} (write decimals for inexact numbers)")
            self.value(e, node)
            out[id(node)] = (e, bits)
        return out[id(root)][0]


def finite_double(value) -> bool:
    """Whether a number is a finite double (a TOML integer may have any number of digits)."""
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def short(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"


def clip(text: str, width: int = 60) -> str:
    return text if len(text) <= width else f"{text[:width - 3]}..."


def _bits(e) -> int:
    """The bits of the exact rationals in ``e`` (numerators plus denominators)."""
    return sum(a.p.bit_length() + a.q.bit_length() for a in sp.preorder_traversal(e) if isinstance(a, sp.Rational))


def read_expression(text: str, names: dict, states) -> sp.Expr:
    """The SymPy expression of ``text`` in ``names`` (name -> SymPy symbol or number), within the
    module's limits; ``states``: the names (or symbols) that are the model's states (for the
    degree bounds). Raises :class:`ExpressionError` (a ``ValueError``) with what was found and
    what is expected."""
    if len(text) > MAX_CHARS:
        raise ExpressionError(f"got an expression of {len(text)} characters; expected at most {MAX_CHARS}")
    src = text.strip()
    try:
        tree = ast.parse(src, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        msg = exc.msg if isinstance(exc, SyntaxError) else type(exc).__name__
        raise ExpressionError(f"got {clip(text)!r} ({msg}); expected an expression") from None
    _check_tree(tree, src)
    names = {**CONSTANTS, **names}
    unknown = sorted({n.id for n in ast.walk(tree) if isinstance(n, ast.Name)} - set(names) - set(FUNCTIONS))
    if unknown:
        raise ExpressionError(f"got the unknown name {unknown[0]!r}; expected a declared name")
    syms = frozenset(s if isinstance(s, sp.Symbol) else sp.Symbol(s) for s in states)
    e = _Builder(src, names, syms).build(tree.body)
    for a in sp.preorder_traversal(e):  # every number a finite double (1e200*x squared is 1e400*x**2)
        if a.is_Number:
            try:
                _value(a, {})
            except (OverflowError, ValueError):
                raise ExpressionError(f"got {clip(text)!r}, which forms a coefficient beyond the largest double "
                                      "(1.8e308); expected finite numbers") from None
    if e.has(sp.zoo, sp.nan, sp.oo, -sp.oo, sp.I):
        raise ExpressionError(f"got {clip(text)!r} = {clip(str(e))}; expected a finite real expression")
    d = degree_bound(e, syms)
    if d > MAX_DEGREE:
        raise ExpressionError(f"got {clip(text)!r}, of degree up to {d} in the states; expected at most {MAX_DEGREE}")
    k = len(e.free_symbols & syms)
    if d >= 2 and e.is_polynomial(*syms) and math.comb(k + d, d) > MAX_TERMS:
        raise ExpressionError(f"got {clip(text)!r}, a polynomial in {k} states of degree up to {d} (up to "
                              f"{math.comb(k + d, d):,} terms expanded); expected at most {MAX_TERMS:,} terms")
    return e


__all__ = ["ExpressionError", "read_expression", "degree_bound", "clip", "finite_double", "short", "FUNCTIONS", "CONSTANTS",
           "MAX_STATES", "MAX_WORK"]
