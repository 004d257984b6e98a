"""What a model file states beyond one model with numbers (the hooks of :mod:`nlfilter.modelfile`):
parameters kept as symbols and covariances in them (:func:`at_values`), a spec with other parameter
values (:func:`spec_with_params`, ``ModelSpec.with_params``), the measurement names (the columns of
a data file, :mod:`nlfilter.data_csv`) and the ``continuous-discrete`` kind with its measurement
times.

The parameters of a file stay SymPy symbols of the model (``params=``): a model with other values is
:meth:`~nlfilter.models.Model.with_params` (no code generated again), which is what
:func:`~nlfilter.fitting.fit` and ``nlfilter fit MODEL.toml DATA.csv --params q,r`` need. A
covariance (``Q``, ``R``, the prior's ``cov``) in the parameters is checked symmetric and positive
(semi-)definite at the file's values; the model evaluates it at every value it is given.
"""

from __future__ import annotations

import pathlib
import re
import tomllib

import numpy as np
import sympy as sp

#: the kinds of model a file may state: the dynamics' and the measurement's keys of each
KINDS = ("discrete", "sde", "continuous-discrete")


def read_toml(path, error):
    """``(name, bytes, text, document)`` of the TOML file ``path``; an unreadable file, bytes that
    are not UTF-8 or a TOML syntax error raise ``error`` (:class:`~nlfilter.modelfile.ModelFileError`)
    with one line ``FILE:LINE: FIELD: ...`` (the line and column ``tomllib`` reports)."""
    name = str(path)
    try:
        data = pathlib.Path(path).read_bytes()
    except OSError as exc:
        raise error(f"{name}:1: file: got {type(exc).__name__} ({exc.strerror or exc}); expected a "
                             "readable TOML model file") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{name}:1: file: got bytes that are not UTF-8 ({exc.reason}); expected a TOML "
                             "file (UTF-8 text)") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        at = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        line = int(at.group(1)) if at else max(1, len(text.splitlines()))
        where = f"column {at.group(2)}" if at else "the end of the file"
        msg = re.sub(r"\s*\(at (line \d+, column \d+|end of document)\)", "", msg)
        raise error(f"{name}:{line}: toml: got invalid TOML at {where} ({msg}); expected a valid TOML "
                             "file") from None
    return name, data, text, doc


def at_values(rd, table: str, key: str, E: sp.Matrix) -> np.ndarray:
    """The covariance ``E`` (a SymPy matrix of numbers and parameters) at the file's parameter
    values, as floats; a matrix in the parameters is recorded in ``rd.symbolic[(table, key)]``
    (the model keeps it as an expression). A value that is not a real number is an error naming
    the field."""
    if E.free_symbols:
        rd.symbolic[(table, key)] = E
    if E.free_symbols & {sp.Symbol(s) for s in rd.states}:
        return None  # R in the states (a discrete model): checked at the prior's mean (check_R)
    out = np.empty(E.shape)
    for i in range(E.rows):
        for j in range(E.cols):
            e = E[i, j].subs(rd.values) if E[i, j].free_symbols else E[i, j]
            try:
                out[i, j] = float(e)
            except (TypeError, ValueError):
                rd.fail(table, key, f"got {E[i, j]} = {e} at the parameters' values; expected a real number",
                        field=f"{table}.{key}[{i}][{j}]")
    return out


def positive_parameters(spec) -> dict:
    """``{name: (0, None)}``: the parameters of ``spec`` that appear on the diagonal of a noise
    covariance (``Q``, ``R``, the prior's ``cov``) with a positive value in the file — scales, which
    ``nlfilter fit`` moves on the log scale (:func:`~nlfilter.fitting.fit`'s ``bounds``)."""
    out = {}
    values = spec.model.params
    for M in (spec.symbolic or {}).values():
        for i in range(min(M.shape)):
            for s in M[i, i].free_symbols:
                if str(s) in values and np.ndim(values[str(s)]) == 0 and values[str(s)] > 0:
                    out[str(s)] = (0.0, None)
    return out


def spec_with_params(spec, values=None, /, **named):
    """``spec`` (a :class:`~nlfilter.modelfile.ModelSpec`) with other parameter values: its model's
    :meth:`~nlfilter.models.Model.with_params` and the prior covariance evaluated again when it is in
    the parameters (checked positive semi-definite: a ``ValueError`` naming ``P0`` otherwise)."""
    model = spec.model.with_params(values, **named)
    P0 = spec.P0
    prior = (spec.symbolic or {}).get(("prior", "cov"))
    if prior is not None:
        sub = {model.symbol(k): v for k, v in model.params.items()}
        P0 = np.array(prior.subs(sub).evalf(), dtype=float)
        scale = max(1.0, float(np.max(np.abs(P0))))
        if not np.all(np.isfinite(P0)) or float(np.min(np.linalg.eigvalsh(P0))) < -1e-10 * scale:
            raise ValueError(f"P0: the prior covariance {prior.tolist()} is {P0.tolist()} at {dict(model.params)}; "
                             "expected a finite positive semi-definite matrix")
    return spec._replace(model=model, P0=P0)


def measurement_times(rd, table: dict, kind: str):
    """``(dt, times)`` of ``[measurement]``: an SDE's ``dt`` (required); a continuous-discrete
    model's ``dt`` (regular times ``dt, 2 dt, ...``) or ``times`` (a list of strictly increasing
    times after the prior's, 0), or neither (the data's ``t`` column gives them), never both;
    ``(None, None)`` for a discrete model."""
    from ._validate import measurement_times as check

    if kind == "discrete":
        return None, None
    dt = float(rd.number("measurement", "dt", table["dt"], positive=True)) if "dt" in table else None
    if "times" not in table:
        return dt, None
    if dt is not None:
        rd.fail("measurement", "times", "got both dt and times; expected one of them (regular or given times)")
    value = table["times"]
    if not isinstance(value, list) or not value:
        rd.fail("measurement", "times", f"got {value!r}; expected a non-empty list of increasing times")
    for v in value:
        rd.number("measurement", "times", v)
    try:
        return None, tuple(check("times", [float(v) for v in value]).tolist())
    except ValueError as exc:
        rd.fail("measurement", "times", str(exc).partition(": ")[2])


def noise_names(rd, table: str, value: dict, taken: dict) -> dict:
    """``{name: Symbol}`` of the non-additive noise of ``[dynamics]`` (``noise = ["w"]``:
    ``x[k+1] = f(x, w)``, ``Q`` the covariance of w, no ``G``) or ``[measurement]`` (``noise =
    ["v"]``: ``y = h(x, v)``, ``R`` the covariance of v); names distinct from ``taken`` (the states,
    the parameters, the other noise). Empty when not given."""
    if "noise" not in value:
        return {}
    names = rd.names(table, "noise", value["noise"])
    clash = [s for s in names if s in taken]
    if clash:
        rd.fail(table, "noise", f"got the name {clash[0]!r}, already a state, parameter or noise; expected new names")
    if table == "dynamics" and "G" in value:
        rd.fail(table, "G", "got G with a non-additive noise; expected no G (the noise enters f: x[k+1] = f(x, w))")
    return {s: sp.Symbol(s) for s in names}


def check_R(rd, model, m0) -> None:
    """A measurement covariance in the states, ``R(x)``, positive definite at the prior's mean
    ``m0`` (where else it is not is named by the model when it is evaluated: ``Model.R_of``)."""
    if getattr(model, "R_constant", True):
        return
    try:
        model.R_of(np.asarray(m0, dtype=float)[None, :], 0)
    except ValueError as exc:
        rd.fail("measurement", "R", f"got R(x) that is not positive definite at the prior's mean {np.asarray(m0).tolist()} "
                                    f"({str(exc).splitlines()[0]}); expected a covariance")


def measurement_names(rd, table: dict, m: int) -> tuple:
    """The measurements' names (``[measurement] names``: the columns of a data file), default
    ``y1 .. ym``; distinct identifiers, one per entry of ``h``, none of them ``t`` or ``path``."""
    if "names" not in table:
        return tuple(f"y{i + 1}" for i in range(m))
    names = rd.names("measurement", "names", table["names"])
    if len(names) != m:
        rd.fail("measurement", "names", f"got {len(names)} name(s); expected {m} (one per entry of h)")
    for s in names:
        if s in ("t", "path"):
            rd.fail("measurement", "names", f"got the name {s!r}; expected a name other than 't' and 'path' (the "
                                            "columns of the times and of the record in a data file)")
    return tuple(names)


class Lines:
    """Where tables and keys sit in the file's text (tomllib gives values, not positions):
    ``line(table, key)`` is the line of ``key`` within ``table`` (header or dotted key), else
    that of the table's header, else 1."""

    _HEADER = re.compile(r"^\s*\[\[?\s*([^\[\]]+?)\s*\]\]?\s*(#.*)?$")
    _KEY = re.compile(r"""^\s*((?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*'))*)\s*=(?!=)""")

    def __init__(self, text: str):
        self.tables, self.keys = {}, {}
        table = ()
        for no, line in enumerate(text.splitlines(), 1):
            h = self._HEADER.match(line)
            if h:
                table = self._parts(h.group(1))
                self.tables.setdefault(table, no)
                continue
            k = self._KEY.match(line)
            if k:
                path = table + self._parts(k.group(1))
                for i in range(1, len(path)):
                    self.tables.setdefault(path[:i], no)
                self.keys.setdefault(path, no)

    @staticmethod
    def _parts(dotted: str) -> tuple:
        return tuple(p.strip().strip("\"'") for p in re.findall(r"""(?:"[^"]*"|'[^']*'|[^.]+)""", dotted))

    def line(self, table: str, key: str | None = None) -> int:
        if key is not None and (table, key) in self.keys:
            return self.keys[(table, key)]
        if key is not None and (table, key) in self.tables:  # a sub-table [table.key]
            return self.tables[(table, key)]
        if (table,) in self.tables:
            return self.tables[(table,)]
        return self.keys.get((table,), 1)  # an inline table: `model = {...}`




def filters(rd, value):
    """``"all"`` or a tuple of registry names (a list in the file)."""
    from .filters import REGISTRY

    if value == "all":
        return "all"
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        rd.fail("run", "filters", f"got {value!r}; expected \"all\" or a non-empty list of registry names")
    unknown = [v for v in value if v not in REGISTRY]
    if unknown:
        rd.fail("run", "filters", f"got the unknown filter(s) {unknown}; expected registry names from "
                                  f"{sorted(REGISTRY)}")
    return tuple(dict.fromkeys(value))


__all__ = ["measurement_times", "noise_names", "check_R", "KINDS", "at_values", "positive_parameters", "spec_with_params", "measurement_names"]
