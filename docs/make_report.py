"""Commit a full reproduction report and regenerate the README's results blocks from it.

    nlfilter reproduce all --report /tmp/full-report          # the full run (seed 0)
    PYTHONPATH=src python docs/make_report.py /tmp/full-report

copies every ``<id>.json`` and ``<id>.png`` of the run into ``docs/report/``, rewrites
``docs/report/index.md`` from those JSON files, and replaces every ``<!-- report:ID -->`` block of
README.md (the summary table; a block may also name an experiment or a committed single run in
``docs/report/runs/``). ``tests/test_report.py`` checks that the
README's blocks and ``docs/report/index.md`` equal what the committed JSON files give.
``python docs/make_report.py`` without a folder only regenerates from ``docs/report/``.
"""

import pathlib
import shutil
import sys

from nlfilter.report import REPORT_DIR, fill_readme, load_folder, write_report
from nlfilter.results import Result

ROOT = pathlib.Path(__file__).resolve().parents[1]


def runs(dest):
    """The committed single runs beside the report (``docs/report/runs/<name>.json``), by name:
    README blocks ``<!-- report:<name> -->`` (e.g. the decisive Table 4.1 run)."""
    return {p.stem: Result.from_json(p) for p in sorted((dest / "runs").glob("*.json"))}


def main(argv):
    dest = ROOT / REPORT_DIR
    dest.mkdir(parents=True, exist_ok=True)
    if argv:
        src = pathlib.Path(argv[0])
        for f in sorted(src.glob("*.json")) + sorted(src.glob("*.png")):
            shutil.copyfile(f, dest / f.name)
    results = load_folder(dest)
    write_report(list(results.values()), dest, figures=False, title="nlfilter: the full reproduction report")
    blocks = {**results, **runs(dest)}
    readme = ROOT / "README.md"
    readme.write_text(fill_readme(readme.read_text(encoding="utf-8"), blocks), encoding="utf-8")
    print(f"wrote {dest / 'index.md'} and the README's blocks ({len(results)} experiments)")


if __name__ == "__main__":
    main(sys.argv[1:])
