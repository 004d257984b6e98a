"""Output a person reads at a glance (issue 29): the compact table of ``nlfilter reproduce`` with
its verdicts and summary line, ``--all`` / ``--notes``, quick runs' "indicative" rows, ``nlfilter
list --filters`` (header, 100 columns, ``--wide``), the papers named as a reader expects, the
refusal of a reference filter in ``compare``, and the note on a measurement that carries no
information for a Gaussian filter. Every test here is cheap (hand-made results, or a 1-second
comparison)."""

from __future__ import annotations

import re

import pytest

from nlfilter import cli, experiments
from nlfilter.report import render_text, row_verdict, section, tally
from nlfilter.results import Result
from nlfilter.sources import PAPERS, cite


def _result(quick=False, paths=200):
    res = Result("cubic-sensor", "a cubic sensor", "seed 001, Tables 5.1-5.2", {"paths": paths},
                 notes=["q=2: 001 Table 5.1: .540", "seed 004 (Henriksen 1979) forms"])
    res.add("tensor", "mse_x", 0.52238, paper=0.522, q=2.0)            # deterministic: reproduced
    res.add("tensor", "mse_x", 0.37761, paper=0.371, q=1.0)            # deterministic: not reproduced
    res.add("optimal", "mse_mc", 0.50, stderr=0.01, paper=0.525, q=2.0)  # Monte Carlo: 2.5 s.e., reproduced
    res.add("ekf", "mse_mc", 0.70, stderr=0.02, q=2.0)
    res.add("ekf", "diverged_fraction", 0.0, q=2.0)
    res.add("ukf", "mse_mc", 0.60, stderr=0.02, q=2.0)
    res.meta = {"quick": quick, "paths": paths}
    return res


def test_compact_table_verdicts_summary_and_what_is_left_out():
    text = render_text(_result())
    lines = text.splitlines()
    assert lines[:2] == ["cubic-sensor: a cubic sensor", "source: Vallot (1981), Tables 5.1-5.2"]
    head = next(i for i, line in enumerate(lines) if line.startswith("quantity"))
    assert lines[head].split() == ["quantity", "filter", "params", "paper", "nlfilter", "s.e.", "verdict"]
    body = lines[head + 2:head + 5]
    assert [line.split()[1] for line in body] == ["tensor", "tensor", "optimal"]  # the rows with a paper value only
    assert "reproduced (0.522 at the 3 printed decimals)" in body[0]
    assert "not reproduced (ours 0.378 at the 3 printed decimals)" in body[1]
    assert body[2].endswith("reproduced (2.5 s.e.)")
    assert "2 reproduced, 1 not reproduced (see the notes: --notes)" in lines
    assert lines[-1] == "3 rows without a paper value: --all; 2 notes: --notes (--json PATH: everything)"
    assert "ekf" not in text and "Henriksen" not in text and "seed" not in text


def test_all_groups_the_other_rows_by_quantity_and_notes_name_the_papers():
    text = render_text(_result(), all_rows=True, notes=True)
    lines = text.splitlines()
    other = lines[lines.index("notes:") - 6:lines.index("notes:") - 1]
    assert other[0].split() == ["quantity", "filter", "params", "nlfilter", "s.e."]
    # grouped: the quantity on its group's first row only (mse_mc: ekf, ukf; then diverged_fraction)
    assert [r.split()[0] for r in other[2:]] == ["mse_mc", "ukf", "diverged_fraction"]
    assert lines[lines.index("notes:") + 1:] == ["- q=2: Vallot (1981) Table 5.1: .540", "- Henriksen (1979) forms"]
    assert "--all" not in lines[-1] and "(see the notes)" in text


def test_quick_run_with_few_paths_marks_monte_carlo_rows_indicative():
    """A quick run's Monte Carlo verdict on 6 paths would judge noise: "indicative" (the would-be
    verdict in the reason); a deterministic row keeps its verdict; 30 paths or a full run: as is."""
    res = _result(quick=True, paths=6)
    mc = res.rows[2]
    assert row_verdict(res, mc) == ("indicative", "quick run, 6 paths; would be: reproduced, 2.5 s.e.")
    assert row_verdict(res, res.rows[0])[0] == "reproduced"
    assert tally({"reproduced": 1, "not reproduced": 1, "indicative": 1}) == (
        "1 reproduced, 1 not reproduced, 1 indicative")
    text = render_text(res)
    assert "1 reproduced, 1 not reproduced, 1 indicative" in text and "6 Monte Carlo paths" in text
    assert row_verdict(_result(quick=True, paths=30), mc)[0] == "reproduced"
    assert row_verdict(_result(quick=False, paths=6), mc)[0] == "reproduced"
    # the report's section says the same (one source of truth)
    assert "indicative (quick run, 6 paths" in section(res) and "Vallot (1981)" in section(res)


def test_reproduce_prints_the_compact_table_all_and_notes(monkeypatch, capsys, tmp_path):
    """The command line's wiring, on a hand-made result (no experiment runs)."""
    monkeypatch.setattr(experiments.Experiment, "run", lambda self, *a, **k: _result())
    assert cli.main(["reproduce", "cubic-sensor", "--no-store"]) == 0
    out = capsys.readouterr().out
    assert "2 reproduced, 1 not reproduced" in out and "diverged_fraction" not in out and "\nnotes:" not in out
    js = tmp_path / "r.json"
    assert cli.main(["reproduce", "cubic-sensor", "--no-store", "--all", "--notes", "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "diverged_fraction" in out and "\nnotes:\n- q=2: Vallot (1981) Table 5.1" in out
    assert Result.from_json(js).rows == _result().rows  # the JSON carries everything


def test_quick_cubic_sensor_uses_enough_paths():
    """The main job's quick run: enough paths for its reference checks (16) and not indicative."""
    from nlfilter.experiments.cubic_sensor import QUICK_PATHS
    from nlfilter.report import QUICK_MIN_PATHS
    assert QUICK_PATHS >= max(16, QUICK_MIN_PATHS)


def test_sources_are_named_never_seed_numbers():
    assert cite("seed 001 (Vallot 1981), ch. 5; seed 003 eqs. 11-15") == "Vallot (1981), ch. 5; Oh & Shin (1995) eqs. 11-15"
    assert cite("000's Fig. 10; dt=0.001 Table; 004 eq. 36") == (
        f"{PAPERS['000']}'s Fig. 10; dt=0.001 Table; Henriksen (1979) eq. 36")
    for exp in experiments.registry().values():
        assert not re.search(r"\bseed\b|\b00\d\b", exp.source), exp.id


def test_list_filters_header_fits_100_columns_wide_has_every_field(capsys):
    from nlfilter.filters import REGISTRY

    def _lines(*args):
        assert cli.main(["list", *args]) == 0
        return capsys.readouterr().out.splitlines()
    lines = _lines("--filters")
    assert lines[0].split() == ["name", "time", "accepts", "source"] and set(lines[1]) <= {"-", " "}
    assert max(map(len, lines)) <= 100
    names = [line.split()[0] for line in lines if line.startswith("  ")]
    assert sorted(names) == sorted(REGISTRY)
    assert not any(re.search(r"\bseed\b|\b00\d\b", line) for line in lines)
    assert "  continuous-second-order " in "\n".join(lines) and "Henriksen (1979)" in "\n".join(lines)
    wide = _lines("--filters", "--wide")
    assert wide[0].split()[:4] == ["name", "class", "family", "time"] and "convention" in wide[0]
    assert [line.split()[0] for line in wide[2:]] == list(REGISTRY)


def test_list_wide_without_filters_is_refused(capsys):
    assert cli.main(["list", "--wide"]) == 2
    assert "--wide: only with --filters" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["grid", "particle"])
def test_compare_refuses_a_reference_filter_clearly(name, capsys):
    assert cli.main(["compare", "examples/models/cubic-sensor.toml", "--filters", f"continuous-ekf,{name}", "--no-store",
                     "--paths", "4", "--steps", "3", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"nlfilter: error: filters: {name}: the grid and particle filters are the reference: pass "
                   "reference= or a dict of name -> filter instance (command line: --reference grid|particle)")


def test_uninformative_measurement_is_said_in_a_note():
    """Stochastic volatility in levels, y = exp(x/2)·v, as h = 0 with R(x) = exp(x): Cov[x, h] = 0,
    so every Gaussian filter returns its prior (its estimates are the same on every path), which a
    note says; the reference (grid) uses the measurements. A linear model gets no such note."""
    import sympy as sp

    from nlfilter import DiscreteModel, compare
    x = sp.Symbol("x")
    sv = DiscreteModel([x], [0.95 * x], [sp.Integer(0) * x], Q=0.1, R=sp.exp(x), name="sv-levels")
    res = compare(sv, ["ekf", "ukf"], 20, paths=6, m0=0.0, P0=1.0, rng=0)
    note = next(n for n in res.notes if "the same estimates on every path" in n)
    assert note.startswith("ekf, ukf: ") and "Cov[x, h(x)] = 0" in note
    lin = DiscreteModel([x], [0.95 * x], [x], Q=0.1, R=1.0)
    assert not any("same estimates" in n for n in compare(lin, ["ekf", "ukf"], 20, paths=6, m0=0.0, P0=1.0,
                                                          rng=0).notes)
