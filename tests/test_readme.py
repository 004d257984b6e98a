"""The README's quickstart runs as written (so it cannot go stale)."""

import pathlib
import re

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_quickstart_runs(tmp_path, monkeypatch, capsys):
    code = re.search(r"## Quickstart\n\n```python\n(.*?)```", README.read_text(), re.S).group(1)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README-quickstart", "exec"), {})
    out = capsys.readouterr().out
    assert out.startswith("ekf Summary(") and "ukf Summary(" in out
    assert (tmp_path / "quickstart.png").stat().st_size > 5000
