"""``backend="auto"``, the default of ``run``, ``smooth`` and ``fit``: the compiled loop where it is
ready or repays its compile, the NumPy loop otherwise.

The rule (:func:`choose`), in order:

1. A filter or model the compiled loop does not take (:func:`~.support.static_refusal`: the
   filter's declaration, its rule, the model's structure) runs on the NumPy loop.
2. A loop already in this process (compiled or loaded by an earlier run) runs compiled.
3. The NumPy loop's estimated time ``W`` (:func:`numpy_seconds`: ``repeats × T × (a + B·b·n^1.5)``
   µs with the per-step and per-path-step costs of the rule kind, :data:`STEP_US`,
   :data:`PATH_STEP_US`) decides the rest: below :data:`LOAD_SECONDS` (numba's import and a cached
   loop's first call in a new process) the NumPy loop; at or above the loop's compile time
   (:data:`COMPILE_SECONDS`) the compiled loop, compiled now and kept on disk; in between the
   compiled loop only where the disk cache holds it (:func:`~.cache.ready`).
4. numba not importable: the NumPy loop.

The costs are measured orders of magnitude (README, Benchmarks: one core), not promises; the rule
needs them to within a factor of a few. Both loops give the same estimates to rounding (1e-12
relative, the compiled loop's tests; the scalar EKF's batch loop bit for bit), so the choice moves
no result beyond that. ``backend="numpy"`` or ``"numba"`` forces either.
"""

from __future__ import annotations

from typing import NamedTuple

from .support import static_refusal

__all__ = ["Choice", "choose", "numpy_seconds", "COMPILE_SECONDS", "LOAD_SECONDS", "STEP_US", "PATH_STEP_US"]

#: the NumPy loop's cost per step, µs (one trajectory: its Python overhead), by rule kind
STEP_US = {"taylor1": 50.0, "nodes": 110.0, "taylor2": 160.0}
#: and per path-step at ``n = 1``, µs, scaled by ``n^1.5`` (1000 paths: 0.12 µs for the EKF at
#: n = 1, 3.6 at n = 4, 22.7 at n = 16; the UKF and second-order filters 2-3× the EKF)
PATH_STEP_US = {"taylor1": 0.25, "nodes": 0.45, "taylor2": 0.6}
#: a loop's first compile, CPU seconds: the scalar EKF's batch loop, the loops specialized to the
#: dimensions (n, m ≤ :data:`~.build.SPECIALIZE_UP_TO`), the general loop
COMPILE_SECONDS = {"scalar": 2.0, "specialized": 45.0, "general": 10.0}
#: a cached loop's first run in a new process (numba's import, reading its code), seconds
LOAD_SECONDS = 1.0


class Choice(NamedTuple):
    """``backend`` (``"numpy"`` or ``"numba"``) and why, in words."""

    backend: str
    why: str


def numpy_seconds(kind: str, n: int, B: int, T: int, repeats: int = 1) -> float:
    """The NumPy loop's estimated time for ``repeats`` runs of ``B`` paths × ``T`` steps."""
    return repeats * T * (STEP_US[kind] + B * PATH_STEP_US[kind] * max(n, 1) ** 1.5) * 1e-6


def choose(flt, B: int, T: int, repeats: int = 1) -> Choice:
    """The backend ``run(..., backend="auto")`` takes for ``flt`` on ``B`` paths × ``T`` steps
    (``repeats``: runs of the same size to come, as a fit's evaluations). See the module's rule."""
    reason = static_refusal(flt)
    if reason is not None:
        return Choice("numpy", f"no compiled loop: {reason}")
    from . import build, cache

    kind, fns, scalar, dims = build.loop_of(flt)
    if build.loaded(kind, fns, flt.model._kernels["f"], scalar, dims):
        return Choice("numba", "the compiled loop is loaded in this process")
    work = numpy_seconds(kind, flt.model.n, B, T, repeats)
    compile_s = COMPILE_SECONDS["scalar" if scalar else "general" if dims is None else "specialized"]
    if work < LOAD_SECONDS:
        return Choice("numpy", f"a short run (NumPy loop ~{work:.2g} s)")
    from .support import available
    if not available():
        return Choice("numpy", "numba does not import here")
    if work >= compile_s:
        return Choice("numba", f"the run (NumPy loop ~{work:.2g} s) repays the compile (~{compile_s:g} s)")
    if cache.ready(*build.text_of(kind, fns, scalar, dims)) is not None:
        return Choice("numba", "the compiled loop is in the disk cache")
    return Choice("numpy", f"the compile (~{compile_s:g} s) costs more than the NumPy loop (~{work:.2g} s)")
