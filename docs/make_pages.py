"""The generated pages of the documentation: one reproduction page per experiment of the committed
report, and the benchmarks page, both written from the committed JSON at build time.

    PYTHONPATH=src python docs/make_pages.py        # writes them without building the docs

* ``docs/reproduction/<id>.rst`` from ``docs/report/<id>.json`` (the full run that
  ``docs/make_report.py`` commits): the rows with a paper value (paper · nlfilter · s.e. ·
  verdict, by :func:`nlfilter.report.verdict`, the rule the README's tables use), the notes, the
  run's figure ``docs/report/<id>.png``, its provenance, and the committed single runs of the same
  experiment (``docs/report/runs/*.json``); ``docs/_generated/reproduction_summary.rst`` the table
  of all of them.
* ``docs/_generated/benchmarks.rst`` from ``benchmarks/results/*.json``: per benchmark the first
  line of its script's docstring, then every run it recorded, its tables (``rows``) and values.

Nothing here computes a number: every value is printed from the JSON (``nlfilter.results``'s
formatting), so the pages cannot drift from the committed results.
"""

from __future__ import annotations

import ast
import json
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def esc(text) -> str:
    """``text`` as literal reST inline text: markup characters escaped, one line, the source papers
    named as a reader names them (:func:`nlfilter.sources.cite`: the JSON may say "seed 004")."""
    from nlfilter.sources import cite

    text = cite(str(text))
    return re.sub(r"([\\`*_|\[\]<>])", r"\\\1", str(text)).replace("\n", " ")


def list_table(header: list[str], rows: list[list[str]], widths: str | None = None) -> str:
    """A reST ``list-table`` (cells are reST already: escape plain text with :func:`esc`)."""
    lines = [".. list-table::", "   :header-rows: 1"] + ([f"   :widths: {widths}"] if widths else []) + [""]
    for row in [header] + rows:
        # an empty cell, or "-" alone (no value), would read as a nested bullet list: "–" instead
        row = ["–" if c in ("", "-") else c for c in row]
        lines += [f"   * - {row[0]}"] + [f"     - {c}" for c in row[1:]]
    return "\n".join(lines) + "\n"


def title(text: str, char: str = "=") -> str:
    return f"{text}\n{char * len(text)}\n"


# -- the reproduction pages --------------------------------------------------------------------

def _verdict_cell(res, row) -> str:
    from nlfilter.report import row_verdict

    v, why = row_verdict(res, row)
    return f"**{v}** ({esc(why)})" if v == "reproduced" else f"*{v}* ({esc(why)})"


def paper_table(res) -> str:
    """The rows of ``res`` that have a paper value: filter, quantity, params, paper, nlfilter, s.e., verdict."""
    from nlfilter.results import _fmt, _fmt_params

    rows = [[f"``{r.filter}``", esc(r.quantity), esc(_fmt_params(r.params)), _fmt(r.paper), _fmt(r.value),
             _fmt(r.stderr), _verdict_cell(res, r)] for r in res.rows if r.paper is not None]
    if not rows:
        return "No row of this experiment has a paper value (a check of nlfilter against itself or a bound).\n"
    return list_table(["filter", "quantity", "params", "paper", "nlfilter", "s.e.", "verdict"], rows)


def other_rows(res) -> str:
    """The rows without a paper value, as one table (filter, quantity, params, nlfilter, s.e.)."""
    from nlfilter.results import _fmt, _fmt_params

    rows = [[f"``{r.filter}``", esc(r.quantity), esc(_fmt_params(r.params)), _fmt(r.value), _fmt(r.stderr)]
            for r in res.rows if r.paper is None]
    return list_table(["filter", "quantity", "params", "nlfilter", "s.e."], rows) if rows else ""


def experiment_page(res, runs, figure: str | None) -> str:
    from nlfilter.report import counts, provenance_line, reader_source
    from nlfilter.sources import cite

    c = counts(res)
    out = [f".. _reproduction-{res.experiment}:", "", title(f"{res.experiment}: {esc(res.title)}"),
           f"Source: {esc(reader_source(res.source))}. Rows with a paper value: **{c['reproduced']} reproduced**, "
           f"**{c['not reproduced']} not reproduced**. Generated from ``docs/report/{res.experiment}.json``; "
           f"the verdict rule is :func:`nlfilter.report.verdict` (within 3 standard errors for a Monte Carlo "
           f"row, to the printed decimals for a deterministic one).", "",
           title("Paper values", "-"), paper_table(res)]
    if res.notes:
        out += [title("Notes", "-")] + [f"* {esc(cite(n))}" for n in res.notes] + [""]
    if figure:
        out += [title("Figure", "-"), f".. image:: {figure}", f"   :alt: the figure of {res.experiment}",
                "   :width: 100%", ""]
    rest = other_rows(res)
    if rest:
        out += [title("All other rows", "-"), rest]
    for name, run in runs:
        rc = counts(run)
        out += [title(f"Committed run {name}", "-"),
                f"{esc(run.title)} (``docs/report/runs/{name}.json``): {rc['reproduced']} reproduced, "
                f"{rc['not reproduced']} not reproduced.", "", paper_table(run),
                *[f"* {esc(cite(n))}" for n in run.notes], "", f"Provenance: {esc(provenance_line(run))}", ""]
    out += [title("Provenance", "-"), esc(provenance_line(res)), ""]
    return "\n".join(out)


def reproduction(report: Path = HERE / "report", out: Path = HERE / "reproduction",
                 generated: Path = HERE / "_generated") -> list[str]:
    """Write one page per ``report/<id>.json`` into ``out`` and the summary table into ``generated``;
    returns the experiment ids."""
    from nlfilter.report import counts, load_folder, reader_source
    from nlfilter.results import Result

    results = load_folder(report)
    runs = [(p.stem, Result.from_json(p)) for p in sorted((report / "runs").glob("*.json"))]
    out.mkdir(parents=True, exist_ok=True)
    generated.mkdir(parents=True, exist_ok=True)
    for stale in out.glob("*.rst"):
        if stale.stem not in results:
            stale.unlink()
    rows = []
    for eid, res in results.items():
        fig = f"../report/{eid}.png" if (report / f"{eid}.png").is_file() else None
        mine = [(n, r) for n, r in runs if r.experiment == eid]
        _write(out / f"{eid}.rst", experiment_page(res, mine, fig))
        c = counts(res)
        secs = (res.meta.get("execution") or {}).get("seconds")
        paths = res.meta.get("paths")
        paths = ", ".join(f"{k} {v}" for k, v in paths.items()) if isinstance(paths, dict) else paths
        rows.append([f":doc:`{eid} <reproduction/{eid}>`", esc(reader_source(res.source)), str(c["reproduced"]),
                     str(c["not reproduced"]), esc(paths), "–" if secs is None else f"{secs:.0f}"])
    total = {k: sum(counts(r)[k] for r in results.values()) for k in ("reproduced", "not reproduced")}
    summary = (f"{len(results)} experiments (full runs); rows with a paper value: **{total['reproduced']} "
               f"reproduced**, **{total['not reproduced']} not reproduced**.\n\n"
               + list_table(["experiment", "source", "reproduced", "not reproduced", "paths", "seconds"], rows))
    _write(generated / "reproduction_summary.rst", summary)
    return list(results)


# -- the benchmarks page -----------------------------------------------------------------------

def _num(x) -> str:
    """A value as plain text: a float at nlfilter's printed precision, anything else as ``str``."""
    from nlfilter.results import _fmt

    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return str(x)
    return str(x) if isinstance(x, int) else _fmt(x)


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


#: the longest cell of a generated table, characters (docutils refuses a line of over 10,000; a run's
#: nested side-by-side rows reach that): a longer one is cut, naming what the JSON holds beyond it
CELL_CHARS = 1500


def _cell(v) -> str:
    """A table cell: a number or a word as text; a dict (flattened to ``key value`` pairs) or a list
    as one literal, so that command-line flags and paths are shown as recorded; cut at
    :data:`CELL_CHARS` (the rest is in the JSON)."""
    if isinstance(v, dict):
        v = ", ".join(f"{k} {_num(x)}" for k, x in _flat(v).items())
    elif isinstance(v, list):
        v = ", ".join(_num(x) for x in v)
    else:
        return esc(_num(v))
    if len(v) > CELL_CHARS:
        v = f"{v[:CELL_CHARS]} … ({len(v) - CELL_CHARS} more characters in the JSON)"
    return f"``{v}``" if v and "``" not in v and not v.startswith(" ") and not v.endswith(" ") else esc(v)


def render_record(rec: dict) -> str:
    """One benchmark record: its scalars as a field table, its notes as a list, each list of dicts
    (``rows``) as a table whose columns are the keys in order of appearance."""
    scalars, tables, notes = {}, {}, []
    for k, v in rec.items():
        if k == "notes" and isinstance(v, list):
            notes += [str(n) for n in v]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tables[k] = v
        elif isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()) and k != "machine":
            tables[k] = [{"": name, **_flat(x)} for name, x in v.items()]
        else:
            scalars[k] = v
    out = []
    if scalars:
        out.append(list_table(["field", "value"], [[esc(k), _cell(v)] for k, v in scalars.items()], "30 70"))
    for name, rows in tables.items():
        cols = list(dict.fromkeys(c for r in rows for c in r))
        out += [f"**{esc(name)}**", "", list_table([esc(c) for c in cols],
                                                   [[_cell(r.get(c, "")) for c in cols] for r in rows])]
    out += [f"* {esc(n)}" for n in notes] + ([""] if notes else [])
    return "\n".join(out)


def _summary_line(script: Path) -> str:
    """The first paragraph of the script's docstring as reST: its inline literals kept, its roles
    (which may name what the API pages do not document) shown as literals, the rest escaped."""
    if not script.is_file():
        return ""
    doc = ast.get_docstring(ast.parse(script.read_text(encoding="utf-8"))) or ""
    text = re.sub(r":[\w:]+:`~?([^`]+)`", r"``\1``", doc.split("\n\n")[0].replace("\n", " "))
    parts = text.split("``")
    return "".join(f"``{p}``" if i % 2 else esc(p) for i, p in enumerate(parts))


def benchmarks(results: Path = ROOT / "benchmarks" / "results", generated: Path = HERE / "_generated") -> list[str]:
    """Write ``generated/benchmarks.rst`` from ``results/*.json``; returns the benchmark names."""
    generated.mkdir(parents=True, exist_ok=True)
    out, names = [], []
    for path in sorted(results.glob("*.json")):
        data = json.loads(path.read_text(encoding="utf-8"))
        names.append(path.stem)
        out += [title(path.stem, "-"), _summary_line(results.parent / f"{path.stem}.py"), "",
                f"From ``benchmarks/results/{path.name}``; the script is ``benchmarks/{path.stem}.py``.", ""]
        runs = data.get("runs") if isinstance(data.get("runs"), dict) else None
        if runs is None:
            out.append(render_record(data))
            continue
        top = {k: v for k, v in data.items() if k != "runs"}
        if top:
            out.append(render_record(top))
        for label, rec in runs.items():
            out += [title(f"{path.stem}: run {label}", "~"), render_record(rec if isinstance(rec, dict) else {"value": rec})]
    _write(generated / "benchmarks.rst", "\n".join(out))
    return names


def _write(path: Path, text: str) -> None:
    """Write only when the text changed (Sphinx then rereads only the pages that did)."""
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def write_all(app=None) -> None:
    """Both generators (conf.py connects this to ``builder-inited``)."""
    reproduction()
    benchmarks()


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "src"))
    write_all()
    print(f"wrote {HERE / 'reproduction'} and {HERE / '_generated' / 'benchmarks.rst'}")
