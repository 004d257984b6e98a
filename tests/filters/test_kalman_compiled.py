"""The Kalman filter on the compiled loop (``KalmanFilter.run(..., backend="numba")``, issue 28
item 5): the same filter as the NumPy loop, the model's matrices read as data.

Tolerance: 1e-12 relative to the size of each output (``|a − b| ≤ 1e-12 · max(1, |a|)``), as
tests/filters/test_compiled.py: the two loops do the same arithmetic in another order (``F (P Fᵀ)``
for ``(F P) Fᵀ``, an LU solve for ``solve``, ``(1 − K H) P (1 − K H)`` for ``(1 − K H)² P``), so
they differ by rounding (measured ≤ 7e-15 here); a change of formula moves them by far more.
The loop is compiled once per process for every linear model (~20 s of CPU on the first test,
shared by the kernels of the other compiled filters); the models are small and the runs short.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, fit
from nlfilter.filters import compiled
from nlfilter.filters.compiled.support import steps_refusal
from nlfilter.filters.kalman import KalmanFilter
from nlfilter.simulate import simulate
from tests.filters.test_compiled import close, same

# every loop these tests compile must be one numba can keep on disk (a kernel that takes a model
# function as a pointer cannot be: "dynamic globals"), so that warning fails the test
pytestmark = [pytest.mark.skipif(not compiled.available(), reason="numba does not import"),
              pytest.mark.filterwarnings("error:Cannot cache compiled function")]

x, k = sp.symbols("x k")
q, r = sp.Symbol("q", positive=True), sp.Symbol("r", positive=True)


def local_level(**params):
    """``x' = x + w``, ``y = x + v`` with the variances as parameters (the MLE of issue 28)."""
    return DiscreteModel([x], [x], [x], Q=[[q]], R=[[r]], params={q: 0.5, r: 1.0, **params})


def tracking():
    """Constant velocity in the plane (4 states), positions measured (2), a drift term b."""
    px, py, vx, vy = sp.symbols("px py vx vy")
    dt = 0.5
    f = [px + dt * vx, py + dt * vy, 0.98 * vx + 0.01, 0.98 * vy]
    G = [[0.5 * dt**2, 0.0], [0.0, 0.5 * dt**2], [dt, 0.0], [0.0, dt]]
    return DiscreteModel([px, py, vx, vy], f, [px, py + 0.2], G, Q=[[0.3, 0.05], [0.05, 0.2]],
                         R=[[0.5, 0.1], [0.1, 0.4]])


@pytest.mark.parametrize("start", ["update", "predict"])
def test_scalar_local_level_as_numpy(start):
    md = local_level()
    ys = simulate(md, 50, paths=3, rng=4, m0=[0.0], P0=[[1.0]]).ys.copy()
    ys[1, 5] = np.nan  # missing on one path
    ys[:, 9] = np.nan  # missing on every path
    flt = KalmanFilter(md, start=start)
    m0 = np.array([[0.0], [0.3], [-0.2]])  # a prior per path
    ref = flt.run(ys, m0, [[10.0]], loglik=True)
    new = flt.run(ys, m0, [[10.0]], loglik=True, backend="numba")
    same(ref, new)
    assert np.isfinite(new.loglik).all()


def test_tracking_four_states_as_numpy():
    md = tracking()
    m0, P0 = np.array([0.0, 1.0, 0.5, -0.3]), np.diag([1.0, 1.0, 0.5, 0.5])
    ys = simulate(md, 40, paths=4, rng=7, m0=m0, P0=P0).ys.copy()
    ys[0, 3, 1] = np.nan  # partly missing: the observed component alone
    ys[2, 10:13, 0] = np.nan
    ys[:, 20] = np.nan
    for start in ("update", "predict"):
        flt = KalmanFilter(md, start=start)
        same(flt.run(ys, m0, P0, loglik=True), flt.run(ys, m0, P0, loglik=True, backend="numba"))
    flt = KalmanFilter(md)  # a batch shape and chunks reach the loop as the NumPy loop's
    same(flt.run(ys.reshape(2, 2, 40, 2), m0, P0, chunk=3), flt.run(ys.reshape(2, 2, 40, 2), m0, P0, chunk=3,
                                                                    backend="numba"))
    same(flt.smooth(ys, m0, P0), flt.smooth(ys, m0, P0, backend="numba"))


def test_time_varying_and_from_matrices_as_numpy():
    """Matrices per time: a parameter array over time and an explicit time dependence; a model
    from matrices (``DiscreteModel.linear``, no SymPy) runs compiled too."""
    a = sp.Symbol("a")
    md = DiscreteModel([x], [a * x + 0.1 * sp.sin(k)], [(1 + 0.01 * k) * x], Q=0.2, R=0.5, params={a: 0.9}, time=k)
    ys = simulate(md, 30, paths=2, rng=1, m0=[0.0], P0=[[1.0]]).ys
    varying = md.with_params(a=np.linspace(0.5, 1.0, 31))
    for start in ("update", "predict"):
        for model in (md, varying):
            flt = KalmanFilter(model, start=start)
            same(flt.run(ys, [0.0], [[1.0]], loglik=True), flt.run(ys, [0.0], [[1.0]], loglik=True, backend="numba"))
    lin = DiscreteModel.linear([[0.9, 0.1], [0.0, 0.8]], [[1.0, 0.5]], 0.1 * np.eye(2), [[0.3]])
    ys2 = simulate(lin, 25, paths=2, rng=2, m0=[0.0, 0.0], P0=np.eye(2)).ys
    flt = KalmanFilter(lin)
    same(flt.run(ys2, [0.0, 0.0], np.eye(2), loglik=True), flt.run(ys2, [0.0, 0.0], np.eye(2), loglik=True,
                                                                     backend="numba"))


def test_divergence_marked_and_raised_as_numpy():
    """A measurement far beyond the predictive law: its log-likelihood term is −inf, the path
    diverges there (marked with ``loglik_failed``, or raised) on both loops alike; an exactly
    observed state (R = 0 on an unobserved direction) keeps finite covariances."""
    md = local_level()
    ys = simulate(md, 20, paths=3, rng=2, m0=[0.0], P0=[[1.0]]).ys.copy()
    ys[1, 7] = 1e200
    flt = KalmanFilter(md)
    ref = flt.run(ys, [0.0], [[1.0]], loglik=True, on_divergence="mark")
    new = flt.run(ys, [0.0], [[1.0]], loglik=True, on_divergence="mark", backend="numba")
    assert ref.diverged.tolist() == [False, True, False] and ref.diverged_step[1] == 7
    same(ref, new)
    with pytest.raises(Exception) as e1:
        flt.run(ys, [0.0], [[1.0]], loglik=True)
    with pytest.raises(Exception) as e2:
        flt.run(ys, [0.0], [[1.0]], loglik=True, backend="numba")
    assert type(e1.value) is type(e2.value) and str(e1.value) == str(e2.value)


def test_what_it_does_not_take_is_named():
    """Correlated noise and parameters per path stay on the NumPy loop (a TypeError naming backend);
    the class declares compiled = True and a subclass that changes a step is refused."""
    md = local_level()
    ys = np.zeros((2, 5, 1))
    cross = DiscreteModel([x], [x], [x], Q=[[1.0]], R=[[1.0]], cross_noise=[[0.3]])
    with pytest.raises(TypeError, match="backend: 'numba'.*cross_noise"):
        KalmanFilter(cross).run(ys, [0.0], [[1.0]], backend="numba")
    per_path = md.with_params(q=np.full((2, 5), 0.5))
    with pytest.raises(TypeError, match="backend: 'numba'.*per path"):
        KalmanFilter(per_path).run(ys, [0.0], [[1.0]], backend="numba")
    assert steps_refusal(KalmanFilter(md)) is None

    class Damped(KalmanFilter):
        def predict(self, state, k):
            return super().predict(state, k)

    assert "Damped overrides predict" in steps_refusal(Damped(md))


def test_fit_on_the_compiled_loop_finds_the_numpy_optimum():
    """The local-level MLE of issue 28 on both loops: the same optimum and standard errors. The
    likelihoods agree to ~1e-15 relative, which the optimizer's finite-difference gradients (steps
    ~1e-8) amplify: the estimates differ by 3e-7 here (bound 1e-5), the standard errors by 1.2e-6
    relative (bound 1e-4), the maximized log-likelihoods by 3e-13 (bound 1e-9 relative)."""
    md = local_level()
    ys = simulate(md, 100, paths=1, rng=3, m0=[0.0], P0=[[1.0]]).ys
    args = dict(filter="kf", m0=[0.0], P0=[[10.0]])
    ref = fit(md, ys, {"q": 1.0, "r": 1.0}, **args)
    new = fit(md, ys, {"q": 1.0, "r": 1.0}, backend="numba", **args)
    assert ref.converged and new.converged
    for name in ("q", "r"):
        assert abs(new.params[name] - ref.params[name]) <= 1e-5 * max(1.0, abs(ref.params[name]))
        assert abs(new.se[name] - ref.se[name]) <= 1e-4 * ref.se[name]
    assert abs(new.loglik - ref.loglik) <= 1e-9 * abs(ref.loglik)


def test_with_params_copy_builds_its_noise_laws_when_read():
    """fit's per-evaluation copy (:meth:`with_params`) factors no noise law it does not use: the
    Gaussian laws of Q and R are built when first read, equal to those built at once, and the
    marker survives pickling (a Dask worker reads the law in another process)."""
    cloudpickle = pytest.importorskip("cloudpickle")  # as Dask pickles (the generated functions)
    from nlfilter.model_noise import LazyGaussian
    from nlfilter.noise import Gaussian

    md = local_level().with_params(q=0.3, r=2.0)
    assert md.__dict__["_process_noise"] is LazyGaussian and md.__dict__["_measurement_noise"] is LazyGaussian
    back = cloudpickle.loads(cloudpickle.dumps(md))
    for model in (md, back):
        assert isinstance(model.process_noise, Gaussian) and model.process_noise.cov.tolist() == [[0.3]]
        assert isinstance(model.measurement_noise, Gaussian) and model.measurement_noise.cov.tolist() == [[2.0]]
    with pytest.raises(ValueError, match="positive semi-definite"):
        local_level().with_params(q=-1.0)  # still checked at once: fit's "refused" values
