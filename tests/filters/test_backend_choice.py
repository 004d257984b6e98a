"""``backend="auto"``, the default of ``run``/``smooth``/``fit``
(:mod:`nlfilter.filters.compiled.choice`): the NumPy loop for short runs and for what the compiled
loop does not take, the compiled loop where it is loaded, cached on disk or repaid by the run.

The rule is tested by what it chooses (:meth:`Filter.backend_for`) and by what the default call
then gives (bit for bit the chosen loop's numbers), never by a clock.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.filters import compiled
from nlfilter.filters.compiled import cache, choice
from nlfilter.filters.ekf import EKF, IteratedEKF
from nlfilter.filters.second_order import SecondOrderFilter
from nlfilter.filters.ukf import UKF

needs_numba = pytest.mark.skipif(not compiled.available(), reason="numba does not import")


def _scalar(a=0.9):
    x = sp.Symbol("x")
    return DiscreteModel([x], f=[a * x], h=[x**3], Q=0.1, R=0.2)


def _five_state():
    """A 5-state tracking-like model (no paper has it): two positions and velocities and a turn rate."""
    px, py, vx, vy, w = sp.symbols("px py vx vy w")
    dt = 0.1
    f = [px + dt * vx, py + dt * vy, vx * sp.cos(w * dt) - vy * sp.sin(w * dt), vx * sp.sin(w * dt) + vy * sp.cos(w * dt), w]
    return DiscreteModel([px, py, vx, vy, w], f=f, h=[sp.sqrt(px**2 + py**2 + 1), sp.atan2(py, px + 3)],
                         Q=np.diag([1e-4, 1e-4, 1e-2, 1e-2, 1e-3]), R=np.diag([0.01, 0.001]))


def test_the_rule_by_size():
    """Short runs stay on the NumPy loop (numba's import and load would cost more than the run),
    runs that repay the compile go compiled, a filter without a compiled loop stays on NumPy
    whatever the size — the 5-state model (general loop: n > SPECIALIZE_UP_TO) and the scalar one."""
    for md, make in ((_five_state(), EKF), (_five_state(), UKF), (_scalar(), EKF)):
        flt = make(md)
        backend, why = flt.backend_for(10, 50)
        assert backend == "numpy" and "short run" in why, why
        if compiled.available():
            backend, why = flt.backend_for(10_000, 10_000)
            # the model-free loop (the 5-state EKF's batch-inner one too), the scalar EKF's own loop
            assert backend == ("numba" if md.n == 1 else "numba-shared") and "repays" in why, why
            # a fit's evaluations count: 30 runs of 1000 x 1000 repay what one does not
            n = md.n
            one = choice.numpy_seconds(compiled.build.loop_of(flt)[0], n, 1000, 1000)
            assert flt.backend_for(1000, 1000, repeats=200)[0].startswith("numba") or 200 * one < 2.0
    backend, why = IteratedEKF(_scalar()).backend_for(10**6, 10**6)
    assert backend == "numpy" and "IteratedEKF" in why


def test_the_cost_model_is_monotone():
    """More paths, steps, repeats or states never make the NumPy loop cheaper (the rule's premise)."""
    for kind in choice.STEP_US:
        base = choice.numpy_seconds(kind, 2, 100, 100)
        assert choice.numpy_seconds(kind, 2, 200, 100) > base
        assert choice.numpy_seconds(kind, 2, 100, 200) > base
        assert choice.numpy_seconds(kind, 4, 100, 100) > base
        assert choice.numpy_seconds(kind, 2, 100, 100, repeats=3) == pytest.approx(3 * base)


def test_a_short_default_run_does_not_import_numba():
    """The default call on a small run decides without numba (its import costs a second)."""
    script = textwrap.dedent("""
        import sys, numpy as np, sympy as sp
        from nlfilter import DiscreteModel
        from nlfilter.filters.ekf import EKF
        x = sp.Symbol("x")
        md = DiscreteModel([x], f=[0.9 * x], h=[x**3], Q=0.1, R=0.2)
        est = EKF(md).run(np.zeros((3, 20, 1)), 0.1, 1.0, loglik=True)
        print("numba" in sys.modules, np.isfinite(est.loglik).all())
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split() == ["False", "True"], out.stdout + out.stderr


@needs_numba
def test_loaded_and_cached_loops_are_used(tmp_path, monkeypatch):
    """After an explicit compiled run the default call runs compiled in this process (the same bits
    as ``backend="numba"``; the scalar EKF's batch loop is also NumPy's bits, so a two-state UKF
    would not tell — the scalar model is used for its short compile); a new process (here: a new
    model object and no module remembered) finds the sealed disk entry for a run between the load
    and the compile cost, and runs the NumPy loop without it."""
    from nlfilter.filters.compiled import template
    monkeypatch.setenv("NLFILTER_CACHE", str(tmp_path / "compiled"))
    monkeypatch.setattr(cache, "_MODULES", {})
    monkeypatch.setattr(template, "_LOOPS", {})  # (no model-free loop in the process either)
    ys = np.random.default_rng(0).normal(size=(2, 30, 1))
    md = _scalar()
    flt = EKF(md)
    mid = (1000, 5000)  # NumPy loop ~1.5 s: above LOAD_SECONDS, below the scalar loop's compile
    assert choice.LOAD_SECONDS < choice.numpy_seconds("taylor1", 1, *mid) < choice.COMPILE_SECONDS["scalar"]
    assert flt.backend_for(*mid) == ("numpy", "the compile (~2 s) costs more than the NumPy loop (~1.5 s so far)")
    forced = flt.run(ys, 0.1, 1.0, loglik=True, backend="numba")
    assert flt.backend_for(2, 30)[0] == "numba"
    default = flt.run(ys, 0.1, 1.0, loglik=True)
    np.testing.assert_array_equal(default.means, forced.means)
    np.testing.assert_array_equal(default.extras["loglik"], forced.extras["loglik"])
    cache._MODULES.clear()
    other = EKF(_scalar())  # the same expressions: the same source, the same entry
    assert other.backend_for(2, 30)[0] == "numpy"  # short: not worth numba's load
    assert other.backend_for(*mid) == ("numba", "the compiled loop is in the disk cache")
    monkeypatch.setenv("NLFILTER_CACHE", str(tmp_path / "empty"))
    assert other.backend_for(*mid)[0] == "numpy"


def test_the_loop_text_is_written_once_per_loop(monkeypatch):
    """The automatic choice asks for the loop's text (to find it on disk) on every run past the
    load threshold; writing a specialized loop's text (:func:`~nlfilter.filters.compiled.flatten.flatten_apart`)
    takes 0.1-0.6 s, more than the small runs it decides about (it made the contract suite 3.5x
    slower once numba was imported). It is written once per loop — also for a new model object
    with the same expressions (the same text) — and again for another loop."""
    from nlfilter.filters.compiled import build
    calls = []
    real = build.flatten_apart
    monkeypatch.setattr(build, "flatten_apart", lambda *a: calls.append(1) or real(*a))
    build._text.cache_clear()
    x1, x2 = sp.symbols("x1 x2")
    make = lambda: DiscreteModel([x1, x2], [x1 + 0.1 * x2, 0.9 * x2 - 0.2 * sp.sin(x1)], [x1], Q=0.01 * np.eye(2), R=0.1)  # noqa: E731
    texts = []
    for md in (make(), make()):
        kind, fns, scalar, dims, _ = build.loop_of(UKF(md))
        assert dims is not None  # the specialized (flattened) loop
        texts += [build.text_of(kind, fns, scalar, dims) for _ in range(3)]
    assert len(calls) == 1 and all(t is texts[0] for t in texts)
    kind, fns, scalar, dims, _ = build.loop_of(EKF(make()))
    assert build.text_of(kind, fns, scalar, dims) != texts[0] and len(calls) == 2


def test_an_empty_cache_is_read_without_the_loops_text(tmp_path, monkeypatch):
    """Where the disk cache holds no sealed entry of a loop's tag (a fresh installation), the
    automatic choice knows neither the model's own loop nor the model-free one is there without
    writing their text (:func:`~nlfilter.filters.compiled.cache.holds_tag`; writing a specialized
    loop's text took 0.1-0.6 s of a run's first call); an entry of another tag does not count, and
    where one of the tag is there, the text is written to look for the loop's own (here: it is not)."""
    from nlfilter.filters.compiled import build, template
    monkeypatch.setenv("NLFILTER_CACHE", str(tmp_path / "compiled"))
    monkeypatch.setattr(cache, "_MODULES", {})
    monkeypatch.setattr(template, "_LOOPS", {})
    asked = []
    monkeypatch.setattr(build, "flatten_apart", lambda *a: asked.append(a) or (_ for _ in ()).throw(AssertionError))
    build._text.cache_clear()
    template.text.cache_clear()
    flt = SecondOrderFilter(_four_state())  # the specialized Taylor-2 loop: the longest text
    kind, fns, scalar, dims, _ = build.loop_of(flt, 1000)
    assert dims is not None and choice.numpy_seconds(kind, 4, 1000, 200) > choice.LOAD_SECONDS
    for tag in (build.tag_of(kind, scalar, dims), build.tag_of(kind, scalar, dims, template=True)):
        assert not cache.holds_tag(tag)
    got = flt.backend_for(1000, 200)
    assert got[0] == "numpy" and "compile" in got[1] and not asked
    other = tmp_path / "compiled" / f"{build.tag_of(kind, True, None)}-{'0' * 32}"  # another tag's sealed entry
    other.mkdir(parents=True)
    (other / "sealed.json").write_text("{}")
    assert not cache.holds_tag(build.tag_of(kind, scalar, dims)) and flt.backend_for(1000, 200) == got and not asked
    mine = tmp_path / "compiled" / f"{build.tag_of(kind, scalar, dims)}-{'0' * 32}"  # one of the tag (not this loop)
    mine.mkdir()
    (mine / "sealed.json").write_text("{}")
    assert cache.holds_tag(build.tag_of(kind, scalar, dims))
    with pytest.raises(AssertionError):  # now the text is written to find the loop's entry
        flt.backend_for(1000, 200)
    assert asked
    build._text.cache_clear()


@needs_numba
def test_repeated_runs_move_to_the_compiled_loop(tmp_path, monkeypatch):
    """Tiered: runs of the same loop that each stay on the NumPy loop add up (``record``: runs, not
    questions), and the first run whose tally reaches the compile time goes compiled; a question
    (``backend_for``) records nothing. Another model's tally is its own."""
    from nlfilter.filters.compiled import template
    monkeypatch.setenv("NLFILTER_CACHE", str(tmp_path / "empty"))
    monkeypatch.setattr(template, "_LOOPS", {})  # (no model-free loop in the process either)
    monkeypatch.setattr(cache, "_MODULES", {})
    flt = EKF(_scalar(0.7))
    work = choice.numpy_seconds("taylor1", 1, 1000, 1000)
    need = int(np.ceil(choice.COMPILE_SECONDS["scalar"] / work))
    assert need >= 3  # several runs, so the test sees the tally
    for _ in range(5):
        assert flt.backend_for(1000, 1000)[0] == "numpy"  # questions only
    picks = [choice.choose(flt, 1000, 1000, record=True).backend for _ in range(need)]
    assert picks == ["numpy"] * (need - 1) + ["numba"]  # (the scalar loop: always the model's own)
    assert EKF(_scalar(0.6)).backend_for(1000, 1000)[0] == "numpy"


def test_auto_is_checked_and_initial_goes_to_numpy():
    """``backend`` names the choices, ``"auto"`` among them; a run with ``initial`` (which the
    Gaussian filters refuse) reaches the NumPy loop's refusal whatever the size."""
    flt = EKF(_scalar())
    with pytest.raises(ValueError, match="backend.*auto"):
        flt.run(np.zeros((1, 5, 1)), 0.1, 1.0, backend="fast")
    with pytest.raises(ValueError, match="initial"):
        flt.run(np.zeros((1, 5, 1)), 0.1, 1.0, initial=object())


@needs_numba
def test_a_model_numba_cannot_compile_runs_on_numpy_by_default(monkeypatch):
    """``backend="numba"`` names the failure (CompileError, a TypeError naming backend); the default
    call that chose the compiled loop runs the NumPy loop instead, with its numbers. numba's
    TypingError is injected (the model files' functions all compile: no real model fails)."""
    from numba.core.errors import TypingError

    from nlfilter.errors import CompileError
    from nlfilter.filters.compiled import run as compiled_run

    def fails(*args):
        raise TypingError("Untyped global name 'g': a function numba does not know")

    monkeypatch.setattr(compiled_run, "_run", fails)
    flt = EKF(_scalar(0.5))
    monkeypatch.setattr(type(flt), "backend_for", lambda self, B, T, **kw: ("numba", "forced by the test"))
    ys = np.random.default_rng(1).normal(size=(2, 10, 1))
    with pytest.raises(CompileError, match="backend: numba cannot compile EKF.*use backend='numpy'"):
        flt.run(ys, 0.1, 1.0, backend="numba")
    default = flt.run(ys, 0.1, 1.0, loglik=True)
    ref = flt.run(ys, 0.1, 1.0, loglik=True, backend="numpy")
    np.testing.assert_array_equal(default.means, ref.means)
    np.testing.assert_array_equal(default.extras["loglik"], ref.extras["loglik"])


def _four_state():
    """chain(4) of benchmarks/_models.py: four sin-coupled states, two measurements."""
    x = sp.symbols("x1:5")
    f = [0.9 * x[i] + 0.1 * sp.sin(x[(i + 1) % 4]) for i in range(4)]
    h = [x[j] + 0.1 * x[j + 2] ** 2 for j in range(2)]
    return DiscreteModel(list(x), f, h, Q=0.01 * np.eye(4), R=0.1 * np.eye(2))


def test_the_loop_by_the_runs_paths(tmp_path, monkeypatch):
    """The EKF on 4-16 states has two loops (:func:`~nlfilter.filters.compiled.build.loop_of`): the
    one-path loop below ``paths_from`` paths (specialized at n = 4, the general loop above), the
    batch-inner loop from there; the automatic choice weighs the compile of the loop that will run
    (no loop is compiled here: the choice only reads the rule and the store)."""
    from nlfilter.filters.compiled import batch_loop, build, template
    monkeypatch.setenv("NLFILTER_CACHE", str(tmp_path / "empty"))
    monkeypatch.setattr(template, "_LOOPS", {})  # (no model-free loop in the process either)
    monkeypatch.setattr(cache, "_MODULES", {})
    assert batch_loop.paths_from(4, True) == batch_loop.PATHS_FROM["specialized"] == 8
    assert batch_loop.paths_from(5, False) == batch_loop.paths_from(8, False) == batch_loop.PATHS_FROM["general"] == 4
    assert batch_loop.paths_from(9, False) == batch_loop.PATHS_FROM["general-large"] == 16
    flt = EKF(_four_state())
    spec = (4, 2, 4, None)
    assert [build.loop_of(flt, B)[3] for B in (0, 1, 7)] == [spec] * 3
    assert [build.loop_of(flt, B)[3] for B in (8, 1000, None)] == [batch_loop.dims_of(4, 2, 4)] * 3
    five = EKF(_five_state())
    assert [build.loop_of(five, B)[3] for B in (1, 3)] == [None, None]
    assert batch_loop.is_batch(build.loop_of(five, 4)[3])
    assert build.loop_of(UKF(_four_state()), 1000)[3] == spec  # the batch-inner loop is the EKF's
    # the model-free loops alike (template.loop_of: the loaded loops asked of its store)
    assert [template.loop_of(flt, B)[3] for B in (1, 7, 8, 1000)] == [spec] * 2 + [batch_loop.dims_of(4, 2, 4)] * 2
    assert template.loop_of(flt, 8)[1].keys() >= set(batch_loop.SLOTS)
    if compiled.available():  # each loop's compile: a run between the two takes the one-path loop only
        T = 200_000  # NumPy ~10.4 s on one path (≥ 10 s), ~13 s on 8 (< 15 s)
        assert choice.COMPILE_SECONDS["specialized"] <= choice.numpy_seconds("taylor1", 4, 1, T)
        assert choice.numpy_seconds("taylor1", 4, 8, T) < choice.COMPILE_SECONDS["batch"]
        assert flt.backend_for(1, T) == ("numba-shared", "the NumPy loop's time (~10 s, this run's and earlier runs') "
                                         "repays the compile of the model-free loop (~10 s), kept for every model of "
                                         "this rule and shape")
        assert flt.backend_for(8, T) == ("numpy", "the compile (~15 s) costs more than the NumPy loop (~13 s so far)")


def test_a_loaded_loop_serves_the_other_size(monkeypatch):
    """Where only one of the two loops is in the process, a run of the other size takes it (a
    process compiles one loop per model); where both are, each size its own. The store is faked:
    nothing is compiled."""
    from nlfilter.filters.compiled import batch_loop, build, template
    flt = EKF(_four_state())
    kind, fns, _, spec, key = build.loop_of(flt, 1)
    wide = batch_loop.dims_of(4, 2, 4)
    store = build.KERNELS.setdefault(key, {})
    monkeypatch.setitem(store, build.loop_name(kind, fns, False, spec), ("loop", None))
    assert build.loop_of(flt, 1000)[3] == spec
    assert flt.backend_for(1000, 200) == ("numba", "the compiled loop is loaded in this process")
    monkeypatch.delitem(store, build.loop_name(kind, fns, False, spec))
    monkeypatch.setitem(store, build.loop_name(kind, fns, False, wide), ("loop", None))
    assert build.loop_of(flt, 1)[3] == wide
    monkeypatch.setitem(store, build.loop_name(kind, fns, False, spec), ("loop", None))
    assert (build.loop_of(flt, 1)[3], build.loop_of(flt, 8)[3]) == (spec, wide)
    # the model-free loops: the loaded one of template's store
    monkeypatch.setattr(template, "_LOOPS", {(kind, False, spec): ("loop", None)})
    assert template.loop_of(flt, 1000)[3] == spec
    monkeypatch.setattr(template, "_LOOPS", {(kind, False, wide): ("loop", None)})
    assert template.loop_of(flt, 1)[3] == wide
