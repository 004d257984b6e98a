"""Fuzz of the options added for issues 30 and 31 on every registered filter that takes them (the
contract's cases, tests/test_contract.py): ``fading_memory(alpha)`` (the Gaussian filters), noise
given per step (``R``/``Q`` arrays through ``with_params``, every discrete filter that lists
"time-varying R") and a square-root filter's prior given as a factor (``SquareRootFilter.belief``).
Bad values are refused naming the argument; extreme but valid ones (a huge fading factor, noise of
1e200 at one step, a factor of 1e-150) give finite numbers, marked paths, or a named refusal."""

from __future__ import annotations

import numpy as np
import pytest

from nlfilter.filters.fading import FadingMemory
from nlfilter.filters.square_root import SquareRootFilter

from .test_filters import CASES, _data

FADING = [c for c in CASES if isinstance(c.filter(), FadingMemory) and c.prior]
PER_STEP = [c for c in CASES if "time-varying R" in getattr(c.filter(), "structures", ()) and c.prior
            and getattr(c.filter(), "time", "discrete") == "discrete" and c.filter().model.kind == "discrete"]
SQRT = [c for c in CASES if isinstance(c.filter(), SquareRootFilter) and c.prior]

BAD_ALPHA = [("0", 0.0), ("0.5", 0.5), ("-1", -1.0), ("nan", float("nan")), ("inf", float("inf")),
             ("string", "2"), ("None", None), ("list", [1.0, 2.0]), ("complex", 1 + 1j), ("bool", True)]


def _run(case, flt, ys=None, **kw):
    return lambda: flt.run(_data(case) if ys is None else ys, case.prior["m0"], case.prior["P0"],
                           on_divergence="mark", loglik=True, **kw)


@pytest.mark.parametrize("case", FADING, ids=[c.name for c in FADING])
def test_fading_memory(fuzz, case):
    for lab, alpha in BAD_ALPHA:
        fuzz.check("options: fading memory, bad", lambda: case.filter().fading_memory(alpha), ("alpha",),
                   label=f"{case.name}: alpha {lab}")
    for alpha in (1.0 + 1e-15, 1e3, 1e150):
        fuzz.check("options: fading memory, extreme", _run(case, case.filter().fading_memory(alpha)), ("alpha",),
                   bad=False, label=f"{case.name}: alpha {alpha:g}")


def _noise(case, name):
    md = case.filter().model
    return np.asarray(md.R if name == "R" else md.Q, dtype=float)


def _rebuilt(case, **noise):
    """The case's filter on its model with the noise ``noise`` given per step (its own constructor
    arguments: the contract's ``make(model=...)``)."""
    return case.make(model=case.filter().model.with_params(**noise))


@pytest.mark.parametrize("case", PER_STEP, ids=[c.name for c in PER_STEP])
def test_per_step_noise(fuzz, case):
    ys = _data(case)
    B, T = ys.shape[0], ys.shape[-2]
    for name in ("R", "Q"):
        C = _noise(case, name)
        k = C.shape[-1]
        good = np.repeat(C[None], T, axis=0)
        neg, nan, asym = good.copy(), good.copy(), good.copy()
        neg[2] = -np.eye(k)
        nan[1, 0, 0] = np.nan
        if k > 1:
            asym[0, 0, 1] += 1.0
        short = good[:-2] if name == "Q" else good[:-1]  # Q needs one step fewer than R (the last predicts nothing)
        bad = [("too short", short), ("wrong size", np.repeat(np.eye(k + 1)[None], T, axis=0)),
               ("negative at a step", neg), ("NaN at a step", nan), ("strings", np.full(good.shape, "a")),
               ("per path, wrong count", np.repeat(good[None], B + 1, axis=0))]
        bad += [("not symmetric", asym)] if k > 1 else []
        for lab, value in bad:
            def call(value=value):
                return _run(case, _rebuilt(case, **{name: value}))()
            fuzz.check("options: per-step noise, bad", call, (name,), label=f"{case.name}: {name} {lab}")
        huge = good.copy()
        huge[2] = 1e200 * np.eye(k)
        fuzz.check("options: per-step noise, extreme",
                   lambda: _run(case, _rebuilt(case, **{name: huge}))(),
                   (name,), bad=False, label=f"{case.name}: {name} 1e200 at one step")


@pytest.mark.parametrize("case", SQRT, ids=[c.name for c in SQRT])
def test_square_root_prior_factor(fuzz, case):
    flt = case.filter()
    m0 = np.asarray(case.prior["m0"], dtype=float)
    n = m0.shape[-1]
    S = np.linalg.cholesky(np.asarray(case.prior["P0"], dtype=float) + 0 * np.eye(n))
    upper = S.T.copy() + np.triu(np.ones((n, n)), 1)
    bad = [("NaN", np.full((n, n), np.nan)), ("wrong size", np.eye(n + 1)), ("strings", np.full((n, n), "a")),
           ("complex", S * (1 + 1j)), ("None", None)]
    bad += [("upper triangular", upper)] if n > 1 else []
    for lab, factor in bad:
        fuzz.check("options: square-root factor, bad", lambda factor=factor: flt.belief(m0, factor), ("factor",),
                   label=f"{case.name}: factor {lab}")
    for lab, factor in (("1e-150", 1e-150 * S), ("1e150", 1e150 * S), ("zero", np.zeros((n, n)))):
        def call(factor=factor):
            state = flt.belief(m0, factor)
            return flt.run(_data(case), state.mean, state.factor @ np.swapaxes(state.factor, -1, -2),
                           on_divergence="mark", loglik=True)
        fuzz.check("options: square-root factor, extreme", call, ("factor", "P0"), bad=False,
                   label=f"{case.name}: factor {lab}")
