"""Fuzz of every registered filter's ``run`` (issue 15, item 7): the contract's cases
(tests/test_contract.py: each filter with a small model and a valid input) fed bad and extreme
inputs, table-driven and by hypothesis. Each call is classified by the harness (conftest.py):
a bad input must be refused with an error naming the argument; an extreme one must give finite
numbers, mark the paths it lost, or be refused naming it."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hst

from nlfilter.filters.backends import refusal

_spec = importlib.util.spec_from_file_location("_contract", Path(__file__).parents[1] / "test_contract.py")
contract = sys.modules["_contract"] = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(contract)
CASES = contract.CASES
T = 5


def _data(case):
    return case.data((2,), T, 3)


def _complex(a):
    return np.asarray(a) * (1 + 0.5j)


# (label, argument the error must name, keyword overrides of run given the valid data, bad?)
def _bad_runs(case):
    d = _data(case)
    out = [
        ("ys complex", "ys", {"ys": _complex(d)}),
        ("ys no paths", "ys", {"ys": d[:0]}),
        ("ys strings", "ys", {"ys": np.full(d.shape, "a")}),
        ("ys None", "ys", {"ys": None}),
        ("on_divergence 1", "on_divergence", {"on_divergence": 1}),
        ("chunk 0", "chunk", {"chunk": 0}),
        ("chunk 2.5", "chunk", {"chunk": 2.5}),
        ("chunk -1", "chunk", {"chunk": -1}),
        ("loglik 'yes'", "loglik", {"loglik": "yes"}),
        ("backend 'gpu'", "backend", {"backend": "gpu"}),
        # the model-free compiled loop: a filter it takes checks the data first (no compile), the
        # others are refused naming backend
        ("ys complex, backend 'numba-shared'", "backend" if refusal("numba-shared", case.filter()) else "ys",
         {"ys": _complex(d), "backend": "numba-shared"}),
        ("t0 nan", "t0", {"t0": float("nan")}),
        ("t0 inf", "t0", {"t0": float("inf")}),
        ("t0 'abc'", "t0", {"t0": "abc"}),
    ]
    if case.prior:
        m0, P0 = case.prior["m0"], case.prior["P0"]
        n = np.size(m0)
        out += [
            ("m0 complex", "m0", {"m0": _complex(m0)}),
            ("m0 nan", "m0", {"m0": np.full(n, np.nan)}),
            ("m0 inf", "m0", {"m0": np.full(n, np.inf)}),
            ("m0 'abc'", "m0", {"m0": "abc"}),
            ("m0 wrong length", "m0", {"m0": np.zeros(n + 1)}),
            ("P0 complex", "P0", {"P0": _complex(P0)}),
            ("P0 nan", "P0", {"P0": np.full_like(P0, np.nan)}),
            # +inf on the diagonal is a diffuse prior where the filter has one (diffuse_prior): -inf is bad for all
            ("P0 inf", "P0", {"P0": np.where(np.eye(n, dtype=bool), -np.inf if getattr(case.filter(), "diffuse_prior", False)
                                             else np.inf, 0.0)}),
            ("P0 negative", "P0", {"P0": -np.eye(n)}),
            ("P0 'abc'", "P0", {"P0": "abc"}),
            ("P0 3-d of the wrong size", "P0", {"P0": np.ones((3, n, n))}),
        ]
    if case.random:
        out += [("rng 'abc'", "rng", {"rng": "abc"}), ("rng -1", "rng", {"rng": -1})]
    return out


def _extreme_runs(case):
    d = _data(case)
    out = [("ys × 1e150", "ys", {"ys": d * 1e150}), ("ys one huge outlier", "ys", {"ys": _outlier(d)}),
           ("ys no steps (empty estimates)", "ys", {"ys": d[:, :0]})]
    if case.prior:
        m0, P0 = case.prior["m0"], np.asarray(case.prior["P0"])
        out += [("P0 × 1e150", "P0", {"P0": P0 * 1e150}), ("P0 × 1e-150", "P0", {"P0": P0 * 1e-150}),
                ("m0 1e150", "m0", {"m0": np.full(np.size(m0), 1e150)})]
    return out


def _outlier(d):
    e = d.copy()
    e[0, 1, 0] = 1e300
    return e


def _call(case, kw, mark=False):
    d = kw.pop("ys", _data(case))
    run_kw = {**case.prior, **case.run_kw, **kw}
    if mark:
        run_kw.setdefault("on_divergence", "mark")
    return lambda: case.filter().run(d, **run_kw)


BAD = [(c, label, name, kw) for c in CASES for label, name, kw in _bad_runs(c)]
EXTREME = [(c, label, name, kw) for c in CASES for label, name, kw in _extreme_runs(c)]


@pytest.mark.parametrize("case,label,name,kw", BAD, ids=[f"{c.name}-{lab}" for c, lab, _, _ in BAD])
def test_bad_run_input_is_refused_naming_it(fuzz, case, label, name, kw):
    fuzz.check("filters: bad input", _call(case, dict(kw)), name, label=f"{case.name}: {label}")


@pytest.mark.parametrize("case,label,name,kw", EXTREME, ids=[f"{c.name}-{lab}" for c, lab, _, _ in EXTREME])
def test_extreme_run_input_is_finite_marked_or_refused(fuzz, case, label, name, kw):
    fuzz.check("filters: extreme input", _call(case, dict(kw), mark=True), name, bad=False,
               label=f"{case.name}: {label}")


# -- hypothesis: random bad entries anywhere in the data and the prior ---------------------------------
_VALUES = hst.sampled_from([np.inf, -np.inf, 1e308, -1e308, 1j, 1e-320])


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(case=hst.sampled_from(CASES), where=hst.sampled_from(["ys", "m0", "P0"]), value=_VALUES,
       seed=hst.integers(0, 2**16))
def test_random_bad_entries(fuzz, case, where, value, seed):
    """One entry of ``ys``, ``m0`` or ``P0`` replaced: ±inf and complex are bad (named errors);
    ±1e308 and a subnormal are extreme (finite, marked or named)."""
    if where != "ys" and not case.prior:
        where = "ys"
    rng = np.random.default_rng(seed)
    base = _data(case) if where == "ys" else np.array(case.prior[where], dtype=float)
    arr = base.astype(complex if isinstance(value, complex) else float)
    idx = tuple(rng.integers(0, s) for s in arr.shape)
    if where == "P0":  # keep it symmetric
        idx = (idx[0], idx[0])
    arr[idx] = value
    bad = isinstance(value, complex) or not np.isfinite(value)
    fuzz.check(f"filters: random {'bad' if bad else 'extreme'} entry", _call(case, {where: arr}, mark=not bad),
               where, bad=bad, label=f"{case.name}: {where}{list(idx)} = {value}")
