"""Every ``--param`` of every experiment is checked by its declared type and range before any
work starts (issue 15, item 5): non-finite numbers, empty lists, wrong types and values outside
the declared range exit 2 with one line naming the parameter."""

from __future__ import annotations

import math

import pytest

from nlfilter import cli, experiments


def _bad_values(exp, name):
    default = exp.params[name]
    items = default if isinstance(default, (list, tuple)) else [default]
    kind = type(items[0]) if items else float
    out = []
    if isinstance(default, (list, tuple)) and default:
        out.append("")                       # an empty list
    if kind is bool:
        out.append("maybe")
    elif kind in (int, float):
        out += ["nan", "inf", "-inf", "abc"]
        if kind is int:
            out.append("2.5")
    spec = exp.ranges.get(name)
    if isinstance(spec, str):
        for part in spec.split(","):         # just outside each bound
            op = part[:2] if part[:2] in (">=", "<=") else part[:1]
            b = float(part[len(op):])
            step = 1 if kind is int else max(1e-6, abs(b) * 1e-3)
            v = b - step if op in (">", ">=") else b + step
            if op == ">":
                v = b
            if op == "<":
                v = b
            out.append(str(int(v)) if kind is int and float(v).is_integer() else repr(float(v)))
    elif isinstance(spec, tuple):
        out.append("no-such-choice")
    return out


CASES = [(eid, name, bad) for eid, exp in experiments.registry().items() for name in exp.params
         for bad in _bad_values(exp, name)]


@pytest.mark.parametrize("eid,name,bad", CASES)
def test_bad_param_exits_2_with_one_line(eid, name, bad, capsys):
    code = cli.main(["reproduce", eid, "--quick", "--no-progress", "--no-store", "--param", f"{name}={bad}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, (eid, name, bad)
    assert len(err) == 1 and f"param {name}" in err[0], err


def test_defaults_pass_their_own_checks_and_ranges_name_parameters():
    for exp in experiments.registry().values():
        assert set(exp.ranges) <= set(exp.params), exp.id
        for name, default in exp.params.items():
            assert exp.check(name, default) == default, (exp.id, name)
    with pytest.raises(ValueError, match="are not parameters"):
        experiments.Experiment("x-demo", "t", "s", {"a": 1}, "nlfilter.experiments.linear_gaussian:run", {"b": ">0"})


def test_python_values_are_checked_too():
    exp = experiments.get("phase-tracking")
    with pytest.raises(ValueError, match="param time_constants=nan: expected a finite number"):
        exp.run({"time_constants": math.nan}, quick=True)
    with pytest.raises(TypeError, match="param grid=2.5: expected an integer"):
        exp.run({"grid": 2.5}, quick=True)
    with pytest.raises(ValueError, match=r"param step=-1.0: expected a value >0"):
        exp.run({"step": -1.0}, quick=True)
