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
import pkgutil
import time
from dataclasses import dataclass
from typing import Callable

from ..results import Result, _decode, _encode, provenance


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    source: str
    params: dict  # name -> default value (its type is the parameter's type)
    func: Callable[..., Result]

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
                return int(value)
            if isinstance(default, float):
                return float(value)
            if isinstance(default, (list, tuple)):
                kind = type(default[0]) if default else float
                return [kind(v) for v in value.split(",") if v != ""]
            if default is None:
                return float(value)
        except ValueError:
            raise ValueError(f"param {name}={value!r}: expected a value of type "
                             f"{type(default).__name__} (default {default!r})") from None
        return value


_REGISTRY: dict[str, Experiment] = {}
_LOADED = False


def experiment(id: str, *, title: str, source: str, params: dict | None = None):
    """Register ``func`` as experiment ``id``."""

    def deco(func):
        if id in _REGISTRY:
            raise ValueError(f"experiment id {id!r} registered twice")
        _REGISTRY[id] = Experiment(id, title, source, dict(params or {}), func)
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
