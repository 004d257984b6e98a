"""Experiments: one module per reproduced table or figure, registered under an id.

An experiment is a function ``run(params: dict, *, quick: bool, runs: int | None, seed: int,
progress: bool) -> Result``. Each module in this package registers its experiments with the
``@experiment`` decorator; :func:`registry` imports every module of the package once, so a new
module needs no edit anywhere else.

Declared parameters (``params``) are the only names ``--param`` accepts; their defaults fix the
types, and values given on the command line are converted to those types. The returned
``Result.params`` are the values that ran: an experiment records what it derives from ``quick``
and ``runs`` (a shorter horizon, the number of Monte Carlo ``paths``) with ``Result.used``;
:meth:`Experiment.run` adds the provenance (``Result.meta``).
"""

from __future__ import annotations

import importlib
import math
import pkgutil
import time
from dataclasses import dataclass, field
from typing import Callable

from ..results import Result, _decode, _encode, provenance


MAX_RUNS = 10**7  # Monte Carlo paths an experiment takes (a block of them is bounded by memory: _validate.memory)


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    source: str
    params: dict  # name -> default value (its type is the parameter's type)
    func: Callable[..., Result]
    ranges: dict = field(default_factory=dict)  # name -> range (see check_range) or a tuple of choices

    def run(self, params: dict | None = None, *, quick: bool = False, runs: int | None = None,
            seed: int = 0, progress: bool = False, chunk: int | None = None, executor=None, store=None,
            scheduler: str | None = None, workers: int | None = None) -> Result:
        """Run with defaults overridden by ``params`` (already typed, or strings to convert).

        ``chunk``: simulate and filter the Monte Carlo paths that many at a time
        (:func:`nlfilter.evaluate.chunk`); the rows are the same for any chunk (per-path streams).
        ``executor`` (``"local"``, ``"dask"`` with ``scheduler``/``workers``, or an executor object)
        and ``store`` (a :class:`~nlfilter.store.ResultsStore`): where the experiment's
        block-structured Monte Carlo (:func:`nlfilter.montecarlo.montecarlo`) is computed and kept —
        the numbers do not depend on either. How it ran is recorded in ``meta["execution"]``."""
        full = dict(self.params)
        for name, value in (params or {}).items():
            full[name] = self.convert(name, value)
        if runs is not None and (isinstance(runs, bool) or not isinstance(runs, int) or runs < 1):
            raise ValueError(f"runs: expected a positive integer, got {runs!r}")
        if runs is not None and runs > MAX_RUNS:
            raise ValueError(f"runs: expected at most {MAX_RUNS:,} Monte Carlo paths, got {runs:,}")
        given = {name: full[name] for name in (params or {})}
        from ..evaluate import chunked
        from ..montecarlo import session
        t0 = time.perf_counter()
        with session(executor=executor, store=store, experiment=self.id, seed=seed, chunk=chunk,
                     progress=progress, scheduler=scheduler, workers=workers) as sess, chunked(chunk):
            res = self.func(full, quick=quick, runs=runs, seed=seed, progress=progress)
        seconds = time.perf_counter() - t0
        res.params = _decode(_encode(res.params))  # as JSON keeps them (tuples as lists, numpy as Python)
        res.meta = provenance(self.id, seed=seed, runs=runs, paths=res.params.get("paths"), quick=quick,
                              given=given)
        res.meta["execution"] = {**sess.execution(), "seconds": round(seconds, 3)}
        return res

    def convert(self, name: str, value):
        """``value`` (a string from the command line, or a Python value) as parameter ``name``:
        converted to the default's type, then checked (:meth:`check`)."""
        return self.check(name, self._convert(name, value))

    def check(self, name: str, value):
        """``value`` of parameter ``name`` if it has the default's type, is finite (numbers; every
        element of a list), is non-empty (a list whose default is not) and lies in the declared
        range or choices (``ranges``); else a ValueError/TypeError naming ``param NAME``."""
        default = self.params[name]
        label = f"param {name}={value!r}"
        items = value if isinstance(default, (list, tuple)) else [value]
        if isinstance(default, (list, tuple)):
            if not isinstance(value, (list, tuple)):
                raise TypeError(f"{label}: expected a list (default {default!r})")
            if default and not value:
                raise ValueError(f"{label}: expected at least one value (default {_show_list(default)})")
        if isinstance(default, (list, tuple)):
            kind = type(default[0]) if default else float
        else:
            kind = type(default)
        for v in items:
            if kind is bool or isinstance(default, bool):
                if not isinstance(v, bool):
                    raise TypeError(f"{label}: expected true or false (default {default!r})")
                continue
            if kind in (int, float) or default is None:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not isinstance(v, int)):
                    raise TypeError(f"{label}: expected {'an integer' if kind is int else 'a number'} "
                                    f"(default {default!r})")
                if not math.isfinite(v):
                    raise ValueError(f"{label}: expected a finite number (default {default!r})")
            elif kind is str and not isinstance(v, str):
                raise TypeError(f"{label}: expected a string (default {default!r})")
            spec = self.ranges.get(name)
            if spec is not None:
                check_range(f"param {name}={v!r}" if isinstance(default, (list, tuple)) else label, v, spec)
        return value

    def _convert(self, name: str, value):
        if name not in self.params:
            raise ValueError(f"param {name!r}: unknown for experiment {self.id!r}; "
                             f"expected one of {sorted(self.params)}")
        default = self.params[name]
        if not isinstance(value, str):
            return value
        try:
            if isinstance(default, bool):
                if value.lower() in ("1", "true", "yes", "on"):
                    return True
                if value.lower() in ("0", "false", "no", "off"):
                    return False
                raise ValueError
            if isinstance(default, int):
                return _scalar(int, value)
            if isinstance(default, float):
                return float(value)
            if isinstance(default, (list, tuple)):
                kind = type(default[0]) if default else float
                return [_scalar(kind, v.strip()) for v in value.split(",") if v.strip() != ""]
            if default is None:
                return float(value)
        except ValueError:
            raise ValueError(f"param {name}={value!r}: expected a value of type "
                             f"{type(default).__name__} (default {default!r})") from None
        return value


def _scalar(kind, text: str):
    """``text`` as ``kind``; an integer may be written ``1e6`` or ``1000.0`` if it is whole."""
    if kind is int:
        try:
            return int(text)
        except ValueError:
            f = float(text)  # ValueError if not a number
            if not (math.isfinite(f) and f.is_integer()):
                raise ValueError from None
            return int(f)
    if kind is bool:
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise ValueError
    return kind(text)


def _show_list(v) -> str:
    return ",".join(map(str, v)) if v else "(empty)"


_OPS = {">": lambda a, b: a > b, ">=": lambda a, b: a >= b, "<": lambda a, b: a < b, "<=": lambda a, b: a <= b}


def check_range(label: str, value, spec) -> None:
    """Check ``value`` against ``spec``: a tuple of allowed values, or a string of comma-separated
    bounds ``OP NUMBER`` (``OP`` one of ``>``, ``>=``, ``<``, ``<=``), e.g. ``">0"``,
    ``">=1,<=1e6"``; a ValueError names ``label``, the value and the range.

    >>> check_range("param T=-1.0", -1.0, ">0")
    Traceback (most recent call last):
    ...
    ValueError: param T=-1.0: expected a value >0
    """
    if isinstance(spec, tuple):
        if value not in spec:
            raise ValueError(f"{label}: expected one of {list(spec)}")
        return
    for part in spec.split(","):
        part = part.strip()
        op = part[:2] if part[:2] in _OPS else part[:1]
        bound = float(part[len(op):])
        if not _OPS[op](value, bound):
            raise ValueError(f"{label}: expected a value " + " and ".join(p.strip() for p in spec.split(",")))


_REGISTRY: dict[str, Experiment] = {}
_LOADED = False


def experiment(id: str, *, title: str, source: str, params: dict | None = None, ranges: dict | None = None):
    """Register ``func`` as experiment ``id``; ``ranges``: name -> the range of a parameter
    (:func:`check_range`: ``">0"``, ``">=1,<=1e6"``) or a tuple of its choices."""

    def deco(func):
        if id in _REGISTRY:
            raise ValueError(f"experiment id {id!r} registered twice")
        unknown = set(ranges or {}) - set(params or {})
        if unknown:
            raise ValueError(f"ranges of {id!r}: {sorted(unknown)} are not parameters")
        _REGISTRY[id] = Experiment(id, title, source, dict(params or {}), func, dict(ranges or {}))
        return func

    return deco


def registry() -> dict[str, Experiment]:
    """All experiments, by id (imports every module of this package on first call)."""
    global _LOADED
    if not _LOADED:
        for mod in pkgutil.iter_modules(__path__):
            importlib.import_module(f"{__name__}.{mod.name}")
        _LOADED = True
    return dict(sorted(_REGISTRY.items()))


def get(id: str) -> Experiment:
    reg = registry()
    if id not in reg:
        raise ValueError(f"experiment {id!r}: unknown; expected one of {sorted(reg)}")
    return reg[id]
