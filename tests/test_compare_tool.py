"""``compare`` in a user's hands (issue 25, items 5-7): the registry by model kind (every filter
that accepts a model runs or is listed as skipped, with the reason), honest rows for filters that
diverge on most paths, and ``nlfilter compare`` as a tool — a reference budget, runs in the
results store that resume after an interruption, and a report with the comparison's numbers."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, compare
from nlfilter.bilinear import BilinearModel
from nlfilter.compare_rows import MIN_SURVIVING_FRACTION, MIN_SURVIVORS
from nlfilter.evaluate import paired_difference
from nlfilter.filters import REGISTRY
from nlfilter.filters.registry import accepting, model_kind

x = sp.Symbol("x")

# -- item 7: the registry by kind --------------------------------------------------------------------
DISCRETE_BILINEAR = BilinearModel([[0.9]], [[1.0]], B=[[1.0]], R=[[1.0]], discrete=True)
MODELS = {  # a few models of each kind compare takes; dt for the continuous-time ones
    "discrete-linear": (DiscreteModel([x], [0.9 * x], [x], Q=0.1, R=0.5), None),
    "discrete-nonpolynomial": (DiscreteModel([x], [0.9 * x + 0.1 * sp.sin(x)], [x**3], Q=0.1, R=0.5), None),
    "sde-linear": (SDEModel([x], [-x], [x], Q=1.0, R=0.5), 0.05),
    "sde-cubic": (SDEModel([x], [-x], [x**3], Q=1.0, R=1.0), 0.05),
    "bilinear": (BilinearModel.from_polynomial(SDEModel([x], [-x], [x**3], Q=1.0, R=1.0)), 0.05),
    "bilinear-discrete": (DISCRETE_BILINEAR, None),
}


def test_a_discrete_bilinear_model_is_its_own_kind_and_gets_its_filter():
    """Regression: ``BilinearModel.kind`` is "bilinear" in both times; the registry maps a
    discrete one to "bilinear-discrete", so ``compare(.., "all")`` runs discrete-optimal-linear."""
    assert model_kind(DISCRETE_BILINEAR) == "bilinear-discrete" and model_kind(MODELS["bilinear"][0]) == "bilinear"
    assert "discrete-optimal-linear" in accepting(REGISTRY, DISCRETE_BILINEAR)
    assert "optimal-linear" not in accepting(REGISTRY, DISCRETE_BILINEAR)
    res = compare(DISCRETE_BILINEAR, "all", 5, paths=4, m0=[0.0], P0=[[0.5]], reference=None, rng=0)
    assert "discrete-optimal-linear" in {r.filter for r in res.rows}
    # on a linear model the optimal linear filter is the Kalman filter (same simulation, same paths)
    assert res.get("discrete-optimal-linear", "mse", component=0).value == pytest.approx(
        res.get("kf", "mse", component=0).value, rel=1e-9)


@pytest.mark.parametrize("case", list(MODELS))
def test_every_filter_accepting_the_kind_runs_or_is_skipped_with_a_reason(case):
    """The contract: every registered filter that accepts the model's kind (or that of the model
    it is simulated through) appears in ``compare(model, "all")``'s rows or in ``skipped``, with
    a non-empty reason — nothing is dropped silently."""
    md, dt = MODELS[case]
    res = compare(md, "all", 5, paths=4, m0=[0.0], P0=[[0.5]], reference=None, rng=0, dt=dt)
    views = [md] + ([md.to_discrete() if md.discrete else md.to_sde()] if isinstance(md, BilinearModel) else [])
    want = {name for m in views for name in accepting(REGISTRY, m)}
    ran = {r.filter for r in res.rows}
    skipped = res.params.get("skipped", {})
    assert ran | set(skipped) == want and not ran & set(skipped)
    assert all(isinstance(v, str) and len(v) > 10 for v in skipped.values()), skipped
    assert ran  # something ran
    if md.__class__ is SDEModel:  # the continuous-discrete filters read samples, not increments: said so
        cd = {n for n in want if n.startswith("continuous-discrete")}
        assert cd and all("discrete-time data" in skipped[n] for n in cd)
    assert any(n.startswith("not run: ") for n in res.notes)


# -- item 6: honest rows for diverging filters ------------------------------------------------------
FAST = SDEModel([x], [-2 * x**3], [x], Q=1.0, R=0.1)  # stiff at dt = 0.2: the moment filters blow up


def test_a_filter_diverging_on_most_paths_gets_no_mse_gap_or_nees_row():
    """The conditional-moment filter diverges on 35 of 40 paths of a fast SDE. Over its 5
    survivors its paired gap is −0.023 ± 0.010: "better than optimal" by 2.2 s.e., a selection
    effect. compare reports its divergence rate and a note, and no number with an s.e."""
    res, sim, est = compare(FAST, ["continuous-ekf", "conditional-moment", "quasilinear"], 20, paths=40, m0=[1.5],
                            P0=[[0.5]], rng=0, dt=0.2, substeps=10, full_output=True)
    assert res.params["reference"]["certified"] is True
    cm = est["conditional-moment"]
    survivors = int(np.sum(~cm.diverged))
    assert survivors < max(MIN_SURVIVORS, MIN_SURVIVING_FRACTION * 40)
    d = paired_difference(cm, est["optimal"], sim.xs, component=0, window=0.5)
    assert d.value < -2 * d.stderr  # what the old rows printed: below the optimum, from 5 selected paths
    for name in ("conditional-moment", "continuous-ekf"):
        assert {r.quantity for r in res.rows if r.filter == name} == {"divergence_rate"}
        assert any(n.startswith(f"{name}: diverged on ") and "no MSE, gap or NEES" in n for n in res.notes)
    assert res.get("conditional-moment", "divergence_rate").value == 1 - survivors / 40
    # no table row below the optimum by more than 2 s.e.
    assert all(r.value >= -2 * r.stderr for r in res.rows if r.quantity.startswith("gap"))
    assert "conditional-moment" not in next(iter(res.series.values()))["lines"]
    assert res.get("quasilinear", "gap_to_optimal", component=0).stderr > 0  # the survivor-free filter is judged
