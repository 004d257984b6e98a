"""The filter registry (``nlfilter.filters.REGISTRY``): a plain dict name -> class that the CLI,
``compare`` and the contract test enumerate."""

from __future__ import annotations

import subprocess
import sys

import pytest

from nlfilter.filters import REGISTRY, get
from nlfilter.filters.base import Filter
from nlfilter.filters.registry import accepting, model_kind, table


def test_unknown_name_lists_the_choices():
    with pytest.raises(ValueError, match=r"^filter: expected one of \[.*'ekf'.*\], got 'bogus'"):
        get("bogus")
    assert get("ekf") is REGISTRY["ekf"]


def test_every_entry_declares_time_and_model_kinds():
    for name, cls in REGISTRY.items():
        assert issubclass(cls, Filter), name  # every filter runs on the one loop
        assert cls.time in ("discrete", "continuous", "by model"), name  # grid, particle: set per instance
        assert cls.accepts and isinstance(cls.accepts, tuple), name
        assert cls.family and cls.source, name


def test_accepting_selects_by_model_kind():
    import sympy as sp

    from nlfilter import DiscreteModel, SDEModel
    x = sp.Symbol("x")
    d = DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=1.0)
    s = SDEModel([x], [-x], [x], Q=1.0, R=1.0)
    assert model_kind(d) == "discrete" and model_kind(s) == "sde"
    dn, sn = accepting(REGISTRY, d), accepting(REGISTRY, s)
    assert {"kf", "ekf", "ukf", "second-order", "discrete-conditional-moment"} <= set(dn)
    assert {"kalman-bucy", "continuous-ekf", "continuous-second-order", "conditional-moment"} <= set(sn)
    assert not set(dn) & {"kalman-bucy", "continuous-ekf", "conditional-moment"}


def test_cli_lists_the_registry():
    out = subprocess.run([sys.executable, "-m", "nlfilter.cli", "list", "--filters"], capture_output=True,
                         text=True, check=True).stdout.splitlines()
    assert sorted(line.split()[0] for line in out if line.startswith("  ")) == sorted(REGISTRY)  # by family
    assert len(table(REGISTRY)) == len(REGISTRY)
