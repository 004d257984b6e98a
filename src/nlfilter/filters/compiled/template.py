"""The model-free loops: the loop of a rule kind compiled once for every model of its dimensions,
the model's functions passed to it as compiled function pointers.

A loop of :mod:`.build` holds the model's functions in its text (the loop, its kernels and f, h,
G and their derivatives compiled as one: LLVM inlines the model into the loop), so a new model is
a new compile of the whole loop — 3-15 s of CPU. Here the same text is made without them
(:func:`.build.source` with ``template=True``): the model's functions are parameters of the loop
(``steps(f, fx, G, h, hx, ys, ...)``), passed down to the predict and update kernels, and called
through their addresses. That loop's text depends only on the rule kind, the dimensions compiled
in and which of the model's function slots exist, so its disk-cache entry (:mod:`.cache`) serves
every model of that shape: compiled once per installation, loaded in about 0.1-0.3 s after. The
model's functions are compiled alone (:func:`functions`: numba ``cfunc``, 0.06-0.17 s each and
0.35 s for numba's first compile in a process, kept on disk too), each with the fixed signature of its slot (:data:`SIGNATURES`), so
that numba types every model's function alike and never compiles the loop again.

The arithmetic is the loop's: the same kernels, the same order; a call through a pointer instead
of the inlined function changes no operation, so the numbers are the model-specific loop's, bit
for bit (tested). The price is the calls (no inlining of f, h into the loop) and, on small models,
the constant-folding of the model's structural zeros: 1.0-1.5× the model-specific loop's time per
path-step (``benchmarks/bench_compile.py``).

The EKF's batch-inner loop (:mod:`.batch_loop`, 4-16 states, runs of many paths) has its
model-free form too (:func:`.batch_loop.source` with no model): the model's functions over a block
of paths (``fb, fxb, hb, hxb, Gb``, slots of their own here), its one-path h and h_x (the lanes
updated one at a time) and the tables of its Jacobians' structural zeros (int64 arrays and their
lengths, :func:`.batch_loop.tables`) are the loop's first arguments; its text depends on ``n, m,
r`` alone. The same bits as the model's own batch-inner loop; 1.05-1.12, 1.03-1.06, 1.04-1.05×
its time per path-step at n = 4, 8, 16 (chain(n), 1000 × 200, paired, CPU time). The cost is
mostly the sums over a table of a length known at run time only, which add into the output, the
table's loop outside the paths' (the block functions inlined instead of called, an experiment:
1.02-1.03× at n = 4, unchanged at n = 8); the own loop's form, a sum in a register with the
table's read inside the paths' loop, was 1.21-1.31× with the tables passed in (that read, from an
array that may alias the outputs, is not hoisted: no vectorized loop), and two terms a pass gained
nothing. Its first compile: 12.9-13.5, 13.6-14.9, 13.8-16.2 s CPU (the own loop's: 11.8-13.1,
12.4-13.4, 13.8-15.8 s; loaded machine, two runs), then 1.0-1.2, 1.2-1.5, 1.4-1.7 s for a new
model of the shape in a new process (``bench_compile.py --shared``, runs "batchtpl-shared" and
"batchtpl-shared-2").
"""

from __future__ import annotations

import functools

__all__ = ["SIGNATURES", "function_text", "functions", "loaded", "loop", "loop_of", "of", "ready", "text"]

_VEC = "void(float64[::1], float64, float64[::1], float64[::1])"
_MAT = "void(float64[::1], float64, float64[::1], float64[:, ::1])"
_TEN = "void(float64[::1], float64, float64[::1], float64[:, :, ::1])"
_TRACE = "void(float64[::1], float64, float64[::1], float64[:, ::1], float64[::1])"
_SCALAR = "float64(float64, float64, float64[::1])"
_BVEC = "void(float64[:, ::1], float64, float64[::1], float64[:, ::1], int64)"
_BMAT = "void(float64[:, ::1], float64, float64[::1], float64[:, :, ::1], int64)"

#: the signature of each of the model's function slots (:data:`.build.FUNCTION_ARGS`): ``fn(x (n,),
#: t, p, out)`` writing ``out`` (f, h: a vector; f_x, h_x, G: a matrix; f_xx, h_xx: a 3-tensor), the
#: contractions ``fn(x, t, p, P, out)``; the scalar batch loop's ``fn(x, t, p) -> float``; the EKF's
#: batch-inner loop's block functions (:data:`.batch_loop.SLOTS`) ``fn(x (n, NB), t, p, out, nb)``
#: writing ``out[..., :nb]`` (f, h: a matrix; f_x, h_x, G: a 3-tensor)
SIGNATURES = {"f": _VEC, "h": _VEC, "fx": _MAT, "hx": _MAT, "G": _MAT, "fxx": _TEN, "hxx": _TEN,
              "fxt": _TRACE, "hxt": _TRACE, "fb": _BVEC, "hb": _BVEC, "fxb": _BMAT, "hxb": _BMAT, "Gb": _BMAT}

_HEADER = """# nlfilter: a model's functions for the model-free loops, generated
# (nlfilter.filters.compiled.template); not to be edited.
import math

import numpy as np
from numba import cfunc


def _cfunc(sig, fn):
    return cfunc(sig, error_model="numpy", cache=True)(fn)
"""


def function_text(fns: dict, scalar: bool = False) -> str:
    """The module text of the model's functions ``fns`` (``{slot: Kernel}``, None for an unused
    Hessian slot: a no-op of the slot's signature), each compiled as a ``cfunc`` named by its slot
    with the slot's signature (``scalar``: the scalar batch loop's)."""
    parts = [_HEADER]
    for slot, k in fns.items():
        sig = _SCALAR if scalar else SIGNATURES[slot]
        if k is None:
            params = "x, t, p, P, out" if slot in ("fxt", "hxt") else "x, t, p, out"
            parts.append(f"def unused_{slot}({params}):\n    pass\n\n\n{slot} = _cfunc({sig!r}, unused_{slot})\n")
        else:
            parts.append(f"{k.source.rstrip()}\n\n\n{slot} = _cfunc({sig!r}, {k.name})\n")
    return "\n\n".join(p.rstrip("\n") + "\n" for p in parts)


def functions(fns: dict, key, scalar: bool = False) -> tuple:
    """``(cfuncs in the order of fns, cache entry)``: the model's functions compiled (or loaded from
    the disk cache) once per model in a process (``key``: its kernel store,
    :data:`~.kernels.KERNELS`)."""
    from .cache import load_source, seal
    from .kernels import KERNELS

    store = KERNELS.setdefault(key, {})
    name = _name(fns, scalar)
    if name not in store:
        module, entry = load_source(function_text(fns, scalar), "functions")
        seal(entry)  # (a cfunc compiles when it is made: its files are written)
        store[name] = (tuple(getattr(module, slot) for slot in fns), entry)
    return store[name]


_LOOPS: dict = {}  # (kind, scalar, dims) -> (loop, cache entry), this process


@functools.lru_cache(maxsize=64)
def text(kind: str, scalar: bool = False, dims=None) -> tuple:
    """``(module text, cache tag)`` of the model-free loop of rule ``kind`` (:func:`.build.source`
    with ``template=True``): the same for every model of that kind, shape and dimensions compiled
    in (the EKF's batch-inner loop: :func:`.batch_loop.source` around the one-path module). Made
    once per process (a specialized loop's text takes 0.1-0.6 s to write)."""
    from .batch_loop import is_batch
    from .batch_loop import source as batch_source
    from .build import source, tag_of

    tag = tag_of(kind, scalar, dims, template=True)
    if is_batch(dims):
        return batch_source(source(kind, {}, template=True), dims, None), tag
    return source(kind, {}, scalar, dims, template=True), tag


def loop(kind: str, scalar: bool = False, dims=None) -> tuple:
    """``(loop, cache entry)``: the model-free loop, compiled or loaded once per process."""
    from .cache import load_source

    name = (kind, scalar, dims)
    if name not in _LOOPS:
        module, entry = load_source(*text(kind, scalar, dims))
        _LOOPS[name] = (module.steps, entry)
    return _LOOPS[name]


def loop_of(flt, B: int | None = None) -> tuple:
    """:func:`.build.loop_of` for the model-free loops: the EKF's batch-inner loop where the model's
    own loop would be the batch-inner one (by ``B``), the loaded loop asked of this module's."""
    from .build import loop_of as own

    return own(flt, B, have=lambda kind, fns, key, scalar, dims: (kind, scalar, dims) in _LOOPS)


def of(flt, B: int | None = None) -> tuple:
    """``(kind, fns, scalar, dims, key)``: the model-free loop that would run ``flt`` on ``B`` paths
    (:func:`loop_of`) and the model's functions it takes (``{slot: Kernel}``,
    :func:`.build.loop_functions`)."""
    from .build import loop_functions

    kind, fns, scalar, dims, key = loop_of(flt, B)
    return kind, {s: fns[s] for s in loop_functions(kind, scalar, dims)}, scalar, dims, key


def loaded(kind: str, fns: dict, key, scalar: bool = False, dims=None) -> bool:
    """Whether the model-free loop and the model's functions ``fns`` are in this process."""
    from .kernels import KERNELS

    return (kind, scalar, dims) in _LOOPS and _name(fns, scalar) in KERNELS.get(key, {})


def ready(kind: str, fns: dict, key, scalar: bool = False, dims=None) -> tuple:
    """``(loop, functions)``: where the model-free loop and the model's functions are without
    compiling, each ``"process"``, ``"disk"`` or None (:func:`.cache.ready`; the loop's text made only
    where the cache holds an entry of its tag, :func:`.cache.ready_by_tag`). Imports nothing."""
    from .build import tag_of
    from .cache import ready as on_disk
    from .cache import ready_by_tag
    from .kernels import KERNELS

    here = (kind, scalar, dims) in _LOOPS
    done = _name(fns, scalar) in KERNELS.get(key, {})
    where = "process" if here else ready_by_tag(tag_of(kind, scalar, dims, template=True), lambda: text(kind, scalar, dims))
    return where, "process" if done else on_disk(function_text(fns, scalar), "functions")


def _name(fns, scalar):
    return ("cfuncs", tuple(fns), scalar, tuple(k is None for k in fns.values()))
