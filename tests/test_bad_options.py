"""Issue 26, item 6: option objects and edge sizes that reached raw NumPy/Python errors; each is
now refused with an error naming the argument (or, for an empty record, answered)."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, simulate
from nlfilter import _validate as V
from nlfilter.bilinear import BilinearModel
from nlfilter.evaluate import loglik
from nlfilter.filters import EKF, QLF, UKF, GridFilter, ParticleFilter, TensorFilter

x = sp.Symbol("x")
D1 = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x + 0.1 * x**2], Q=0.1, R=0.2)
S1 = SDEModel([x], [-x**3], [x], Q=0.5, R=0.1)
BIL = BilinearModel([[-1.0]], [[1.0]], G=[[[0.3]]], B=[[1.0]], R=[[1.0]])
YS = 0.3 * np.random.default_rng(0).standard_normal((2, 5, 1))
P = {"m0": [0.5], "P0": [[0.2]]}


@pytest.mark.parametrize("value", [["mark"], {"mark": 1}, np.array(["mark"]), None, 1, b"mark"],
                         ids=["list", "dict", "array", "None", "int", "bytes"])
def test_choice_refuses_any_object_naming_the_option(value):
    """(tests/fuzz/test_smoothers.py adds an object whose hash, equality and repr raise, for every
    option of every filter.)"""
    with pytest.raises(ValueError, match=r"^on_divergence: expected one of \['mark', 'raise'\], got "):
        EKF(D1).run(YS, **P, on_divergence=value)
    if value is None:  # start=None is the default: the convention of the data (Filter.for_timing)
        flt = EKF(D1, start=None)
        assert flt.start == "update" and not flt.start_stated
        return
    with pytest.raises(ValueError, match=r"^start: expected one of \['predict', 'update'\], got "):
        EKF(D1, start=value)


def test_choice_returns_the_option_and_shows_values_briefly():
    assert type(V.choice("x", np.str_("mark"), {"mark", "raise"})) is str
    with pytest.raises(ValueError) as err:
        V.choice("x", np.zeros(10_000), {"a"})
    assert len(str(err.value)) < 150


@pytest.mark.parametrize("make,name", [
    (lambda: UKF(D1, kappa="a"), "kappa"),
    (lambda: UKF(D1, alpha=1e-300), "alpha"),  # n + λ = α² n underflows: the weights divided by 0
    (lambda: UKF(D1, alpha=1e-6), "alpha"),  # weights ~1e12: their sums lose 1e-4 to rounding
    (lambda: UKF(D1, alpha=1e200), "alpha"),
    (lambda: ParticleFilter(D1, 50, threshold=None), "threshold"),
    (lambda: GridFilter(D1, (-4.0, 4.0), [10, 10]), "size"),
    (lambda: GridFilter(D1, "abc", 41), "bounds"),
    (lambda: TensorFilter(BIL, 0.05, targets=[]), "targets"),
    (lambda: TensorFilter(BIL, 0.05, targets=[7]), "targets"),
    (lambda: simulate("x", 5, paths=2, rng=1, **P), "model"),
    (lambda: simulate(D1, 5, paths=2, rng=1, m0=np.zeros((3, 1)), P0=[[0.2]]), "m0"),
    (lambda: simulate(D1, 5, paths=2, rng=1, x0=np.zeros((2, 3, 1))), "x0"),
    (lambda: QLF(S1, 0.05).run(YS, **P, t0=1e300), "t0"),
    (lambda: simulate(S1, 5, paths=2, rng=1, dt=0.05, t0=1e300, **P), "t0"),
    (lambda: loglik(EKF(D1), YS * (1 + 1j), **P), "ys"),
], ids=["ukf-kappa", "ukf-alpha-tiny", "ukf-alpha-small", "ukf-alpha-huge", "pf-threshold", "grid-size", "grid-bounds",
        "tensor-targets-empty", "tensor-targets-range", "simulate-model", "simulate-m0", "simulate-x0", "qlf-t0",
        "simulate-t0", "loglik-complex"])
def test_bad_option_is_refused_naming_it(make, name):
    with pytest.raises((ValueError, TypeError), match=rf"^{name}: "):
        make()


def test_usual_options_still_pass():
    """The checks refuse only what the examples above show: α = 1e-3 (the usual small spread),
    one size per axis, a per-path m0 of the batch's shape."""
    assert UKF(D1, alpha=1e-3).alpha == 1e-3
    assert [len(a) for a in GridFilter(D1, (-4.0, 4.0), [11]).axes] == [11]
    sim = simulate(D1, 5, paths=2, rng=1, m0=np.array([[0.1], [0.2]]), P0=[[0.2]])
    assert sim.xs.shape == (2, 5, 1)


class _ReprRaises(str):
    """A filter name (a str) whose ``repr`` raises: the message shows its type instead."""

    def __repr__(self):
        raise RuntimeError("repr")


class _Unshowable:
    def __repr__(self):
        raise RuntimeError("repr")


def test_compare_names_a_hostile_filters_or_reference_argument():
    from nlfilter import compare
    kw = dict(paths=2, m0=[0.5], P0=[[0.2]], reference=None)
    with pytest.raises(TypeError, match=r"^filters: expected 'all', a list"):
        compare(D1, _Unshowable(), 3, **kw)
    with pytest.raises(ValueError, match=r"^filters: expected registry names"):
        compare(D1, [_ReprRaises("no-such-filter")], 3, **kw)
    with pytest.raises(ValueError, match=r"^reference: expected one of"):
        compare(D1, ["ekf"], 3, **{**kw, "reference": _ReprRaises("no-such-reference")})
