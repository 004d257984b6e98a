"""Assembling the compiled loops: the one loop template (:mod:`.loops`) with the predict and
update kernels of the rule's kind (:mod:`.rule_kernels`), and those with the model's functions
(:mod:`.kernels`), bound as globals; once per model and kind.

Each loop is one generated module (:func:`source`): the kernels of :mod:`.path_linalg` and
:mod:`.step_kernels`, the model's functions, the kind's kernels and the loop, as text, written to
the disk cache and imported from there (:mod:`.cache`), so numba keeps its machine code for the
next process. The specialized loops (:data:`SPECIALIZE_UP_TO`) get the dimensions as constants
and every kernel expanded into the text of three functions, the loop, its predict and its update
(:mod:`.flatten`; LLVM inlines the two into the loop: 3-4× shorter compiles than numba's
``inline="always"`` of each kernel, the same machine arithmetic). Every function but the loop is
compiled without the wrappers that would let Python or C call it (the loop alone is called from
Python). The sources are read once, at import: later edits of the files cannot skew the compiled
code.
"""

from __future__ import annotations

import functools
import inspect

from . import (
    batch_loop,
    cd_kernels,
    ito_kernels,
    loops,
    path_linalg,
    rule_kernels,
    sqrt_kernels,
    step_kernels,
)
from .cache import load_source
from .flatten import flatten_apart
from .kalman_loop import KALMAN_KEY, SCALAR
from .kernels import KERNELS, model_kernels, scalar_kernels
from .support import rule_kind

__all__ = ["FUNCTION_ARGS", "SPECIALIZE_UP_TO", "SPECIALIZE_NODES_UP_TO", "SPECIALIZE_TAYLOR2_UP_TO", "loop_of",
           "source", "steps", "text_of", "tag_of", "on_disk", "loaded", "loop_name"]

#: the functions a source takes first (bound as globals by :func:`steps`): the model's functions
#: of each kernel, the kernels of the template
FUNCTION_ARGS = {"steps_scalar_": ("f", "fx", "h", "hx", "G"), "steps_": ("predict", "update"),
                 "predict_taylor1_": ("f", "fx", "G"), "update_taylor1_": ("h", "hx"),
                 "predict_nodes_": ("f", "G"), "update_nodes_": ("h",),
                 "predict_taylor2_": ("f", "fx", "fxx", "fxt"), "update_taylor2_": ("h", "hx", "hxx", "hxt"),
                 "predict_sqrt_taylor1_": ("f", "fx", "G"), "update_sqrt_taylor1_": ("h", "hx"),
                 "predict_sqrt_nodes_": ("f", "G"), "update_sqrt_nodes_": ("h",),
                 "predict_ito_": (), "update_ito_": ("f", "fx", "fxx", "h", "hx", "hxx", "G"),
                 "predict_cd_": ("f", "fx", "fxt", "G"), "predict_cd_nodes_": ("f", "G")}

#: loops of models up to this state and measurement dimension are specialized: the dimensions
#: compiled in as constants and the helpers expanded into the loop (:func:`_flat`; the compiler
#: then unrolls the small loops: 2-5× faster at n ≤ 4 than the general loop, at a compile time of
#: 3.4-5.2 s CPU per model and rule kind on an idle core — 4.7-9.1 s as one flat function, 2-3×
#: that with numba's own inlining — against 3-7 s for the general loop);
#: larger models take the general loop. The arithmetic is the same (no fast-math), so both give
#: the same numbers to the last bit.
SPECIALIZE_UP_TO = 4
#: the node rules' (UKF, CKF, GHKF, SLF) loops are specialized up to this dimension (where
#: :data:`SPECIALIZE_UP_TO` is not 0, which turns every specialization off): their sigma-point sums
#: gain most from the dimensions compiled in (the UKF at n = 8: 20 % faster than the general
#: loop), at a compile no longer than the general loop's (benchmarks/bench_compile.py)
SPECIALIZE_NODES_UP_TO = 8
#: and the Taylor-2 loops (the second-order filters) up to this dimension, on the same condition: at
#: n = 8 (benchmarks/bench_dimensions.py's chain, 300 × 200, one core, loaded machine, user CPU time)
#: 1.51 µs per path-step against the general loop's 2.43, the same bits, a first compile of 10.4 s
#: against 8.2
SPECIALIZE_TAYLOR2_UP_TO = 8
#: the square-root filters' kinds (:mod:`.sqrt_kernels`): always the general loop (their QR steps
#: gain little from dimensions compiled in, and the flattened loop would double the compile)
SQRT_KINDS = ("sqrt-taylor1", "sqrt-nodes")

_KERNEL_MODULES = (path_linalg, step_kernels)
#: the helper kernels of a kind's own module (the square-root kinds', the continuous Itô kind's)
_KIND_MODULES = {"sqrt-taylor1": (sqrt_kernels,), "sqrt-nodes": (sqrt_kernels,), "ito": (cd_kernels, ito_kernels),
                 **{k: (cd_kernels,) for k in cd_kernels.KERNELS}}
#: the kernels whose first parameter is a model function (:func:`_helpers`)
_TAKES_FUNCTIONS = ("nodes_moments_", "nodes_gqg_")
_SOURCE = {f.__name__: inspect.getsource(f)  # read once, at import
           for f in (*path_linalg.SOURCES, *step_kernels.SOURCES, *sqrt_kernels.SOURCES, *ito_kernels.SOURCES,
                     *cd_kernels.SOURCES,
                     *loops.SOURCES.values(),
                     *(k for pair in rule_kernels.KERNELS_BY_KIND.values() for k in pair))}


def _jit_line(name: str, src_name: str, **kw) -> str:
    args = "".join(f", {k}={v!r}" for k, v in kw.items())
    return f"{name} = {'_jit' if kw.get('cache') else '_inner'}({src_name}{args})\n"


def _helpers(kind: str = "") -> list:
    """The kernels of :mod:`.path_linalg` and :mod:`.step_kernels` (and :mod:`.sqrt_kernels`' for the
    square-root kinds) as source, each jitted under its name (``chol_`` as ``chol``; the general loops')."""
    out = []
    for mod in _KERNEL_MODULES + _KIND_MODULES.get(kind, ()):
        for f in mod.SOURCES:
            h = f.__name__
            # a kernel taking a model function as argument is always inlined: called, it would get
            # the function as a pointer, which numba cannot keep on disk ("dynamic globals")
            kw = {"inline": "always"} if h in _TAKES_FUNCTIONS else {}
            out += [_SOURCE[h], _jit_line(h[:-1], h, **kw)]
    return out


def _bind(name, fns, dims, keep=False):
    """The source of ``name`` with its leading parameters that name entries of ``fns`` dropped (they
    are bound as globals; ``keep``: left as parameters, the model-free loop's, :mod:`.template`)
    and, with ``dims = (n, m, r, N)``, the dimensions read from the arrays replaced by constants
    (``N`` None: read from the nodes)."""
    head, rest = _SOURCE[name].split("(", 1)
    params, body = rest.split("):\n", 1)
    plist = [x.strip() for x in params.replace("\n", " ").split(",") if x.strip()]
    drop = []
    while not keep and plist[len(drop)] in fns:
        drop.append(plist[len(drop)])
    if dims is not None:
        n, m, r, N = dims
        for old, new in (("    B, T, mdim = ys.shape\n", f"    B, T = ys.shape[0], ys.shape[1]\n    mdim = {m}\n"),
                         ("    n = m0.shape[1]\n", f"    n = {n}\n"), ("    r = Q.shape[0]\n", f"    r = {r}\n"),
                         ("    N = z.shape[0]\n", f"    N = {N}\n" if N is not None else "    N = z.shape[0]\n")):
            body = body.replace(old, new, 1)
    missing = [a for a in FUNCTION_ARGS.get(name, ()) if a not in (plist if keep else drop)]
    if missing:  # pragma: no cover - a guard on this package's own code
        raise RuntimeError(f"steps: {name} does not start with {missing}")
    return head + "(" + ", ".join(plist[len(drop):]) + "):\n" + body


#: the kernels a specialized loop calls as functions of their own (:func:`_flat`), each flattened
#: with the dimensions compiled in and inlined into the loop by LLVM (``forceinline``: the machine
#: code of one flat function). numba's front end takes a time growing faster than a function's size
#: (its liveness and SSA passes: blocks × variables): the loop, its predict and its update compiled
#: apart take 0.55-0.7× the CPU time of one flat function of all three (benchmarks/bench_compile.py)
_APART = ("predict", "update")
#: and, by kind, kernels that are functions of their own there too (the Itô step's likelihood: flattened
#: into its update it doubled the loop's compile, 5.9 -> 10.4-11.9 s CPU at n = 1, loaded)
_APART_KIND = {"ito": ("likelihood", "ito_terms")}
#: and the kernels called as functions of their own, not inlined: the node rules' rare cases (the
#: divergence test where P's own Cholesky factor cannot decide, :func:`~.path_linalg.psd_root_`; a
#: square root where none is kept, a path's first step), whose code in the loop's text lengthened
#: the compile by 10-25 % at n = 4 (1-2 s) for nothing the loop runs often
_CALLED = ("psd_exact", "sqrt_check")
_UNUSED3 = "def unused3_(x, t, p, out):\n    pass\n"
_UNUSED_TRACE = "def unused_trace_(x, t, p, P, out):\n    pass\n"
#: the contractions' slots (:func:`~.kernels.model_kernels`' ``f_xxtr``, ``h_xxtr``): their unused function
_TRACE_SLOTS = ("fxt", "hxt")
_HEADER = """# nlfilter: a compiled loop, generated (nlfilter.filters.compiled.build); not to be edited: the
# cache compares this file with the source it must hold and writes it again where they differ.
import math

import numpy as np
from numba import njit


def _jit(fn, **kw):
    return njit(error_model="numpy", nogil=True, _nrt=False, **kw)(fn)


def _inner(fn, **kw):  # called by the loop only: no wrapper for Python or C to compile
    return _jit(fn, no_cpython_wrapper=True, no_cfunc_wrapper=True, **kw)


LOG_2PI = {log2pi!r}


def unused3_(x, t, p, out):  # the Hessian slots of a first-order Taylor-2 form: never called
    pass


def unused_trace_(x, t, p, P, out):  # and its contraction slots
    pass


unused3 = _inner(unused3_)
unused_trace = _inner(unused_trace_)
"""


def loop_functions(kind: str, scalar: bool = False, dims=None) -> tuple:
    """The model's function slots a model-free loop of rule ``kind`` takes first, in order
    (:mod:`.template`): those of its predict kernel, then its update kernel's new ones (the EKF's
    batch-inner loop, ``dims``: :data:`.batch_loop.SLOTS`)."""
    if batch_loop.is_batch(dims):
        return batch_loop.SLOTS
    if scalar:
        return FUNCTION_ARGS[loops.steps_scalar_.__name__]
    names = [k.__name__ for k in rule_kernels.KERNELS_BY_KIND[kind]]
    return tuple(dict.fromkeys(FUNCTION_ARGS[names[0]] + FUNCTION_ARGS[names[1]]))


def _threaded(loop: str, kind: str) -> str:
    """The loop template's source taking the model's functions first and passing each kernel its
    own (the model-free loop, :mod:`.template`)."""
    pred, upd = (FUNCTION_ARGS[k.__name__] for k in rule_kernels.KERNELS_BY_KIND[kind])

    def first(names):  # (the Itô kind's predict takes none)
        return "".join(f"{a}, " for a in names)
    for old, new in ((f"def {loops.steps_.__name__}(", f"def {loops.steps_.__name__}({first(loop_functions(kind))}"),
                     ("predict(m, P, ", f"predict({first(pred)}m, P, "), ("update(m, P, ", f"update({first(upd)}m, P, ")):
        if loop.count(old) != 1:  # pragma: no cover - a guard on this package's own code
            raise RuntimeError(f"steps: the loop template must call {old!r} once")
        loop = loop.replace(old, new)
    return loop


def _flat(kind: str, fns: dict, dims, template: bool = False) -> list:
    """The parts of a specialized loop's module after the header: ``jacobi`` (rare, long: a call),
    the model's functions too large to inline, the predict and update kernels (:data:`_APART`) each
    a flat function of its own with the dimensions compiled in, and the loop calling them, every
    other kernel expanded into their text (:func:`.flatten.flatten_apart`; numba then types three
    functions instead of inlining the kernels call site by call site: the same arithmetic, a
    fraction of the compile)."""
    defs = {f.__name__[:-1]: _SOURCE[f.__name__] for mod in _KERNEL_MODULES + _KIND_MODULES.get(kind, ())
            for f in mod.SOURCES if f.__name__ != "jacobi_"}
    parts = [_SOURCE["jacobi_"], _jit_line("jacobi", "jacobi_")]
    for arg, k in {} if template else fns.items():  # (model-free: the loop's parameters)
        if k is None:
            defs[arg] = _UNUSED_TRACE if arg in _TRACE_SLOTS else _UNUSED3
        elif k.inline:
            defs[arg] = k.source
        else:
            parts += [k.source, _jit_line(arg, k.name)]
    for role, f in zip(("predict", "update"), rule_kernels.KERNELS_BY_KIND[kind]):
        defs[role] = _bind(f.__name__, fns, dims, template)
    loop = _bind(loops.steps_.__name__, {"predict": None, "update": None}, dims)
    if template:
        loop = _threaded(loop, kind)
    text, made = flatten_apart(loop, defs, _APART + _APART_KIND.get(kind, ()) + _CALLED)
    for name, src in made.items():
        inline = {} if name.startswith(_CALLED) else {"forceinline": True}
        parts += [src, _jit_line(name, name + "_", **inline)]
    return parts + [text, _jit_line("steps", loops.steps_.__name__, cache=True)]


def source(kind: str, fns: dict, scalar: bool = False, dims=None, template: bool = False) -> str:
    """The module text of the loop of rule ``kind`` (see :func:`steps`): one file holding all it
    runs — the kernels of :mod:`.path_linalg` and :mod:`.step_kernels`, the model's functions
    ``fns`` (``{arg name: Kernel}``; ``None`` for an unused Hessian slot), the kind's predict and
    update kernels with the model's functions bound as globals, and the loop, ``steps``, whose
    machine code numba keeps on disk (``cache=True``; :mod:`.cache`). ``template``: the model-free
    loop (:mod:`.template`): no model in the text, its functions the loop's first parameters
    (:func:`loop_functions`), passed down to the kernels."""
    parts = [_HEADER.format(log2pi=step_kernels.LOG_2PI)]
    if dims is not None and not scalar:
        return "\n\n".join(p.rstrip("\n") + "\n" for p in parts + _flat(kind, fns, dims, template))
    parts += _helpers(kind)
    for arg, k in {} if template else fns.items():
        if k is None:
            parts.append(f"{arg} = {'unused_trace' if arg in _TRACE_SLOTS else 'unused3'}\n")
        else:
            parts += [k.source, _jit_line(arg, k.name, **({"inline": "always"} if k.inline else {}))]
    if scalar:
        loop = loops.steps_scalar_.__name__
    else:
        loop = loops.steps_.__name__
        for role, f in zip(("predict", "update"), rule_kernels.KERNELS_BY_KIND[kind]):
            parts += [_bind(f.__name__, fns, dims, template), _jit_line(role, f.__name__, inline="always")]
    text = _bind(loop, {"predict": None, "update": None} if not scalar else fns, dims, template and scalar)
    if template and not scalar:
        text = _threaded(text, kind)
    parts += [text, _jit_line("steps", loop, cache=True)]
    return "\n\n".join(p.rstrip("\n") + "\n" for p in parts)


def loop_of(flt, B: int | None = None, have=None):
    """``(kind, fns, scalar, dims, key)``: the loop that runs ``flt`` on ``B`` paths (:func:`steps`'
    arguments): its rule kind, the model's functions (:mod:`.kernels`, generated once per model),
    whether it is the scalar batch loop (the EKF on one state, measurement and noise; the KF on one
    state and measurement), the dimensions compiled in (models up to :data:`SPECIALIZE_UP_TO`) or
    None, the store its loops are kept in (:data:`~.kernels.KERNELS`: the model's, the KF's one).

    The run's size matters to the EKF on 4-16 states (:func:`.batch_loop.serves`): from
    :func:`.batch_loop.paths_from` paths (8 where the one-path loop is specialized, n = 4; 4 at
    5-8 states, 16 above)
    the batch-inner loop, below it the one-path loop (one trajectory of chain(4): 0.35 µs per step,
    user CPU time, against the batch-inner loop's 1.17; see :data:`.batch_loop.PATHS_FROM`) — unless
    only the other of the two is in this process already (compiled or loaded by an earlier run):
    that one, so that a process compiles one loop per model (the loaded one costs at most 1.5× the
    time per path-step of the other at n = 4 from 8 paths, 3.3× on one path; a compile costs
    5-30 s). ``B`` None: a batch of any size (the batch-inner loop where the rule has one);
    ``have(kind, fns, key, scalar, dims)``: whether that
    loop is in this process (default :func:`loaded`; the model-free loops', :func:`.template.loop_of`)."""
    have = loaded if have is None else have
    md = flt.model
    n, mdim, r = md.n, md.m, md.r
    kind = rule_kind(flt)
    if kind == "kalman":  # the matrices are data: one loop for every linear model (the scalar one's f, h, G read them)
        return (kind, SCALAR, True, None, KALMAN_KEY) if n == mdim == 1 else (kind, {}, False, None, KALMAN_KEY)
    key = md._kernels["f"]
    if kind == "taylor1" and n == mdim == r == 1:
        return kind, scalar_kernels(md), True, None, key
    limit = SPECIALIZE_UP_TO
    if kind in ("nodes", "taylor2") and limit:
        limit = max(limit, SPECIALIZE_NODES_UP_TO if kind == "nodes" else SPECIALIZE_TAYLOR2_UP_TO)
    dims = (n, mdim, r, None) if max(n, mdim) <= limit and kind not in SQRT_KINDS else None
    # the continuous Itô kind: the Hessians on small models whatever the rule, so that its Taylor-1 and
    # Taylor-2 filters share one loop (one compile; the rule's switches are data, ks)
    second = (kind in ("taylor2", "cd-taylor2") and flt.rule.second) or (kind == "ito" and (flt.rule.second or dims is not None))
    fns = model_kernels(md, second=second)
    # the kernels' parameter names -> model_kernels' (first-order Taylor-2: the Hessian slots are
    # never called; None, a compiled no-op, fills them)
    args = {"taylor1": {"f": "f", "fx": "f_x", "h": "h", "hx": "h_x", "G": "G"}, "nodes": {"f": "f", "h": "h", "G": "G"},
            "taylor2": {"f": "f", "fx": "f_x", "fxx": "f_xx", "fxt": "f_xxtr", "h": "h", "hx": "h_x", "hxx": "h_xx",
                        "hxt": "h_xxtr"},
            "sqrt-taylor1": {"f": "f", "fx": "f_x", "h": "h", "hx": "h_x", "G": "G"},
            "sqrt-nodes": {"f": "f", "h": "h", "G": "G"},
            "ito": {"f": "f", "fx": "f_x", "fxx": "f_xx", "h": "h", "hx": "h_x", "hxx": "h_xx", "G": "G"},
            "cd-taylor1": {"f": "f", "fx": "f_x", "fxt": "f_xxtr", "h": "h", "hx": "h_x", "G": "G"},
            "cd-taylor2": {"f": "f", "fx": "f_x", "fxt": "f_xxtr", "h": "h", "hx": "h_x", "hxx": "h_xx",
                           "hxt": "h_xxtr", "G": "G"},
            "cd-nodes": {"f": "f", "h": "h", "G": "G"}}[kind]
    fns = {a: fns.get(w) for a, w in args.items()}
    if batch_loop.serves(kind, n, mdim):  # the batch-inner loop (the model's functions over blocks too)
        wide = batch_loop.dims_of(n, mdim, r)
        batch = B is None or B >= batch_loop.paths_from(n, dims is not None)
        if B is not None and not have(kind, fns, key, False, wide if batch else dims):
            batch = batch != have(kind, fns, key, False, dims if batch else wide)  # only the other one is loaded
        if batch:
            return kind, {**fns, **batch_loop.block_kernels(md)}, False, wide, key
    return kind, fns, False, dims, key


def steps(kind: str, fns: dict, key, scalar: bool = False, dims=None):
    """The raw loop of rule ``kind``: the template (:func:`.loops.steps_`) with the kind's predict
    and update kernels (:mod:`.rule_kernels`) bound as globals, and in those the model's functions
    ``fns`` (``{"f", "fx", "h", "hx", "G"[, "fxx", "hxx"]}`` as :class:`~.kernels.Kernel` sources;
    numba then calls them directly and can inline them; passed as arguments they would be
    first-class function pointers); ``scalar``: the scalar batch loop. ``dims``: ``(n, m, r, N)``
    compiled in as constants (``N`` None: read from the nodes), with the helpers inlined
    (:data:`SPECIALIZE_UP_TO`); the kernels are always inlined into
    the template (one call site each). Made once per model (``key``: its kernel store) and kind in a
    process, and loaded from the disk cache (:mod:`.cache`) where another process compiled it.
    Returns ``(loop, cache entry)``."""
    store = KERNELS.setdefault(key, {})
    name = loop_name(kind, fns, scalar, dims)
    if name not in store:
        module, entry = load_source(*text_of(kind, fns, scalar, dims))
        store[name] = (module.steps, entry)
    return store[name]


def loop_name(kind, fns, scalar, dims):
    second = fns.get("fxx") is not None or fns.get("fxt") is not None  # (a first-order Taylor-2 form: neither)
    return ("steps", kind, not second if kind in ("taylor2", "ito", "cd-taylor2") else scalar, dims)


def text_of(kind: str, fns: dict, scalar: bool = False, dims=None) -> tuple:
    """``(module text, cache tag)`` of the loop :func:`steps` makes (:func:`source`; the batch-inner
    loop: :func:`.batch_loop.source` around it). Made once per loop in a process: the automatic
    backend asks for it on every run past its first threshold, and a specialized loop's text takes
    0.1-0.6 s to write (:func:`.flatten.flatten`), more than the small run it decides about."""
    return _text(kind, tuple(fns.items()), scalar, dims)


@functools.lru_cache(maxsize=256)
def _text(kind: str, fns: tuple, scalar: bool, dims) -> tuple:
    fns = dict(fns)
    if batch_loop.is_batch(dims):
        return batch_loop.source(source(kind, fns), dims, fns), tag_of(kind, scalar, dims)
    return source(kind, fns, scalar, dims), tag_of(kind, scalar, dims)


def tag_of(kind: str, scalar: bool = False, dims=None, template: bool = False) -> str:
    """The cache tag of the loop :func:`text_of` makes (``template``: the model-free loop's,
    :func:`.template.text`), without its text (:func:`.cache.holds_tag`)."""
    tag = f"{kind}-batch" if batch_loop.is_batch(dims) else f"{kind}{'-scalar' if scalar else ''}"
    return f"{tag}-template" if template else tag


def on_disk(kind: str, fns: dict, scalar: bool = False, dims=None) -> bool:
    """Whether the disk cache holds the model's own loop (:func:`.cache.ready`), its text made only
    where the cache holds an entry of its tag at all."""
    from .cache import ready_by_tag

    return ready_by_tag(tag_of(kind, scalar, dims), lambda: text_of(kind, fns, scalar, dims)) is not None


def loaded(kind: str, fns: dict, key, scalar: bool = False, dims=None) -> bool:
    """Whether :func:`steps` has this loop for the model of kernel store ``key`` in this process."""
    return loop_name(kind, fns, scalar, dims) in KERNELS.get(key, {})
