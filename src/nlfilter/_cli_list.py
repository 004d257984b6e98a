"""``nlfilter list`` (the experiments: id, title, source; ``--params``: what ``--param`` takes) and
``nlfilter list --filters`` (the filter registry: a table with a header that fits 100 columns,
``--wide``: every field). Sources are named as a reader expects (:func:`nlfilter.sources.cite`)."""

from __future__ import annotations

import re

from .sources import cite

WIDTH = 100  # the columns ``nlfilter list --filters`` fits in (``--wide``: no limit)
_YEAR = re.compile(r"\b(?:1[89]|20)\d\d\b\)?")


def _show(value) -> str:
    """A default as ``--param`` takes it (lists comma-separated)."""
    if isinstance(value, (list, tuple)):
        return ",".join(map(str, value))
    return str(value)


def list_experiments(params: bool) -> None:
    """One line per experiment, ``id<TAB>title<TAB>source``; with ``params`` its ``--param NAME=DEFAULT``
    lines (and their ranges) under it."""
    from . import experiments

    for exp in experiments.registry().values():
        print(f"{exp.id}\t{exp.title}\t{cite(exp.source)}")
        if params:
            for name, default in sorted(exp.params.items()):
                rng = exp.ranges.get(name)
                shown = "" if rng is None else ("  (one of " + ", ".join(rng) + ")" if isinstance(rng, tuple)
                                                else "  (" + rng.replace(",", ", ") + ")")
                print(f"    --param {name}={_show(default)}{shown}")


def short_source(text: str) -> str:
    """The first reference of a filter's ``source``, up to its year: "Henriksen (1979)",
    "Julier & Uhlmann 1997" (the whole text when it names no year)."""
    text = cite(text)
    m = _YEAR.search(text)
    return text[:m.end()] if m else text


def _fit(text: str, width: int) -> str:
    return text if len(text) <= width else text[:max(width - 1, 0)] + "…"


def list_filters(wide: bool) -> list[str]:
    """The lines of ``nlfilter list --filters``: the registry grouped by family (in registry order),
    each filter's name, time, model kinds and its first reference, cut to :data:`WIDTH` columns;
    ``wide``: every field of :func:`nlfilter.filters.registry.table`, uncut."""
    from .filters import REGISTRY
    from .filters.registry import table
    from .report import _columns

    rows = table(REGISTRY)
    if wide:
        fields = ["name", "class", "family", "time", "accepts", "needs", "likelihood", "smoother", "source",
                  "measurement_convention"]
        body = [[cite(r[f]) or "-" for f in fields] for r in rows]
        return _columns([f.replace("_", " ") for f in fields], body)
    families = list(dict.fromkeys(r["family"] or "-" for r in rows))
    head = ["name", "time", "accepts"]
    body = [["  " + r["name"], r["time"] or "-", r["accepts"] or "-"] for r in rows]
    widths = [max([len(h)] + [len(b[i]) for b in body]) for i, h in enumerate(head)]
    room = WIDTH - sum(widths) - 2 * len(widths)
    srcs = [_fit(short_source(r["source"]) or "-", room) for r in rows]
    lines = _columns(head + ["source"], [b + [c] for b, c in zip(body, srcs)])[:2]
    for fam in families:
        lines.append(f"{fam}:")
        for r, b, src in zip(rows, body, srcs):
            if (r["family"] or "-") == fam:
                lines.append("  ".join([c.ljust(w) for c, w in zip(b, widths)] + [src]).rstrip())
    lines += ["", "--wide: every field (class, needs, likelihood, smoother, whole source, measurement convention)"]
    return lines
