"""The source-level inlining of the specialized compiled loops (:mod:`nlfilter.filters.compiled.flatten`),
tested without numba: the generated modules run as plain Python.

Tolerance: none — equality to the last bit. The expansion must keep every operation and its order
(numba then compiles the same arithmetic: no fast-math, no reassociation), and plain Python
evaluates both texts with the same IEEE double operations, so any difference is a bug of the
transform. (numba's compiled flat loops against the general loop, also to the last bit:
``test_compiled.py::test_specialized_loops_give_the_same_numbers``.)
"""

from __future__ import annotations

import types

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters.compiled import build, run as compiled_run
from nlfilter.filters.compiled.flatten import flatten, flatten_apart
from nlfilter.filters.ekf import EKF
from nlfilter.filters.second_order import SecondOrderFilter
from nlfilter.filters.ukf import UKF

# -- the transform on small functions ----------------------------------------------------------

FIRST_NEGATIVE = '''
def first_negative(a, n):
    """The index of the first negative entry of a[:n], or -1 (a return inside two loops)."""
    for i in range(n):
        for j in range(2):
            if a[i] * (j + 1) < 0.0:
                return i
    return -1
'''

BUMP = '''
def bump(x, k):
    k = k + 1          # a parameter assigned: bound to a fresh local, the caller's name untouched
    x[0] += k
    if k > 2:
        return True, 2.0 * k
    return False, 0.5
'''

ROOT = '''
def root(a, x, log, n):
    k = 1
    found = first_negative(a, n)
    ok, v = bump(x, k)
    both = ok and record(log, v)   # record runs only where ok: the short circuit is kept
    if not first_negative(a, n) >= 0:
        x[1] = k + v
    return found, ok, v, both, k
'''

RECORD = '''
def record(log, v):
    log.append(v)
    return v > 1.0
'''

DEFS = {"first_negative": FIRST_NEGATIVE, "bump": BUMP, "record": RECORD}


def _run(src, name, defs, *args):
    ns = {}
    for text in defs.values():
        exec(text, ns)  # the callees, under their own names ...
    for called, text in defs.items():
        ns[called] = ns[text.split("def ", 1)[1].split("(", 1)[0]]  # ... and the names called
    exec(src, ns)
    return ns[name](*args)


@pytest.mark.parametrize("a", [[1.0, 2.0, 3.0], [1.0, -2.0, 3.0], [-1.0, 2.0, 3.0]])
@pytest.mark.parametrize("x0", [0.0, 5.0])
def test_flattened_function_does_what_the_calls_did(a, x0):
    flat = flatten(ROOT, DEFS)
    assert "first_negative(" not in flat and "bump(" not in flat and "record(" not in flat
    outs = []
    for src, defs in ((ROOT, DEFS), (flat, {})):
        x, log = [x0, 0.0], []
        outs.append((_run(src, "root", defs, np.array(a), x, log, 3), x, log))
    assert outs[0] == outs[1]


def test_short_circuit_is_kept():
    """``ok and record(...)`` with ok False: record is not run (log stays empty)."""
    flat = flatten(ROOT, DEFS)
    x, log = [0.0, 0.0], []
    _run(flat, "root", {}, np.array([1.0]), x, log, 1)  # bump: k = 2, not > 2 -> ok False
    assert log == []


def test_constant_dimensions_fold_the_branches_of_other_sizes():
    """A dimension assigned a constant once (the specialized loops' ``n = 2``) is compiled in:
    ``if n == 1`` branches of other sizes are dropped from the text."""
    callee = "def size(n):\n    if n == 1:\n        return 10.0\n    if n == 2:\n        return 20.0\n    return 0.0\n"
    flat = flatten("def root(y):\n    n = 2\n    y[0] = size(n)\n", {"size": callee})
    assert "10.0" not in flat and "0.0" not in flat.replace("20.0", "")
    y = [0.0]
    _run(flat, "root", {}, y)
    assert y == [20.0]


def test_calls_kept_apart_become_functions_of_their_constants():
    """``flatten_apart``: a call of a name kept apart becomes a call of a function of its own, one
    per callee and constant arguments (those compiled in, their branches folded), flattened the
    same way; the program does what the calls did."""
    size = "def size(n, y):\n    if n == 1:\n        return 10.0 + y\n    return first_negative(y, n)\n"
    root = ("def root(a, x, log, n):\n    u = size(1, a[0]) + size(1, a[1])\n    v = size(3, a)\n"
            "    w = bump(x, n)\n    return u, v, w\n")
    defs = {**DEFS, "size": size}
    text, made = flatten_apart(root, defs, ("size", "bump"))
    assert sorted(made) == ["bump_1", "size_1", "size_2"]  # size(1, .) once, size(3, .) once
    one, three = sorted(("size_1", "size_2"), key=lambda k: "10.0" not in made[k])  # size(1, .), size(3, .)
    assert f"{one}(a[0]) + {one}(a[1])" in text and f"{three}(a)" in text and "bump_1(x, n)" in text
    assert "first_negative(" not in made[one] + made[three] and "n == 1" not in made[three]
    ns = {}
    for src in made.values():
        exec(src, ns)  # noqa: S102 - the generated functions, run as Python
    for name in made:
        ns[name] = ns[name + "_"]
    exec(text, ns)  # noqa: S102
    for a in ([1.0, 2.0, 3.0], [1.0, -2.0, 3.0]):
        outs = []
        for run in (lambda *args: _run(root, "root", defs, *args), ns["root"]):
            x = [0.0, 0.0]
            outs.append((run(np.array(a), x, [], 3), x))
        assert outs[0] == outs[1]


@pytest.mark.parametrize("bad, what", [
    ("def k(x, *a):\n    return x\n", "positional"),
    ("def k(x):\n    global z\n    return x\n", "Global"),
])
def test_what_it_cannot_expand_is_refused(bad, what):
    with pytest.raises(ValueError, match=what):
        flatten("def root(y):\n    return k(y)\n", {"k": bad})


def test_a_global_the_root_shadows_is_refused():
    with pytest.raises(ValueError, match="reads the global scale"):
        flatten("def root(y):\n    scale = 2.0\n    return k(y)\n", {"k": "def k(x):\n    return x * scale\n"})


# -- the specialized loops' modules, run as Python: flat text against the general loop's ------

x1, x2 = sp.symbols("x1 x2")


def _model(G):
    """Two states, two measurements; ``G``: the noise gain (state-dependent: the node rules' G(X_i)
    sum; the second-order filters take a constant one)."""
    return DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * sp.sin(x2), 0.8 * x2 - 0.1 * x1 * x2], [x1 + x2**2 / 4, sp.atan(x2)],
                         G, Q=[[0.02, 0.005], [0.005, 0.01]], R=[[0.1, 0.0], [0.0, 0.2]])


def _python(monkeypatch):
    """Loops loaded as plain Python: the module text exec'd with ``_jit`` the identity."""
    jit = 'return njit(error_model="numpy", nogil=True, _nrt=False, **kw)(fn)'

    def load(text, tag):
        assert jit in text
        ns = {}
        exec(compile(text.replace(jit, "return fn"), f"<{tag}>", "exec"), ns)
        return types.SimpleNamespace(steps=ns["steps"]), None
    monkeypatch.setattr(build, "load_source", load)
    monkeypatch.setattr(compiled_run, "seal", lambda entry: None)


@pytest.mark.parametrize("make, G", [(EKF, [[1.0, 0.0], [0.1 * x1, 1.0]]), (UKF, [[1.0, 0.0], [0.1 * x1, 1.0]]),
                                     (lambda md: SecondOrderFilter(md, form="gaussian"), None)],
                         ids=["taylor1", "nodes", "taylor2"])
def test_flat_loop_text_equals_the_general_loop_as_python(make, G, monkeypatch):
    _python(monkeypatch)
    md = _model(G)
    flt = make(md)
    ys = 0.3 * np.random.default_rng(4).normal(size=(2, 6, 2))
    ys[0, 2, 1] = np.nan  # partly missing
    ys[:, 4] = np.nan  # missing on every path
    out = []
    for limit in (0, 4):  # the general loop, then the specialized (flat) one
        monkeypatch.setattr(build, "SPECIALIZE_UP_TO", limit)
        out.append(flt.run(ys, [0.2, -0.1], 0.3 * np.eye(2), loglik=True, backend="numba", on_divergence="mark"))
    assert build.loop_of(flt)[3] == (2, 2, 2, None) and not out[1].diverged.any()
    for a, b in ((out[0].means, out[1].means), (out[0].covs, out[1].covs),
                 (out[0].extras["loglik"], out[1].extras["loglik"])):
        np.testing.assert_array_equal(a, b)


def test_the_return_flag_does_not_take_a_local_of_the_callee():
    """A return inside a loop sets a flag; a callee local of the same name stays its own."""
    callee = ("def k(a):\n    done = 0\n    for i in range(3):\n        if a[i] < 0:\n            return i\n"
              "        done += 1\n    return -done\n")
    flat = flatten("def root(a):\n    x = k(a)\n    return x\n", {"k": callee})
    for a, want in (([1, 2, 3], -3), ([1, -2, 3], 1)):
        assert _run(flat, "root", {}, a) == want
