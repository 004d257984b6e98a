"""Inlining at the source level: a function's calls of other functions, given as source, expanded
into its own text, so that numba types and compiles one flat function instead of inlining its
kernels itself (``inline="always"`` inlines numba's IR and types each call site again: a
specialized loop took 20-40 s to compile; the same loop flattened here compiles in a fraction).

The expansion keeps the arithmetic as written, operation by operation and in order (the numbers
are the same to the last bit): an expanded call binds its parameters (to the caller's name or
constant where the callee never assigns the parameter, else to a fresh local assigned the argument
once, before the body, as a call evaluates its arguments), renames the callee's locals apart (``x``
→ ``x__7``), and turns its ``return v`` into an assignment of the call's target; a return that
leaves a loop early sets a flag and breaks (the loops around and the statements after it test the
flag). A call inside an expression is first evaluated into a fresh local before the statement (in
``a and f(...)``, only where ``a`` is true: the short circuit is kept).

What the kernels may use (checked; anything else raises ``ValueError``): positional arguments,
plain statements, ``if``/``for``/``while`` (no ``else`` on a loop holding a return, no expanded
call in a ``while`` test or a conditional expression), no ``global``/``nonlocal``, no nested
functions.
"""

from __future__ import annotations

import ast
import copy
import functools
import itertools
import textwrap

__all__ = ["flatten", "flatten_apart"]


def flatten(root: str, defs: dict) -> str:
    """The source of the function ``root`` (source text of one ``def``) with every call of a name
    in ``defs`` (``{name called: source of its def}``; the def's own name does not matter) expanded,
    recursively (a kernel calling another). Calls of other names are left as they are."""
    return _Inliner(defs).run(root)


def flatten_apart(root: str, defs: dict, apart) -> tuple:
    """:func:`flatten`, but the calls of the names in ``apart`` (names of ``defs``) are not expanded:
    each becomes a call of a function of its own, flattened the same way, made once per callee and
    constant arguments (``psd_check(m, P, 4, tol, W, L, ev)`` → ``psd_check_1(m, P, tol, W, L, ev)``,
    the 4 compiled in and what it decides folded). Returns ``(root's source, {name: source})``, the
    functions' ``def`` named ``name + "_"``."""
    made = {}
    text = _Inliner(defs, apart, made).run(root)
    return text, {name: src for name, src in made.values()}


def _parse(src: str) -> ast.FunctionDef:
    fn = ast.parse(textwrap.dedent(src)).body[0]
    if not isinstance(fn, ast.FunctionDef):
        raise ValueError(f"flatten: expected the source of one def, got {type(fn).__name__}")
    a = fn.args
    if a.vararg or a.kwarg or a.kwonlyargs or a.defaults or a.posonlyargs:
        raise ValueError(f"flatten: {fn.name} must take plain positional parameters only")
    for node in ast.walk(fn):
        if isinstance(node, (ast.Global, ast.Nonlocal, ast.Lambda, ast.AsyncFunctionDef, ast.ClassDef, ast.Try,
                             ast.With, ast.Yield, ast.YieldFrom, ast.NamedExpr)) or (
                isinstance(node, ast.FunctionDef) and node is not fn):
            raise ValueError(f"flatten: {fn.name} uses {type(node).__name__}, which is not expanded")
    if fn.body and isinstance(fn.body[0], ast.Expr) and isinstance(fn.body[0].value, ast.Constant):
        fn.body = fn.body[1:] or [ast.Pass()]  # the docstring
    return fn


@functools.cache
def _parsed(src: str) -> ast.FunctionDef:
    """:func:`_parse` of a callee's source, once per process (its tree only read, or copied before it
    is changed: an inliner and the inliners of its functions apart parse the same kernels)."""
    return _parse(src)


def _has(node, kind) -> bool:
    return any(isinstance(x, kind) for x in ast.walk(node))


def _stored(fn: ast.FunctionDef) -> set:
    return {x.id for x in ast.walk(fn) if isinstance(x, ast.Name) and isinstance(x.ctx, (ast.Store, ast.Del))}


def _always_returns(stmts) -> bool:
    if not stmts:
        return False
    last = stmts[-1]
    if isinstance(last, ast.Return):
        return True
    return isinstance(last, ast.If) and _always_returns(last.body) and _always_returns(last.orelse)


def _assign(target, value):
    return ast.Assign(targets=[target], value=value, lineno=0)


def _name(id_, store=False):
    return ast.Name(id=id_, ctx=ast.Store() if store else ast.Load())


class _Inliner:
    def __init__(self, defs: dict, apart=(), made=None):
        self.sources = defs
        self.defs = {name: _parsed(src) for name, src in defs.items() if name not in apart}
        self.apart = {name: _parsed(src) for name, src in defs.items() if name in apart}
        self.made = {} if made is None else made  # (callee, constant arguments) -> (name, source)
        self.count = itertools.count(1)

    def run(self, root: str) -> str:
        fn = _parse(root)
        self.root_names = _stored(fn) | {a.arg for a in fn.args.args}
        fn = ast.fix_missing_locations(_Consts(_const_locals(fn)).visit(fn))
        fn.body = self.block(fn.body)
        if self.apart:
            for node in ast.walk(fn):
                if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in self.apart:
                    self.call_apart(node)
        return ast.unparse(ast.fix_missing_locations(ast.Module(body=[fn], type_ignores=[]))) + "\n"

    def call_apart(self, call: ast.Call) -> None:
        """``call`` (of a name in ``apart``) made a call of the callee's function for its constant
        arguments (made here the first time: the callee flattened around those constants)."""
        callee = call.func.id
        params = [a.arg for a in self.apart[callee].args.args]
        if len(call.args) != len(params) or call.keywords or any(isinstance(a, ast.Starred) for a in call.args):
            raise ValueError(f"flatten: {callee} takes {len(params)} positional arguments")
        fixed = {i: a.value for i, a in enumerate(call.args) if isinstance(a, ast.Constant)}
        key = (callee, tuple((i, type(v).__name__, v) for i, v in sorted(fixed.items())))  # True, 1, 1.0 apart
        if key not in self.made:
            name = f"{callee}_{sum(k[0] == callee for k in self.made) + 1}"
            keep = [p for i, p in enumerate(params) if i not in fixed]
            wrap = (f"def {name}_({', '.join(keep)}):\n    return {callee}("
                    + ", ".join(repr(fixed[i]) if i in fixed else p for i, p in enumerate(params)) + ")\n")
            self.made[key] = (name, None)  # the name taken before the callee's own calls are made
            inner = _Inliner(self.sources, [a for a in self.apart if a != callee], self.made)
            self.made[key] = (name, inner.run(wrap))
        call.func.id = self.made[key][0]
        call.args = [a for i, a in enumerate(call.args) if i not in fixed]

    def fresh(self, base: str) -> str:
        return f"{base}__{next(self.count)}"

    def expands(self, node) -> bool:
        return isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in self.defs

    def any_call(self, node) -> bool:
        return any(self.expands(x) for x in ast.walk(node))

    # -- statements -------------------------------------------------------------------------------
    def block(self, stmts) -> list:
        out = []
        for s in stmts:
            out += self.stmt(s)
        return out

    def stmt(self, s) -> list:
        if isinstance(s, ast.If):
            pre, s.test = self.hoist(s.test)
            s.body, s.orelse = self.block(s.body), self.block(s.orelse)
            return pre + [s]
        if isinstance(s, ast.For):
            pre, s.iter = self.hoist(s.iter)
            s.body, s.orelse = self.block(s.body), self.block(s.orelse)
            return pre + [s]
        if isinstance(s, ast.While):
            if self.any_call(s.test):
                raise ValueError("flatten: an expanded call in a while test")
            s.body, s.orelse = self.block(s.body), self.block(s.orelse)
            return [s]
        if isinstance(s, ast.Expr) and self.expands(s.value):
            pre, call = self.hoist_args(s.value)
            return pre + self.expand(call, None)
        if isinstance(s, ast.Assign) and len(s.targets) == 1 and self.expands(s.value) \
                and not self.any_call(s.targets[0]):
            pre, call = self.hoist_args(s.value)
            return pre + self.expand(call, s.targets[0])
        if isinstance(s, (ast.Assign, ast.AugAssign, ast.AnnAssign, ast.Expr, ast.Return)):
            if s.value is None or not self.any_call(s.value):
                return [s]
            for t in getattr(s, "targets", [getattr(s, "target", None)]):
                if t is not None and self.any_call(t):
                    raise ValueError("flatten: an expanded call in an assignment target")
            pre, s.value = self.hoist(s.value)
            return pre + [s]
        if self.any_call(s):
            raise ValueError(f"flatten: an expanded call in a {type(s).__name__} statement")
        return [s]

    # -- expressions: calls evaluated into fresh locals, in order --------------------------------
    def hoist(self, e):
        """``(statements, e')``: ``e`` with its expanded calls replaced by locals the statements set."""
        if not self.any_call(e):
            return [], e
        if self.expands(e):
            pre, call = self.hoist_args(e)
            t = self.fresh("v")
            return pre + self.expand(call, _name(t, True)), _name(t)
        if isinstance(e, ast.BoolOp):  # a and b / a or b: b evaluated only where a does not decide
            t = self.fresh("v")
            pre, first = self.hoist(e.values[0])
            pre.append(_assign(_name(t, True), first))
            rest = e.values[1:]
            more, nxt = self.hoist(rest[0] if len(rest) == 1 else ast.BoolOp(op=e.op, values=rest))
            test = _name(t) if isinstance(e.op, ast.And) else ast.UnaryOp(op=ast.Not(), operand=_name(t))
            pre.append(ast.If(test=test, body=more + [_assign(_name(t, True), nxt)], orelse=[]))
            return pre, _name(t)
        if isinstance(e, (ast.IfExp, ast.Lambda, ast.comprehension, ast.ListComp, ast.GeneratorExp, ast.SetComp,
                          ast.DictComp)):
            raise ValueError(f"flatten: an expanded call in a {type(e).__name__}")
        pre = []
        for field, value in ast.iter_fields(e):
            if isinstance(value, ast.expr):
                p, new = self.hoist(value)
                pre += p
                setattr(e, field, new)
            elif isinstance(value, list):
                for i, v in enumerate(value):
                    if isinstance(v, ast.expr):
                        p, value[i] = self.hoist(v)
                        pre += p
        return pre, e

    def hoist_args(self, call):
        pre = []
        for i, a in enumerate(call.args):
            p, call.args[i] = self.hoist(a)
            pre += p
        if call.keywords:
            raise ValueError(f"flatten: keyword arguments in a call of {call.func.id}")
        return pre, call

    # -- one call ---------------------------------------------------------------------------------
    def expand(self, call: ast.Call, target) -> list:
        """The statements of ``target = call`` (``target`` None: the value is dropped), expanded."""
        fn = copy.deepcopy(self.defs[call.func.id])
        params = [a.arg for a in fn.args.args]
        if len(call.args) != len(params) or any(isinstance(a, ast.Starred) for a in call.args):
            raise ValueError(f"flatten: {call.func.id} takes {len(params)} arguments, given {len(call.args)}")
        k = next(self.count)
        stored = _stored(fn)
        rename = {v: f"{v}__{k}" for v in stored | set(params)}
        subst, pre = {}, []
        for prm, arg in zip(params, call.args):
            if prm not in stored and isinstance(arg, (ast.Name, ast.Constant)):
                subst[prm] = arg  # bound to the caller's name or constant (never assigned in the callee)
            else:
                pre.append(_assign(_name(rename[prm], True), arg))  # evaluated once, before the body
        for node in ast.walk(fn):
            if isinstance(node, ast.Name):
                if node.id not in subst and node.id not in rename and node.id in self.root_names:
                    raise ValueError(f"flatten: {call.func.id} reads the global {node.id}, a local of the root function")
                if node.id in subst:
                    node.id = subst[node.id].id if isinstance(subst[node.id], ast.Name) else node.id
                elif node.id in rename:
                    node.id = rename[node.id]
        consts = {rename.get(v, v): c for v, c in _const_locals(fn).items()}
        consts.update({p: a for p, a in subst.items() if isinstance(a, ast.Constant)})
        fn = _Consts(consts).visit(fn)
        fn = ast.fix_missing_locations(fn)
        body = self.block(fn.body)
        flag = f"done__{k}"
        while flag in rename.values():  # a local of the callee named done
            flag = "_" + flag
        out = _Returns(target, flag).block(body, "top")
        return pre + ([_assign(_name(flag, True), ast.Constant(False))] if _has_flag(out, flag) else []) + out


class _Consts(ast.NodeTransformer):
    """Names bound to constants replaced by them, and what these decide folded: comparisons,
    ``not``, ``and``/``or`` of constants, and ``if`` on a constant reduced to the branch taken
    (numba then never types the dead branch; e.g. :func:`~.path_linalg.psd_ok_`'s other sizes)."""

    def __init__(self, consts):
        self.consts = consts

    def visit_Name(self, node):
        c = self.consts.get(node.id)
        return ast.copy_location(ast.Constant(c.value), node) if c is not None and isinstance(node.ctx, ast.Load) else node

    def visit_Compare(self, node):
        self.generic_visit(node)
        items = [node.left, *node.comparators]
        if len(node.ops) == 1 and all(isinstance(x, ast.Constant) and type(x.value) in (int, bool) for x in items):
            a, b = items[0].value, items[1].value
            op = {ast.Eq: a == b, ast.NotEq: a != b, ast.Lt: a < b, ast.LtE: a <= b, ast.Gt: a > b, ast.GtE: a >= b}
            if type(node.ops[0]) in op:
                return ast.copy_location(ast.Constant(op[type(node.ops[0])]), node)
        return node

    def visit_UnaryOp(self, node):
        self.generic_visit(node)
        if isinstance(node.op, ast.Not) and isinstance(node.operand, ast.Constant) and isinstance(node.operand.value, bool):
            return ast.copy_location(ast.Constant(not node.operand.value), node)
        return node

    def visit_BoolOp(self, node):
        self.generic_visit(node)
        first = node.values[0]
        if isinstance(first, ast.Constant) and isinstance(first.value, bool):
            decides = first.value is (not isinstance(node.op, ast.And))  # False and .../True or ...
            if decides or len(node.values) == 1:
                return first
            return node.values[1] if len(node.values) == 2 else ast.BoolOp(op=node.op, values=node.values[1:])
        return node

    def visit_If(self, node):
        self.generic_visit(node)
        if isinstance(node.test, ast.Constant) and isinstance(node.test.value, bool):
            return (node.body if node.test.value else node.orelse) or ast.Pass()
        return node


def _const_locals(fn: ast.FunctionDef) -> dict:
    """The locals of ``fn`` assigned once, at its top level, an int constant (the dimensions a
    specialized loop compiles in), and never stored otherwise: ``{name: Constant}``."""
    counts = {}
    for x in ast.walk(fn):
        if isinstance(x, ast.Name) and isinstance(x.ctx, (ast.Store, ast.Del)):
            counts[x.id] = counts.get(x.id, 0) + 1
    params = {a.arg for a in fn.args.args}
    out = {}
    for s in fn.body:
        if isinstance(s, ast.Assign) and len(s.targets) == 1 and isinstance(s.targets[0], ast.Name) \
                and isinstance(s.value, ast.Constant) and type(s.value.value) is int:
            name = s.targets[0].id
            if counts.get(name) == 1 and name not in params:
                out[name] = s.value
    return out


def _has_flag(stmts, flag) -> bool:
    return any(isinstance(x, ast.Name) and x.id == flag for s in stmts for x in ast.walk(s))


class _Returns:
    """A callee's body with ``return v`` as ``target = v``: where the return ends a branch the
    statements after the ``if`` move to the other branch; inside a loop (or where a branch may
    both return and fall through) the return sets ``flag`` (and breaks out of the loop), and what
    follows tests it. ``mode``: ``"top"`` (nothing follows a return), ``"flag"`` (a return sets
    the flag), ``"loop"`` (sets it and breaks)."""

    def __init__(self, target, flag):
        self.target, self.flag = target, flag

    def ret(self, s, mode) -> list:
        out = []
        if s.value is not None and self.target is not None:
            out.append(_assign(copy.deepcopy(self.target), s.value))
        if mode != "top":
            out.append(_assign(_name(self.flag, True), ast.Constant(True)))
        if mode == "loop":
            out.append(ast.Break())
        return out or [ast.Pass()]

    def block(self, stmts, mode) -> list:
        out = []
        for i, s in enumerate(stmts):
            if isinstance(s, ast.Return):
                return out + self.ret(s, mode)  # what follows a return is never run
            if not _has(s, ast.Return):
                out.append(s)
                continue
            rest = stmts[i + 1:]
            if isinstance(s, ast.If) and mode != "loop" and not _loop_return(s):
                b_all, o_all = _always_returns(s.body), _always_returns(s.orelse)
                b_ret, o_ret = _has_any(s.body, ast.Return), _has_any(s.orelse, ast.Return)
                if (b_all or not b_ret) and (o_all or not o_ret):  # each branch returns always or never
                    s.body = self.block(s.body + ([] if b_all else rest), mode) or [ast.Pass()]
                    s.orelse = self.block(s.orelse + ([] if o_all else rest), mode)
                    return out + [s]
            inner = "loop" if mode == "loop" else "flag"
            if isinstance(s, (ast.For, ast.While)):
                if s.orelse:
                    raise ValueError("flatten: a loop with an else clause holds a return")
                s.body = self.block(s.body, "loop")
            elif isinstance(s, ast.If):
                s.body = self.block(s.body, inner) or [ast.Pass()]
                s.orelse = self.block(s.orelse, inner)
            else:  # pragma: no cover - returns live in statements only
                raise ValueError(f"flatten: a return inside a {type(s).__name__}")
            out.append(s)
            if mode == "loop":
                if isinstance(s, (ast.For, ast.While)):  # (a branch's return breaks by itself)
                    out.append(ast.If(test=_name(self.flag), body=[ast.Break()], orelse=[]))
                continue
            rest = self.block(rest, mode)
            if rest:
                out.append(ast.If(test=ast.UnaryOp(op=ast.Not(), operand=_name(self.flag)), body=rest, orelse=[]))
            return out
        return out


def _has_any(stmts, kind) -> bool:
    return any(_has(s, kind) for s in stmts)


def _loop_return(s) -> bool:
    """Whether ``s`` holds a return inside a loop."""
    return any(isinstance(x, (ast.For, ast.While)) and _has(x, ast.Return) for x in ast.walk(s))
