"""Figures (matplotlib, object-oriented API, no global state).

An experiment puts what a reader would rather look at into ``Result.series``: a dict of panels,
drawn side by side into one PNG by :func:`plot_result`. Two kinds of panel:

* line panel (default)::

    {"x": array (increasing), "lines": {label: y array}, "xlabel": str, "ylabel": str,
     "logx": bool, "logy": bool, "styles": {label: fmt},
     "bands": {label: (lo, hi)},          # shaded; a band keyed by a line's label takes its colour
     "paper": {label: (x, y)},            # the paper's values as hollow diamonds, "label (paper)";
                                          # x None: a dotted horizontal line at y
     "points": {label: (x, y, err)},      # single measured values with error bars
     "note": str}                         # one line under the panel's title

* bar panel (categories on x, one bar per group, e.g. filters × problems)::

    {"kind": "bar", "categories": [str], "bars": {label: values}, "errors": {label: values},
     "paper": {label: values (None where the paper gives none)}, "xlabel", "ylabel", "logy"}

``logy`` not stated: a log y-axis when the panel's values are all positive and span more than
:data:`LOG_DECADES` decades (one bad filter at MSE 2000 would otherwise flatten every other
curve); ``logy=False`` keeps a linear axis.

Colours follow the label across all panels of a figure; "optimal" (or "optimal (…)") is black and
drawn thicker, so the gap to the optimal filter reads the same everywhere.
"""

from __future__ import annotations

import math
import textwrap

import numpy as np

from .sources import cite

_PAPER = dict(marker="D", ms=7, mfc="none", mew=1.6, ls="none", zorder=5)
#: a panel whose positive values span more decades than this gets a log y-axis
LOG_DECADES = 2.0


def _values(panel) -> np.ndarray:
    """Every y value a panel draws (lines, points, the paper's values, bars), finite ones only."""
    ys = [np.asarray(y, dtype=float).ravel() for y in panel.get("lines", {}).values()]
    ys += [np.asarray(p[1], dtype=float).ravel() for p in panel.get("points", {}).values()]
    ys += [np.asarray(p[1] if panel.get("kind", "line") == "line" else p, dtype=float).ravel()
           for p in panel.get("paper", {}).values() if p is not None and not isinstance(p, (int, float))]
    ys += [np.asarray(v, dtype=float).ravel() for v in panel.get("bars", {}).values()]
    v = np.concatenate(ys) if ys else np.zeros(0)
    return v[np.isfinite(v)]


def log_scale(panel) -> bool:
    """Whether a panel's y-axis is logarithmic: its ``logy`` if stated, else whether its values
    are all positive and span more than :data:`LOG_DECADES` decades."""
    if panel.get("logy") is not None:
        return bool(panel["logy"])
    v = _values(panel)
    return bool(v.size) and v.min() > 0 and math.log10(v.max() / v.min()) > LOG_DECADES


class _Colours:
    """One colour per label for the whole figure; "optimal…" labels are black."""

    def __init__(self):
        from matplotlib import colormaps

        self._cycle = [colormaps["tab10"](i) for i in range(10)]
        self._seen: dict[str, tuple] = {}

    def __call__(self, label: str):
        key = _key(label)
        if key == "optimal":
            return (0.0, 0.0, 0.0, 1.0)
        if key not in self._seen:
            self._seen[key] = self._cycle[len(self._seen) % len(self._cycle)]
        return self._seen[key]


def _key(label: str) -> str:
    """The filter a label names: "optimal (MC)" -> "optimal"."""
    return label.split(" (")[0].strip().lower()


def plot_result(result, path, *, dpi: int = 100) -> None:
    """Write the panels of ``result.series`` to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    panels = result.series
    if not panels:
        raise ValueError(f"result of {result.experiment!r}: has no series to plot")
    n = len(panels)
    ncol = 2 if n == 4 else min(3, n)
    nrow = math.ceil(n / ncol)
    shared = _shared_labels(panels)  # line panels showing the same filters share one legend
    cols = {i % ncol for i, (k, p) in enumerate(panels.items()) if k not in shared and _outside(p)}
    width = 5.0 * ncol + 1.9 * len(cols) + (1.9 if shared else 0.0)  # room for legends right of axes
    fig = Figure(figsize=(max(7.5, width), 3.7 * nrow + 0.7), layout="constrained")
    colour = _Colours()
    handles = {}
    for i, (name, panel) in enumerate(panels.items()):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        if panel.get("kind", "line") == "bar":
            _bars(ax, panel, colour)
        else:
            _lines(ax, panel, colour)
        if panel.get("logx"):
            ax.set_xscale("log")
        if log_scale(panel):
            ax.set_yscale("log")
        wrap = 60 if ncol > 1 else 90
        title = textwrap.fill(cite(name), wrap) + ("\n" + textwrap.fill(panel["note"], wrap) if panel.get("note") else "")
        ax.set_title(title, fontsize=9.5)
        ax.set_xlabel(panel.get("xlabel", ""), fontsize=9)
        ax.set_ylabel(panel.get("ylabel", ""), fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(alpha=0.3)
        h, labels = ax.get_legend_handles_labels()
        if shared and name in shared:
            handles[i] = dict(zip(labels, h))
        elif _outside(panel):
            ax.legend(fontsize=7.5, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        else:
            ax.legend(fontsize=7.5, framealpha=0.85)
    if handles:  # in the order of the fullest panel, then what the others add; the band note last
        merged = {}
        for per in sorted(handles.values(), key=len, reverse=True):
            merged.update({k: v for k, v in per.items() if k not in merged})
        merged = dict(sorted(merged.items(), key=lambda kv: kv[0].startswith("shaded")))
        fig.legend(list(merged.values()), list(merged), loc="outside right upper", fontsize=8)
    title, source = _heading(result)
    head = textwrap.fill(f"{result.experiment}: {title}", 130)
    fig.suptitle(f"{head}\n" + textwrap.fill(f"source: {cite(source)}", 130), fontsize=10)
    import io

    from .results import atomic_write

    buf = io.BytesIO()  # drawn in memory, then written atomically: never a partial PNG
    fig.savefig(buf, dpi=dpi, format="png")
    atomic_write(path, buf.getvalue())


def _heading(result) -> tuple[str, str]:
    """The registered experiment's full title and source (the result's own if not registered)."""
    from .experiments import registry

    exp = registry().get(result.experiment)
    return (exp.title, exp.source) if exp else (result.title, result.source)


def _shared_labels(panels) -> set:
    """Names of the line panels that share one figure legend (empty: each panel keeps its own)."""
    lines = {k: set(p.get("lines", {})) | set(p.get("paper", {})) for k, p in panels.items()
             if p.get("kind", "line") == "line"}
    if len(lines) < 2:
        return set()
    union = set().union(*lines.values())
    if all(len(v) >= 0.6 * len(union) for v in lines.values()) and len(union) > 2:
        return set(lines)
    return set()


def _outside(panel) -> bool:
    """Long legends, and those of grouped bars (which fill the axes), go right of the axes."""
    return _n_entries(panel) > 5 or (panel.get("kind") == "bar" and len(panel.get("bars", {})) > 1)


def _many_paper(paper) -> bool:
    """More than two paper markers on a line panel: one legend entry for all of them."""
    return sum(px is not None for px, _ in paper.values()) > 2


def _n_entries(panel) -> int:
    paper = panel.get("paper", {})
    many = panel.get("kind", "line") == "line" and _many_paper(paper)
    return sum(len(panel.get(k, {})) for k in ("lines", "bars", "points")) + (1 if many else len(paper))


def _lines(ax, panel, colour):
    x = np.asarray(panel["x"], dtype=float)
    lines = panel.get("lines", {})
    for label, y in lines.items():
        style = panel.get("styles", {}).get(label, "-")
        lw = 2.0 if _key(label) == "optimal" else 1.3
        kw = {} if any(c in style for c in "bgrcmykw") else {"color": colour(label)}  # fmt colour wins
        ax.plot(x, np.asarray(y, dtype=float), style, label=label, lw=lw, ms=4, **kw)
    shaded = False
    for label, (lo, hi) in panel.get("bands", {}).items():
        if label in lines:  # the Monte Carlo band of a line: its colour, one legend entry for all
            ax.fill_between(x, lo, hi, color=colour(label), alpha=0.15, lw=0)
            shaded = True
        else:
            ax.fill_between(x, lo, hi, alpha=0.2, label=label, color=colour(label))
    for label, (px, py, err) in panel.get("points", {}).items():
        ax.errorbar(px, py, yerr=err, fmt="o", ms=5, capsize=3, color=colour(label), label=label, zorder=4)
    paper = panel.get("paper", {})
    many = _many_paper(paper)
    for label, (px, py) in paper.items():
        if px is None:
            ax.axhline(py, color=colour(label), ls=":", lw=1.4, label=f"{label} (paper)")
        else:
            ax.plot(px, py, color=colour(label), label="_" if many else f"{label} (paper)", **_PAPER)
    if many:
        ax.plot([], [], color="k", label="paper (◇ in its line's colour)", **_PAPER)
    if shaded:  # one legend entry for all Monte Carlo bands
        ax.fill_between([], [], [], color="0.5", alpha=0.3, lw=0, label="shaded: ± 2 s.e. (Monte Carlo)")


def _bars(ax, panel, colour):
    cats = list(panel["categories"])
    groups = list(panel["bars"])
    k = np.arange(len(cats))
    w = 0.8 / max(1, len(groups))
    labelled = False
    for j, label in enumerate(groups):
        xs = k - 0.4 + w * (j + 0.5)
        y = np.asarray(panel["bars"][label], dtype=float)
        err = panel.get("errors", {}).get(label)
        col = [colour(c) for c in cats] if len(groups) == 1 else colour(label)  # one group: filter colours
        ax.bar(xs, y, w * 0.92, color=col, alpha=0.85, label=label,
               yerr=None if err is None else np.asarray(err, dtype=float), capsize=2,
               error_kw={"lw": 0.8})
        pap = panel.get("paper", {}).get(label)
        if pap is not None:
            py = np.array([np.nan if v is None else v for v in pap], dtype=float)
            if np.isfinite(py).any():
                ax.plot(xs, py, color="k", label="_" if labelled else "paper", **_PAPER)  # one legend entry
                labelled = True
    tilt = max(map(len, cats), default=0) > 9
    ax.set_xticks(k, cats, rotation=25 if tilt else 0, ha="right" if tilt else "center",
                  rotation_mode="anchor", fontsize=8)
    if panel.get("ylim") is not None:
        ax.set_ylim(*panel["ylim"])
