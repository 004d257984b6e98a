"""Input checks at the public boundary: every message names the argument, what was given and
what was expected (docs/architecture.rst, `_validate.py`)."""

from __future__ import annotations

import math
import numbers
import reprlib

import numpy as np


def as_float_array(name: str, value, *, ndim_min: int | None = None, ndim: int | None = None,
                   shape_tail: tuple | None = None) -> np.ndarray:
    """Convert ``value`` to a float64 array and check its dimensions.

    ``shape_tail`` fixes the trailing axes (``None`` entries are free).
    """
    if np.iscomplexobj(value):  # NumPy would drop the imaginary part with a mere ComplexWarning
        raise TypeError(f"{name}: expected real numbers, got {np.asarray(value).dtype}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: expected an array of real numbers, got {type(value).__name__}") from exc
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name}: expected an array with {ndim} dimension(s), got shape {arr.shape}")
    if ndim_min is not None and arr.ndim < ndim_min:
        raise ValueError(f"{name}: expected at least {ndim_min} dimension(s), got shape {arr.shape}")
    if shape_tail is not None:
        tail = arr.shape[arr.ndim - len(shape_tail):] if arr.ndim >= len(shape_tail) else None
        if tail is None or any(t is not None and t != a for t, a in zip(shape_tail, tail)):
            want = "(..., " + ", ".join("*" if t is None else str(t) for t in shape_tail) + ")"
            raise ValueError(f"{name}: expected trailing shape {want}, got shape {arr.shape}")
    return arr


def finite(name: str, arr: np.ndarray, *, allow_nan: bool = False) -> np.ndarray:
    if not (np.isinf(arr) if allow_nan else ~np.isfinite(arr)).any():  # (the common case: one pass)
        return arr
    bad = ~np.isfinite(arr)
    if allow_nan:
        bad &= ~np.isnan(arr)
    if np.any(bad):
        raise ValueError(f"{name}: expected finite values, got {int(bad.sum())} non-finite entr(y/ies)")
    return arr


def mean(name: str, value, n: int, **shape) -> np.ndarray:
    """A mean vector: a real scalar (repeated ``n`` times) or an array ``(..., n)`` (``shape``:
    further keywords of :func:`as_float_array`), finite."""
    if np.ndim(value):
        arr = as_float_array(name, value, shape_tail=(n,), **shape)
    else:
        arr = np.full(n, as_float_array(name, value)[()])
    return finite(name, arr)


def covariance(name: str, value, n: int | None = None, *, batch: bool = False,
               tol: float = 1e-10) -> np.ndarray:
    """Check a covariance matrix (or a batch of them when ``batch``): square, symmetric, PSD.

    A scalar is accepted for ``n == 1`` (or ``n`` unknown) and becomes a 1x1 matrix.
    """
    arr = as_float_array(name, value)
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    if arr.ndim < 2 or (not batch and arr.ndim != 2):
        raise ValueError(f"{name}: expected a square matrix{' batch' if batch else ''}, got shape {arr.shape}")
    if arr.shape[-1] != arr.shape[-2]:
        raise ValueError(f"{name}: expected a square matrix, got shape {arr.shape}")
    if n is not None and arr.shape[-1] != n:
        raise ValueError(f"{name}: expected shape ({n}, {n}), got {arr.shape}")
    if arr.shape == (1, 1) and math.isfinite(arr[0, 0]):  # one variance: the checks below are its sign
        if arr[0, 0] < -tol * max(1.0, abs(arr[0, 0])):  # (a fit's Q, R, P0 at every evaluation: no LAPACK)
            raise ValueError(f"{name}: expected a positive semi-definite matrix, "
                             f"got smallest eigenvalue {arr[0, 0]:.3g}")
        return arr
    finite(name, arr)
    scale = max(1.0, float(np.max(np.abs(arr)))) if arr.size else 1.0
    asym = np.max(np.abs(arr - np.swapaxes(arr, -1, -2))) if arr.size else 0.0
    if asym > tol * scale:
        raise ValueError(f"{name}: expected a symmetric matrix, got asymmetry {asym:.3g}")
    if arr.size:
        w = np.linalg.eigvalsh(0.5 * (arr + np.swapaxes(arr, -1, -2)))
        if np.min(w) < -tol * scale:
            raise ValueError(f"{name}: expected a positive semi-definite matrix, "
                             f"got smallest eigenvalue {np.min(w):.3g}")
    return arr


def real(name: str, value) -> float:
    """A finite real scalar (a time, an offset) as a float."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.ndarray)) or np.ndim(value):
        raise TypeError(f"{name}: expected a real number, got {shown(value)}")
    if np.iscomplexobj(value) or not np.isfinite(value):
        raise (TypeError if np.iscomplexobj(value) else ValueError)(
            f"{name}: expected a finite real number, got {shown(value)}")
    return float(value)


def time_grid(t0: float, dt: float, steps: int) -> float:
    """``t0`` of a time grid ``t0 + k·dt``, ``k = 0..steps``, refused (naming ``t0``) where float64
    cannot resolve the step: its spacing at the grid's largest ``|t|`` must be at most ``1e-4·dt``
    (at ``t0 = 1e300`` every ``t0 + k·dt`` is the same number, and an integrator over the grid
    cannot advance)."""
    far = abs(t0) + steps * dt
    if not np.spacing(far) <= 1e-4 * dt:
        raise ValueError(f"t0: the time grid t0 + k·dt (dt = {dt:g}, {steps} steps) is not resolved in float64 at "
                         f"t0 = {t0!r} (spacing {np.spacing(far):.3g} there); expected |t0| well below "
                         f"{1e-4 * dt / np.finfo(float).eps:.3g}")
    return t0


def measurement_times(name: str, value, t0: float = 0.0) -> np.ndarray:
    """Measurement times ``t_1 < t_2 < ...`` after the prior's ``t0`` (irregular intervals of a
    continuous-discrete model), as a read-only float array ``(T,)``: finite, strictly increasing
    (a time repeated or out of order is a ValueError naming ``name`` and the first such entry)."""
    t = as_float_array(name, value, ndim=1).copy()
    if t.size == 0:
        raise ValueError(f"{name}: got no times; expected at least one measurement time")
    finite(name, t)
    if not t[0] > t0:
        raise ValueError(f"{name}: got the first time {float(t[0])!r}; expected times after the prior's time t0 = {t0!r}")
    d = np.diff(t)
    if np.any(d <= 0):
        k = int(np.flatnonzero(d <= 0)[0]) + 1
        if d[k - 1] == 0:
            raise ValueError(f"{name}: got the time {float(t[k])!r} twice (entries {k - 1} and {k}); expected "
                             "strictly increasing times, each once")
        raise ValueError(f"{name}: got the time {float(t[k])!r} (entry {k}) after {float(t[k - 1])!r} (entry {k - 1}); "
                         "expected strictly increasing times, in order")
    time_grid(t0, float(d.min()) if d.size else float(t[0] - t0), t.size)
    t.setflags(write=False)
    return t


MEMORY_BOUND = 8 * 2 ** 30  # bytes: a run or simulation that would allocate more is refused up front


def memory(name: str, nbytes: float, what: str) -> None:
    """Refuse, naming ``name``, a call whose arrays (``what``) would take more than :data:`MEMORY_BOUND`."""
    if nbytes > MEMORY_BOUND:
        raise ValueError(f"{name}: {what} would need {nbytes / 2 ** 30:.3g} GiB, more than the "
                         f"{MEMORY_BOUND / 2 ** 30:g} GiB bound; expected fewer (or run them in chunks)")


def positive(name: str, value, *, strict: bool = True, integer: bool = False):
    """A positive (or non-negative) scalar."""
    if integer:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise TypeError(f"{name}: expected an integer, got {shown(value)}")
    elif isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a real number, got {shown(value)}")
    if not np.isfinite(value) or (value <= 0 if strict else value < 0):
        raise ValueError(f"{name}: expected a {'positive' if strict else 'non-negative'} "
                         f"{'integer' if integer else 'number'}, got {shown(value)}")
    return value


def shown(value, limit: int = 80) -> str:
    """A short ``repr`` of any object for an error message: bounded in length (a large array, a
    long list) and never failing (an object whose ``__repr__`` raises shows its type)."""
    try:
        r = reprlib.Repr()
        r.maxstring = r.maxother = limit
        text = r.repr(value)
    except Exception:  # noqa: BLE001 - a message must not fail on a hostile __repr__
        text = f"<{type(value).__name__} object>"
    return text if len(text) <= limit else text[:limit - 3] + "..."


def choice(name: str, value, options):
    """``value`` if it is one of ``options`` (a set of strings), else a ValueError naming ``name``,
    for any Python object: an unhashable one (a list, a dict, an array), one whose
    ``__eq__``/``__hash__``/``__repr__`` raises or returns an array, is refused with that
    message, never with NumPy's or Python's own error. The option of ``options`` equal to
    ``value`` is returned (a ``numpy.str_`` becomes the ``str``)."""
    match = None
    if isinstance(value, str):  # options are strings: nothing else can match, and str hashing cannot fail
        match = next((o for o in options if str.__eq__(o, value) is True), None)
    if match is None:
        raise ValueError(f"{name}: expected one of {sorted(options)!r}, got {shown(value)}")
    return match
