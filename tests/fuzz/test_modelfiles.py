"""Fuzz of model files (issue 26): hostile expressions from a small seeded grammar — deep nesting,
towers of powers, huge integers and exponents, constants that overflow a double, functions outside
their domain, unknown functions, Python injection — placed in every expression field of a valid
file, each loaded under a time limit (the harness's alarm) and a memory limit (``RLIMIT_AS``: what
the process has plus :data:`MEMORY`). A hostile expression must be refused ``named`` (a
``ModelFileError`` naming its key); an expression the generator cannot promise is hostile (a
random mix) must be ``named`` or load into a model whose every number is a finite double."""

from __future__ import annotations

import random
import resource

import pytest
import sympy as sp

from nlfilter.modelfile import ModelFileError, load_model

MEMORY = 1 << 30  # bytes a case may add to the process's address space (the 9**9**9 integer took ~1.5 GB)
LIMIT = 10.0  # seconds per case (a bounded parse takes milliseconds; the harness's default is 20)
SEED = 26

FIELDS = {  # key -> (old text in BASE, format of the new text, names the error must carry)
    "dynamics.f": ('"0.9*x + 0.1*y"', '"{}"', "dynamics.f"),
    "dynamics.G": ('[["1"], ["0.5"]]', '[["{}"], ["0.5"]]', "dynamics.G"),
    "dynamics.Q": ("Q = [[0.1]]", 'Q = [["{}"]]', "dynamics.Q"),
    "measurement.h": ('h = ["x"]', 'h = ["{}"]', "measurement.h"),
    "measurement.R": ("R = [[0.5]]", 'R = [["{}"]]', "measurement.R"),
    "prior.cov": ("cov = [1.0, 1.0]", 'cov = ["{}", 1.0]', "prior.cov"),
}
BASE = """\
[model]
kind = "discrete"
states = ["x", "y"]
[parameters]
q = 0.1
[dynamics]
f = ["0.9*x + 0.1*y", "0.8*y"]
G = [["1"], ["0.5"]]
Q = [[0.1]]
[measurement]
h = ["x"]
R = [[0.5]]
[prior]
mean = [0.0, 0.0]
cov = [1.0, 1.0]
"""


class _Grammar:
    """Hostile expressions; ``hostile(kind)`` is refused by construction, ``wild()`` may not be."""

    ATOMS = ["x", "y", "q", "2", "0.5", "pi", "E", "1e-3"]
    FUNCS = ["sin", "cos", "exp", "log", "sqrt", "atan", "tanh", "Abs", "erf"]

    def __init__(self, seed):
        self.r = random.Random(seed)

    def wild(self, depth=4) -> str:
        r = self.r
        if depth == 0 or r.random() < 0.25:
            return r.choice(self.ATOMS)
        pick = r.random()
        if pick < 0.3:
            return f"{r.choice(self.FUNCS)}({self.wild(depth - 1)})"
        if pick < 0.5:
            return f"({self.wild(depth - 1)})**{r.choice(['2', '3', '0.5', '-1', str(r.randint(4, 40))])}"
        return f"({self.wild(depth - 1)}) {r.choice('+-*/')} ({self.wild(depth - 1)})"

    def hostile(self, kind: str) -> str:
        r = self.r
        w = self.wild(2)
        if kind == "tower":
            return "**".join(str(r.randint(3, 9)) for _ in range(r.randint(4, 6)))  # ≥ 3**3**3**3
        if kind == "exponent":
            return f"({w} + x)**{r.choice(['10**10', '100000', '2**20', str(r.randint(1025, 10**6))])}"
        if kind == "integer":
            return str(r.randint(1, 9)) + "0" * r.randint(309, 2000) + f"*({w})"
        if kind == "overflow":
            return r.choice([f"1e{r.randint(309, 5000)}*x", f"10**{r.randint(309, 1024)}*x", f"exp({r.randint(710, 10**6)})*x",
                             f"cosh({r.randint(711, 5000)})", f"exp(exp(exp({r.randint(10, 100)})))*x",
                             f"(1e{r.randint(155, 300)}*x)**{r.randint(2, 9)}"])
        if kind == "domain":
            return r.choice(["acos(2)", "asin(-3)", "log(0)", "log(-1)*x", "sqrt(-2)", "x/0", "1/(2-2)", "(-8)**(1/3)",
                             "tan(pi/2)*x", "0**-1"])
        if kind == "nesting":
            f = r.choice(self.FUNCS)
            n = r.randint(41, 120)
            return f"{f}(" * n + "x" + ")" * n
        if kind == "size":
            return " + ".join(f"{r.choice(self.FUNCS)}(x*{k})" for k in range(r.randint(400, 700)))
        if kind == "unknown":
            return r.choice([f"gamma({w})", f"foo(x)", "x.real", "x[0]", "x if y else 0", "x^2", "'x'", "x @ y",
                             "lambda: 0", "0x10*x", "2j*x", "x == y"])
        if kind == "injection":
            return r.choice(["__import__('os').system('false')", "().__class__.__bases__[0]", "eval('1')",
                             "open('/etc/passwd')", "exec('x=1')", "globals()", "x.__dict__", "getattr(x, 'p')"])
        if kind == "exact":
            return f"((10**{r.randint(100, 300)} + 1)/10**{r.randint(100, 300)})**{r.randint(200, 1024)}*x"
        raise AssertionError(kind)


KINDS = ("tower", "exponent", "integer", "overflow", "domain", "nesting", "size", "unknown", "injection", "exact")


def _limited(fn):
    """``fn`` under an address-space limit of what the process has plus :data:`MEMORY`."""
    def run():
        with open("/proc/self/status") as f:
            vm = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        cap = vm + MEMORY if hard == resource.RLIM_INFINITY else min(hard, vm + MEMORY)
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
        try:
            return fn()
        finally:
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    return run


def _cases():
    g = _Grammar(SEED)
    cases = []
    for kind in KINDS:
        for field in FIELDS:
            cases.append((f"{kind} in {field}", field, g.hostile(kind), True))
    for i in range(8):  # each that loads builds a model (~0.5 s): a few
        cases.append((f"wild #{i}", g.r.choice(["dynamics.f", "measurement.h"]), g.wild(5), False))
    return cases


CASES = _cases()


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("model-fuzz")


@pytest.mark.parametrize("label,field,expr,bad", CASES, ids=[c[0] for c in CASES])
def test_hostile_model_file_is_refused_by_name(fuzz, folder, label, field, expr, bad):
    old, new, name = FIELDS[field]
    path = folder / f"{label.replace(' ', '_').replace('#', '')}.toml"
    path.write_text(BASE.replace(old, new.format(expr.replace('"', "'")), 1))

    def load():
        spec = load_model(path)
        for M in (spec.model.sym[k] for k in ("f", "h", "G")):  # every number a finite double
            for a in (a for e in M for a in sp.preorder_traversal(e)):
                if a.is_Number:
                    float(a)  # OverflowError (raw) if not
                    assert abs(float(a)) < float("inf"), f"{a} in the model"
        return spec.P0

    outcome, detail = fuzz.check("model files", _limited(load), [name], bad=bad, limit=LIMIT, label=label)
    if outcome == "named":
        assert detail.startswith(f"{path}:") and ("; expected " in detail or len(detail) >= 200), detail


def test_injection_runs_nothing_in_any_field(folder):
    """The grammar's injection strings in every string field of a file (not only expressions):
    refused, and nothing they name happens (a marker file never appears)."""
    flag = folder / "PWNED"
    payload = f"__import__('os').system('touch {flag}')"
    for old, new in (('kind = "discrete"', f'kind = "{payload}"'), ('states = ["x", "y"]', f'states = ["x", "{payload}"]'),
                     ("q = 0.1", f'"{payload}" = 0.1'), ("mean = [0.0, 0.0]", f'mean = ["{payload}", 0.0]'),
                     ("[model]", f'[model]\nname = "{payload}"'), ("[prior]", f'[run]\nfilters = ["{payload}"]\n[prior]')):
        path = folder / "evil.toml"
        path.write_text(BASE.replace(old, new.replace("'", "\\'") if old == "q = 0.1" else new, 1))
        try:
            load_model(path)
        except ModelFileError as exc:
            assert str(exc).startswith(f"{path}:"), exc
    assert not flag.exists()
