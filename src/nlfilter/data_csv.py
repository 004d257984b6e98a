"""Measurements as CSV files, checked against a model file (:mod:`nlfilter.modelfile`): what
``nlfilter simulate MODEL.toml --out DATA.csv`` writes and ``nlfilter fit MODEL.toml DATA.csv``
reads.

The file
--------
One header line, then one line per measurement::

    path,t,y1,theta,omega
    0,0,0.8127,0.9981,0.0173
    0,1,0.7702,0.9952,-0.0586
    ...

* the measurements: one column per entry of ``h``, named by the file's ``[measurement] names``
  (default ``y1 .. ym``); an empty cell or ``nan`` is a missing measurement;
* ``t``: the measurement times — required for a ``continuous-discrete`` model without ``dt``
  (strictly increasing, after the prior's time 0: irregular intervals are what it is for); for
  the other kinds optional and checked: a ``discrete`` model's steps ``0, 1, ..., T-1``, an
  ``sde``'s interval ends ``dt, 2 dt, ..., T dt``, a continuous-discrete model with ``dt`` its
  ``dt, 2 dt, ...``;
* ``path`` (optional): the record a line belongs to, for several independent records that share
  the parameters (a fit sums their log-likelihoods); every record has the same times;
* the states, by their names (optional: what ``simulate --states`` writes, the truth; a fit
  ignores them).

Any other column, a column twice, a missing measurement column, a value that is not a number, a
time repeated or out of order is a :class:`DataFileError` (a ``ValueError``) of one line
``FILE:LINE: COLUMN: what was given; what was expected``.
"""

from __future__ import annotations

import csv
import math
import pathlib
from typing import NamedTuple

import numpy as np

__all__ = ["DataFileError", "Data", "read_csv", "write_csv"]


class DataFileError(ValueError):
    """A data file that does not fit its model: ``FILE:LINE: COLUMN: what was given; what was expected``."""


class Data(NamedTuple):
    """What a data file holds: ``ys (paths, T, m)`` (NaN: missing), ``times (T,)`` (None when the
    file has no ``t`` column), ``xs (paths, T, n)`` the states when given (else None) and the
    ``paths`` labels in the order of ``ys``."""

    ys: np.ndarray
    times: np.ndarray | None
    xs: np.ndarray | None
    paths: tuple


def write_csv(path, spec, ys, times, xs=None) -> None:
    """Write ``ys (paths, T, m)`` measured at ``times (T,)`` (and the states ``xs (paths, T, n)``
    when given) as the CSV file above, the columns named after ``spec``'s measurements and
    states; the ``path`` column only for more than one record. Numbers are written with
    ``repr`` (read back exactly)."""
    ys = np.asarray(ys, dtype=float)
    P, T, m = ys.shape
    names = list(spec.names)
    states = [str(s) for s in spec.model.states] if xs is not None else []
    header = (["path"] if P > 1 else []) + ["t"] + names + states
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for p in range(P):
            for k in range(T):
                row = ([p] if P > 1 else []) + [repr(float(times[k]))] + [repr(float(v)) for v in ys[p, k]]
                if xs is not None:
                    row += [repr(float(v)) for v in xs[p, k]]
                w.writerow(row)


def _number(fail, line, column, text) -> float:
    s = text.strip()
    if s == "" or s.lower() == "nan":
        return math.nan
    try:
        v = float(s)
    except ValueError:
        fail(line, column, f"got {s[:40]!r}; expected a number (empty or nan: missing)")
    if math.isinf(v):
        fail(line, column, f"got {s[:40]!r}; expected a finite number (empty or nan: missing)")
    return v


def read_csv(path, spec) -> Data:
    """Read a data file for the model file ``spec`` (a :class:`~nlfilter.modelfile.ModelSpec`):
    the columns checked against its measurement and state names, the times against its kind
    (module docstring).

    Raises
    ------
    DataFileError
        (a ``ValueError``) one line ``FILE:LINE: COLUMN: what was given; what was expected``: an
        unreadable file, no header, an unknown, repeated or missing column, a line of another
        length, a value that is not a number, a time repeated or out of order, records with
        different times.
    """
    name = str(path)

    def fail(line, column, what):
        raise DataFileError(f"{name}:{line}: {column}: {what}")

    try:
        text = pathlib.Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        fail(1, "file", f"got {type(exc).__name__} ({getattr(exc, 'strerror', None) or exc}); expected a readable "
                        "CSV file (UTF-8 text)")
    rows = [(no, r) for no, r in enumerate(csv.reader(text.splitlines()), 1) if r and any(c.strip() for c in r)]
    if not rows:
        fail(1, "header", "got an empty file; expected a header line and one line per measurement")
    hno, header = rows[0]
    header = [c.strip() for c in header]
    meas, states = list(spec.names), [str(s) for s in spec.model.states]
    known = ["path", "t", *meas, *states]
    for c in header:
        if c not in known:
            fail(hno, c or "header", f"got the unknown column {c!r}; expected the columns {meas} (the model's "
                                     f"measurements), 't' (times), 'path' (records) and optionally the states {states}")
    for c in header:
        if header.count(c) > 1:
            fail(hno, c, f"got the column {c!r} {header.count(c)} times; expected it once")
    missing = [c for c in meas if c not in header]
    if missing:
        fail(hno, missing[0], f"got no column {missing[0]!r}; expected one column per measurement {meas} (the "
                              f"model's [measurement] names; the header is {header})")
    body = rows[1:]
    if not body:
        fail(hno + 1, "data", "got a header and no data; expected one line per measurement")
    col = {c: i for i, c in enumerate(header)}
    records = {}  # path label -> list of (line, t, y, x)
    for no, r in body:
        if len(r) != len(header):
            fail(no, "line", f"got {len(r)} values; expected {len(header)} (one per column of the header)")
        label = r[col["path"]].strip() if "path" in col else "0"
        if "path" in col and not label:
            fail(no, "path", "got an empty record label; expected the record (path) the line belongs to")
        t = _number(fail, no, "t", r[col["t"]]) if "t" in col else None
        if t is not None and math.isnan(t):
            fail(no, "t", f"got {r[col['t']].strip()!r}; expected a finite time")
        y = [_number(fail, no, c, r[col[c]]) for c in meas]
        x = [_number(fail, no, c, r[col[c]]) for c in states if c in col]
        records.setdefault(label, []).append((no, t, y, x))
    T = {len(v) for v in records.values()}
    if len(T) > 1:
        lens = {k: len(v) for k, v in records.items()}
        fail(body[-1][0], "path", f"got records of different lengths {lens}; expected every record to have the "
                                  "same measurement times")
    times = None
    if "t" in col:
        first = next(iter(records.values()))
        times = np.array([t for _, t, _, _ in first])
        for k in range(1, len(first)):
            if first[k][1] == first[k - 1][1]:
                fail(first[k][0], "t", f"got the time {first[k][1]!r} again (lines {first[k - 1][0]} and "
                                       f"{first[k][0]}); expected strictly increasing times, each once")
            if first[k][1] < first[k - 1][1]:
                fail(first[k][0], "t", f"got the time {first[k][1]!r} after {first[k - 1][1]!r} (line "
                                       f"{first[k - 1][0]}); expected strictly increasing times (sort the lines)")
        for label, rec in records.items():
            for (no, t, _, _), want in zip(rec, times):
                if t != want:
                    fail(no, "t", f"got the time {t!r} in record {label!r}; expected {want!r}, the time of the "
                                  "same line of the first record (every record has the same times)")
        _check_times(spec, times, first, fail)
    elif spec.kind == "continuous-discrete" and spec.dt is None:
        fail(hno, "t", f"got no column 't'; expected the measurement times (a continuous-discrete model without "
                       f"[measurement] dt; the header is {header})")
    ys = np.array([[y for _, _, y, _ in rec] for rec in records.values()], dtype=float)
    xs = None
    if all(c in col for c in states):
        xs = np.array([[x for _, _, _, x in rec] for rec in records.values()], dtype=float)
    return Data(ys, times, xs, tuple(records))


def _check_times(spec, times, first, fail) -> None:
    """The times of a data file against the model's kind (module docstring)."""
    T = len(times)
    if spec.kind == "continuous-discrete" and spec.dt is None:
        if times[0] <= 0:
            fail(first[0][0], "t", f"got the first time {float(times[0])!r}; expected a time after the prior's, 0 (the "
                                   "first measurement follows the prior)")
        return
    if spec.kind == "discrete":
        want, what = np.arange(T, dtype=float), "the steps 0, 1, ..., T-1 (a discrete model)"
    else:
        want, what = spec.dt * np.arange(1, T + 1), f"dt, 2 dt, ... with dt = {spec.dt!r} (the file's [measurement] dt)"
    bad = np.flatnonzero(~np.isclose(times, want, rtol=1e-9, atol=1e-12 * max(1.0, abs(float(want[-1])))))
    if bad.size:
        k = int(bad[0])
        fail(first[k][0], "t", f"got the time {float(times[k])!r}; expected {float(want[k])!r}: {what}")
