"""The README is the front door (issue 29): at most 200 lines, the first code before line 40, its
commands those CI runs, its "your own model" example runs and prints what it shows, and its
reproduction table is the committed report's. The manual's code (docs/guide/*.rst) runs as written
(so it cannot go stale), and its hand-written result tables quote the committed report."""

import pathlib
import re
import textwrap

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GUIDE = ROOT / "docs" / "guide"


def rst_code(path, language="python"):
    """The ``.. code-block:: LANGUAGE`` blocks of an RST file, dedented, in order."""
    text = path.read_text(encoding="utf-8")
    blocks = re.findall(rf"^\.\. code-block:: {language}\n\n((?:(?:   .*)?\n)+)", text, re.M)
    return [textwrap.dedent(b).strip("\n") + "\n" for b in blocks]


def rst_as_markdown(text):
    """An RST page's headings (``### title``) and list-tables (Markdown pipe rows, a rule after the
    header) as the Markdown that :func:`nlfilter.report.unquoted_numbers` reads; other lines as they are."""
    lines, out, i = text.splitlines(), [], 0
    while i < len(lines):
        line = lines[i]
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if line.strip() and nxt and set(nxt) <= set("=-~^") and len(nxt) >= len(line.rstrip()):
            out.append("### " + line)
            i += 2
            continue
        if line.startswith(".. list-table::"):
            i += 1
            while i < len(lines) and (lines[i].startswith("   :") or not lines[i].strip()):
                i += 1
            rows = []
            while i < len(lines) and lines[i].startswith(("   * -", "     -")):
                cell = lines[i][6:].strip() if lines[i].startswith("   * -") else lines[i][6:].strip()
                if lines[i].startswith("   * -"):
                    rows.append([cell])
                else:
                    rows[-1].append(cell)
                i += 1
            out += ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
            out += ["| " + " | ".join(r) + " |" for r in rows[1:]]
            continue
        out.append(line)
        i += 1
    return "\n".join(out)


# -- the README -------------------------------------------------------------------------------------

def test_readme_is_short_and_starts_with_code():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200
    assert next(i for i, line in enumerate(lines, 1) if line.startswith("```")) < 40


def test_readme_commands_are_what_ci_runs():
    """The two fresh-machine commands, after their venv, are those of ``.ci/run`` byte for byte."""
    text = README.read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    cmds = re.findall(r"```bash\npython3 -m venv \.venv && \. \.venv/bin/activate && (.*)\n```", text)
    assert cmds == ["pip install . && nlfilter reproduce cubic-sensor --quick",
                    'pip install ".[test]" && python -m pytest -n auto']
    assert "pip install -q . && nlfilter reproduce cubic-sensor --quick" in ci
    assert 'pip install -q ".[test]" && python -m pytest -n auto' in ci


def _table_lines(out):
    """The (filter, quantity, params) cells of a ``Result.table()`` printout, and its closing lines'
    first words."""
    lines = out.strip().splitlines()
    rows = [tuple(line.split()[:3]) for line in lines[4:] if re.match(r"\w+ +\w+ ", line)
            and not line.startswith(("reference", "window"))]
    tail = [line.split(":")[0] if line.startswith("reference") else line.split()[0]
            for line in lines if line.startswith(("reference", "window"))]
    return lines[:1], lines[2].split(), rows, tail


def test_readme_own_model_runs_and_prints_what_it_shows(tmp_path, monkeypatch, capsys):
    """The "Your own model" block runs as written (sizes cut: 30 steps and 16 paths instead of 100 and
    64 — the same code path, the reference's refinement on all 16 paths) and prints a table of the
    same structure as the README shows: the same title, columns, (filter, quantity, params) rows in
    the same order and closing lines; the numbers differ with the sizes."""
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Your own model"):text.index("## The reproduction")]
    code, shown = re.findall(r"```python\n(.*?)```", section, re.S)[0], re.findall(r"```text\n(.*?)```", section, re.S)[0]
    assert "100, paths=64" in code
    guide = rst_code(GUIDE / "model.rst")[0]  # (the second block, noise per step: the test below)
    assert code.startswith(guide)  # the guide's model is the README's
    monkeypatch.chdir(tmp_path)
    exec(compile(code.replace("100, paths=64", "30, paths=16"), "README-own-model", "exec"), {})
    out = capsys.readouterr().out
    assert _table_lines(out) == _table_lines(shown)
    assert "certified" in out.splitlines()[-3]


def test_guide_noise_per_step_runs_as_written():
    """docs/guide/model.rst's second block (R given per step, issue 31 item 4) after its model (the
    README's pendulum), as written: the EKF's log-likelihood is finite on every path."""
    model_code, per_step = rst_code(GUIDE / "model.rst")[:2]
    ns = {}
    exec(compile(model_code + per_step, "model.rst", "exec"), ns)
    assert ns["est"].means.shape == (4, 100, 2) and np.isfinite(ns["est"].loglik).all()


def test_guide_angles_block_builds_its_model():
    """docs/guide/model.rst's third block (angles, issue 31 item 1), as written: the bearing state and
    measurement are declared angular, and a UKF on it keeps its bearing estimates in (−π, π]."""
    ns = {}
    exec(compile(rst_code(GUIDE / "model.rst")[2], "model.rst", "exec"), ns)
    model = ns["model"]
    assert list(model.angles.states) == [0] and list(model.angles.measurements) == [1]
    from nlfilter import simulate
    sim = simulate(model, 40, paths=2, rng=0, m0=[3.0, 10.0, 2.0], P0=np.diag([0.01, 0.1, 0.1]))
    est = ns["UKF"](model).run(sim.ys, [3.0, 10.0, 2.0], np.diag([0.01, 0.1, 0.1]))
    assert np.all(np.abs(est.means[..., 0]) <= np.pi) and np.isfinite(est.covs).all()


def test_readme_model_file_is_the_example():
    """The README's TOML block is ``examples/models/pendulum.toml`` as shipped (the guide includes the file)."""
    text = README.read_text(encoding="utf-8")
    (block,) = re.findall(r"```toml\n(.*?)```", text, re.S)
    assert block == (ROOT / "examples" / "models" / "pendulum.toml").read_text()
    assert ".. literalinclude:: ../../examples/models/pendulum.toml" in (GUIDE / "model.rst").read_text()


def test_readme_links_exist():
    text = README.read_text(encoding="utf-8")
    links = [u.split("#")[0] for u in re.findall(r"\]\(([^)\s]+)\)", text) if "://" not in u]
    assert len(links) >= 10 and [u for u in links if not (ROOT / u).exists()] == []


def test_sources_are_named_as_a_reader_expects():
    """issue 29 item 3: in the README and the guide a source paper is "Vallot (1981)", never "seed 001";
    "seed" is only the random seed."""
    pages = [README, ROOT / "docs" / "bibliography.rst", ROOT / "docs" / "architecture.rst",
             ROOT / "docs" / "index.rst", *sorted(GUIDE.glob("*.rst"))]
    for page in pages:
        text = page.read_text(encoding="utf-8")
        assert re.findall(r"(?i)seeds?[- ]00\d|\bseed-000|\"seeds\"", text) == [], page.name


# -- the guide's code runs as written ---------------------------------------------------------------

def test_quickstart_runs(tmp_path, monkeypatch, capsys):
    (code,) = rst_code(GUIDE / "filters.rst")
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "guide-filters", "exec"), {})
    out = capsys.readouterr().out
    assert out.startswith("ekf Summary(") and "ukf Summary(" in out
    assert (tmp_path / "quickstart.png").stat().st_size > 5000


def test_compare_blocks_run(tmp_path, monkeypatch):
    """The guide's ``compare`` blocks run as written on the quickstart's model (sizes cut: 20 steps,
    4 paths, so that the test stays fast; the code path is the same)."""
    (quick,) = rst_code(GUIDE / "filters.rst")
    blocks = rst_code(GUIDE / "compare.rst")
    assert len(blocks) == 2
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(quick.replace("500, paths=200", "20, paths=4"), "guide-filters", "exec"), ns)
    for i, code in enumerate(blocks):
        code = code.replace("200, paths=100", "20, paths=4")
        exec(compile(code, f"guide-compare-{i}", "exec"), ns)
    res = ns["res"]
    assert {r.filter for r in res.rows} == {"ekf", "ckf", "second-order", "optimal"}
    assert (tmp_path / "compare.png").stat().st_size > 5000


def test_likelihood_block_runs(tmp_path, monkeypatch, capsys):
    """The likelihood blocks run as written, the second after the first (sizes cut: 60 steps, 2
    paths, a 101-point grid; the code path is the same): a converged fit, the fixed-lag smoother,
    posterior draws, a finite diffuse log-likelihood and the exact diffuse smoother."""
    first, second = rst_code(GUIDE / "likelihood.rst")
    code = (first + second).replace("300, paths=4", "60, paths=2").replace("401))", "101))")
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(code, "guide-likelihood", "exec"), ns)
    out = capsys.readouterr().out
    assert ns["est"].loglik.shape == (2,) and ns["sm"].means.shape == (2, 60, 1)
    assert "converged" in out and ns["res"].se_ok
    assert ns["lagged"].means.shape == (2, 60, 1) and ns["draws"].shape == (2, 100, 60, 1)
    assert np.isfinite(ns["draws"]).all() and np.isfinite(ns["lagged"].covs).all()
    assert np.isfinite(ns["flat"].covs).all()  # the exact diffuse smoother: the level identified at step 0


def test_compiled_block_runs(tmp_path, monkeypatch, capsys):
    """The compiled-loop block runs as written (2000 steps instead of 100,000; the code path is the
    same) and gives the NumPy loop's estimates."""
    (code,) = rst_code(GUIDE / "speed.rst")
    code = code.replace("100_000", "2000")
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(code, "guide-compiled", "exec"), ns)
    assert ns["est"].means.shape == (1, 2000, 1)
    ref = ns["EKF"](ns["model"]).run(ns["ys"], m0=0.5, P0=0.1)
    assert abs(ns["est"].means - ref.means).max() < 1e-12


def test_model_file_error_is_what_a_typo_gives(tmp_path):
    """The one-line error the guide shows is what a typo in the pendulum file gives."""
    from nlfilter.modelfile import ModelFileError, load_model

    text = (GUIDE / "model.rst").read_text(encoding="utf-8")
    broken = tmp_path / "pendulum.toml"
    broken.write_text((ROOT / "examples" / "models" / "pendulum.toml").read_text().replace(
        'sin(theta)"]', 'sin(thet)"]', 1))
    with pytest.raises(ModelFileError) as info:
        load_model(broken)
    shown = re.search(r"``(pendulum\.toml:\d+: .*?), \.\.\.``", text, re.S).group(1)
    assert str(info.value).replace(str(broken), "pendulum.toml").startswith(re.sub(r"\s+", " ", shown))


# -- the guide's result tables quote the committed report -------------------------------------------

def _committed():
    """The committed full report's results and single runs, as docs/make_report.py reads them."""
    from nlfilter.report import REPORT_DIR, load_folder
    from nlfilter.results import Result
    dest = ROOT / REPORT_DIR
    res = load_folder(dest)
    res.update({p.stem: Result.from_json(p) for p in sorted((dest / "runs").glob("*.json"))})
    return res


def _results_page():
    return rst_as_markdown((GUIDE / "results.rst").read_text(encoding="utf-8"))


def test_results_table_4_1_quotes_the_committed_run():
    """The Table 4.1 paragraph (hand-written) quotes the committed decisive run: each value and
    standard error as printed (5 decimals), the distance in standard errors (1 decimal)."""
    run = _committed()["phase-tracking-table-4.1"]
    text = _results_page()
    part = text[text.index("**Table 4.1 decided**"):text.index("**The thesis' LQF")]
    assert run.params["paths"] == 256 and run.params["time_constants"] == 2000
    for name in ("pll", "lqf", "tensor", "optimal"):
        row = run.get(name, "mse_theta", P=0.129)
        line = next(ln for ln in part.splitlines() if ln.startswith(f"| {name}"))
        v, se = map(float, re.search(r"\| ([\d.]+) ± ([\d.]+) \|", line).groups())
        assert (v, se) == (round(row.value, 5), round(row.stderr, 5)), name
        if row.paper is not None:
            k = float(re.search(r"\(([\d.]+) s\.e\.\)", line).group(1))
            assert k == round(abs(row.value - row.paper) / row.stderr, 1), name
            ex = run.get(name, "excess_mse_theta", P=0.129)
            ev, ese = map(float, re.findall(r"([\d.]+) ± ([\d.]+) \|$", line)[0])
            assert (ev, ese) == (round(ex.value, 5), round(ex.stderr, 5)), name


def test_results_hand_tables_quote_the_committed_report():
    """Every number of the results page's hand-written tables is a value, standard error or paper
    value of a row of the committed report — or of a run kept in docs/report/runs — of the
    experiment its section names, at the number's printed digits
    (nlfilter.report.unquoted_numbers): a rerun that moves a number, or a typo, fails here."""
    from nlfilter.report import unquoted_numbers
    text = "## Experiments and results\n\n" + _results_page() + "\n\n## End\n"
    assert text.count("\n| ") > 80  # the tables were read
    committed = _committed()
    assert unquoted_numbers(text, committed) == []
    moved = text.replace("| 0.581 ± 0.013 |", "| 0.582 ± 0.013 |", 1)  # the check sees a moved digit
    assert moved != text and unquoted_numbers(moved, committed) == [("second-order", "0.582 ± 0.013", "0.582")]


def test_docstrings_cite_only_documents_in_the_project():
    """issue 10 item 8.7: the sources cited a design document that the project does not ship; every
    ``*.md`` a source file names must exist in the repository."""
    cited = {}
    for path in sorted((ROOT / "src").rglob("*.py")) + sorted((ROOT / "tests").rglob("*.py")):
        if path == pathlib.Path(__file__).resolve():
            continue  # this test names the missing document itself
        for name in re.findall(r"\b([\w./-]+\.md)\b", path.read_text(encoding="utf-8")):
            cited.setdefault(name, []).append(path.relative_to(ROOT).as_posix())
    # files the code writes (the report's page, in the folder the user names) are not citations
    written = {"index.md", "DIR/index.md", "folder/index.md"}
    missing = {n: p for n, p in cited.items() if not (ROOT / n).exists() and n != "README.md" and n not in written}
    assert missing == {}
    assert "DESIGN.md" not in cited
