"""Figures (matplotlib, object-oriented API, no global state).

An experiment puts what a reader would rather look at into ``Result.series``: a dict of panels,
each ``{"x": array, "lines": {label: y array}, "xlabel": str, "ylabel": str,
"logx": bool, "logy": bool, "bands": {label: (lo, hi)}}``. :func:`plot_result` draws them side by
side and writes one PNG.
"""

from __future__ import annotations

import math
import textwrap

import numpy as np


def plot_result(result, path, *, dpi: int = 120) -> None:
    """Write the panels of ``result.series`` to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    panels = result.series
    if not panels:
        raise ValueError(f"result of {result.experiment!r}: has no series to plot")
    ncol = min(3, len(panels))
    nrow = math.ceil(len(panels) / ncol)
    fig = Figure(figsize=(max(7.0, 5.2 * ncol), 3.8 * nrow + 0.4), layout="constrained")
    for i, (name, panel) in enumerate(panels.items()):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        x = np.asarray(panel["x"])
        for label, y in panel["lines"].items():
            style = panel.get("styles", {}).get(label, "-")
            ax.plot(x, np.asarray(y), style, label=label, lw=1.3, ms=4)
        for label, (lo, hi) in panel.get("bands", {}).items():
            ax.fill_between(x, lo, hi, alpha=0.2, label=label)
        if panel.get("logx"):
            ax.set_xscale("log")
        if panel.get("logy"):
            ax.set_yscale("log")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(panel.get("xlabel", ""))
        ax.set_ylabel(panel.get("ylabel", ""))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(textwrap.fill(f"{result.experiment}: {result.title}", 110), fontsize=10)
    fig.savefig(path, dpi=dpi)
