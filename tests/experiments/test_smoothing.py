"""Experiment ``smoothing`` (quick path): every Gaussian RTS smoother beside its own filter and the
optimal smoother on the 1-D and 2-D cubic sensors (issue 12). The assertions compare paired
differences with their own standard errors (16 paths)."""

import pytest

from nlfilter.experiments import get
from nlfilter.experiments.rts_smoothing import FILTERS

MODELS = {"cubic": 1, "rotating-cubic": 2}
CONSISTENT = ("ukf", "ckf", "ghkf")  # NEES near n: their smoothers are trusted to help


@pytest.fixture(scope="module")
def quick():
    return get("smoothing").run({}, quick=True, seed=0)


def _ref(res, model):
    return next(r.filter for r in res.rows if r.params.get("model") == model and r.quantity == "smoothed_mse"
                and r.filter not in FILTERS)


def _gap(res, f, model, i):
    return next(r for r in res.rows if r.filter == f and r.params == {"model": model, "component": i}
                and r.quantity.startswith("smoothed_gap_to_"))


def test_rows_for_every_smoother_and_component(quick):
    for model, n in MODELS.items():
        for f in (*FILTERS, _ref(quick, model)):
            for i in range(n):
                for q in ("mse", "smoothed_mse", "smoothing_gain"):
                    assert quick.get(f, q, model=model, component=i).stderr > 0
                if f in FILTERS:
                    _gap(quick, f, model, i)


def test_no_smoother_beats_the_optimal_smoother(quick):
    """Every smoother's paired gap to the optimal (reference) smoother is ≥ −3 s.e."""
    for model, n in MODELS.items():
        for f in FILTERS:
            for i in range(n):
                g = _gap(quick, f, model, i)
                assert g.value > -3 * g.stderr, (f, model, i, g)


def test_smoothing_helps_the_optimal_and_the_consistent_filters(quick):
    """The optimal smoother improves on the optimal filter, and so do the unscented, cubature and
    Gauss–Hermite smoothers on theirs, most on the component seen only through the dynamics
    (measured gains ≈ 3 s.e. on the cubic sensor, 3-4 s.e. on the unmeasured x2)."""
    for model, i in (("cubic", 0), ("rotating-cubic", 1)):
        for f in (*CONSISTENT, _ref(quick, model)):
            g = quick.get(f, "smoothing_gain", model=model, component=i)
            assert g.value > 2 * g.stderr, (f, model, g)
