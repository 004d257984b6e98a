import json
import subprocess
import sys

from nlfilter import cli


def test_list_names_every_experiment(capsys):
    assert cli.main(["list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert any(line.startswith("linear-gaussian\t") for line in lines)
    assert all(len(line.split("\t")) == 3 for line in lines)


def test_list_params_round_trip_through_param(capsys):
    """Every listed ``--param NAME=DEFAULT`` line is accepted back by the experiment and converts
    to its default (lists included)."""
    from nlfilter import experiments

    assert cli.main(["list", "--params"]) == 0
    current, seen = None, 0
    for line in capsys.readouterr().out.splitlines():
        if not line.startswith("    "):
            current = experiments.get(line.split("\t")[0])
            continue
        name, _, value = line.strip().removeprefix("--param ").split("  (")[0].partition("=")
        default = current.params[name]
        got = current.convert(name, value)
        assert got == (list(default) if isinstance(default, tuple) else default) or str(got) == str(default)
        seen += 1
    assert seen == sum(len(e.params) for e in experiments.registry().values()) > 0


def test_reproduce_quick_writes_schema(tmp_path, capsys):
    out = tmp_path / "out.json"
    png = tmp_path / "fig.png"
    assert cli.main(["reproduce", "linear-gaussian", "--quick", "--no-progress", "--json", str(out),
                     "--plot", str(png), "--param", "r=0.4"]) == 0
    data = json.loads(out.read_text())
    assert set(data) == {"experiment", "title", "source", "params", "rows", "notes", "meta"}
    assert data["params"]["r"] == 0.4
    rows = {(r["filter"], r["quantity"]): r for r in data["rows"]}
    for f in ("kf", "ekf", "ukf", "grid", "particle", "riccati"):
        assert (f, "mse") in rows
        assert set(rows[(f, "mse")]) == {"filter", "quantity", "params", "paper", "value", "stderr"}
    ric = rows[("riccati", "mse")]["value"]
    kf = rows[("kf", "mse")]
    assert abs(kf["value"] - ric) < 4 * kf["stderr"]  # KF is optimal: its MSE is the Riccati value
    # gaps to the KF, paired on common noise: EKF/UKF are the KF on a linear model (exact up to
    # rounding); the grid is within 4 paired se plus its discretization; the particle filter
    # can only lose (within 4 se of zero from below)
    for f in ("ekf", "ukf"):
        assert abs(rows[(f, "gap_to_optimal")]["value"]) < 1e-12
    g = rows[("grid", "gap_to_optimal")]
    assert abs(g["value"]) < 4 * g["stderr"] + 1e-3 * ric
    pf = rows[("particle", "gap_to_optimal")]
    assert pf["value"] > -4 * pf["stderr"]
    assert png.stat().st_size > 10_000
    assert "riccati" in capsys.readouterr().out


def _run(*args):
    return subprocess.run([sys.executable, "-m", "nlfilter.cli", *args], capture_output=True, text=True)


def test_errors_are_one_line_exit_2():
    for args in (["reproduce", "no-such"], ["reproduce", "linear-gaussian", "--param", "zz=1"],
                 ["reproduce", "linear-gaussian", "--param", "r=abc"],
                 ["reproduce", "linear-gaussian", "--param", "noequals"], ["frobnicate"]):
        p = _run(*args)
        assert p.returncode == 2, args
        assert len(p.stderr.strip().splitlines()) == 1 and "Traceback" not in p.stderr, p.stderr
