"""The result table every experiment returns, the CLI prints and the JSON files keep.

JSON schema (kept by every experiment; :meth:`Result.from_json` reads it back)::

    {"experiment": str, "title": str, "source": str,
     "params": {...},            # the values that ran (quick overrides and Monte Carlo paths included)
     "rows": [{"filter": str, "quantity": str, "params": {...},
               "paper": number|null, "value": number, "stderr": number|null}],
     "notes": [str],             # what the table's numbers mean (verdicts, windows, divergences)
     "meta": {"experiment": str, "seed": int|null, "runs": int|null (as requested),
              "paths": int|{case: int}|null (as simulated), "quick": bool, "given": {...} (params as given),
              "command": str|null, "nlfilter": str, "numpy": str, "python": str,
              "timestamp": str (UTC, ISO 8601)}}

A row is identified by ``(filter, quantity, params)``: no two rows of a table share it.
Non-finite numbers (in rows, params and meta) are written as the strings ``"nan"``, ``"inf"`` and
``"-inf"`` (JSON has no such numbers) and read back as floats, so the round trip is exact; ``null``
is "none" (no paper value, no standard error). ``series`` (the figures' arrays) is not written.
"""

from __future__ import annotations

import contextlib
import json
import math
import platform
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any


@dataclass(frozen=True, eq=False)
class Row:
    """One measured number, with the paper's value beside it when the paper gives one."""

    filter: str
    quantity: str
    value: float
    stderr: float | None = None
    paper: float | None = None
    params: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"filter": self.filter, "quantity": self.quantity, "params": _encode(self.params),
                "paper": _num(self.paper), "value": _num(self.value), "stderr": _num(self.stderr)}

    @classmethod
    def from_dict(cls, d: dict) -> "Row":
        return cls(d["filter"], d["quantity"], _float(d["value"]), _float(d.get("stderr")),
                   _float(d.get("paper")), _decode(d.get("params", {})))

    def key(self) -> tuple:
        """What identifies the row in its table: ``(filter, quantity, params)``."""
        return (self.filter, self.quantity, json.dumps(_encode(self.params), sort_keys=True, default=_default))

    def __eq__(self, other):  # NaN equals NaN here: a row read back from JSON equals the row written
        if not isinstance(other, Row):
            return NotImplemented
        return (self.key() == other.key()
                and all(_same(a, b) for a, b in ((self.value, other.value), (self.stderr, other.stderr),
                                                 (self.paper, other.paper))))

    __hash__ = None


def _same(a, b) -> bool:
    return a == b or (a is not None and b is not None and math.isnan(a) and math.isnan(b))


_NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def _num(x):
    """A number as JSON keeps it: finite floats as numbers, NaN and ±inf as strings."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else "nan" if math.isnan(x) else "inf" if x > 0 else "-inf"


def _float(x):
    """Inverse of :func:`_num`."""
    if x is None:
        return None
    if isinstance(x, str):
        if x not in _NONFINITE:
            raise ValueError(f"number: expected a JSON number, null or one of {sorted(_NONFINITE)}, got {x!r}")
        return _NONFINITE[x]
    return float(x)


def _encode(o):
    """``o`` with numpy values as Python ones, tuples as lists and non-finite floats as strings."""
    if isinstance(o, dict):
        return {str(k): _encode(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_encode(v) for v in o]
    if isinstance(o, bool) or o is None or isinstance(o, (int, str)):
        return o
    if isinstance(o, float):
        return _num(o)
    return _encode(_default(o))


def _decode(o):
    """Inverse of :func:`_encode` (the strings ``"nan"``, ``"inf"``, ``"-inf"`` become floats)."""
    if isinstance(o, dict):
        return {k: _decode(v) for k, v in o.items()}
    if isinstance(o, list):
        return [_decode(v) for v in o]
    if isinstance(o, str) and o in _NONFINITE:
        return _NONFINITE[o]
    return o


def provenance(experiment: str, *, seed=None, runs=None, paths=None, quick=False, given=None,
               command=None) -> dict:
    """What ran, for ``Result.meta``: the experiment id, the seed, the Monte Carlo runs requested
    (``None``: the experiment's default) and the paths simulated, the quick flag, the parameters as
    given, the command line, the versions of nlfilter, numpy and Python, and a UTC timestamp."""
    import numpy as np

    from . import __version__

    return {"experiment": experiment, "seed": seed, "runs": runs, "paths": paths, "quick": bool(quick),
            "given": _encode(dict(given or {})), "command": command, "nlfilter": __version__,
            "numpy": np.__version__, "python": platform.python_version(),
            "timestamp": datetime.now(timezone.utc).isoformat(timespec="seconds")}


@dataclass
class Result:
    """An experiment's table, plus arrays for its figures (``series``, not written to JSON and not
    compared by ``==``), the notes that say what the numbers mean, and provenance (``meta``, see
    :func:`~nlfilter.results.provenance`). ``params`` are the values that ran: an experiment records each value it
    derives (a quick horizon, the number of paths) with :meth:`used`.

    >>> res = Result("demo", "a demo", "no paper", {"T": 1.0})
    >>> res.used("paths", 6)
    6
    >>> _ = res.add("kf", "mse", float("nan"), method="off-line")
    >>> _ = res.add("kf", "mse", 0.5, stderr=float("inf"), method="monte carlo")
    >>> res.add("kf", "mse", 0.4, method="off-line")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: row ('kf', 'mse', {'method': 'off-line'}): already in the table of 'demo'; ...
    >>> Result.from_json(res.to_dict()) == res
    True
    """

    experiment: str
    title: str
    source: str
    params: dict
    rows: list[Row] = field(default_factory=list)
    series: dict[str, Any] = field(default_factory=dict, compare=False)
    notes: list[str] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def add(self, filter: str, quantity: str, value, stderr=None, paper=None, **params) -> Row:
        """Append a row; ValueError if a row with the same ``(filter, quantity, params)`` exists."""
        row = Row(filter, quantity, float(value), None if stderr is None else float(stderr),
                  None if paper is None else float(paper), params)
        key = row.key()
        if any(r.key() == key for r in self.rows):
            raise ValueError(f"row {(filter, quantity, params)}: already in the table of {self.experiment!r}; "
                             "expected rows unique in (filter, quantity, params)")
        self.rows.append(row)
        return row

    def used(self, name: str, value):
        """Record ``value`` as the parameter ``name`` that ran (e.g. a quick run's horizon) -> ``value``."""
        self.params[name] = value
        return value

    def get(self, filter: str, quantity: str, **params) -> Row:
        """The single row matching ``filter``, ``quantity`` and the given row params."""
        hits = [r for r in self.rows if r.filter == filter and r.quantity == quantity
                and all(r.params.get(k) == v for k, v in params.items())]
        if len(hits) != 1:
            raise KeyError(f"{len(hits)} rows match filter={filter!r}, quantity={quantity!r}, {params}")
        return hits[0]

    def to_dict(self) -> dict:
        """The JSON form (module docstring); ``series`` is left out."""
        return {"experiment": self.experiment, "title": self.title, "source": self.source,
                "params": _encode(self.params), "rows": [r.to_dict() for r in self.rows],
                "notes": list(self.notes), "meta": _encode(self.meta)}

    def to_json(self, path) -> None:
        """Write the JSON form to ``path`` atomically (a temporary file beside it, then renamed):
        an interrupted write never leaves a truncated file."""
        text = json.dumps(self.to_dict(), indent=2, allow_nan=False, ensure_ascii=False) + "\n"
        atomic_write(path, text.encode("utf-8"))

    @classmethod
    def from_json(cls, source) -> "Result":
        """A ``Result`` from a JSON file written by :meth:`to_json` (a path) or from its dict
        (:meth:`to_dict`): equal to the one written (``series`` is not in the JSON: empty)."""
        if isinstance(source, dict):
            d = source
        else:
            with open(source) as fh:
                d = json.load(fh)
        missing = [k for k in ("experiment", "title", "source", "params", "rows") if k not in d]
        if missing:
            raise ValueError(f"source: expected a result's JSON with keys experiment, title, source, params, "
                             f"rows; missing {missing}")
        res = cls(d["experiment"], d["title"], d["source"], _decode(d["params"]),
                  notes=list(d.get("notes", [])), meta=_decode(d.get("meta", {})))
        for r in d["rows"]:
            row = Row.from_dict(r)
            res.add(row.filter, row.quantity, row.value, row.stderr, row.paper, **row.params)
        return res

    def table(self) -> str:
        """A plain-text table: paper value beside measured value and its standard error."""
        head = ["filter", "quantity", "params", "paper", "value", "stderr"]
        body = [[r.filter, r.quantity, _fmt_params(r.params), _fmt(r.paper), _fmt(r.value),
                 _fmt(r.stderr)] for r in self.rows]
        widths = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)]
        lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)),
                 "  ".join("-" * w for w in widths)]
        lines += ["  ".join(c.ljust(w) for c, w in zip(b, widths)) for b in body]
        return "\n".join([f"{self.experiment}: {self.title}", f"source: {self.source}", *lines, *self.notes])


def atomic_write(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and ``os.replace``."""
    import os
    import tempfile

    path = os.fspath(path)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), prefix=".nlfilter-", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _fmt(x) -> str:
    if x is None:
        return "-"
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e5):
        return f"{x:.4e}"
    return f"{x:.5g}"


def _fmt_params(p: dict) -> str:
    return ",".join(f"{k}={v}" for k, v in p.items()) or "-"


def _default(o):
    try:
        import numpy as np
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:  # pragma: no cover
        pass
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
