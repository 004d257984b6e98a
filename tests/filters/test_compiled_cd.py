"""The continuous-discrete filters on the compiled loop (issue 28, item 6: the continuous filters'
RK4 substeps compiled): ``ContinuousDiscreteEKF``, ``ContinuousDiscreteSecondOrderFilter`` (every
form but the first-order one, whose Taylor-1 arithmetic is the EKF's) and the node rules' (UKF,
CKF, GHKF: one loop, the rule's table as data) give the NumPy loop's estimates to 1e-12 relative —
both starts, RK4 and Euler, several substeps, partly missing measurements and a step missing on
every path, divergence marks, the log-likelihood, the smoother, a Simulation's timing — and what
the loop does not take is refused naming ``backend``.

Five compiles: a pendulum with a state-dependent G and two measurements (n = 2, specialized; the
Taylor-1 and the node loops), the same pendulum with a constant G for the second-order forms, a 5-state coupled model past the
specialized sizes (the general loop), and the scalar model of the refusal tests (specialized,
n = 1), each of them a model the papers do not have.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import compiled
from nlfilter.filters.cubature import ContinuousDiscreteCKF, ContinuousDiscreteGHKF
from nlfilter.filters.ekf import ContinuousDiscreteEKF, ContinuousDiscreteIEKF
from nlfilter.filters.rules import FORMS
from nlfilter.filters.second_order import ContinuousDiscreteSecondOrderFilter
from nlfilter.filters.ukf import ContinuousDiscreteUKF
from nlfilter.simulate import simulate_continuous_discrete
from tests.filters.test_compiled import same

pytestmark = [pytest.mark.skipif(not compiled.available(), reason="numba does not import"),
              pytest.mark.filterwarnings("error:Cannot cache compiled function")]

th, om, x = sp.symbols("theta omega x")
DT = 0.05


def _data(md, m0, P0, B=6, T=40):
    ys = np.array(simulate_continuous_discrete(md, T, dt=DT, paths=B, rng=3, m0=m0, P0=P0).ys)
    ys[1, 3, 0] = np.nan  # partly missing
    ys[2, 9] = np.nan  # missing on one path
    ys[:, 15] = np.nan  # missing on every path: the step only predicts
    return ys


@pytest.fixture(scope="module")
def pendulum():
    """A damped pendulum whose noise grows with the angle (G(x)), seen through sin θ and ω²."""
    md = SDEModel([th, om], [om, -4.0 * sp.sin(th) - 0.3 * om], [sp.sin(th), om**2 / 4],
                  G=[[0], [1 + 0.2 * th**2]], Q=0.5, R=0.02 * np.eye(2))
    m0, P0 = np.array([0.8, 0.0]), 0.1 * np.eye(2)
    return md, m0, P0, _data(md, m0, P0)


SETUPS = {"rk4-predict": {"substeps": 2}, "rk4-update": {"substeps": 1, "start": "update"},
          "euler": {"scheme": "euler", "substeps": 3}}


@pytest.mark.parametrize("name", list(SETUPS))
def test_same_estimates_and_likelihood_as_numpy(pendulum, name):
    md, m0, P0, ys = pendulum
    flt = ContinuousDiscreteEKF(md, DT, **SETUPS[name])
    m0s = m0 + 0.01 * np.arange(6)[:, None]  # a prior per path
    ref = flt.run(ys, m0s, P0, loglik=True, on_divergence="mark")
    new = flt.run(ys, m0s, P0, loglik=True, on_divergence="mark", backend="numba")
    assert not ref.diverged.any()
    same(ref, new)
    assert compiled.build.loop_of(flt)[0] == "cd-taylor1"


NODES = {"ukf": lambda md, **kw: ContinuousDiscreteUKF(md, DT, **kw),
         "ukf-scaled-euler": lambda md, **kw: ContinuousDiscreteUKF(md, DT, alpha=0.7, kappa=1.0, scheme="euler",
                                                                     substeps=3, **kw),
         "ckf": lambda md, **kw: ContinuousDiscreteCKF(md, DT, substeps=2, **kw),
         "ghkf": lambda md, **kw: ContinuousDiscreteGHKF(md, DT, order=3, **kw)}


@pytest.mark.parametrize("name", list(NODES))
def test_node_rules_as_numpy(pendulum, name):
    """The sigma points of every stage point of the integrator, E[G Q Gᵀ] over them (G(x) here)."""
    md, m0, P0, ys = pendulum
    flt = NODES[name](md, start="update" if name == "ckf" else None)
    ref = flt.run(ys, m0, P0, loglik=True, on_divergence="mark")
    new = flt.run(ys, m0, P0, loglik=True, on_divergence="mark", backend="numba")
    assert not ref.diverged.any()
    same(ref, new)
    assert compiled.build.loop_of(flt)[0] == "cd-nodes"


@pytest.fixture(scope="module")
def pendulum_fixed_g():
    """The pendulum with additive noise on ω (the second-order filters take a constant G)."""
    md = SDEModel([th, om], [om, -4.0 * sp.sin(th) - 0.3 * om], [sp.sin(th), om**2 / 4], Q=[[0.0, 0.0], [0.0, 0.5]],
                  R=0.02 * np.eye(2))
    m0, P0 = np.array([0.8, 0.0]), 0.1 * np.eye(2)
    return md, m0, P0, _data(md, m0, P0)


@pytest.mark.parametrize("form", [f for f in FORMS if f != "first-order"])
def test_second_order_forms_as_numpy(pendulum_fixed_g, form):
    """One loop for every second-order form (the form's switches are data); the truncated-Jazwinski
    form loses the covariance on two paths here, the Gaussian one on one: the same paths at the
    same steps."""
    md, m0, P0, ys = pendulum_fixed_g
    flt = ContinuousDiscreteSecondOrderFilter(md, DT, form=form, substeps=2)
    ref = flt.run(ys, m0, P0, loglik=True, on_divergence="mark")
    new = flt.run(ys, m0, P0, loglik=True, on_divergence="mark", backend="numba")
    same(ref, new)
    assert not ref.diverged.all() and (ref.diverged.any() or form != "truncated-jazwinski")
    assert compiled.build.loop_of(flt)[0] == "cd-taylor2"
    euler = ContinuousDiscreteSecondOrderFilter(md, DT, form=form, scheme="euler", substeps=3, start="update")
    same(euler.run(ys, m0, P0, on_divergence="mark"), euler.run(ys, m0, P0, on_divergence="mark", backend="numba"))


def test_smoother_and_simulation_timing(pendulum):
    """The RTS smoother over the compiled filter's output, and a Simulation's dt, start and t0."""
    md, m0, P0, _ = pendulum
    sim = simulate_continuous_discrete(md, 25, dt=DT, paths=3, rng=4, m0=m0, P0=P0, t0=2.0)
    flt = ContinuousDiscreteEKF(md, None, substeps=2)
    same(flt.smooth(sim, m0, P0, backend="numpy"), flt.smooth(sim, m0, P0, backend="numba"))
    same(flt.run(sim, m0, P0, backend="numpy"), flt.run(sim, m0, P0, backend="numba"))


def test_five_states_the_general_loop():
    """Past the specialized sizes: a ring of five states coupled through tanh, two measurements."""
    s = sp.symbols("s1:6")
    md = SDEModel(list(s), [-s[i] + 0.8 * sp.tanh(s[(i + 1) % 5]) for i in range(5)], [s[0] + s[2], s[3] * s[4]],
                  Q=0.3 * np.eye(5), R=0.05 * np.eye(2))
    m0, P0 = np.full(5, 0.2), np.eye(5)
    ys = _data(md, m0, P0, B=4, T=30)
    flt = ContinuousDiscreteEKF(md, DT, substeps=2)
    assert compiled.build.loop_of(flt)[3] is None  # the general loop
    same(flt.run(ys, m0, P0, loglik=True), flt.run(ys, m0, P0, loglik=True, backend="numba"))


@pytest.fixture(scope="module")
def cubic():
    return SDEModel([x], [-x + 0.5 * sp.sin(x)], [x**3], Q=0.5, R=0.1)


def test_divergence_marked_and_raised_as_numpy(cubic):
    """Data of 1e200 on some paths: the update's covariance is lost there, at the same steps."""
    ys = np.full((4, 12, 1), 0.3)
    ys[1, 5:] = 1e200
    ys[3, 2:] = -1e200
    flt = ContinuousDiscreteEKF(cubic, 0.1)
    ref = flt.run(ys, 0.5, 0.1, on_divergence="mark")
    new = flt.run(ys, 0.5, 0.1, on_divergence="mark", backend="numba")
    assert ref.diverged.tolist() == [False, True, False, True]
    same(ref, new)
    with pytest.raises(DivergenceError) as a:
        flt.run(ys, 0.5, 0.1)
    with pytest.raises(DivergenceError) as b:
        flt.run(ys, 0.5, 0.1, backend="numba")
    assert a.value.step == b.value.step and list(a.value.paths) == list(b.value.paths)


def test_what_it_does_not_take_is_refused_naming_backend(cubic):
    ys = np.full((2, 10, 1), 0.3)
    flt = ContinuousDiscreteEKF(cubic, 0.1)
    with pytest.raises(TypeError, match="backend: 'numba'.*regular grid"):
        flt.at_times(0.1 * np.arange(1, 11) ** 1.5).run(ys, 0.5, 0.1, backend="numba")
    t = sp.Symbol("t")
    timed = SDEModel([x], [-x + sp.sin(t)], [x**3], Q=1.0, R=1.0, time=t)
    with pytest.raises(TypeError, match="backend: 'numba'.*time"):
        ContinuousDiscreteEKF(timed, 0.1).run(ys, 0.5, 0.1, backend="numba")
    moving = SDEModel([x], [-x], [x**3], G=[[1.0 + 0.1 * x]], Q=1.0, R=1.0)
    with pytest.raises(TypeError, match="backend: 'numba'.*G that depends on neither the state nor the time"):
        ContinuousDiscreteSecondOrderFilter(moving, 0.1).run(ys, 0.5, 0.1, backend="numba")

    class MyPrediction(ContinuousDiscreteEKF):
        def _predict(self, state, k, cross=False):
            return super()._predict(state, k, cross)
    with pytest.raises(TypeError, match="backend: 'numba'.*overrides _predict"):
        MyPrediction(cubic, 0.1).run(ys, 0.5, 0.1, backend="numba")
    assert MyPrediction(cubic, 0.1).backend_for(10**4, 10**4)[0] == "numpy"
    with pytest.raises(TypeError, match="backend: 'numba'.*iterated"):
        ContinuousDiscreteIEKF(cubic, 0.1).run(ys, 0.5, 0.1, backend="numba")


def test_auto_counts_the_substeps(cubic):
    """The cost rule reads the NumPy loop's cost per substep of the integrator: a run that does not
    repay the compile with one substep does with twenty."""
    from nlfilter.filters.compiled import choice

    def work(sub):
        return choice.numpy_seconds("cd-taylor1", 1, 1, 1000) * sub
    assert work(1) < choice.COMPILE_SECONDS["specialized"] <= work(400)
    fresh = SDEModel([x], [-x + 0.25 * sp.sin(x)], [x**3], Q=0.5, R=0.1)  # a loop in no process nor cache
    assert ContinuousDiscreteEKF(fresh, 0.1).backend_for(1, 1000)[0] == "numpy"
    one = ContinuousDiscreteEKF(fresh, 0.1, substeps=400).backend_for(1, 1000)
    assert one[0] == "numba-shared" and "repays" in one[1]  # (the model-free loop: compiled now, or ready)
