"""Models as files: a stochastic model, its prior and a comparison's defaults in a small TOML file
(:func:`load_model`; ``nlfilter compare MODEL.toml`` runs every filter that applies against the
certified reference).

The file
--------
A pendulum observed through the sine of its angle (``examples/models/pendulum.toml``)::

    [model]
    name = "pendulum"              # optional (default: the file's name)
    kind = "discrete"              # "discrete": x[k+1] = f + G w, y = h + v
                                   # "sde": dx = drift dt + diffusion dβ, dy = h dt + dη
                                   # "continuous-discrete": the sde's dx, y(t_k) = h + v_k
    states = ["theta", "omega"]
    # angles = { states = ["theta"], measurements = [0] }   # optional: angular components, wrapped
                                   # to (−π, π] (states by name, measurements by index into h)

    [parameters]                   # optional: numbers; they stay symbols of the model (fit them)
    g = 9.81
    dt = 0.05

    [dynamics]
    f = ["theta + dt*omega", "omega - dt*g*sin(theta)"]   # an SDE: drift = [...]
    G = [["0"], ["1"]]             # optional noise input (n × r; default the identity); an SDE: diffusion
    # noise = ["w"]                # discrete only: non-additive noise, f in w (then no G; Q: Cov w)
    Q = [[0.001]]                  # optional r × r covariance of w (an SDE: intensity, E dβ dβᵀ = Q dt);
                                   # default the identity
    [measurement]
    h = ["sin(theta)"]
    R = [[0.1]]                    # m × m, positive definite (an SDE: intensity, E dη dηᵀ = R dt);
                                   # discrete: may use the states, R(x) ("0.1 + theta**2")
    # noise = ["v"]                # discrete only: non-additive noise, h in v (R: Cov v)
    # dt = 0.01                    # an SDE only (required there): the measurement interval
    # names = ["y"]                # optional: the measurements' names (a data file's columns;
                                   # default y1 .. ym)

    [prior]                        # x[0] ~ N(mean, cov); every filter starts there
    mean = [1.0, 0.0]
    cov = [[0.1, 0], [0, 0.1]]     # or its diagonal: [0.1, 0.1]

    [run]                          # optional defaults of `nlfilter compare` (its options override them)
    steps = 200                    # default 100
    paths = 200                    # default 200 (at least 2)
    filters = "all"                # or a list of registry names (`nlfilter list --filters`)
    seed = 0                       # default 0

Expressions (the entries of ``f``/``drift``, ``G``/``diffusion`` and ``h``) are strings (or plain
numbers) in the declared states, the parameters, the constants ``pi`` and ``E``, and the functions
``sin cos tan asin acos atan atan2 sinh cosh tanh exp log sqrt Abs sign erf Min Max``, with
``+ - * / **`` and parentheses; any other name (a typo), any other syntax (attribute access,
indexing, strings, ``^``: powers are ``**``) is an error naming it, and nothing in a file is ever
evaluated as Python. The covariances ``Q``, ``R`` and ``cov`` hold numbers, or strings in the
parameters only (``"q*dt"``); each is checked symmetric and positive semi-definite (``R``
positive definite: the reference filters need its density).

Parameters, measurement times, data
-----------------------------------
The parameters stay SymPy symbols of the model (``params=``, :mod:`nlfilter.modelfile_kinds`):
``load_model(path).with_params(q=0.2)`` is the spec with another value (the model's
:meth:`~nlfilter.models.Model.with_params`, no code generated again, and the prior's ``cov``
evaluated again when it is in the parameters), and ``nlfilter fit MODEL.toml DATA.csv --params
q,r`` estimates them (maximum likelihood, :func:`~nlfilter.fitting.fit`; a parameter on the
diagonal of a covariance is moved on the log scale). A covariance in the parameters is checked
at the file's values. ``kind = "continuous-discrete"`` states an SDE (``drift``, ``diffusion``, as
``"sde"``) measured at discrete times ``y_k = h(x(t_k)) + v_k``, ``v_k ~ N(0, R)``, the prior at
time 0: ``[measurement]`` gives ``dt`` (regular times ``dt, 2 dt, ...``), or ``times = [0.1, 0.35,
...]`` (strictly increasing, after 0: irregular intervals), or neither (a data file's ``t`` column
gives them); never both. ``nlfilter simulate MODEL.toml --out DATA.csv`` writes data (a CSV
whose columns are the measurements' names and ``t``: :mod:`nlfilter.data_csv`, which checks a
data file against its model), ``nlfilter compare`` runs the continuous-discrete filters at the
file's times (:mod:`nlfilter.modelfile_times`).

Errors
------
Every problem raises :class:`ModelFileError` (a ``ValueError``) with one line
``FILE:LINE: FIELD: what was given; what was expected``, ``LINE`` the line of the offending key
(or of its table), e.g. ``pendulum.toml:13: dynamics.Q: got a 2×2 matrix; expected 1×1 (r × r,
r = 1: the columns of G)``. Unknown tables and keys are refused with the expected ones (a typo is
never ignored); a TOML syntax error keeps the line and column ``tomllib`` reports.

>>> import pathlib, tempfile
>>> text = '''
... [model]
... kind = "discrete"
... states = ["x"]
... [dynamics]
... f = ["0.9*x"]
... Q = [[0.1]]
... [measurement]
... h = ["x**3"]
... R = [[0.5]]
... [prior]
... mean = [0.0]
... cov = [[1.0]]
... '''
>>> with tempfile.TemporaryDirectory() as d:
...     path = pathlib.Path(d, "cubic.toml"); _ = path.write_text(text)
...     spec = load_model(path)
>>> spec.model, spec.steps, spec.dt, spec.m0.tolist()
(DiscreteModel(n=1, m=1, r=1, cubic), 100, None, [0.0])
"""

from __future__ import annotations

import hashlib
import io
import keyword
import numbers
import pathlib
import re
import tokenize
from typing import NamedTuple

import numpy as np
import sympy as sp

from ._modelexpr import (CONSTANTS, FUNCTIONS, MAX_CHARS, MAX_STATES, MAX_WORK, ExpressionError, clip,
                         finite_double, read_expression, short)
from .modelfile_kinds import KINDS, at_values, check_R, filters as _filters, measurement_names, measurement_times, noise_names
from .modelfile_kinds import read_toml, spec_with_params
from .modelfile_kinds import Lines as _Lines
from .models import DiscreteModel, SDEModel

_NUMBERS = {"Integer": sp.Integer, "Float": sp.Float, "Rational": sp.Rational}  # reserved: SymPy's number names
RESERVED = set(FUNCTIONS) | set(CONSTANTS) | set(_NUMBERS)
_OPERATORS = {"+", "-", "*", "/", "**", "(", ")", ","}

DEFAULTS = {"steps": 100, "paths": 200, "filters": "all", "seed": 0}

# the schema: table -> {key: required?}; the dynamics' keys depend on the kind
_TABLES = {
    "model": {"name": False, "kind": True, "states": True, "angles": False},
    "parameters": None,  # any identifier
    "dynamics": None,    # by kind, below
    "measurement": None,
    "prior": {"mean": True, "cov": True},
    "run": {"steps": False, "paths": False, "filters": False, "seed": False},
}
_REQUIRED_TABLES = ("model", "dynamics", "measurement", "prior")
_DYNAMICS = {"discrete": {"f": True, "G": False, "Q": False, "noise": False}, "sde": {"drift": True, "diffusion": False, "Q": False}}
_DYNAMICS["continuous-discrete"] = _DYNAMICS["sde"]
_MEASUREMENT = {"discrete": {"h": True, "R": True, "names": False, "noise": False},
                "sde": {"h": True, "R": True, "dt": True, "names": False},
                "continuous-discrete": {"h": True, "R": True, "dt": False, "times": False, "names": False}}


class ModelFileError(ValueError):
    """A model file that cannot be read: ``FILE:LINE: FIELD: what was given; what was expected``."""


class ModelSpec(NamedTuple):
    """What a model file states: the built ``model`` (:class:`~nlfilter.models.DiscreteModel` or
    :class:`~nlfilter.models.SDEModel`), the prior ``m0 (n,)``, ``P0 (n, n)``, the measurement
    interval ``dt`` (an SDE; ``None`` for a discrete model), the comparison's defaults ``steps``,
    ``paths``, ``filters`` (``"all"`` or a tuple of registry names) and ``seed``, and the file's
    ``path`` and the ``sha256`` of its bytes."""

    model: object
    m0: np.ndarray
    P0: np.ndarray
    dt: float | None
    steps: int
    paths: int
    filters: object
    seed: int
    path: str
    sha256: str
    kind: str = "discrete"
    names: tuple = ()
    symbolic: dict | None = None
    times: tuple | None = None

    def with_params(self, values=None, /, **named) -> ModelSpec:
        """This spec with other parameter values (a dict by name, or keywords): the model's
        :meth:`~nlfilter.models.Model.with_params` and the prior's covariance when it is in the
        parameters (:func:`~nlfilter.modelfile_kinds.spec_with_params`)."""
        return spec_with_params(self, values, **named)


class _Reader:
    """One file's checks: every error names the file, the line and the field."""

    def __init__(self, path: str, text: str):
        self.path, self.lines = path, _Lines(text)
        self.states = ()  # the model's state names, once read (the expressions' degree bounds)
        self.work = 0  # Σ (SymPy nodes × states used) over the expressions read (MAX_WORK)
        self.values = {}  # parameter symbol -> its value in the file (the parameters stay symbols)
        self.symbolic = {}  # (table, key) -> the SymPy matrix of a covariance in the parameters

    def fail(self, table: str, key: str | None, what: str, field: str | None = None):
        field = field or (f"{table}.{key}" if key else table)
        raise ModelFileError(f"{self.path}:{self.lines.line(table, key)}: {field}: {what}")

    def table(self, doc: dict, name: str, required: bool) -> dict:
        value = doc.get(name)
        if value is None:
            if required:
                self.fail(name, None, f"got no [{name}] table; expected one (the tables a model file needs: "
                                      f"{', '.join(f'[{t}]' for t in _REQUIRED_TABLES)})")
            return {}
        if not isinstance(value, dict):
            self.fail(name, None, f"got the value {value!r}; expected a table [{name}]")
        return value

    def keys(self, table: str, value: dict, schema: dict, note: str = "") -> None:
        for key in value:
            if key not in schema:
                self.fail(table, key, f"got the unknown key {key!r}; expected one of {sorted(schema)}{note}")
        for key, required in schema.items():
            if required and key not in value:
                self.fail(table, None, f"got no key {key!r}; expected the keys {[k for k, r in schema.items() if r]}"
                                       + (f" (optional: {[k for k, r in schema.items() if not r]})"
                                          if not all(schema.values()) else ""),
                          field=f"{table}.{key}")

    def string(self, table, key, value) -> str:
        if not isinstance(value, str) or not value:
            self.fail(table, key, f"got {value!r}; expected a non-empty string")
        return value

    def number(self, table, key, value, *, positive=False, integer=False, minimum=None):
        ok = (isinstance(value, numbers.Integral) if integer else isinstance(value, numbers.Real))
        if isinstance(value, bool) or not ok:
            self.fail(table, key, f"got {value!r}; expected {'an integer' if integer else 'a number'}")
        if not finite_double(value):
            self.fail(table, key, f"got {short(value)}; expected a finite number (a double)")
        if positive and value <= 0:
            self.fail(table, key, f"got {value!r}; expected a positive {'integer' if integer else 'number'}")
        if minimum is not None and value < minimum:
            self.fail(table, key, f"got {value!r}; expected an integer ≥ {minimum}")
        return value

    def names(self, table, key, value) -> list:
        if not isinstance(value, list) or not value or not all(isinstance(s, str) for s in value):
            self.fail(table, key, f"got {value!r}; expected a non-empty list of names (strings)")
        for s in value:
            if not s.isidentifier() or keyword.iskeyword(s) or "__" in s or s in RESERVED:
                self.fail(table, key, f"got the name {s!r}; expected an identifier that is not a Python keyword, "
                                      f"has no '__' and is not one of the reserved names {sorted(RESERVED)}")
        if len(set(value)) != len(value):
            self.fail(table, key, f"got {value!r}; expected distinct names")
        return value

    # -- expressions ---------------------------------------------------------------------------
    def expr(self, table, key, field, value, allowed: dict, what: str) -> sp.Expr:
        """A SymPy expression from a string (or a number) in the names of ``allowed`` only."""
        if isinstance(value, bool) or not isinstance(value, (str, numbers.Real)):
            self.fail(table, key, f"got {value!r}; expected an expression (a string) or a number", field)
        if isinstance(value, numbers.Real):
            if not finite_double(value):
                self.fail(table, key, f"got {short(value)}; expected a finite number (a double)", field)
            return sp.Integer(value) if isinstance(value, numbers.Integral) else sp.Float(value)
        text = value
        if len(text) > MAX_CHARS:
            self.fail(table, key, f"got an expression of {len(text)} characters; expected at most {MAX_CHARS}", field)
        try:
            tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))
        except (tokenize.TokenError, SyntaxError, IndentationError) as exc:
            self.fail(table, key, f"got {clip(text)!r} ({exc.args[0]}); expected an expression", field)
        for tok in tokens:
            if tok.type in (tokenize.NEWLINE, tokenize.NL, tokenize.ENDMARKER, tokenize.NUMBER):
                continue
            if tok.type == tokenize.NAME:
                if tok.string not in allowed and tok.string not in FUNCTIONS and tok.string not in CONSTANTS:
                    self.fail(table, key, f"got the unknown name {tok.string!r} in {clip(text)!r}; expected {what}, the "
                                          f"constants pi, E or the functions {' '.join(FUNCTIONS)}", field)
                continue
            if tok.type == tokenize.OP and tok.string in _OPERATORS:
                continue
            hint = " (powers are **)" if tok.string == "^" else ""
            self.fail(table, key, f"got {tok.string!r} in {clip(text)!r}{hint}; expected names, numbers, + - * / ** "
                                  "and parentheses", field)
        for tok in tokens:  # decimal numbers only (no 0x10, 1_000, 2j)
            if tok.type == tokenize.NUMBER and not re.fullmatch(r"(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", tok.string):
                self.fail(table, key, f"got the number {tok.string!r} in {clip(text)!r}; expected a real decimal number",
                          field)
        try:  # bounded in time and memory; nothing is evaluated as Python (nlfilter._modelexpr)
            e = read_expression(text, allowed, self.states)
        except ExpressionError as exc:
            self.fail(table, key, str(exc), field)
        held = {p: v for p, v in self.values.items() if p in e.free_symbols}
        if held and e.subs(held).has(sp.zoo, sp.nan):  # the parameters stay symbols: x/a at the file's a = 0
            self.fail(table, key, f"got {clip(text)} (a division by zero at the file's parameter values "
                                  f"{', '.join(f'{p} = {v}' for p, v in held.items())}); expected a finite expression",
                      field)
        used = len(e.free_symbols)
        if used:  # what the model's derivatives will cost (MAX_WORK)
            self.work += used * sum(1 for _ in sp.preorder_traversal(e))
            if self.work > MAX_WORK:
                self.fail(table, key, f"got expressions whose size times the states they use totals {self.work:,} "
                                      f"by this one; expected at most {MAX_WORK:,} in one file (MAX_WORK: the "
                                      "model differentiates each expression by each of its states)", field)
        return e

    def vector(self, table, key, value, n, allowed, what) -> list:
        if not isinstance(value, list) or not value:
            self.fail(table, key, f"got {value!r}; expected a non-empty list of expressions (strings)")
        if n is not None and len(value) != n:
            self.fail(table, key, f"got {len(value)} expression(s); expected {n} (one per state)")
        return [self.expr(table, key, f"{table}.{key}[{i}]", v, allowed, what) for i, v in enumerate(value)]

    def matrix(self, table, key, value, allowed, what, rows=None, cols=None, why="") -> list:
        """A list of equal-length lists of expressions; ``rows``/``cols`` fixed when given."""
        if (not isinstance(value, list) or not value or not all(isinstance(r, list) and r for r in value)
                or len({len(r) for r in value}) != 1):
            self.fail(table, key, f"got {value!r}; expected a matrix: a list of rows, each a non-empty list of "
                                  "the same length")
        shape = (len(value), len(value[0]))
        if (rows is not None and shape[0] != rows) or (cols is not None and shape[1] != cols):
            want = f"{rows if rows is not None else 'any'}×{cols if cols is not None else 'any'}"
            self.fail(table, key, f"got a {shape[0]}×{shape[1]} matrix; expected {want}{why}")
        return [[self.expr(table, key, f"{table}.{key}[{i}][{j}]", v, allowed, what) for j, v in enumerate(r)]
                for i, r in enumerate(value)]

    def covariance(self, table, key, value, size, params, why="", definite=False) -> np.ndarray:
        """A ``size × size`` symmetric PSD (PD with ``definite``) matrix of numbers (or strings in
        the parameters), or its diagonal (a list of ``size`` entries)."""
        what = f"numbers or the parameters {sorted(params)}" if params else "numbers"
        if not isinstance(value, list) or not value:
            self.fail(table, key, f"got {value!r}; expected a {size}×{size} matrix (a list of {size} rows) or its "
                                  f"diagonal (a list of {size} entries){why}")
        if isinstance(value, list) and value and not any(isinstance(r, list) for r in value):
            if len(value) != size:
                self.fail(table, key, f"got a diagonal of {len(value)} entries; expected {size}×{size} (or its "
                                      f"diagonal of {size}){why}")
            diag = [self.expr(table, key, f"{table}.{key}[{i}]", v, params, what) for i, v in enumerate(value)]
            E = sp.diag(*diag)
        else:
            E = sp.Matrix(self.matrix(table, key, value, params, what, size, size, why + f" (or its diagonal of {size})"))
        M = at_values(self, table, key, E)
        if M is None:  # R in the states: R(x), checked at the prior's mean (modelfile_kinds.check_R)
            return None
        if not np.all(np.isfinite(M)):
            self.fail(table, key, f"got {M.tolist()}; expected finite entries")
        scale = max(1.0, float(np.max(np.abs(M))))
        if np.max(np.abs(M - M.T)) > 1e-10 * scale:
            self.fail(table, key, f"got {M.tolist()}; expected a symmetric matrix")
        w = float(np.min(np.linalg.eigvalsh(M)))
        if w < -1e-10 * scale or (definite and w <= 1e-12 * scale):
            self.fail(table, key, f"got {M.tolist()} (smallest eigenvalue {w:.3g}); expected a positive "
                                  f"{'definite' if definite else 'semi-definite'} matrix")
        return M


def load_model(path) -> ModelSpec:
    """Read a model file (module docstring): the model built from it, its prior and the
    comparison's defaults, as a :class:`ModelSpec`.

    Parameters
    ----------
    path : str or path-like, a TOML file

    Raises
    ------
    ModelFileError
        (a ``ValueError``) one line ``FILE:LINE: FIELD: what was given; what was expected``, for a
        missing or unreadable file, a TOML syntax error, an unknown table or key, a name an
        expression does not declare, a wrong shape, a non-finite number or a covariance that is
        not positive semi-definite.
    """
    if not isinstance(path, (str, pathlib.PurePath)):
        raise TypeError(f"path: expected a file path (str or pathlib.Path), got {type(path).__name__}")
    name, data, text, doc = read_toml(path, ModelFileError)
    rd = _Reader(name, text)
    for key, value in doc.items():
        if key not in _TABLES:
            what = (f"the unknown table [{key}]" if isinstance(value, dict) else f"the key {key!r} outside any table")
            rd.fail(key, None, f"got {what}; expected the tables {', '.join(f'[{t}]' for t in _TABLES)}")
        if not isinstance(value, dict):
            rd.fail(key, None, f"got the value {value!r}; expected a table [{key}]")

    # [model]
    mt = rd.table(doc, "model", True)
    rd.keys("model", mt, _TABLES["model"])
    kind = rd.string("model", "kind", mt["kind"])
    if kind not in _DYNAMICS:
        rd.fail("model", "kind", f"got {kind!r}; expected one of {', '.join(map(repr, KINDS))}")
    states = rd.names("model", "states", mt["states"])
    if len(states) > MAX_STATES:
        rd.fail("model", "states", f"got {len(states)} states; expected at most {MAX_STATES} (MAX_STATES)")
    rd.states = tuple(states)
    title = rd.string("model", "name", mt["name"]) if "name" in mt else pathlib.Path(name).stem
    n = len(states)
    syms = {s: sp.Symbol(s) for s in states}

    # [parameters]
    pt = rd.table(doc, "parameters", False)
    params = {}
    for key, value in pt.items():
        if not isinstance(key, str) or not key.isidentifier() or keyword.iskeyword(key) or "__" in key \
                or key in RESERVED:
            rd.fail("parameters", key, f"got the name {key!r}; expected an identifier that is not a Python keyword, "
                                       f"has no '__' and is not one of the reserved names {sorted(RESERVED)}")
        if key in syms:
            rd.fail("parameters", key, f"got {key!r}, a state's name; expected a parameter name distinct from the "
                                       f"states {states}")
        rd.number("parameters", key, value)
        params[key] = sp.Symbol(key)  # kept a symbol: ModelSpec.with_params, nlfilter fit
        rd.values[params[key]] = value
    allowed = {**syms, **params}
    what = f"a state {states}" + (f" or a parameter {sorted(params)}" if params else "")

    # [dynamics]
    dt_ = rd.table(doc, "dynamics", True)
    fkey, gkey = ("f", "G") if kind == "discrete" else ("drift", "diffusion")
    rd.keys("dynamics", dt_, _DYNAMICS[kind], f" (kind = {kind!r}: " + ("x[k+1] = f + G w)" if kind == "discrete" else
                                                                       "dx = drift dt + diffusion dβ)"))
    wn = noise_names(rd, "dynamics", dt_, allowed)  # non-additive noise: its symbols in f
    f = rd.vector("dynamics", fkey, dt_[fkey], n, {**allowed, **wn}, what + (f" or a noise {list(wn)}" if wn else ""))
    G = None
    if gkey in dt_:
        G = rd.matrix("dynamics", gkey, dt_[gkey], allowed, what, rows=n, why=f" (n × r, n = {n} states)")
    r = len(wn) if wn else n if G is None else len(G[0])
    Q = (rd.covariance("dynamics", "Q", dt_["Q"], r, params,
                       f" (r × r, r = {r}: the columns of {gkey})" if G is not None else
                       f" (r × r, r = n = {n}: {gkey} is the identity)")
         if "Q" in dt_ else np.eye(r))

    # [measurement]
    mt_ = rd.table(doc, "measurement", True)
    rd.keys("measurement", mt_, _MEASUREMENT[kind], " (dt: an SDE's measurement interval)" if kind == "discrete" else "")
    vn = noise_names(rd, "measurement", mt_, {**allowed, **wn})
    h = rd.vector("measurement", "h", mt_["h"], None, {**allowed, **vn}, what + (f" or a noise {list(vn)}" if vn else ""))
    m = len(h)
    R = rd.covariance("measurement", "R", mt_["R"], len(vn) or m, {**params, **(syms if kind == "discrete" else {})},
                      f" (p × p, p = {len(vn)}: the noises of h)" if vn else f" (m × m, m = {m}: the entries of h)",
                      definite=True)
    dt, times = measurement_times(rd, mt_, kind)
    names = measurement_names(rd, mt_, m)

    # [prior]
    pr = rd.table(doc, "prior", True)
    rd.keys("prior", pr, _TABLES["prior"])
    mean = pr["mean"]
    if not isinstance(mean, list) or len(mean) != n:
        rd.fail("prior", "mean", f"got {mean!r}; expected a list of {n} numbers (one per state {states})")
    m0 = np.array([float(rd.number("prior", "mean", v)) for v in mean])
    P0 = rd.covariance("prior", "cov", pr["cov"], n, params, f" (n × n, n = {n} states)")

    # [run]
    rn = rd.table(doc, "run", False)
    rd.keys("run", rn, _TABLES["run"])
    run = dict(DEFAULTS)
    if "steps" in rn:
        run["steps"] = int(rd.number("run", "steps", rn["steps"], integer=True, positive=True))
    if "paths" in rn:
        run["paths"] = int(rd.number("run", "paths", rn["paths"], integer=True, minimum=2))
    if "seed" in rn:
        run["seed"] = int(rd.number("run", "seed", rn["seed"], integer=True, minimum=0))
        if run["seed"] > 2**63 - 1:  # the results store keeps a seed as a 64-bit SQLite INTEGER
            rd.fail("run", "seed", f"got {run['seed']}; expected an integer from 0 to 2**63 - 1")
    if "filters" in rn:
        run["filters"] = _filters(rd, rn["filters"])

    cls = DiscreteModel if kind == "discrete" else SDEModel
    try:
        model = cls(list(syms.values()), f, h, G=G, Q=rd.symbolic.get(("dynamics", "Q"), Q),
                    R=rd.symbolic.get(("measurement", "R"), R), params=rd.values, name=title,
                    angles=mt.get("angles"),
                    **({"noise": list(wn.values()) or None, "meas_noise": list(vn.values()) or None} if wn or vn else {}))
    except (ValueError, TypeError) as exc:  # what the checks above do not anticipate
        text = str(exc).splitlines()[0]
        # the model's message names its argument (f, h, G, Q, R): the file's key, at its line
        arg, _, rest = text.partition(": ")
        where = {"f": ("dynamics", fkey), "G": ("dynamics", gkey), "Q": ("dynamics", "Q"),
                 "h": ("measurement", "h"), "R": ("measurement", "R"), "angles": ("model", "angles")}.get(arg)
        if arg == "angles" and rest:  # the declaration's own message: what was given, what was expected
            rd.fail("model", "angles", rest)
        if where is not None and rest:
            rd.fail(*where, f"got an expression the library refuses ({rest}); expected a valid {cls.__name__}")
        rd.fail("dynamics", None, f"got a model the library refuses ({text}); expected a "
                                  f"valid {cls.__name__}", field="model")
    check_R(rd, model, m0)
    return ModelSpec(model, m0, P0, dt, run["steps"], run["paths"], run["filters"], run["seed"], name,
                     hashlib.sha256(data).hexdigest(), kind, names, rd.symbolic, times)


__all__ = ["ModelFileError", "ModelSpec", "load_model"]
