"""``backend="auto"``, the default of ``run``, ``smooth`` and ``fit``: the compiled loop where it is
ready or repays its compile, the NumPy loop otherwise.

The rule (:func:`choose`), in order — a tiered one, as a JIT's: the NumPy loop first, the compiled
loop once the process has shown it repeats the work. Two compiled loops can serve a model: its own
(``"numba"``: the model's functions inlined) and the model-free loop of its rule kind and shape
(``"numba-shared"``, :mod:`.template`: compiled once for every model of that shape, the model's
functions, compiled alone in about a second, passed to it; the same bits, 1.0-1.4× the time per
path-step of a one-path own loop, 1.03-1.12× that of the EKF's batch-inner loop, whose model-free form
takes the model's block functions and its Jacobians' zero tables as data):

1. A filter or model the compiled loop does not take (:func:`~.support.static_refusal`: the
   filter's declaration, its rule, the model's structure) runs on the NumPy loop.
   Every later step asks about the loop that would run these ``B`` paths
   (:func:`~.build.loop_of`: the EKF on 4-16 states has two, the one-path loop below
   :func:`~.batch_loop.paths_from` paths and the batch-inner one from there — or the one of them
   already in this process), with its own compile time.
2. The model's own loop already in this process (compiled or loaded by an earlier run) runs.
   The model-free loop in this process with the model's functions runs, until the time its runs
   took (:func:`shared_tally`) times the share the own loop would have saved (``1 − 1/gain``,
   :data:`FULL_GAIN`) reaches the own loop's compile: then the own loop is compiled.
3. ``W``: the NumPy loop's estimated time for this run (:func:`numpy_seconds`:
   ``repeats × T × (a + B·b·n^1.5)`` µs with the per-step and per-path-step costs of the rule kind,
   :data:`STEP_US`, :data:`PATH_STEP_US`; times the filter's ``substeps`` for the kinds of
   :data:`PER_SUBSTEP`) plus that of the earlier runs of the same loop in this
   process that took the NumPy loop. Below the cost of loading a cached loop (:data:`LOAD_SECONDS`:
   numba's import; :data:`LOADED_SECONDS` once numba is imported) the NumPy loop. Above it: the
   model's own loop where the disk cache holds it (:func:`~.build.on_disk`); the model-free loop
   where the disk holds that and ``W`` also repays compiling the model's functions
   (:data:`FIRST_COMPILE_SECONDS`, :data:`FUNCTION_SECONDS`); at or above the loop's compile time
   (:data:`COMPILE_SECONDS`) a compile, kept on disk: of the model-free loop (then every later
   model of the shape costs its functions only). The scalar batch loop (the EKF on one state) is
   always the model's own: its compile (0.8 s) is about the model-free loop's functions' (0.5 s),
   and its inlined functions run 1.4-1.6× faster than five calls by address per path-step.
4. numba not importable: the NumPy loop.

So a single short run never imports numba; a fit, whose evaluations count as ``repeats``, or a
process running the same model again and again, moves to the compiled loop as soon as the time
it would save exceeds the time to get it.

The costs are measured orders of magnitude (docs/guide/speed.rst and the benchmarks page: one core), not promises; the rule
needs them to within a factor of a few. The loops give the same estimates to rounding (1e-12
relative, the compiled loop's tests; the scalar EKF's batch loop bit for bit; the two compiled
loops of a model bit for bit), so the choice moves no result beyond that. ``backend="numpy"``,
``"numba"`` or ``"numba-shared"`` forces one.
"""

from __future__ import annotations

import sys
from typing import NamedTuple

from .support import CD_KINDS, static_refusal

__all__ = ["Choice", "choose", "numpy_seconds", "shared_tally", "COMPILE_SECONDS", "FIRST_COMPILE_SECONDS", "FUNCTION_SECONDS",
           "FULL_GAIN", "LOAD_SECONDS", "LOADED_SECONDS", "STEP_US",
           "PATH_STEP_US", "PER_SUBSTEP"]

#: the NumPy loop's cost per step, µs (one trajectory: its Python overhead), by rule kind
STEP_US = {"kalman": 40.0, "taylor1": 50.0, "nodes": 110.0, "taylor2": 160.0, "sqrt-taylor1": 120.0, "sqrt-nodes": 240.0,
           "ito": 110.0, "cd-taylor1": 50.0, "cd-taylor2": 110.0,
           "cd-nodes": 120.0}
#: and per path-step at ``n = 1``, µs, scaled by ``n^1.5`` (1000 paths: 0.12 µs for the EKF at
#: n = 1, 3.6 at n = 4, 22.7 at n = 16; the UKF and second-order filters 2-3× the EKF; the square-root
#: filters 2.2-2.4× their standard form per step, 1.5-1.9× per path-step, measured at n = 2)
#: The continuous Itô filters (``"ito"``: the continuous EKF and second-order filters, RK4, one
#: substep; the cubic sensor, n = 1, one core, loaded machine): 71-140 µs per step on one trajectory
#: (EKF 71, truncated 108, Gaussian second-order 140), 0.46-1.0 µs per path-step at 64 paths and
#: 0.11-0.15 at 1000; at n = 2, 1.1 (EKF) to 5.1 (Gaussian) µs per path-step at 1000 paths (the n^1.5
#: scale is low there: the NumPy loop's n = 1 products are broadcasts, its n = 2 ones matmuls)
#: The continuous-discrete EKF (``"cd-taylor1"``), per substep of the integrator (:data:`PER_SUBSTEP`;
#: RK4; one core, loaded machine, n = 1 and 2): 54 µs per step on one trajectory with one substep,
#: 169 with four (n = 1; 93 and 228 at n = 2); per path-step at 1000 paths 0.16 and 0.42 µs (n = 1),
#: 0.77 and 1.9 (n = 2). The compiled loop: 0.06-0.07 µs per path-step at n = 1, one substep.
#: The continuous-discrete second-order filters (``"cd-taylor2"``; seed 004's falling body, n = 3,
#: RK4): 230-270 µs per step on one trajectory with one substep, 1040-1130 with ten; per path-step
#: at 1000 paths 0.82-0.93 µs per substep with ten (1.6-2.7 with one: the update's share). The
#: continuous-discrete node filters (``"cd-nodes"``; the UKF on a 2-state pendulum, RK4): 136 µs per
#: step on one trajectory with one substep, 381 with four; 1.45-1.75 µs per path-substep at 1000 paths
PATH_STEP_US = {"kalman": 0.2, "taylor1": 0.25, "nodes": 0.45, "taylor2": 0.6, "sqrt-taylor1": 0.5, "sqrt-nodes": 0.7,
                "ito": 0.4, "cd-taylor1": 0.15, "cd-taylor2": 0.16,
                "cd-nodes": 0.5}
#: the kinds whose costs above are per substep of the filter's integrator (``substeps``): the
#: continuous-discrete ones
PER_SUBSTEP = CD_KINDS
#: a loop's first compile, CPU seconds: the scalar EKF's batch loop, the loops specialized to the
#: dimensions (n, m ≤ :data:`~.build.SPECIALIZE_UP_TO`; the loop, its predict and its update
#: flattened apart: 3.4-5.2 s measured by benchmarks/bench_compile.py on an idle core, run
#: "compile-split", against 4.7-9.1 s for one flat loop, which took 10-21 s on a loaded machine),
#: the general loop (EKF n = 16: 5.8 s idle), the EKF's batch-inner loop (:mod:`.batch_loop`,
#: 4-16 states: 10.0-10.3, 11.3-11.4, 13.4-13.8 s at n = 4, 8, 16 on a loaded machine, paired,
#: since its sums' lengths alone are compiled in and its rare lanes' update is one flat function;
#: 16-28 s before — see :func:`~.build.loop_of`); the continuous Itô loop (specialized, or general past n = 4): 6.1 s
#: at n = 1, ~8 s at n = 2 (general: ~10 s), loaded
COMPILE_SECONDS = {"scalar": 2.0, "specialized": 10.0, "general": 10.0, "batch": 15.0}
#: the model-free loops (:mod:`.template`): numba's first compile in a process (its compiler's
#: set-up), and then each of the model's functions compiled alone, CPU seconds (a 4-state chain:
#: five functions in 0.85 s, loaded machine)
FIRST_COMPILE_SECONDS = 0.35
FUNCTION_SECONDS = 0.1
#: the model's own loop's speed over the model-free loop's, per path-step: one path (1.0-1.4×,
#: the calls of the model's functions through their addresses) and the EKF's batch-inner loop
#: (its model-free form, :func:`.batch_loop.source`: chain(n) of benchmarks/_models.py, 1000 × 200,
#: one process, 11-15 paired runs on one core of a loaded machine, CPU time, three or four sessions, ratio
#: of the best runs: 1.05-1.12, 1.03-1.06, 1.04-1.05 at n = 4, 8, 16), by :func:`~.batch_loop.is_batch`
FULL_GAIN = {False: 1.25, True: 1.1}
#: a cached loop's first run in a new process, CPU seconds: numba's import (0.1), nlfilter's
#: compiled modules (0.07), the loop's text (0.04-0.09), numba's first use of its target (0.15),
#: reading the loop's code (0.02-0.05): 0.40-0.43 s at n = 4 (benchmarks/bench_dimensions.py
#: --cache warm, run "warm-cache-calls"; 1.0 s was assumed before). The NumPy loop's time must
#: reach it before numba is imported: a single call cheaper than that stays on NumPy (faster for
#: that call), and a process repeating it loads the loop at the call that would have repaid it
LOAD_SECONDS = 0.4
#: the same once numba is imported in the process (reading the loop's code)
LOADED_SECONDS = 0.1


class Choice(NamedTuple):
    """``backend`` (``"numpy"`` or ``"numba"``) and why, in words."""

    backend: str
    why: str


def numpy_seconds(kind: str, n: int, B: int, T: int, repeats: int = 1) -> float:
    """The NumPy loop's estimated time for ``repeats`` runs of ``B`` paths × ``T`` steps."""
    return repeats * T * (STEP_US[kind] + B * PATH_STEP_US[kind] * max(n, 1) ** 1.5) * 1e-6


def choose(flt, B: int, T: int, repeats: int = 1, record: bool = False) -> Choice:
    """The backend ``run(..., backend="auto")`` takes for ``flt`` on ``B`` paths × ``T`` steps
    (``repeats``: runs of the same size to come, as a fit's evaluations). See the module's rule.
    ``record``: the run happens (a NumPy run's time is added to its loop's tally); a question only
    (:meth:`~nlfilter.filters.base.Filter.backend_for`) records nothing."""
    reason = static_refusal(flt)
    if reason is not None:
        return Choice("numpy", f"no compiled loop: {reason}")
    from . import batch_loop, build

    kind, fns, scalar, dims, key = build.loop_of(flt, B)
    if build.loaded(kind, fns, key, scalar, dims):
        return Choice("numba", "the compiled loop is loaded in this process")
    store = build.KERNELS.setdefault(key, {})
    batch = batch_loop.is_batch(dims)
    compile_s = COMPILE_SECONDS["scalar" if scalar else "general" if dims is None else "batch" if batch else "specialized"]
    shared = None if kind == "kalman" or scalar else _shared(flt, B)
    if shared is not None and shared[1]():  # the model-free loop, ready to run
        saved = store.get(shared_tally(kind), 0.0) * (1.0 - 1.0 / FULL_GAIN[batch])
        if saved < compile_s:
            return Choice("numba-shared", "the model-free loop and the model's functions are loaded in this process")
        return Choice("numba", f"the time the model's own loop would have saved on the model-free loop's runs "
                               f"(~{saved:.2g} s) repays its compile (~{compile_s:g} s)")
    tally = ("numpy seconds", build.loop_name(kind, fns, scalar, dims))
    work = numpy_seconds(kind, flt.model.n, B, T, repeats) * (flt.substeps if kind in PER_SUBSTEP else 1)
    spent = store.get(tally, 0.0) + work  # with this run's: what this loop would have saved in the process
    load_s = LOADED_SECONDS if "numba" in sys.modules else LOAD_SECONDS
    if spent >= load_s:  # numba imported only where the compiled loop is taken (its import: ~0.1 s)
        got = _got(spent, compile_s, load_s, build.on_disk(kind, fns, scalar, dims), shared)
        if got is not None:
            from .support import available
            return got if available() else Choice("numpy", "numba does not import here")
    if record:
        store[tally] = spent
    if spent < load_s:
        return Choice("numpy", f"a short run (NumPy loop ~{work:.2g} s; ~{spent:.2g} s in this process)")
    return Choice("numpy", f"the compile (~{compile_s:g} s) costs more than the NumPy loop (~{spent:.2g} s so far)")


def _got(spent, compile_s, load_s, own, shared):
    """The compiled loop a run that has repaid the cost of loading numba takes (the NumPy loop's
    time ``spent``), or None: the model's own loop on disk; the model-free loop on disk once its
    model's functions are repaid; else, repaid by ``spent``, a compile: of the model-free loop (then
    every later model of its shape is a matter of its functions; its speed within
    :data:`FULL_GAIN` of the model's own loop's), of the model's own loop where no model-free loop
    serves (the Kalman filter's is model-free already; the scalar EKF keeps its own)."""
    if own:
        return Choice("numba", "the compiled loop is in the disk cache")
    where = shared[2]() if shared is not None else (None, None)
    functions_s = 0.0 if where[1] else FIRST_COMPILE_SECONDS + FUNCTION_SECONDS * shared[0] if shared else 0.0
    if where[0] is not None and spent >= load_s + functions_s:
        return Choice("numba-shared", f"the NumPy loop's time (~{spent:.2g} s) repays the model's functions "
                                      f"(~{load_s + functions_s:.2g} s) on the model-free loop, ready on disk")
    if spent < compile_s:
        return None
    if shared is not None:  # (its compile and the model's own loop's: alike, ±5 %; batch-inner: +3-10 %)
        return Choice("numba-shared", f"the NumPy loop's time (~{spent:.2g} s, this run's and earlier runs') repays the "
                                      f"compile of the model-free loop (~{compile_s:g} s), kept for every model of "
                                      "this rule and shape")
    return Choice("numba", f"the NumPy loop's time (~{spent:.2g} s, this run's and earlier runs') repays "
                           f"the compile (~{compile_s:g} s)")


def shared_tally(kind: str) -> tuple:
    """The key, in the model's kernel store, of the seconds its runs spent on the model-free loop of
    rule ``kind`` (:func:`~.run.run_shared` adds them)."""
    return ("shared seconds", kind)


def _shared(flt, B):
    """``(number of the model's functions, loaded(), ready())`` of the model-free loop that would
    run ``flt``: whether it is in this process with the model's functions (:func:`.template.loaded`),
    and where each is without compiling (:func:`.template.ready`: writes the loop's text, 0.1-0.6 s
    once per process, where the disk cache holds an entry of its tag at all; asked of runs past the
    cost of loading numba only)."""
    from . import template

    kind, slots, scalar, dims, key = template.of(flt, B)
    return (len(slots), lambda: template.loaded(kind, slots, key, scalar, dims),
            lambda: template.ready(kind, slots, key, scalar, dims))
