"""The fuzz suite's harness (issue 15, item 7): every call of the suite is classified, and the
counts per area are printed at the end of the test session.

A call is one of

``named``      a ``ValueError``/``TypeError`` (or an :mod:`nlfilter.errors` error) raised by
               nlfilter's own code whose message names one of the arguments the case names;
``unnamed``    such an error whose message names none of them;
``raw``        any other exception, or one raised inside NumPy/SciPy/SymPy (or generated code)
               and not caught by nlfilter — a ``LinAlgError`` from ``np.linalg.solve``, a
               ``SympifyError``, a ``ZeroDivisionError`` in lambdified code;
``accepted``   a bad input that returned (its output finite);
``silent nan`` a return value holding NaN/inf that no divergence flag accounts for;
``hang``       a call still running after :data:`LIMIT` seconds (it is interrupted);
``handled``    an extreme but valid input (huge data, a wide prior) that returned finite numbers,
               or marked the paths it lost, or was refused with a named error.

A bad input passes only as ``named``; an extreme one as ``named`` or ``handled``. The command
line's cases are ``clean`` (exit 2 or 130 with at most three lines and no traceback) or not.
"""

from __future__ import annotations

import re
import signal
import traceback
from pathlib import Path

import numpy as np
import pytest

import nlfilter
from nlfilter.errors import NLFilterError

LIMIT = 20.0  # seconds a fuzzed call may take before it counts as a hang (the bound: 60)
PACKAGE = str(Path(nlfilter.__file__).resolve().parent)


class _Hang(BaseException):
    """Raised by the alarm in a call past :data:`LIMIT` (a BaseException: no ``except Exception``
    inside nlfilter swallows it)."""


def _alarm(signum, frame):
    raise _Hang()


def _raised_by_nlfilter(exc: BaseException) -> bool:
    """Whether the innermost frame of ``exc``'s traceback is nlfilter's own source."""
    frames = traceback.extract_tb(exc.__traceback__)
    return bool(frames) and str(Path(frames[-1].filename).resolve()).startswith(PACKAGE)


def _nonfinite(value, depth: int = 0) -> bool:
    """Whether ``value`` holds NaN/inf that nothing flags: arrays, numbers, tuples, dicts; an
    ``Estimates``, ``Simulation`` or ``LogLik`` only outside the paths it marks diverged (an
    ``Estimates``' per-step log-likelihood terms ``extras["loglik"]`` included)."""
    if depth > 4 or value is None or isinstance(value, (str, bytes, bool)):
        return False
    diverged = getattr(value, "diverged", None)
    if diverged is not None and hasattr(value, "_fields"):
        ok = ~np.asarray(diverged, dtype=bool)
        fields = {name: getattr(value, name) for name in value._fields}
        extras = fields.get("extras") or {}
        if "loglik" in extras:
            fields["loglik"] = extras["loglik"]
        for name, arr in fields.items():
            if name in ("means", "covs", "xs", "ys", "loglik", "value", "stderr", "spread") and \
                    isinstance(arr, np.ndarray) and arr.dtype.kind == "f":
                if name == "covs" and np.all(np.isnan(arr)):
                    continue  # a filter that carries no covariance (documented: NaN covs)
                if not np.all(np.isfinite(arr[ok])):
                    return True
        return False
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "fc" and not np.all(np.isfinite(value))
    if isinstance(value, (float, np.floating, complex)):
        return not np.isfinite(value)
    if isinstance(value, dict):
        return any(_nonfinite(v, depth + 1) for v in value.values())
    if isinstance(value, (tuple, list)) and len(value) < 100:
        return any(_nonfinite(v, depth + 1) for v in value)
    return False


def classify(fn, names, *, bad: bool = True, limit: float = LIMIT) -> tuple[str, str]:
    """Run ``fn()`` and classify it (module docstring); ``names``: the argument(s) an error must
    name. Returns ``(outcome, detail)``."""
    names = (names,) if isinstance(names, str) else tuple(names)
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = fn()
    except _Hang:
        return "hang", f"still running after {limit:g} s"
    except (ValueError, TypeError, NLFilterError) as exc:
        msg = str(exc)
        own = isinstance(exc, NLFilterError) or _raised_by_nlfilter(exc)
        if not own:
            return "raw", f"{type(exc).__module__}.{type(exc).__name__}: {msg[:200]}"
        if any(re.search(rf"(?<![\w.]){re.escape(n)}(?!\w)", msg) for n in names):
            return "named", msg.splitlines()[0][:200] if msg else ""
        return "unnamed", f"{type(exc).__name__}: {msg[:200]}"
    except Exception as exc:  # noqa: BLE001 - classifying every failure is the point
        return "raw", f"{type(exc).__module__}.{type(exc).__name__}: {str(exc)[:200]}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    if _nonfinite(out):
        return "silent nan", "the result holds NaN/inf outside any marked path"
    return ("accepted", "returned") if bad else ("handled", "returned finite or marked")


class Fuzz:
    """The fixture: ``fuzz.check(area, fn, names, bad=True)`` classifies, counts and asserts.
    The counts go to the session's table (``tests/conftest.py``: gathered from every xdist worker
    and printed at the session's end)."""

    def __init__(self, table):
        self.counts, self.failures = table["counts"], table["failures"]

    def check(self, area: str, fn, names, *, bad: bool = True, limit: float = LIMIT, label: str = ""):
        outcome, detail = classify(fn, names, bad=bad, limit=limit)
        self.counts[area][outcome] += 1
        allowed = {"named"} if bad else {"named", "handled"}
        if outcome not in allowed:
            self.failures.append(f"{area}: {label}: {outcome}: {detail}")
        assert outcome in allowed, f"{label}: {outcome}: {detail}"
        return outcome, detail

    def count(self, area: str, outcome: str, ok: bool, label: str = ""):
        self.counts[area][outcome] += 1
        if not ok:
            self.failures.append(f"{area}: {label}: {outcome}")


@pytest.fixture
def fuzz(request):
    return Fuzz(request.config.fuzz_table)
