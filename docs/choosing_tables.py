"""The tables of ``choosing.rst``: small :func:`nlfilter.compare` runs, committed as JSON.

    PYTHONPATH=src python docs/choosing_tables.py      # reruns them: writes docs/choosing/<case>.json

Each table is one ``compare(model, "all", ...)`` on common random numbers against the certified
reference; the standard errors printed beside the numbers say how far they can be trusted. The runs
(a minute of CPU with every registered filter, most of it the certified references) are made by
the command above and committed, like the reproduction report; the documentation build renders
the committed JSON (:func:`write`) with each run's provenance. ``tests/test_docs.py`` checks that
each committed run covers exactly the filters ``compare(model, "all")`` would run or skip today, so a
newly registered filter cannot be missing from the tables.
"""

import sys
from pathlib import Path

import numpy as np
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, compare
from nlfilter.problems import quadratic

x = sp.Symbol("x")


def cases():
    """name -> (title, model, the ``compare(model, "all", steps, **kwargs)`` arguments
    ``(steps, kwargs)``, its description)."""
    cubic = DiscreteModel([x], f=[0.99 * x], h=[x**3], Q=0.01, R=0.1)
    quad = quadratic()
    oh_shin = SDEModel([x], [-x**3], [x], Q=0.05, R=0.05)
    return {
        "cubic": ("Discrete cubic sensor (the README's quickstart)", cubic,
                  (200, dict(paths=200, m0=0.5, P0=0.1, rng=0)),
                  "``x[k+1] = 0.99 x + w``, ``y = x³ + v``, Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1; "
                  "200 steps, 200 paths, MSE over the second half."),
        "quadratic": ("Strong quadratic measurement (Henriksen's (1979) problem)", quad.model,
                      (quad.steps, dict(paths=200, m0=quad.m0, P0=quad.P0, rng=0, on_divergence="mark")),
                      ":func:`nlfilter.problems.quadratic`: "
                      "``x[k+1] = 0.7 x + 0.02 x² + w``, ``y = x + 0.3 x² + v``, q = 1, r = 0.2, P0 = 1; "
                      "50 steps, 200 paths, MSE over the second half."),
        "oh-shin": ("Continuous time: Oh & Shin's (1995) example", oh_shin,
                    (100, dict(paths=60, m0=4.0, P0=0.05, dt=0.01, substeps=5, rng=0)),
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


#: the committed runs, one ``<case>.json`` (:meth:`nlfilter.results.Result.to_json`) per case
RUNS = Path(__file__).resolve().parent / "choosing"


def run_all(folder: Path = RUNS) -> None:
    """Run every case's ``compare`` and write its Result to ``folder/<case>.json``."""
    folder.mkdir(parents=True, exist_ok=True)
    for key, (_, model, (steps, kwargs), _) in cases().items():
        compare(model, "all", steps, **kwargs).to_json(folder / f"{key}.json")


def _provenance(meta: dict) -> str:
    secs = (meta.get("execution") or {}).get("seconds")
    return (f"Computed by ``python docs/choosing_tables.py`` with nlfilter {meta['nlfilter']}, NumPy "
            f"{meta['numpy']} and Python {meta['python']} on {meta['timestamp'][:10]}"
            + (f" ({secs:.0f} s)." if isinstance(secs, (int, float)) else "."))


def write(out: Path, folder: Path = RUNS) -> None:
    """Write ``choosing_<case>.rst`` (a title-less block: description, table, reference, provenance)
    to ``out`` from the committed runs in ``folder``."""
    from nlfilter.results import Result

    out.mkdir(parents=True, exist_ok=True)
    for key, (title, _, _, desc) in cases().items():
        res = Result.from_json(folder / f"{key}.json")
        ref = res.params["reference"]
        skipped = res.params.get("skipped") or {}
        text = [f"**{title}.** {desc}", "", table(res), "",
                f"Reference: {ref['label']} ({ref['kind']}). "
                + (f"Not run on this model: {', '.join(f'``{s}``' for s in skipped)}. " if skipped else "")
                + _provenance(res.meta), ""]
        (out / f"choosing_{key}.rst").write_text("\n".join(text), encoding="utf-8")


if __name__ == "__main__":
    run_all(Path(sys.argv[1]) if len(sys.argv) > 1 else RUNS)
