"""Fuzz of the entry points added for issue 30 — ``sample_posterior`` and ``fixed_lag`` — with the
bad data and priors that ``run`` gets (test_filters.py), for every registered discrete Gaussian
filter with an RTS backward pass (both entry points) and every registered reference filter with a
backward kernel (grid, particle: ``sample_posterior``), plus bad ``n`` and ``lag``: each refused
naming the argument."""

from __future__ import annotations

from pathlib import Path

import pytest

from nlfilter import fixed_lag, sample_posterior

try:  # test_smoothers' loader: the module of a file as pytest loaded it, not a second copy
    from test_smoothers import _module
except ImportError:  # pragma: no cover - imported as a package module
    from .test_smoothers import _module

S = _module("_fuzz_smoothers", Path(__file__).parent / "test_smoothers.py")
CASES, F = S.CASES, S.F

RTS = [c for c in CASES if c.filter().smoother == "rts" and hasattr(c.filter(), "_predict_cross")
       and c.filter().time != "continuous"]
REFERENCE = [c for c in CASES if callable(getattr(c.filter(), "_sample", None)) and c.filter().smoother is not None]
NAMES = ("ys", "m0", "P0")


def _bad(case):
    return [(lab, n, kw) for lab, n, kw in F._bad_runs(case) if n in NAMES and set(kw) <= set(NAMES)]


@pytest.mark.parametrize("case", RTS + REFERENCE, ids=[c.name for c in RTS + REFERENCE])
def test_bad_input_is_refused_naming_it(fuzz, case):
    lags = case in RTS  # fixed_lag: the Gaussian filters only
    for lab, name, kw in _bad(case) + [("n 0", "n", {"n": 0}), ("lag 0", "lag", {"lag": 0})]:
        if name == "lag" and not lags:
            continue
        args = {"ys": F._data(case), **case.prior, **{k: v for k, v in kw.items() if k in NAMES}}
        n, lag = kw.get("n", 2), kw.get("lag", 2)
        if name != "lag":
            fuzz.check("sampling: bad input", lambda: sample_posterior(case.filter(), args["ys"], args["m0"],
                                                                       args["P0"], n=n, rng=0),
                       (name,), label=f"{case.name}: sample_posterior: {lab}")
        if name != "n" and lags:
            fuzz.check("sampling: bad input", lambda: fixed_lag(case.filter(), args["ys"], args["m0"], args["P0"], lag),
                       (name,), label=f"{case.name}: fixed_lag: {lab}")
