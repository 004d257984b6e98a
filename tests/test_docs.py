"""The documentation builds with warnings as errors (issue 14, item 5): Sphinx with the API
reference from the docstrings, the theory pages, and the sphinx-gallery examples, each of which
the build executes (so every ``examples/plot_*.py`` runs here)."""

import os
import pathlib
import shutil
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("plot_*.py"))


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """Build a copy of docs/ and examples/ (so that the gallery's generated sources never land in
    the working tree and every example runs afresh) into ``html``; returns (html dir, log)."""
    for mod in ("sphinx", "numpydoc", "sphinx_gallery"):
        pytest.importorskip(mod, reason=f"{mod} is not installed (pip install '.[docs]')")
    tmp = tmp_path_factory.mktemp("docs")
    ignore = shutil.ignore_patterns("_build", "auto_examples", "_generated", "generated", "sg_execution_times.rst",
                                    "__pycache__")
    shutil.copytree(ROOT / "docs", tmp / "docs", ignore=ignore)
    shutil.copytree(ROOT / "examples", tmp / "examples", ignore=ignore)
    env = dict(os.environ, MPLBACKEND="Agg",
               PYTHONPATH=os.pathsep.join([str(ROOT / "src")] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    html = tmp / "html"
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q", "-b", "html",
                           str(tmp / "docs"), str(html)], capture_output=True, text=True, env=env, timeout=600)
    return html, proc


def test_docs_build_without_warnings(built):
    html, proc = built
    assert proc.returncode == 0, proc.stdout[-5000:] + proc.stderr[-5000:]
    for page in ("index", "notation", "choosing", "implementing", "api", "theory/gaussian", "theory/second_order",
                 "theory/quasilinear", "theory/bilinear", "theory/moment_bayes", "theory/reference",
                 "auto_examples/index"):
        assert (html / f"{page}.html").is_file(), page
    api = (html / "api.html").read_text(encoding="utf-8")
    for name in ("DiscreteModel", "compare", "SecondOrderFilter", "QuasilinearFilter", "OptimalLinearFilter",
                 "ZeroOrderMomentFilter", "GridFilter", "ParticleFilter", "REGISTRY", "Result"):
        assert f'<span class="pre">{name}</span>' in api, name
    # the "choosing a filter" page carries the tables of its build-time compare runs
    choosing = (html / "choosing.html").read_text(encoding="utf-8")
    assert choosing.count("<table") >= 3 and "ukf" in choosing and "gap to optimal" in choosing


def test_every_example_is_in_the_gallery_and_ran(built):
    html, proc = built
    assert proc.returncode == 0, proc.stderr[-5000:]
    assert len(EXAMPLES) >= 4
    index = (html / "auto_examples" / "index.html").read_text(encoding="utf-8")
    for path in EXAMPLES:
        page = html / "auto_examples" / f"{path.stem}.html"
        assert page.is_file(), path.name
        assert f"{path.stem}.html" in index, path.name
        # executed: its figures were rendered by the build
        assert list((html / "_images").glob(f"sphx_glr_{path.stem}_001.png")), path.name
