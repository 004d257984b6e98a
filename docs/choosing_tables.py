"""The tables of ``choosing.rst``: small :func:`nlfilter.compare` runs made at build time.

    PYTHONPATH=src python docs/choosing_tables.py      # writes docs/_generated/choosing_*.rst

Each table is one ``compare(model, "all", ...)`` on common random numbers against the certified
reference; sizes are small (a few seconds each) so that the documentation build stays fast; the
standard errors printed beside the numbers say how far they can be trusted.
"""

from pathlib import Path

import numpy as np
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, compare
from nlfilter.problems import quadratic

x = sp.Symbol("x")


def cases():
    """name -> (title, the ``compare`` call as a zero-argument function, its description)."""
    cubic = DiscreteModel([x], f=[0.99 * x], h=[x**3], Q=0.01, R=0.1)
    quad = quadratic()
    oh_shin = SDEModel([x], [-x**3], [x], Q=0.05, R=0.05)
    return {
        "cubic": ("Discrete cubic sensor (the README's quickstart)",
                  lambda: compare(cubic, "all", 200, paths=200, m0=0.5, P0=0.1, rng=0),
                  "``x[k+1] = 0.99 x + w``, ``y = x³ + v``, Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1; "
                  "200 steps, 200 paths, MSE over the second half."),
        "quadratic": ("Strong quadratic measurement (Henriksen's (1979) problem)",
                      lambda: compare(quad.model, "all", quad.steps, paths=200, m0=quad.m0, P0=quad.P0, rng=0,
                                      on_divergence="mark"),
                      ":func:`nlfilter.problems.quadratic`: "
                      "``x[k+1] = 0.7 x + 0.02 x² + w``, ``y = x + 0.3 x² + v``, q = 1, r = 0.2, P0 = 1; "
                      "50 steps, 200 paths, MSE over the second half."),
        "oh-shin": ("Continuous time: Oh & Shin's (1995) example",
                    lambda: compare(oh_shin, "all", 100, paths=60, m0=4.0, P0=0.05, dt=0.01, substeps=5, rng=0),
                    "``dx = −x³ dt + dβ``, ``dy = x dt + dη``, Q = R = 0.05, m0 = 4, D0 = 0.05, dt = 0.01; "
                    "t ∈ [0, 1], 60 paths, MSE over the second half."),
    }


def _fmt(row):
    if row is None or not np.isfinite(row.value):
        return "–"
    if row.stderr is None:
        return f"{row.value:.4g}"
    return f"{row.value:.4g} ± {row.stderr:.2g}"


def table(res) -> str:
    """A reST list-table of ``res``: per filter MSE, gap to the reference, NEES, divergence rate."""
    names = list(dict.fromkeys(r.filter for r in res.rows))

    def get(name, quantity, **params):
        try:
            return res.get(name, quantity, **params)
        except (KeyError, LookupError, ValueError):
            return None

    lines = [".. list-table::", "   :header-rows: 1", "",
             "   * - filter", "     - MSE (± s.e.)", "     - gap to optimal (paired)", "     - NEES",
             "     - divergence rate"]
    for name in names:
        gap = get(name, "gap_to_optimal", component=0) or get(name, "gap_to_reference", component=0)
        nees = get(name, "nees") or get(name, "offline_mse", component=0)
        nees_txt = _fmt(nees) if nees is None or nees.quantity == "nees" else f"(off-line MSE {_fmt(nees)})"
        lines += [f"   * - ``{name}``", f"     - {_fmt(get(name, 'mse', component=0))}", f"     - {_fmt(gap)}",
                  f"     - {nees_txt}", f"     - {_fmt(get(name, 'divergence_rate'))}"]
    return "\n".join(lines) + "\n"


def write(out: Path) -> None:
    """Write ``choosing_<case>.rst`` (a title-less block: description, table, reference) to ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    for key, (title, run, desc) in cases().items():
        res = run()
        ref = res.params["reference"]
        skipped = res.params.get("skipped") or {}
        text = [f"**{title}.** {desc}", "", table(res), "",
                f"Reference: {ref['label']} ({ref['kind']}). "
                + (f"Not run on this model: {', '.join(f'``{s}``' for s in skipped)}." if skipped else ""), ""]
        (out / f"choosing_{key}.rst").write_text("\n".join(text), encoding="utf-8")


if __name__ == "__main__":
    write(Path(__file__).resolve().parent / "_generated")
