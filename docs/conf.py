"""Sphinx configuration of the nlfilter documentation.

Build (from the repository root, after ``pip install ".[docs]"``)::

    python -m sphinx -b html docs docs/_build/html

The API reference comes from the numpydoc docstrings (``api.rst`` and one page per area in
``api/``), the gallery from ``examples/plot_*.py`` (sphinx-gallery runs every one of them during
the build), the tables of the "choosing a filter" page from small :func:`nlfilter.compare` runs
committed as JSON (``choosing/``, rerun by ``choosing_tables.py``), and the reproduction and benchmarks pages from the
committed JSON (``make_pages.py``). Maths is written as MathML by the build (``_ext/mathml.py``):
the site loads nothing from the network. ``nitpicky``: every cross-reference must resolve
(``_ext/pyrefs.py`` resolves a name the way Python does).
"""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "_ext"))
if (ROOT / "src" / "nlfilter").is_dir():  # a source checkout: document this tree, not an installed copy
    sys.path.insert(0, str(ROOT / "src"))

import nlfilter  # noqa: E402

project = "nlfilter"
author = "the nlfilter authors"
copyright = "the nlfilter authors, MIT licence"
release = version = nlfilter.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "mathml",    # _ext/mathml.py: maths as MathML at build time (no script, no CDN)
    "pyrefs",    # _ext/pyrefs.py: references resolved as Python resolves the name
]
html_math_renderer = "mathml"

exclude_patterns = ["_build", "_generated", "figures", "report", "**.ipynb_checkpoints", "sg_execution_times.rst"]
templates_path = []
source_suffix = {".rst": "restructuredtext"}
root_doc = "index"
nitpicky = True   # every cross-reference must resolve (tests/test_docs.py builds with -W)
# Third-party names without an inventory (intersphinx needs the network, which the build must not):
# each is named exactly; nothing of nlfilter's is ignored.
nitpick_ignore = [
    ("py:class", "sympy.printing.numpy.NumPyPrinter"),
    ("py:class", "sympy.printing.pycode.PythonCodePrinter"),
    ("py:class", "numpy.linalg.LinAlgError"),
    ("py:func", "scipy.integrate.solve_ivp"),
    ("py:mod", "sqlite3"),
]
suppress_warnings = ["config.cache"]  # sphinx-gallery's conf values are not picklable

# -- autodoc / numpydoc ------------------------------------------------------------------------
autosummary_generate = False        # the API pages use automodule; autosummary only for tables
autodoc_default_options = {"members": True, "show-inheritance": True}  # public bases only (_ext/pyrefs.py)
autodoc_member_order = "bysource"
autodoc_typehints = "none"          # the numpydoc Parameters sections say the types
numpydoc_show_class_members = False  # automodule lists the members once
numpydoc_class_members_toctree = False
numpydoc_validation_checks = set()

# -- sphinx-gallery ----------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": "../examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"plot_",     # every plot_*.py is executed
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "abort_on_example_error": True,
    "capture_repr": (),
    "matplotlib_animations": False,
    "reset_modules": ("matplotlib",),
    "show_memory": False,
    "write_computation_times": False,
}

html_theme = "alabaster"
html_static_path = ["_static"]
html_css_files = ["nlfilter.css"]
html_title = f"nlfilter {release}"
html_theme_options = {"description": "moment-based nonlinear filters", "page_width": "1100px",
                      "sidebar_width": "240px"}


def _choosing_tables(app):
    import choosing_tables

    choosing_tables.write(HERE / "_generated")


def _implementing_code(app):
    """The worked node rule of ``implementing.rst``, from the library's own source (one source of
    truth): the ``Cubature5`` table and the ``"ckf5"`` registry entry, written to ``_generated``."""
    import inspect

    from nlfilter import filters
    from nlfilter.filters import rules

    lines = inspect.getsource(filters).splitlines()
    first = next(i for i, line in enumerate(lines) if line.lstrip().startswith('"ckf5": rule_filter('))
    last = first
    while "".join(lines[first:last + 1]).count("(") > "".join(lines[first:last + 1]).count(")"):
        last += 1
    entry = "\n".join(lines[first:last + 1])
    code = (inspect.getsource(rules._cubature5_table) + "\n\n" + inspect.getsource(rules.Cubature5)
            + "\n\n# nlfilter/filters/__init__.py\nREGISTRY = {\n    ...\n" + entry + "\n    ...\n}\n")
    out = HERE / "_generated"
    out.mkdir(parents=True, exist_ok=True)
    (out / "implementing_ckf5.py").write_text(code, encoding="utf-8")


def _generated_pages(app):
    """The reproduction pages and the benchmarks page, from the committed JSON (make_pages.py)."""
    import make_pages

    make_pages.write_all(app)


def _cite_sources(app, what, name, obj, options, lines):
    """Docstrings name the source papers by their file number ("seed 004 eq. 19"); the API pages
    name them as a reader does ("Henriksen (1979) eq. 19"): :func:`nlfilter.sources.cite`, the
    one table of papers (the command line and the report use it too)."""
    from nlfilter.sources import cite

    lines[:] = [cite(line) for line in lines]


def setup(app):
    app.connect("autodoc-process-docstring", _cite_sources)
    app.connect("builder-inited", _generated_pages)
    app.connect("builder-inited", _choosing_tables)
    app.connect("builder-inited", _implementing_code)
