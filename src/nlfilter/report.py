"""The reproduction report: every experiment's paper values beside ours, with a verdict each.

:func:`write_report` writes ``DIR/index.md`` (one section per experiment: a table
paper · nlfilter · s.e. · optimum · verdict for every row that has a paper value, the experiment's
notes, and the run's provenance), ``DIR/<id>.json`` (the whole result) and ``DIR/<id>.png`` (its
figure). :func:`render_table` is the one Markdown table of an experiment. The README carries the
summary of the committed full report (:func:`render_readme_summary`) between
``<!-- report:summary -->`` and ``<!-- /report:summary -->`` (:func:`readme_blocks`,
:func:`fill_readme`; a test checks that it equals what the committed report gives).

The verdict rule (:func:`verdict`), stated once:

* a **Monte Carlo** row (it has a standard error ``se``): *reproduced* when
  ``|ours − paper| ≤ 3 se``; else *not reproduced*, with the distance in standard errors.
  (When the paper's value is itself a Monte Carlo estimate, its own error is not counted: a
  "not reproduced" then says that the paper's printed value is off by more than our run can
  explain.)
* a **deterministic** row (no standard error: an off-line, exact computation): *reproduced* when
  ours, rounded to the decimals the paper printed, equals the paper's value (a tolerance of half a
  unit in the last printed place); else *not reproduced*, with both values.
* a row whose value is not finite: *not reproduced* (no number).

>>> from nlfilter.results import Row
>>> verdict(Row("kf", "mse", 0.5243, stderr=0.001, paper=0.522))
('reproduced', '2.3 s.e.')
>>> verdict(Row("kf", "mse", 0.3776, paper=0.371))
('not reproduced', 'ours 0.378 at the 3 printed decimals')
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from .results import Result, Row, _fmt, _fmt_params, atomic_write
from .sources import cite

MC_SIGMAS = 3.0  # a Monte Carlo row is reproduced within this many of our standard errors


def _decimals(x: float) -> int:
    """The decimals the paper printed: those of the shortest repr of its value (0.1401 -> 4, 9.2 -> 1, 12.0 -> 0)."""
    text = repr(float(x))
    if "e" in text or "E" in text:
        mant, exp = text.lower().split("e")
        d = len(mant.split(".")[1]) if "." in mant else 0
        return max(0, d - int(exp))
    frac = text.split(".")[1] if "." in text else ""
    return 0 if frac == "0" else len(frac)


def verdict(row: Row) -> tuple[str, str]:
    """``(verdict, reason)`` of a row with a paper value (module docstring); ``("", "")`` without one."""
    if row.paper is None:
        return "", ""
    v, p = row.value, row.paper
    if v is None or not math.isfinite(v):
        return "not reproduced", f"no finite value ({v})"
    if row.stderr is not None and math.isfinite(row.stderr) and row.stderr > 0:
        k = abs(v - p) / row.stderr
        return ("reproduced" if k <= MC_SIGMAS else "not reproduced"), f"{k:.1f} s.e."
    d = _decimals(p)
    tol = 0.5 * 10.0 ** (-d) * (1 + 1e-9)
    shown = f"{v:.{d}f}"
    if abs(v - p) <= tol:
        return "reproduced", f"{shown} at the {d} printed decimals"
    return "not reproduced", f"ours {shown} at the {d} printed decimals"


#: a quick run's Monte Carlo row on fewer paths is "indicative": its s.e. is itself too noisy
QUICK_MIN_PATHS = 30


def _fewest_paths(res: Result):
    """The fewest Monte Carlo paths of any case of ``res`` (``meta["paths"]``: an int or per case), or None."""
    paths = res.meta.get("paths")
    vals = list(paths.values()) if isinstance(paths, dict) else [paths]
    vals = [v for v in vals if isinstance(v, int) and not isinstance(v, bool)]
    return min(vals) if vals else None


def row_verdict(res: Result, row: Row) -> tuple[str, str]:
    """:func:`verdict` of ``row`` in its run ``res``: a Monte Carlo row of a quick run on fewer than
    :data:`QUICK_MIN_PATHS` paths is ``("indicative", ...)`` — its verdict would judge noise."""
    v, why = verdict(row)
    n = _fewest_paths(res)
    if v and row.stderr is not None and res.meta.get("quick") and n is not None and n < QUICK_MIN_PATHS:
        return "indicative", f"quick run, {n} paths; would be: {v}, {why}"
    return v, why


def _optimum(res: Result, row: Row):
    for r in res.rows:
        if r.filter == "optimal" and r.quantity == row.quantity and r.params == row.params:
            return r.value
    return None


def render_table(res: Result) -> str:
    """The Markdown table of ``res``'s rows that carry a paper value: filter, quantity, params,
    paper, nlfilter, s.e., optimum (the ``optimal`` row of the same quantity and params, if any),
    verdict (reason)."""
    lines = ["| filter | quantity | params | paper | nlfilter | s.e. | optimum | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    for r in res.rows:
        if r.paper is None:
            continue
        v, why = row_verdict(res, r)
        opt = _optimum(res, r)
        lines.append(f"| {r.filter} | {r.quantity} | {_fmt_params(r.params)} | {_fmt(r.paper)} | {_fmt(r.value)} | "
                     f"{_fmt(r.stderr)} | {_fmt(opt)} | {v} ({why}) |")
    if len(lines) == 2:
        lines.append("| (no row of this experiment has a paper value) | | | | | | | |")
    return "\n".join(lines)


def counts(res: Result) -> dict:
    """``{"reproduced": n, "not reproduced": m}`` over the rows with a paper value (and
    ``"indicative": k`` when a quick run has such rows: :func:`row_verdict`)."""
    out = {"reproduced": 0, "not reproduced": 0}
    for r in res.rows:
        v, _ = row_verdict(res, r)
        if v:
            out[v] = out.get(v, 0) + 1
    return out


def tally(c: dict) -> str:
    """``counts`` as a phrase: "7 reproduced, 3 not reproduced" (", 2 indicative" when a quick run has them)."""
    return f"{c['reproduced']} reproduced, {c['not reproduced']} not reproduced" + (
        f", {c['indicative']} indicative" if c.get("indicative") else "")


def _columns(head: list[str], body: list[list[str]]) -> list[str]:
    """Plain-text columns: ``head``, a rule, ``body``; each column as wide as its widest cell."""
    widths = [max([len(h)] + [len(b[i]) for b in body]) for i, h in enumerate(head)]
    return ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip()
            for row in [head, ["-" * w for w in widths], *body]]


def _many(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


def render_text(res: Result, *, all_rows: bool = False, notes: bool = False) -> str:
    """The table ``nlfilter reproduce ID`` prints: the rows with a paper value (quantity · filter ·
    params · paper · nlfilter · s.e. · verdict, :func:`row_verdict`), one summary line, then — with
    ``all_rows`` — the other rows grouped by quantity, and — with ``notes`` — the notes. What is
    left out is named on the last line (the JSON always holds everything)."""
    out = [f"{res.experiment}: {cite(res.title)}", f"source: {cite(res.source)}"]
    if res.meta.get("quick"):
        n = _fewest_paths(res)
        out.append("quick run: small sizes, same code paths" + (f"; {n} Monte Carlo paths" if n else "")
                   + " (the published numbers come from full runs)")
    paper = [r for r in res.rows if r.paper is not None]
    other = [r for r in res.rows if r.paper is None]
    out.append("")
    if paper:
        body = []
        for r in paper:
            v, why = row_verdict(res, r)
            body.append([r.quantity, r.filter, _fmt_params(r.params), _fmt(r.paper), _fmt(r.value), _fmt(r.stderr),
                         f"{v} ({why})"])
        out += _columns(["quantity", "filter", "params", "paper", "nlfilter", "s.e.", "verdict"], body)
        c = counts(res)
        out += ["", tally(c) + ("" if not c["not reproduced"] else " (see the notes)" if notes or not res.notes
                                else " (see the notes: --notes)")]
    else:
        out.append("no row of this experiment has a paper value (a check of nlfilter, or a paper that prints no "
                   "numbers): its rows follow")
    if other and (all_rows or not paper):
        groups = {}
        for r in other:
            groups.setdefault(r.quantity, []).append(r)
        body = [[q if i == 0 else "", r.filter, _fmt_params(r.params), _fmt(r.value), _fmt(r.stderr)]
                for q, rows in groups.items() for i, r in enumerate(rows)]
        out += ["", *_columns(["quantity", "filter", "params", "nlfilter", "s.e."], body)]
    if notes and res.notes:
        out += ["", "notes:", *(f"- {cite(n)}" for n in res.notes)]
    left = [_many(len(other), "row") + " without a paper value: --all"] if other and paper and not all_rows else []
    left += [_many(len(res.notes), "note") + ": --notes"] if res.notes and not notes else []
    if left:
        out += ["", "; ".join(left) + " (--json PATH: everything)"]
    return "\n".join(out)


def render_summary(results: list[Result], link: str = "#{id}") -> str:
    """One line per experiment: its rows with a paper value reproduced / not reproduced, the paths
    simulated and the run's seconds; ``link`` (``{id}`` is replaced) is each name's target."""
    lines = ["| experiment | reproduced | not reproduced | paths | seconds |", "|---|---|---|---|---|"]
    for res in results:
        c = counts(res)
        secs = (res.meta.get("execution") or {}).get("seconds")
        paths = res.meta.get("paths")
        if isinstance(paths, dict):
            paths = ", ".join(f"{k} {v}" for k, v in paths.items())
        target = link.replace("{id}", res.experiment)
        lines.append(f"| [`{res.experiment}`]({target}) | {c['reproduced']} | {c['not reproduced']} | "
                     f"{paths} | {'-' if secs is None else f'{secs:.0f}'} |")
    return "\n".join(lines)


# The source papers as a reader names them (docs/bibliography.rst has the full references); the
# registry's and the committed JSON's sources may still name them by their file number ("seed 001").
def reader_source(source: str) -> str:
    """``source`` with every paper named as a reader expects: ``"seed 001, Tables 5.1-5.2"`` ->
    ``"Vallot (1981), Tables 5.1-5.2"``, ``"seed 004 (Henriksen 1979) eqs. 11"`` -> ``"Henriksen (1979)
    eqs. 11"``; an nlfilter check is ``"no paper: ..."`` (the issue it came from left out).

    >>> reader_source("seed 003 (Oh & Shin 1995), Section 5")
    'Oh & Shin (1995), Section 5'
    """
    import re
    out = cite(source)
    out = re.sub(r"^nlfilter check \(no paper\): ", "no paper: ", out)
    out = re.sub(r"; issue \d+$", "", out)
    out = re.sub(r"\b([A-Z][^\W\d_]+) ((?:19|20)\d\d)\b", r"\1 (\2)", out)  # "Särkkä 2013" -> "Särkkä (2013)"
    return out[:1].upper() + out[1:]


def render_readme_summary(results: list[Result], link: str = "#{id}") -> str:
    """The README's table of the reproduction: one line per experiment, its source as a reader names
    it (:func:`reader_source`) and its rows with a paper value reproduced / not reproduced ("–" where
    the source prints no value to compare), then one line with the totals."""
    lines = ["| experiment | source | reproduced | not reproduced |", "|---|---|---|---|"]
    total = {"reproduced": 0, "not reproduced": 0}
    for res in results:
        c = counts(res)
        for k in total:
            total[k] += c[k]
        shown = [str(c[k]) if any(c.values()) else "–" for k in ("reproduced", "not reproduced")]
        lines.append(f"| [`{res.experiment}`]({link.replace('{id}', res.experiment)}) | "
                     f"{reader_source(res.source)} | {shown[0]} | {shown[1]} |")
    return "\n".join(lines + ["", f"{len(results)} experiments; rows with a paper value: {total['reproduced']} "
                                   f"reproduced, {total['not reproduced']} not reproduced (–: no printed value to "
                                   "compare; what the experiment checks instead is in its notes)."])


def provenance_line(res: Result) -> str:
    m = res.meta
    ex = m.get("execution") or {}
    secs = ex.get("seconds")
    paths = m.get("paths")
    return (f"nlfilter {m.get('nlfilter')}, numpy {m.get('numpy')}, Python {m.get('python')}; seed {m.get('seed')}, "
            f"paths {paths}, {'quick' if m.get('quick') else 'full'} run"
            + (f", {secs:.0f} s" if isinstance(secs, (int, float)) else "")
            + (f" on the {ex['executor']} executor" if ex.get("executor") else "")
            + f"; {m.get('timestamp')}" + (f"; `{m['command']}`" if m.get("command") else ""))


def _pm(row) -> str:
    """``value ± s.e.`` of a row (``–`` for none)."""
    if row is None:
        return "–"
    return _fmt(row.value) + ("" if row.stderr is None else f" ± {_fmt(row.stderr)}")


def render_comparison(res: Result) -> str:
    """The Markdown tables of a :func:`nlfilter.compare` result (which has no paper values): per
    filter and component its MSE and its paired gap to the reference (``gap_to_optimal``, or
    ``gap_to_reference`` when the reference is not certified), each ± its standard error; per
    filter its NEES ± s.e. (n for a consistent filter), off-line MSE and divergence rate; and the
    reference's certificate."""
    names = list(dict.fromkeys(r.filter for r in res.rows))
    comps = sorted({r.params["component"] for r in res.rows if "component" in r.params})

    def get(name, quantity, **kw):
        hits = [r for r in res.rows if r.filter == name and r.quantity == quantity
                and all(r.params.get(k) == v for k, v in kw.items())]
        return hits[0] if hits else None

    gap = next((q for q in ("gap_to_optimal", "gap_to_reference") if any(r.quantity == q for r in res.rows)),
               "gap_to_optimal")
    lines = [f"| filter | component | MSE ± s.e. | {gap.replace('_', ' ')} ± s.e. |", "|---|---|---|---|"]
    for name in names:
        for i in comps:
            m = get(name, "mse", component=i)
            if m is not None:
                lines.append(f"| {name} | {i} | {_pm(m)} | {_pm(get(name, gap, component=i))} |")
    n = len(comps)
    lines += ["", f"| filter | NEES ± s.e. (≈ {n} if consistent) | off-line MSE | divergence rate |",
              "|---|---|---|---|"]
    for name in names:
        off = [get(name, "offline_mse", component=i) for i in comps]
        off_txt = ", ".join(_fmt(r.value) for r in off if r is not None) or "–"
        dr = get(name, "divergence_rate")
        lines.append(f"| {name} | {_pm(get(name, 'nees'))} | {off_txt} | {_pm(dr)} |")
    ref = res.params.get("reference")
    if ref:
        kind, size = ref.get("kind"), ref.get("size")
        size = ("×".join(map(str, size)) + " grid" if kind == "grid" else
                f"{size} particles" if kind == "particle" else kind)
        verdict = {True: "certified", False: "not converged", None: "not checked"}[ref.get("certified")]
        err = ", ".join(f"{d:+.2g} ± {se:.2g}" for d, se in ref.get("error", []))
        lines += ["", f"Reference (the yardstick, `{ref.get('label')}`): {size}, {verdict}"
                  + (f"; a finer reference on {ref.get('paths')} paths moved its MSE by {err}" if err else "")
                  + (f"; {ref['reason']}" if ref.get("reason") else "") + "."]
    budget = res.params.get("reference_budget")
    if budget:
        lines += ["", f"Reference budget: {budget['seconds']:g} s"
                  + (" (capped the reference)" if budget["capped"] else "") + "".join(f"; {t}" for t in budget["log"])]
    return "\n".join(lines)


def section(res: Result, figure: str | None = None) -> str:
    if res.experiment == "compare":  # a comparison on the user's model: its own numbers, no paper
        parts = [f'<a id="{res.experiment}"></a>', "", f"## `{res.experiment}` — {res.title}", "",
                 f"Source: {res.source}.", "", render_comparison(res), ""]
        if res.notes:
            parts += [*(f"- {n}" for n in res.notes), ""]
        if figure:
            parts += [f"![{res.experiment}]({figure})", ""]
        return "\n".join(parts + [f"Provenance: {provenance_line(res)}", ""])
    c = counts(res)
    parts = [f'<a id="{res.experiment}"></a>', "", f"## `{res.experiment}` — {cite(res.title)}", "",
             f"Source: {cite(res.source)}. Rows with a paper value: {tally(c)}.", "", render_table(res), ""]
    if res.notes:
        parts += [*(f"- {cite(n)}" for n in res.notes), ""]
    if figure:
        parts += [f"![{res.experiment}]({figure})", ""]
    parts += [f"Provenance: {provenance_line(res)}", ""]
    return "\n".join(parts)


def write_report(results: list[Result], folder, *, figures: bool = True, title: str | None = None) -> Path:
    """Write ``folder/index.md``, ``folder/<id>.json`` and (``figures``) ``folder/<id>.png`` for
    ``results``; returns the path of ``index.md``. Every file is written atomically."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    total = {"reproduced": 0, "not reproduced": 0}
    body = []
    for res in results:
        res.to_json(folder / f"{res.experiment}.json")
        if figures and res.series:
            from .plots import plot_result
            plot_result(res, folder / f"{res.experiment}.png")
        # a result read back from the store has no series: its figure is the one written when it ran
        fig = f"{res.experiment}.png" if (folder / f"{res.experiment}.png").exists() else None
        for k, n in counts(res).items():
            total[k] = total.get(k, 0) + n
        body.append(section(res, fig))
    quick = any(r.meta.get("quick") for r in results)
    if results and all(r.experiment == "compare" for r in results):  # nlfilter compare --report DIR
        head = [f"# {title or 'nlfilter: comparison report'}", "",
                "Every filter against the reference on one shared simulation (`nlfilter.compare`): MSE and the "
                "paired gap to the reference per component, NEES, divergence, the reference's certificate."]
        atomic_write(folder / "index.md", "\n".join(head + [""] + body).encode("utf-8"))
        return folder / "index.md"
    head = [f"# {title or 'nlfilter: reproduction report'}", "",
            f"{len(results)} experiments ({'quick runs: small sizes, same code paths' if quick else 'full runs'}); "
            f"rows with a paper value: {tally(total)}.",
            "", "Verdicts: a Monte Carlo row is reproduced when it lies within "
            f"{MC_SIGMAS:g} of our standard errors of the paper's value; a deterministic row when it rounds to the "
            "paper's printed decimals (`nlfilter.report`). The notes under each table say what the numbers mean "
            "and, for each \"not reproduced\", what the project found.", "",
            render_summary(results, link="#{id}")]
    text = "\n".join(head + [""] + body)
    index = folder / "index.md"
    atomic_write(index, text.encode("utf-8"))
    return index


def readme_blocks(text: str) -> dict[str, str]:
    """The generated blocks of a README: ``{experiment id: text between the markers}``."""
    import re
    return {m.group(1): m.group(2).strip("\n")
            for m in re.finditer(r"<!-- report:([\w.-]+) -->\n(.*?)<!-- /report:\1 -->", text, re.S)}


def render_block(eid: str, results: dict[str, Result]) -> str:
    """The text of README block ``eid``: ``summary`` (:func:`render_readme_summary`, linking to the
    committed report) or an experiment id (:func:`render_table`, folded under a summary line)."""
    if eid == "summary":  # the experiments (not the single runs kept beside them)
        exps = [r for k, r in results.items() if k == r.experiment]
        return render_readme_summary(exps, link=f"{REPORT_LINK}#{{id}}")
    if eid not in results:
        raise ValueError(f"README block report:{eid}: no result for it; expected 'summary' or one of {sorted(results)}")
    res = results[eid]
    c = counts(res)
    return (f"<details><summary>Paper values row by row ({c['reproduced']} reproduced, {c['not reproduced']} not "
            f"reproduced; generated from <code>{REPORT_DIR}/{eid}.json</code>)</summary>\n\n"
            f"{render_table(res)}\n\n</details>")


REPORT_DIR = "docs/report"  # the committed full report (docs/make_report.py)
REPORT_LINK = f"{REPORT_DIR}/index.md"


def fill_readme(text: str, results: dict[str, Result]) -> str:
    """``text`` with every ``<!-- report:ID -->`` block replaced by :func:`render_block`."""
    import re

    def sub(m):
        return f"<!-- report:{m.group(1)} -->\n{render_block(m.group(1), results)}\n<!-- /report:{m.group(1)} -->"
    return re.sub(r"<!-- report:([\w.-]+) -->\n(.*?)<!-- /report:\1 -->", sub, text, flags=re.S)


def load_folder(folder) -> dict[str, Result]:
    """Every ``<id>.json`` result in ``folder``, by experiment id."""
    out = {}
    for name in os.listdir(folder):
        if name.endswith(".json"):
            res = Result.from_json(Path(folder) / name)
            out[res.experiment] = res
    return dict(sorted(out.items()))  # by id, as the registry lists them


def _printed_as(token: str, values) -> bool:
    """Whether the number ``token`` as printed (``0.1858``, ``−6e-11``, ``3.90e4``) is one of
    ``values`` rounded to its printed digits (half a unit of its last digit), in sign or magnitude."""
    t = token.replace("−", "-").lstrip("-")
    mant, _, exp = t.partition("e")
    dec = len(mant.partition(".")[2])
    tol = 0.5 * 10.0 ** ((int(exp) if exp else 0) - dec) * (1 + 1e-9)
    x = float(t)
    return any(abs(abs(v) - x) <= tol for v in values)


def unquoted_numbers(text: str, results: dict[str, Result]) -> list[tuple[str, str, str]]:
    """The numbers of a README's hand-written result tables that its report does not hold.

    In the section between ``## Experiments and results`` and the next ``## `` heading, outside
    the generated ``<!-- report:ID -->`` blocks, every number in a table's body cells (not its
    header row; distances "3.5 s.e." aside) must be the value, standard error or paper value of a
    row (or its distance to the paper's value), or a percentage of one, of a result whose id starts with an experiment id named in
    backticks in the table's heading, at the number's printed digits. Returns ``(heading ids,
    cell, number)`` for each that is not: the README's tables cannot drift from the report."""
    import re
    start = text.index("## Experiments and results")
    end = text.index("\n## ", start + 1)
    part = re.sub(r"<!-- report:([\w.-]+) -->\n.*?<!-- /report:\1 -->", "", text[start:end], flags=re.S)
    number = re.compile(r"(?<![\w.])[-−]?\d+(?:\.\d+)?(?:e[-−+]?\d+)?(?![\w.]*\s*s\.e\.)")
    ids, values, in_table, bad = [], [], False, []
    for line in part.splitlines():
        if line.startswith("#"):
            ids = [i for i in re.findall(r"`([a-z0-9-]+)`", line)]
            values = [float(v) * s for k, res in results.items() if any(k.startswith(i) for i in ids)
                      for r in res.rows for v in (r.value, r.stderr, r.paper, _minus(r.value, r.paper))
                      if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                      for s in (1.0, 100.0)]
            continue
        if not (line.startswith("|") and line.rstrip().endswith("|")):
            in_table = False
            continue
        if not in_table or set(line) <= set("|-: "):  # a table's header row, its rule
            in_table = True
            continue
        for cell in [c.strip() for c in line.strip().strip("|").split("|")][1:]:
            bad += [(",".join(ids), cell, tok) for tok in number.findall(cell) if not _printed_as(tok, values)]
    return bad


def _minus(a, b):
    return a - b if isinstance(a, (int, float)) and isinstance(b, (int, float)) else None
