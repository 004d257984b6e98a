"""Experiments: one module per reproduced table or figure, each registered here under an id.

An experiment is a function ``run(params: dict, *, quick: bool, runs: int | None, seed: int,
progress: bool) -> Result``. :data:`EXPERIMENTS` below is the registry, the one place an
experiment's id, title, source, parameters and their ranges are stated; each entry names its
function as a ``"module:function"`` string, imported on first use (:attr:`Experiment.func`), so
``nlfilter list`` (and ``--params``) reads the registry without importing any experiment (nor
NumPy, SymPy, SciPy or the filters). ``tests/test_experiments_registry.py`` checks that every
module of this package is registered and every entry's function is there.

Declared parameters (``params``) are the only names ``--param`` accepts; their defaults fix the
types, and values given on the command line are converted to those types. The returned
``Result.params`` are the values that ran: an experiment records what it derives from ``quick``
and ``runs`` (a shorter horizon, the number of Monte Carlo ``paths``) with ``Result.used``;
:meth:`Experiment.run` adds the provenance (``Result.meta``).
"""

from __future__ import annotations

import math
import pkgutil
import time
from dataclasses import dataclass, field
from typing import Callable

from ..results import Result, _decode, _encode, provenance
from ..sources import cite


MAX_RUNS = 10**7  # Monte Carlo paths an experiment takes (a block of them is bounded by memory: _validate.memory)


@dataclass(frozen=True)
class Experiment:
    id: str
    title: str
    source: str
    params: dict  # name -> default value (its type is the parameter's type)
    target: str  # "module:function" of the experiment's function, imported on first use (func)
    ranges: dict = field(default_factory=dict)  # name -> range (see check_range) or a tuple of choices

    def __post_init__(self):
        unknown = set(self.ranges) - set(self.params)
        if unknown:
            raise ValueError(f"ranges of {self.id!r}: {sorted(unknown)} are not parameters")

    @property
    def func(self) -> Callable[..., Result]:
        """The experiment's function (``target``, imported on first use)."""
        return pkgutil.resolve_name(self.target)

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
        res.source, res.notes = cite(res.source), [cite(n) for n in res.notes]  # papers by name, not file number
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


_BLOCK = {"block": 0}  # paths per Monte Carlo block; 0: all of the run's paths in one block (one batch)
_BLOCK_RANGE = {"block": ">=0,<=1000000"}
_LAWS = ("uniform", "bimodal", "skewed", "near-gaussian")  # the input laws of moment_systems.LAWS


def _index(*entries: Experiment) -> dict[str, Experiment]:
    """``{id: entry}`` in the order of the ids; an id stated twice is a ValueError."""
    out = {}
    for e in entries:
        if e.id in out:
            raise ValueError(f"experiment id {e.id!r} registered twice")
        out[e.id] = e
    return dict(sorted(out.items()))


#: Every experiment by id (the registry; ``nlfilter list`` prints it in this order).
EXPERIMENTS = _index(
    Experiment(
        "cubic-sensor",
        title="Cubic sensor: optimal linear filter, tensor post-processors, bound, Monte Carlo",
        source="Vallot (1981), Tables 5.1-5.2 (ch. 5, Appendix B)",
        target="nlfilter.experiments.cubic_sensor:run",
        params={"q": [2.0, 1.0], "r": [1.0, 1.0], "T": 60.0, "burn": 5.0, "dt": 0.0, "monte_carlo": True,
                "block": 200},  # block: the default full run's paths (one batch)
        ranges={"q": ">0", "r": ">0", "T": ">0,<=100000", "burn": ">=0", "dt": ">=0,<=1", "block": ">=1,<=1000000"}),
    Experiment(
        "cubic-sensor-closures",
        title="Conditional-moment filters (Gaussian, Edgeworth-4 closures) vs EKF and the optimal filter on the "
              "cubic sensor",
        source="Vallot (1981), ch. 5, eqs. 5.1-5.4; Oh & Shin (1995) eqs. 11-15 (closures)",
        target="nlfilter.experiments.cubic_closures:run",
        params={"q": [2.0, 1.0], "r": [1.0, 1.0], "dt": 0.01, "t_end": 20.0, "burn_in": 5.0, "grid_size": 301,
                "block": 300},  # block: the default full run's paths (one batch; --param block=N for finer resume/Dask)
        ranges={"q": ">0", "r": ">0", "dt": ">0,<=1", "t_end": ">0,<=100000", "burn_in": ">=0",
                "grid_size": ">=11,<=100001", "block": ">=1,<=1000000"}),
    Experiment(
        "linear-gaussian",
        title="Linear Gaussian 2-state model: every filter against the Riccati steady state",
        source="nlfilter check (no paper): Riccati equation",
        target="nlfilter.experiments.linear_gaussian:run",
        params={"q1": 0.1, "q2": 0.2, "r": 0.5, "steps": 200, "grid": 61, "particles": 1000,
                "block": 1000},  # block: the default full run's paths (one batch)
        ranges={"q1": ">0", "q2": ">0", "r": ">0", "steps": ">=2,<=1000000", "grid": ">=5,<=100001",
                "particles": ">=10,<=10000000", "block": ">=1,<=1000000"}),
    Experiment(
        "moment-first-order",
        title="First-order system: moment filter vs Kalman vs grid optimum",
        source="the moment-algorithm dissertation, eqs. 2.4-2.5 (Chapter IV, outlined in the abstract)",
        target="nlfilter.experiments.moment_systems:run_first_order",
        params={"h": 0.5, "w_bound": 2.0, "N": [2, 4, 6], "laws": list(_LAWS), "T": 2000, "skip": 500,
                "n0": 100.0, "window": 20, "grid": 400, **_BLOCK},
        ranges={"h": ">-1,<1", "w_bound": ">0", "N": ">=1,<=12", "laws": _LAWS, "T": ">=2,<=10000000",
                "skip": ">=0", "n0": ">0", "window": ">=1,<=100000", "grid": ">=10,<=100000", **_BLOCK_RANGE}),
    Experiment(
        "moment-second-order",
        title="Second-order system: moment filter vs Kalman vs particle optimum",
        source="the moment-algorithm dissertation, eqs. 2.6-2.8 (Chapter V, outlined in the abstract)",
        target="nlfilter.experiments.moment_systems:run_second_order",
        params={"h1": 0.6, "h2": -0.5, "d1": 1.0, "d2": 1.0, "w_bound": 1.5, "N": [2, 4, 6],
                "laws": list(_LAWS), "T": 400, "skip": 100, "n0": 100.0, "window": 20,
                "particles": 4000, "bounding": "polygon", "directions": 16, **_BLOCK},
        ranges={"w_bound": ">0", "N": ">=1,<=12", "laws": _LAWS, "T": ">=2,<=1000000", "skip": ">=0",
                "n0": ">0", "window": ">=1,<=100000", "particles": ">=10,<=10000000", "bounding": ("polygon", "box"),
                "directions": ">=4,<=1024", **_BLOCK_RANGE}),
    Experiment(
        "oh-shin",
        title="QLF vs MQLF (Edgeworth closure) on dx = −x³dt + dβ, dy = x dt + dη",
        source="Oh & Shin (1995), Section 5, eqs. 18-33, Fig. 2",
        target="nlfilter.experiments.oh_shin:run",
        params={"Q": 0.05, "R": 0.05, "m0": 4.0, "D0": 0.05, "order": 4, "t_end": 1.0, "dt": 0.01,
                "grid_size": 601, "block": 4000},  # block: the default full run's paths (one batch)
        ranges={"Q": ">0", "R": ">0", "D0": ">0", "order": ">=3,<=12", "t_end": ">0,<=10000", "dt": ">0,<=1",
                "grid_size": ">=11,<=100001", "block": ">=1,<=1000000"}),
    Experiment(
        "phase-tracking",
        title="Phase tracking: PLL, linear quadrature filter, tensor filter, optimal",
        source="Vallot (1981), Figs. 4.3-4.4, Table 4.1 (ch. 4, Appendix A)",
        target="nlfilter.experiments.phase_tracking:run",
        params={"P": [], "q": 1.0, "sim_P": 0.129, "time_constants": 500.0, "discard": 25.0,
                "step": 0.01, "grid": 256, "sweep": 100, "simulate": True, "block": 32},
        ranges={"P": ">0,<=100", "q": ">0", "sim_P": ">0,<=100", "time_constants": ">0,<=1e5", "discard": ">=0",
                "step": ">0,<=0.5", "grid": ">=0,<=65536", "sweep": ">=2,<=10000", "block": ">=1,<=100000"}),
    Experiment(
        "second-order",
        title="Second-order filters: Henriksen's correct truncated form vs the pre-correction, modified and "
              "Gaussian forms, EKF, UKF and the optimal reference",
        source="Henriksen (1979) eqs. 11, 18-23, 33, 35-37; falling body of Athans, Wishner & "
               "Bertolini 1968",
        target="nlfilter.experiments.henriksen:run",
        params={
            "problem": "all",  # "all" or a comma list of quadratic, state-noise, falling-body
            "steps": 0,  # 0 = the problem's default (50, 200, 60)
            # quadratic: x' = a x + b x² + w, y = x + c x² + v
            "quad_a": 0.7, "quad_b": 0.02, "quad_c": 0.3, "quad_q": 1.0, "quad_r": 0.2,
            # state-noise: dx = −a x dt + (s0 + s1 x + s2 x²) dβ, dy = (x + c x²) dt + dη
            "sn_a": 1.0, "sn_s0": 0.3, "sn_s1": 0.8, "sn_s2": 0.1, "sn_c": 0.5, "sn_r": 0.2, "sn_dt": 0.01,
            "sn_innovation": "update",  # "update" (stable discrete absorption of dy) or "ito" (explicit increment)
            # falling body: measurement noise variance, RK4 substeps per second, particles of the reference
            "fb_r": 1e4, "fb_substeps": 20, "fb_particles": 1000, "fb_pf_runs": 100,
            "grid_size": 401,
            **_BLOCK,
        },
        ranges={"steps": ">=0,<=100000", "quad_q": ">0", "quad_r": ">0", "sn_r": ">0", "sn_dt": ">0,<=1",
                "sn_innovation": ("update", "ito"), "fb_r": ">0", "fb_substeps": ">=1,<=10000",
                "fb_particles": ">=10,<=10000000", "fb_pf_runs": ">=2,<=100000", "grid_size": ">=11,<=100001",
                **_BLOCK_RANGE}),
    Experiment(
        "square-root",
        title="Square-root filters beside their standard forms on ill-conditioned problems: PSD loss, "
              "divergence, MSE, cost",
        source="nlfilter check (no paper): Grewal & Andrews, Kalman Filtering: Theory and Practice (square-root "
               "filtering); issue 30",
        target="nlfilter.experiments.square_root_pairs:run",
        params={"problem": "all",  # "all" or a comma list of noiseless, long-run, stiff, quadratic, falling-body
                "r": [1e-8, 1e-10, 1e-12, 1e-14, 1e-16, 1e-18], "noiseless_q": 0.0,
                "long_steps": 200000, "long_pairs": ["kf", "ukf"], "long_tau": 1e4, "long_r": 1e-2,
                "stiff_lambda": 1000.0, "stiff_r": 1e-8, "stiff_dt": 0.1, "stiff_substeps": 100,
                "quad_r": 0.2, "fb_r": 1e4, "fb_substeps": 20},
        ranges={"r": ">0,<1", "noiseless_q": ">=0", "long_steps": ">=2,<=10000000", "long_tau": ">0",
                "long_r": ">0", "stiff_lambda": ">0", "stiff_r": ">0", "stiff_dt": ">0,<=10",
                "stiff_substeps": ">=1,<=100000", "quad_r": ">0", "fb_r": ">0", "fb_substeps": ">=1,<=10000"}),
    Experiment(
        "smoothing",
        title="RTS smoothers of every Gaussian filter against the optimal smoother (cubic sensors)",
        source="nlfilter check (no paper): Särkkä 2013 ch. 8-9 (Gaussian RTS smoothers); issue 12",
        target="nlfilter.experiments.rts_smoothing:run",
        params={"steps": 50, "particles": 1000, **_BLOCK},
        ranges={"steps": ">=2,<=100000", "particles": ">=10,<=1000000", **_BLOCK_RANGE}),
    Experiment(
        "zero-order",
        title="Zero-order problem: ensemble MSE of optimal, moment and linear estimators",
        source="the moment-algorithm dissertation, Table 1 (eqs. 3.7, 3.20, 3.21, 3.24)",
        target="nlfilter.experiments.zero_order_problem:run_table1",
        params={"J": [0, 2, 4, 6, 8, 10], "N": [2, 4, 6], "eps": 1e-6, **_BLOCK},
        ranges={"J": ">=0,<=40", "N": ">=1,<=12", "eps": ">0,<1", **_BLOCK_RANGE}),
    Experiment(
        "zero-order-adaptive",
        title="Zero-order adaptive moment filter: time-averaged MSE vs n",
        source="the moment-algorithm dissertation, Fig. 10 (a) J=10, (b) J=0; flow chart Fig. 7",
        target="nlfilter.experiments.zero_order_problem:run_fig10",
        params={"J": [10, 0], "N": [2, 4, 6], "n0": 100.0, "window": 20, "n_max": 3000, "eps": 1e-6,
                "invalid_moments": "ignore", **_BLOCK},
        ranges={"J": ">=0,<=40", "N": ">=1,<=12", "n0": ">0", "window": ">=1,<=100000", "n_max": ">=2,<=10000000",
                "eps": ">0,<1", "invalid_moments": ("warn", "keep", "ignore"), **_BLOCK_RANGE}),
    Experiment(
        "zero-order-robustness",
        title="Zero-order filter under input/noise correlation and non-additive noise",
        source="the moment-algorithm dissertation, Chapter III (abstract: correlation and non-additive "
               "measurement)",
        target="nlfilter.experiments.zero_order_problem:run_robustness",
        params={"J": 10, "N": [2, 4, 6], "r": [0.0, 0.3, 0.6, 0.9], "beta": [0.0, 0.3, 0.6], "n": 3000,
                "n0": 100.0, "window": 20, **_BLOCK},
        ranges={"J": ">=0,<=40", "N": ">=1,<=12", "r": ">-1,<1", "beta": ">=-10,<=10", "n": ">=2,<=10000000",
                "n0": ">0", "window": ">=1,<=100000", **_BLOCK_RANGE}),
)

def registry() -> dict[str, Experiment]:
    """All experiments, by id (:data:`EXPERIMENTS`; a copy: nothing is imported)."""
    return dict(EXPERIMENTS)


def get(id: str) -> Experiment:
    reg = registry()
    if id not in reg:
        raise ValueError(f"experiment {id!r}: unknown; expected one of {sorted(reg)}")
    return reg[id]
