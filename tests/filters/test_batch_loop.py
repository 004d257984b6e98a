"""The EKF's batch-inner compiled loop (issue 28, item 4; :mod:`nlfilter.filters.compiled.batch_loop`):
the same filter as the NumPy loop, with every convention of the one-path loop.

One model, one compile (~20-40 s of CPU: the loop is specialized to the model's dimensions), and
every convention on it: 40 paths (a full block of 32 and a partial one), a prior per path, a
G that depends on the state, partly missing measurements (one component; every component of one
path; one step missing on every path), both starts, the log-likelihood outputs, and paths that
diverge at different steps (marked, and raised with the NumPy loop's message).

Tolerance: 1e-12 relative to the size of each output (``|a − b| ≤ 1e-12 · max(1, |a|)``), as
``test_compiled.py``: the loops sum in a different order and the batch loop solves with a Cholesky
factor where NumPy takes an LU solve; on this model the differences are rounding (≤ 1e-14 measured
over 30 steps), and any change of formula moves the outputs by 1e-4 or more.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import compiled
from nlfilter.filters.compiled import batch_loop, build
from nlfilter.filters.ekf import EKF
from nlfilter.simulate import simulate
from tests.filters.test_compiled import same

pytestmark = [pytest.mark.skipif(not compiled.available(), reason="numba does not import"),
              pytest.mark.filterwarnings("error:Cannot cache compiled function")]

x1, x2, x3, x4, a = sp.symbols("x1 x2 x3 x4 a")


def four():
    """Four states, two measurements, a parameter, a state-dependent G; ``x4 → a x4²`` is not measured:
    it settles where ``|x4| < 1/a`` and overflows (the path diverges) where it starts above."""
    f = [0.9 * x1 + 0.1 * sp.sin(x2), 0.8 * x2 + 0.1 * x3 * x1, 0.9 * x3 + 0.05 * sp.cos(x1), a * x4**2]
    h = [x1 + 0.1 * x2**2, x3 - 0.2 * x2]
    G = [[1.0, 0, 0, 0], [0.1 * x1, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 0.1]]
    return DiscreteModel([x1, x2, x3, x4], f, h, G, Q=0.01 * np.eye(4), R=[[0.1, 0.02], [0.02, 0.2]],
                         params={a: 0.5}, name="four states")


@pytest.fixture(scope="module")
def case():
    md = four()
    B = 40
    m0 = np.zeros((B, 4)) + 0.01 * np.arange(B)[:, None]
    m0[:, 3] = 0.5
    m0[[5, 33], 3] = [3.0, 6.0]  # these two diverge (overflow), at different steps
    ys = simulate(md.with_params(a=0.0), 30, paths=B, rng=4, m0=[0.1, 0.0, 0.1, 0.0], P0=0.1 * np.eye(4)).ys.copy()
    ys[1, 4, 0] = np.nan  # partly missing
    ys[2, 9] = np.nan  # missing on one path
    ys[:, 15] = np.nan  # missing on every path
    ys[35, 20:23, 1] = np.nan  # in the second block
    return md, ys, m0, 0.1 * np.eye(4)


@pytest.mark.parametrize("start", ["update", "predict"])
def test_batch_loop_as_numpy(case, start):
    md, ys, m0, P0 = case
    flt = EKF(md, start=start)
    assert batch_loop.is_batch(build.loop_of(flt)[3])  # this model takes the batch-inner loop
    ref = flt.run(ys, m0, P0, loglik=True, on_divergence="mark")
    new = flt.run(ys, m0, P0, loglik=True, on_divergence="mark", backend="numba")
    assert ref.diverged.sum() == 2 and len(set(ref.diverged_step[ref.diverged].tolist())) == 2
    same(ref, new)
    assert np.isfinite(new.loglik[~new.diverged]).all()
    with pytest.raises(DivergenceError) as e1:
        flt.run(ys, m0, P0)
    with pytest.raises(DivergenceError) as e2:
        flt.run(ys, m0, P0, backend="numba")
    assert str(e1.value) == str(e2.value)


def test_structural_zeros_skipped():
    """The products with F and H sum over the Jacobians' structural non-zeros only (tables in the
    generated text, so the disk cache keys on them), in their order, padded with zeros to the longest
    row; a Jacobian without a zero sums over every index, as without tables. (No compile: the text.)"""
    flt = EKF(four())
    kind, fns, scalar, dims, _ = build.loop_of(flt)
    tables = batch_loop.patterns(fns)
    # F: rows {0, 1}, {0, 1, 2}, {0, 2}, {3}; H: rows {0, 1}, {1, 2}; H's columns: {0}, {0, 1}, {1}, {}
    assert tables["FZ"] == ([[0, 1, 2], [0, 1, 2], [0, 2, 1], [3, 0, 1]], 3)
    assert tables["HZ"] == ([[0, 1], [1, 2]], 2)
    assert tables["HT"] == (None, 2)  # a column with both rows: every index
    text = build.text_of(kind, fns, scalar, dims)[0]
    assert "FZ = np.array([[0, 1, 2], [0, 1, 2], [0, 2, 1], [3, 0, 1]]" in text and "HT =" not in text
    assert "q = FZ[j, z]" in text and "a = HT[j, z]" not in text and "for a in range(kt):" in text
    assert "out[0, 2, b_] = 0.0" not in fns["fxb"].source  # the zeros are never written (alloc's zeros)
    x = sp.symbols("y1:5")  # every entry non-zero: no table at all
    dense = DiscreteModel(list(x), [sum(x) + xi**2 for xi in x], [sum(x) ** 2], Q=np.eye(4), R=1.0)
    k2, f2, s2, d2, _ = build.loop_of(EKF(dense))
    assert all(t is None for t, _ in batch_loop.patterns(f2).values())
    text = build.text_of(k2, f2, s2, d2)[0]
    assert not any(f"= {t}[" in text or f"{t} = np" in text for t in ("FZ", "HZ", "HT")) and "kf < n" not in text


def test_the_model_free_batch_loop(case):
    """``backend="numba-shared"`` on the batch-inner loop (:mod:`~nlfilter.filters.compiled.template`:
    the block functions, h, h_x and the tables of the Jacobians' zeros passed to one loop of the
    shape): the model's own batch-inner loop's bits — partly missing steps, a step missing on every
    path, paths diverging by overflow and one on data of 1e200 (marked). A second model of the shape,
    with other structural zeros, runs on the same loop object (its functions and tables only), as
    NumPy. (One compile: the model-free loop; the own loop is the test above's.)"""
    from nlfilter.filters.compiled import template

    md, ys, m0, P0 = case
    ys = ys.copy()
    ys[20, 12:] = 1e200
    flt = EKF(md)
    shared = flt.run(ys, m0, P0, loglik=True, on_divergence="mark", backend="numba-shared")
    own = flt.run(ys, m0, P0, loglik=True, on_divergence="mark", backend="numba")
    for name in ("means", "covs", "diverged", "diverged_step"):
        assert np.array_equal(getattr(own, name), getattr(shared, name), equal_nan=True), name
    for name in ("loglik", "innovation", "innovation_cov"):
        assert np.array_equal(own.extras[name], shared.extras[name], equal_nan=True), name
    assert shared.diverged.sum() == 3 and shared.diverged[20]
    kind, fns, scalar, dims, _ = template.loop_of(flt, len(ys))
    assert batch_loop.is_batch(dims) and ("taylor1", False, dims) in template._LOOPS
    loops = dict(template._LOOPS)
    other = DiscreteModel([x1, x2, x3, x4], [0.7 * x1 + 0.2 * x4, 0.9 * x2, 0.5 * x3 + 0.1 * sp.sin(x1), 0.3 * x4],
                          [x2 + x4**2, sp.atan(x3)], Q=0.02 * np.eye(4), R=[[0.1, 0.0], [0.0, 0.2]])
    flt2 = EKF(other)
    assert batch_loop.patterns(template.loop_of(flt2, len(ys))[1]) != batch_loop.patterns(fns)
    same(flt2.run(ys, m0, P0, loglik=True, on_divergence="mark"),
         flt2.run(ys, m0, P0, loglik=True, on_divergence="mark", backend="numba-shared"))
    assert template._LOOPS == loops  # the same loop object: no compile
    text = template.text(kind, scalar, dims)[0]  # the text: no model in it
    assert "sin(" not in text and "FZ = np.array" not in text and "def b_" not in text
