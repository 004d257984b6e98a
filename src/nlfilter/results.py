"""The result table every experiment returns, the CLI prints and the JSON files keep.

JSON schema (kept by every experiment)::

    {"experiment": str, "title": str, "source": str, "params": {...},
     "rows": [{"filter": str, "quantity": str, "params": {...},
               "paper": number|null, "value": number, "stderr": number|null}]}
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Row:
    """One measured number, with the paper's value beside it when the paper gives one."""

    filter: str
    quantity: str
    value: float
    stderr: float | None = None
    paper: float | None = None
    params: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"filter": self.filter, "quantity": self.quantity, "params": dict(self.params),
                "paper": _num(self.paper), "value": _num(self.value), "stderr": _num(self.stderr)}


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None if math.isnan(x) else x


@dataclass
class Result:
    """An experiment's table, plus arrays for its figures (``series``, not written to JSON)."""

    experiment: str
    title: str
    source: str
    params: dict
    rows: list[Row] = field(default_factory=list)
    series: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def add(self, filter: str, quantity: str, value, stderr=None, paper=None, **params) -> Row:
        row = Row(filter, quantity, float(value), None if stderr is None else float(stderr),
                  None if paper is None else float(paper), params)
        self.rows.append(row)
        return row

    def get(self, filter: str, quantity: str, **params) -> Row:
        """The single row matching ``filter``, ``quantity`` and the given row params."""
        hits = [r for r in self.rows if r.filter == filter and r.quantity == quantity
                and all(r.params.get(k) == v for k, v in params.items())]
        if len(hits) != 1:
            raise KeyError(f"{len(hits)} rows match filter={filter!r}, quantity={quantity!r}, {params}")
        return hits[0]

    def to_dict(self) -> dict:
        return {"experiment": self.experiment, "title": self.title, "source": self.source,
                "params": _jsonable(self.params), "rows": [r.to_dict() for r in self.rows]}

    def to_json(self, path) -> None:
        with open(path, "w") as fh:
            json.dump(self.to_dict(), fh, indent=2, allow_nan=False, default=_default)
            fh.write("\n")

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


def _jsonable(d: dict) -> dict:
    return json.loads(json.dumps(d, default=_default))
