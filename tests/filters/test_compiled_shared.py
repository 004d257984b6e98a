"""The model-free loops (``backend="numba-shared"``, :mod:`nlfilter.filters.compiled.template`): the
loop of a rule kind compiled once for every model of its shape, the model's functions passed to it
by address.

Tolerances: against the model's own compiled loop, none — the same kernels in the same order, a
call through a pointer instead of an inlined function: the same bits (``array_equal``, NaN where
NaN). Against the NumPy loop, the compiled loop's 1e-12 relative (tests/filters/test_compiled.py
states why). The loops compile once per rule kind and shape for the whole test session.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import compiled
from nlfilter.filters.compiled import build, cache, choice, template
from nlfilter.filters.ekf import EKF, IteratedEKF
from nlfilter.filters.kalman import KalmanFilter
from nlfilter.filters.second_order import SecondOrderFilter
from nlfilter.filters.ukf import UKF
from nlfilter.simulate import simulate
from tests.filters.test_backend_choice import _five_state  # (a 5-state tracking model: no paper has it)

pytestmark = [pytest.mark.skipif(not compiled.available(), reason="numba does not import"),
              pytest.mark.filterwarnings("error:Cannot cache compiled function")]

RTOL = 1e-12
x1, x2, a = sp.symbols("x1 x2 a")


def two_state(c=0.9):
    """Two states, two measurements, a parameter and a G that depends on the state."""
    f = [c * x1 + 0.1 * sp.sin(x2), a * x2 - 0.05 * x1 * x2]
    h = [x1 + 0.1 * x2**2, sp.atan(x2)]
    G = [[1.0, 0.0], [0.1 * x1, 1.0]]
    return DiscreteModel([x1, x2], f, h, G, Q=[[0.02, 0.005], [0.005, 0.01]], R=[[0.1, 0.02], [0.02, 0.2]],
                         params={a: 0.8})


def data(md, B=6, T=40, seed=0):
    """Simulated data with what the loops must handle alike: a step measured on no path, a partly
    measured step, and a path whose data of 1e200 makes it diverge (marked)."""
    ys = simulate(md, T, paths=B, rng=seed, m0=np.full(md.n, 0.3), P0=0.5 * np.eye(md.n)).ys.copy()
    ys[:, 7] = np.nan
    ys[1, 11, 0] = np.nan
    ys[2, 20:] = 1e200
    return ys


def run(flt, ys, backend, start=None):
    m0 = np.full(flt.model.n, 0.3)
    return flt.run(ys, m0, 0.5 * np.eye(flt.model.n), loglik=True, on_divergence="mark", backend=backend)


def same(e1, e2):
    for name in ("means", "covs", "diverged", "diverged_step"):
        assert np.array_equal(getattr(e1, name), getattr(e2, name), equal_nan=True), name
    for name in ("loglik", "innovation", "innovation_cov"):
        assert np.array_equal(e1.extras[name], e2.extras[name], equal_nan=True), name


def close(e1, e2):
    ok = ~e1.diverged
    assert np.array_equal(e1.diverged, e2.diverged) and np.array_equal(e1.diverged_step, e2.diverged_step)
    for a1, a2 in ((e1.means, e2.means), (e1.covs, e2.covs), (e1.extras["loglik"], e2.extras["loglik"])):
        a1, a2 = a1[ok], a2[ok]
        assert np.all(np.abs(a1 - a2) <= RTOL * np.maximum(1.0, np.abs(a1)))


def test_the_model_free_loop_gives_the_models_own_loops_bits():
    """EKF, 2 states (tests/filters/test_compiled.py's model, a time-varying input among its terms:
    its own specialized loop is compiled there too): the model's own loop and the model-free one,
    bit for bit — missing steps, a partly missing step, a diverging path, the likelihood; then a
    second model of the same shape runs on the same loop object, compiling only its functions, and
    agrees with the NumPy loop."""
    from tests.filters.test_compiled import nonlinear

    md = nonlinear()
    ys = data(md)
    flt = EKF(md)
    shared = run(flt, ys, "numba-shared")
    same(run(flt, ys, "numba"), shared)
    assert shared.diverged[2] and not shared.diverged[0]
    kind, slots, scalar, dims, key = template.of(flt, 6)
    loops = dict(template._LOOPS)
    other = EKF(two_state(0.7))
    close(run(other, ys, "numpy"), run(other, ys, "numba-shared"))
    assert template._LOOPS == loops  # the same loop, not another compile
    assert template.loaded(kind, slots, key, scalar, dims)
    # the loop's text holds no model: two models of the shape share it, and its cache entry
    text, tag = template.text(kind, scalar, dims)
    assert "atan" not in text and "sin(" not in text and tag == "taylor1-template"


def test_the_scalar_loop_and_the_time_convention():
    """The scalar batch loop (the EKF on one state): bit for bit its own loop's, both starts."""
    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[0.9 * x + 0.2 * sp.sin(x)], h=[x**3], Q=0.1, R=0.2)
    ys = data(md)
    for start in ("update", "predict"):
        flt = EKF(md, start=start)
        same(run(flt, ys, "numba"), run(flt, ys, "numba-shared"))


def test_the_node_rule_on_a_five_state_model_and_the_smoother():
    """The UKF on a 5-state tracking model (the general loop), and its smoother, as the NumPy loop."""
    md = _five_state()
    ys = simulate(md, 30, paths=3, rng=1, m0=np.array([1.0, 0.5, 0.2, 0.1, 0.3]), P0=0.01 * np.eye(5)).ys
    flt = UKF(md)
    m0, P0 = np.array([1.0, 0.5, 0.2, 0.1, 0.3]), 0.01 * np.eye(5)
    close(flt.run(ys, m0, P0, loglik=True, backend="numpy"), flt.run(ys, m0, P0, loglik=True, backend="numba-shared"))
    s1, s2 = flt.smooth(ys, m0, P0, backend="numpy"), flt.smooth(ys, m0, P0, backend="numba-shared")
    assert np.allclose(s1.means, s2.means, rtol=0, atol=RTOL * max(1.0, np.abs(s1.means).max()))


def test_second_order_forms_share_one_loop():
    """The Taylor-2 kind's loop takes the Hessians' slots as arguments: the first-order form (no
    Hessians: no-op functions in their slots) and the Gaussian form run on one loop, as NumPy."""
    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[0.95 * x + 0.1 * sp.cos(x)], h=[x + 0.2 * x**2], Q=0.05, R=0.1)
    ys = data(md)
    for form in ("first-order", "gaussian"):
        flt = SecondOrderFilter(md, form=form)
        close(run(flt, ys, "numpy"), run(flt, ys, "numba-shared"))
    assert sum(k[0] == "taylor2" for k in template._LOOPS) == 1


def test_what_the_model_free_loop_does_not_take_is_named():
    """A filter the compiled loop does not take is refused by name; the Kalman filter's loop is
    model-free already (its matrices are data) and runs as with ``backend="numba"``."""
    md = two_state()
    with pytest.raises(TypeError, match="backend.*numba-shared.*IteratedEKF"):
        IteratedEKF(md).run(np.zeros((1, 5, 2)), np.zeros(2), np.eye(2), backend="numba-shared")
    lin = DiscreteModel([x1], [0.9 * x1], [x1], Q=0.1, R=0.2)
    ys = simulate(lin, 30, paths=2, rng=3, m0=np.zeros(1), P0=np.eye(1)).ys
    kf = KalmanFilter(lin)
    same(kf.run(ys, np.zeros(1), np.eye(1), loglik=True, backend="numba"),
         kf.run(ys, np.zeros(1), np.eye(1), loglik=True, backend="numba-shared"))


def test_the_automatic_tiers(tmp_path, monkeypatch):
    """``backend="auto"`` (nothing compiled here: the rule reads the stores and the disk):
    a model-free loop ready on disk serves a run that repays the model's functions only; loaded with
    the model's functions, it serves every run; its runs' time, once the model's own loop would have
    saved its compile on them, moves the model to its own loop."""
    monkeypatch.setenv("NLFILTER_CACHE", str(tmp_path / "empty"))
    monkeypatch.setattr(template, "_LOOPS", {})
    monkeypatch.setattr(cache, "_MODULES", {})
    flt = EKF(two_state(0.55))
    kind, slots, scalar, dims, key = template.of(flt, 1)
    assert template.ready(kind, slots, key, scalar, dims) == (None, None)
    T = 40_000  # one path: NumPy ~2 s, past loading numba and the model's functions, short of a compile
    assert choice.LOAD_SECONDS + choice.FIRST_COMPILE_SECONDS + choice.FUNCTION_SECONDS * len(slots) <= \
        choice.numpy_seconds(kind, 2, 1, T) < choice.COMPILE_SECONDS["specialized"]
    assert flt.backend_for(1, T)[0] == "numpy"
    monkeypatch.setattr(template, "ready", lambda *a: ("disk", None))
    backend, why = flt.backend_for(1, T)
    assert backend == "numba-shared" and "ready on disk" in why, why
    monkeypatch.setattr(template, "loaded", lambda *a: True)
    assert flt.backend_for(1, 5)[0] == "numba-shared"
    store = build.KERNELS.setdefault(key, {})
    monkeypatch.setitem(store, choice.shared_tally(kind), choice.COMPILE_SECONDS["specialized"] / (1 - 1 / choice.FULL_GAIN[False]))
    backend, why = flt.backend_for(1, 5)
    assert backend == "numba" and "would have saved" in why, why


def _others():
    """The kinds with kernels of their own, on the models their own tests compile (the same
    expressions: the same cache entries): ``(filter, ys, m0, P0)``."""
    from nlfilter.filters.ekf import ContinuousDiscreteEKF, ContinuousEKF
    from nlfilter.filters.square_root_filters import SquareRootUKF
    from tests.filters import test_compiled_cd, test_compiled_ito, test_compiled_sqrt

    cd = test_compiled_cd.pendulum.__wrapped__()
    ito = test_compiled_ito.sensor.__wrapped__()
    sq = test_compiled_sqrt.data.__wrapped__()
    return {"cd-taylor1": (ContinuousDiscreteEKF(cd[0], test_compiled_cd.DT, substeps=2), cd[3], cd[1], cd[2]),
            "ito": (ContinuousEKF(ito[0], test_compiled_ito.DT), ito[1], [0.1], [[1.0]]),
            "sqrt-nodes": (SquareRootUKF(sq[0]), sq[1], test_compiled_sqrt.M0, test_compiled_sqrt.P0)}


@pytest.mark.parametrize("kind", ["cd-taylor1", "ito", "sqrt-nodes"])
def test_the_other_kinds_give_their_own_loops_bits(kind):
    """The continuous-discrete, continuous Itô and square-root kinds (the Itô kind's predict takes
    none of the model's functions: its update takes them all) on the model-free loop: the model's
    own loop's bits."""
    flt, ys, m0, P0 = _others()[kind]
    assert build.loop_of(flt)[0] == kind
    kw = {"loglik": True, "on_divergence": "mark"}
    same(flt.run(ys, m0, P0, backend="numba", **kw), flt.run(ys, m0, P0, backend="numba-shared", **kw))


def test_a_run_that_compiles_adds_nothing_to_the_tally():
    """The model-free loop's tally (what moves a model to its own loop) counts runs on the loop
    already loaded, not the run that compiled or loaded it."""
    x = sp.Symbol("x")
    md = DiscreteModel([x], f=[0.8 * x + 0.1 * sp.sin(x)], h=[x**3], Q=0.1, R=0.2)  # (the scalar loop: warm)
    flt = EKF(md)
    store = build.KERNELS.setdefault(md._kernels["f"], {})
    ys = data(md)
    run(flt, ys, "numba-shared")
    assert store.get(choice.shared_tally("taylor1"), 0.0) == 0.0
    run(flt, ys, "numba-shared")
    assert store[choice.shared_tally("taylor1")] > 0.0
