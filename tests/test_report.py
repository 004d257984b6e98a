"""The reproduction report (nlfilter.report, ``nlfilter reproduce all --report DIR``): the
verdict rule, a complete quick report of every experiment, its resume from the store."""

from __future__ import annotations

import math

import pytest

from nlfilter import cli, experiments
from nlfilter.report import _decimals, counts, fill_readme, readme_blocks, render_block, render_table, verdict
from nlfilter.results import Result, Row


def test_printed_decimals():
    assert [_decimals(x) for x in (0.1401, 9.2, 12.0, 0.54, 5.63, 1e-5, 2.5e-3, 21.4)] == [4, 1, 0, 2, 2, 5, 4, 1]


def test_verdict_rule():
    # Monte Carlo: within 3 of our standard errors
    assert verdict(Row("f", "q", 0.150, stderr=0.001, paper=0.1477))[0] == "reproduced"       # 2.3 se
    assert verdict(Row("f", "q", 0.139, stderr=0.0003, paper=0.1477)) == ("not reproduced", "29.0 s.e.")
    # deterministic: half a unit in the paper's last printed place
    assert verdict(Row("f", "q", 0.52238, paper=0.522))[0] == "reproduced"
    assert verdict(Row("f", "q", 0.5225, paper=0.522))[0] == "reproduced"                     # the edge
    assert verdict(Row("f", "q", 0.52251, paper=0.522))[0] == "not reproduced"
    assert verdict(Row("f", "q", 9.16, paper=9.2))[0] == "reproduced"
    assert verdict(Row("f", "q", math.nan, paper=1.0))[0] == "not reproduced"
    assert verdict(Row("f", "q", 1.0)) == ("", "")                                            # no paper value
    # a standard error of 0 or NaN (one path) is treated as deterministic, never as "within 0 se"
    assert verdict(Row("f", "q", 0.52238, stderr=math.nan, paper=0.522))[0] == "reproduced"


def test_table_and_readme_blocks():
    res = Result("demo", "a demo", "no paper", {})
    res.add("kf", "mse", 0.52238, paper=0.522, P=1)
    res.add("optimal", "mse", 0.5, P=1)
    res.add("kf", "gap", 0.1)
    table = render_table(res)
    assert table.splitlines()[2] == "| kf | mse | P=1 | 0.522 | 0.52238 | - | 0.5 | reproduced (0.522 at the 3 printed decimals) |"
    assert len(table.splitlines()) == 3 and counts(res) == {"reproduced": 1, "not reproduced": 0}
    text = "intro\n<!-- report:demo -->\nold table\n<!-- /report:demo -->\nend\n"
    filled = fill_readme(text, {"demo": res})
    assert readme_blocks(filled) == {"demo": render_block("demo", {"demo": res})} and filled.endswith("end\n")
    assert table in filled and "<details>" in filled
    with pytest.raises(ValueError, match="report:demo"):
        fill_readme(text, {})


@pytest.fixture
def quick_report(quick_reproduction):
    """``nlfilter reproduce all --quick --report DIR`` (tests/conftest.py, shared with
    tests/test_results.py): the report folder and the command's arguments."""
    return quick_reproduction.folder, quick_reproduction.argv


def test_quick_report_is_complete(quick_report):
    out, _ = quick_report
    index = (out / "index.md").read_text()
    reg = experiments.registry()
    for eid in reg:
        res = Result.from_json(out / f"{eid}.json")
        assert res.meta["quick"] and res.meta["seed"] == 0 and res.meta["execution"]["seconds"] >= 0
        assert f'<a id="{eid}"></a>' in index and f"## `{eid}`" in index
        assert render_table(res) in index  # the table of every experiment, verdicts included
        assert (out / f"{eid}.png").stat().st_size > 10_000
        c = counts(res)
        assert f"| [`{eid}`](#{eid}) | {c['reproduced']} | {c['not reproduced']} |" in index
    assert index.count("Provenance: nlfilter ") == len(reg)
    total = sum(counts(Result.from_json(out / f"{e}.json"))["reproduced"] for e in reg)
    assert f"{total} reproduced" in index.splitlines()[2]


def test_rerun_reads_finished_experiments_back(quick_report, capsys):
    out, argv = quick_report
    before = (out / "index.md").read_text()
    capsys.readouterr()
    reg = experiments.registry()
    with pytest.MonkeyPatch.context() as mp:  # nothing is run again
        mp.setattr(experiments.Experiment, "run", lambda *a, **k: pytest.fail("an experiment ran again"))
        assert cli.main(argv) == 0
    err = capsys.readouterr().err
    assert err.count("finished earlier, read back") == len(reg)
    assert (out / "index.md").read_text() == before


def test_reproduce_all_refuses_per_experiment_options(capsys, tmp_path):
    for extra in (["--param", "T=1"], ["--runs", "3"], ["--json", str(tmp_path / "a.json")],
                  ["--report", str(tmp_path / "missing" / "r")]):
        assert cli.main(["reproduce", "all", "--quick", *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and extra[0] in err[0], err


ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def _committed():
    """The committed full report's results and single runs, as docs/make_report.py reads them."""
    from nlfilter.report import REPORT_DIR, load_folder
    dest = ROOT / REPORT_DIR
    res = load_folder(dest) if dest.exists() else {}
    res.update({p.stem: Result.from_json(p) for p in sorted((dest / "runs").glob("*.json"))})
    return res


def test_readme_blocks_equal_the_committed_report():
    """Every generated block of the README is what docs/make_report.py makes of the committed
    JSON files (so the README's tables cannot drift from the report), and docs/report/index.md
    too; every experiment of the registry is in the committed report."""
    from nlfilter.report import render_block
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = readme_blocks(text)
    results = _committed()
    assert set(blocks) == {"summary"}  # the README's one table (the results tables: tests/test_readme.py)
    for eid, body in blocks.items():
        assert body == render_block(eid, results), eid
    reg = experiments.registry()
    exps = [results[e] for e in reg if e in results]
    assert [r.experiment for r in exps] == list(reg), "an experiment is missing from docs/report"
    assert all(not r.meta["quick"] and r.meta["seed"] == 0 for r in exps)
