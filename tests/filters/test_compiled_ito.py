"""The continuous-time (Itô) filters on the compiled loop (issue 28, item 6): the continuous EKF
and second-order filters (``ContinuousGaussianFilter`` over a Taylor rule, ``innovation="ito"``)
give the NumPy loop's estimates to 1e-12 relative, divergence marks and missing increments
and the log-likelihood included; what the loop does not take is refused naming ``backend``.

One model, one compile (a specialized loop, n = 1 state and m = 2 measurements so that partly
missing increments are exercised; the Hessians are in it, so the EKF and every second-order form
share it).
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import compiled
from nlfilter.filters.ekf import ContinuousEKF
from nlfilter.filters.second_order import ContinuousSecondOrderFilter
from tests.filters.test_compiled import same

pytestmark = [pytest.mark.skipif(not compiled.available(), reason="numba does not import"),
              pytest.mark.filterwarnings("error:Cannot cache compiled function")]

x, c = sp.symbols("x c")
DT = 0.01


@pytest.fixture(scope="module")
def sensor():
    """A cubic sensor with a second, quadratic channel (correlated noise), a parameter; increments
    from a simple Euler simulation, partly missing, missing on one path, missing on every path."""
    md = SDEModel([x], [-x], [x**3, x + c * x**2], Q=2.0, R=[[1.0, 0.2], [0.2, 0.5]], params={c: 0.3})
    rng = np.random.default_rng(5)
    B, T = 8, 150
    xs, dys = rng.normal(0.0, 1.0, B), np.empty((B, T, 2))
    for k in range(T):
        dys[:, k, 0] = xs**3 * DT + np.sqrt(DT) * rng.normal(size=B)
        dys[:, k, 1] = (xs + 0.3 * xs**2) * DT + np.sqrt(0.5 * DT) * rng.normal(size=B)
        xs = xs - xs * DT + np.sqrt(2 * DT) * rng.normal(size=B)
    dys[1, 4, 0] = np.nan
    dys[2, 9] = np.nan
    dys[:, 15] = np.nan
    dys[3, 20:23, 1] = np.nan
    return md, dys


FILTERS = {"ekf": lambda md: ContinuousEKF(md, DT),
           "ekf-euler": lambda md: ContinuousEKF(md, DT, scheme="euler", substeps=3),
           **{f: (lambda md, f=f: ContinuousSecondOrderFilter(md, DT, form=f))
              for f in ("truncated", "truncated-jazwinski", "gaussian", "modified-gaussian", "first-order")},
           "gaussian-2": lambda md: ContinuousSecondOrderFilter(md, DT, form="gaussian", substeps=2)}


@pytest.mark.parametrize("name", list(FILTERS))
def test_same_estimates_as_numpy(sensor, name):
    md, dys = sensor
    flt = FILTERS[name](md)
    m0 = 0.2 + 0.1 * np.arange(8)[:, None]  # a prior per path
    loglik = name != "truncated-jazwinski"  # its innovation covariance is screened batch-wide: NumPy only
    ref = flt.run(dys, m0, [[1.0]], on_divergence="mark", loglik=loglik)
    new = flt.run(dys, m0, [[1.0]], on_divergence="mark", backend="numba", loglik=loglik)
    same(ref, new)
    assert not loglik or np.isfinite(new.loglik[~new.diverged]).all()


def test_divergence_marked_and_raised_as_numpy(sensor):
    """The truncated-Jazwinski form's −½ P (P h_xx) forcing drives the covariance indefinite on some
    paths here: the same paths, the same steps, NaN from there on; raised at the same step."""
    md, dys = sensor
    flt = ContinuousSecondOrderFilter(md, DT, form="truncated-jazwinski")
    m0 = 0.2 + 0.1 * np.arange(8)[:, None]
    ref = flt.run(dys, m0, [[1.0]], on_divergence="mark")
    new = flt.run(dys, m0, [[1.0]], on_divergence="mark", backend="numba")
    assert ref.diverged.any() and not ref.diverged.all()
    same(ref, new)
    with pytest.raises(DivergenceError) as a:
        flt.run(dys, m0, [[1.0]])
    with pytest.raises(DivergenceError) as b:
        flt.run(dys, m0, [[1.0]], backend="numba")
    assert a.value.step == b.value.step and list(a.value.paths) == list(b.value.paths)


def test_what_it_does_not_take_is_refused_naming_backend(sensor):
    md, dys = sensor
    flt = ContinuousSecondOrderFilter(md, DT, form="truncated-jazwinski")
    with pytest.raises(TypeError, match="backend: 'numba'.*loglik"):
        flt.run(dys, [0.1], [[1.0]], loglik=True, backend="numba")
    auto = flt.run(dys, [0.1], [[1.0]], loglik=True, on_divergence="mark")  # auto: this likelihood runs on NumPy
    same(auto, flt.run(dys, [0.1], [[1.0]], loglik=True, on_divergence="mark", backend="numpy"))
    upd = ContinuousSecondOrderFilter(md, DT, innovation="update")
    with pytest.raises(TypeError, match="backend: 'numba'.*innovation='update'"):
        upd.run(dys, [0.1], [[1.0]], backend="numba")
    assert upd.backend_for(10**4, 10**4)[0] == "numpy"
    t = sp.Symbol("t")
    timed = SDEModel([x], [-x + sp.sin(t)], [x**3], Q=1.0, R=1.0, time=t)
    with pytest.raises(TypeError, match="backend: 'numba'.*time"):
        ContinuousEKF(timed, DT).run(dys[..., :1], [0.1], [[1.0]], backend="numba")
    moving = SDEModel([x], [-x], [x**3], G=[[1.0 + 0.1 * x]], Q=1.0, R=1.0)
    with pytest.raises(TypeError, match="backend: 'numba'.*G that does not depend on the state"):
        ContinuousSecondOrderFilter(moving, DT).run(dys[..., :1], [0.1], [[1.0]], backend="numba")


def test_auto_takes_the_loaded_loop(sensor):
    """The rule of the discrete filters: once the loop is in the process, the default runs it (the
    same numbers as ``backend="numba"``); its cost model has the kind's row."""
    md, dys = sensor
    flt = ContinuousSecondOrderFilter(md, DT, form="truncated")
    forced = flt.run(dys, [0.1], [[1.0]], backend="numba")
    assert flt.backend_for(8, 150) == ("numba", "the compiled loop is loaded in this process")
    np.testing.assert_array_equal(flt.run(dys, [0.1], [[1.0]]).means, forced.means)
    assert compiled.choose(flt, 8, 150).backend == "numba"
    assert compiled.build.loop_of(flt)[0] == "ito"
