"""The entry point of ``Filter.run(..., backend="numba")``: :func:`run_compiled` prepares the
run (prior, parameters, work arrays), picks the loop of the rule's kind (:mod:`.build`) and
:func:`finish` raises or returns its :class:`~nlfilter.filters.estimates.Estimates` as the NumPy
loop would.
"""

from __future__ import annotations

import functools
import time
from types import MappingProxyType

import numpy as np

from ...errors import CompileError, DivergenceError
from ..estimates import Estimates
from ..linalg import PSD_TOL, mm, symmetrize
from ..recorder import loglik_divergence
from ..rules import FORM_TABLE
from . import batch_loop, build, template
from .cache import seal
from .cd_kernels import constants as cd_constants
from .kalman_loop import matrices, scalar_parameters
from .loops import alloc_path
from .rule_kernels import ALLOC
from .choice import shared_tally
from .support import rule_kind, unsupported

__all__ = ["run_compiled", "run_shared", "finish"]

_KIND = {"none": 0, "-quarter": 1, "gaussian": 2}
_FORCE = {"none": 0, "truncated": 1, "gaussian": 2}


def _nodes(flt, n):
    """``(z (N, n), w (N,), wc (N,))``: the rule's table (:meth:`~nlfilter.filters.rules.NodeRule.unit_nodes`),
    as writeable copies (one numba type for every rule)."""
    return tuple(np.array(a, float) for a in flt.rule.unit_nodes(n))


def _plain(a):
    """``a`` as a writeable C-contiguous float array (a read-only or strided array is another
    numba type: it would compile the loop again)."""
    a = np.asarray(a, dtype=float)
    return a if a.flags.c_contiguous and a.flags.writeable else np.array(a, dtype=float, order="C")


def run_compiled(flt, yf, batch, m0, P0, on, loglik, progress=False, shared=False):
    """:meth:`Filter.run` of ``flt`` on ``yf (B, T, m)`` by the compiled loop: the same
    :class:`~nlfilter.filters.estimates.Estimates` (path-major ``(B, T, ...)``, reshaped to ``batch``);
    ``progress``: a bar over blocks of paths; ``shared``: the model-free loop of the rule kind and
    dimensions, the model's functions passed to it (:mod:`.template`; ``backend="numba-shared"``)."""
    reason = unsupported(flt)
    if reason is not None:
        raise TypeError(f"backend: 'numba' cannot run {type(flt).__name__} here: {reason}; use backend='numpy'")
    rule = getattr(flt, "rule", None)
    if loglik and getattr(flt, "time", None) == "continuous" and rule.second and FORM_TABLE[rule.form].innovation == "-quarter":
        # a CompileError: backend="auto" runs NumPy
        raise CompileError(f"backend: 'numba' cannot run {type(flt).__name__} with loglik=True and the form "
                           f"{rule.form!r} (the NumPy loop screens its innovation covariance over the batch); use "
                           "backend='numpy'")
    from numba.core.errors import TypingError
    try:
        return _run(flt, yf, batch, m0, P0, on, loglik, progress, shared)
    except TypingError as exc:  # a function of the model numba cannot compile
        raise CompileError(f"backend: numba cannot compile {type(flt).__name__} on this model "
                           f"({str(exc).splitlines()[0]}); use backend='numpy'") from exc


def run_shared(flt, yf, batch, m0, P0, on, loglik, progress=False):
    """:func:`run_compiled` on the model-free loop (``backend="numba-shared"``, :mod:`.template`);
    the time of a run on the loop already loaded (no compile in it) is added to the model's tally
    (:func:`.choice.shared_tally`: the automatic backend moves to the model's own loop once that
    would have repaid its compile)."""
    kind = rule_kind(flt)
    if kind == "kalman":  # (its loop is model-free already)
        return run_compiled(flt, yf, batch, m0, P0, on, loglik, progress, shared=True)
    _, slots, scalar, dims, key = template.of(flt, yf.shape[0])
    warm = template.loaded(kind, slots, key, scalar, dims)
    start = time.perf_counter()
    est = run_compiled(flt, yf, batch, m0, P0, on, loglik, progress, shared=True)
    if warm:
        store = build.KERNELS.setdefault(flt.model._kernels["f"], {})
        tally = shared_tally(kind)
        store[tally] = store.get(tally, 0.0) + time.perf_counter() - start
    return est


def _loop(flt, B, shared):
    """``(kind, loop, scalar, dims, entries)``: the compiled loop that runs ``flt`` on ``B`` paths
    (``shared``: the model-free one, its first arguments, the model's functions, bound)."""
    kind, fns, scalar, dims, key = template.loop_of(flt, B) if shared else build.loop_of(flt, B)
    if not shared or kind == "kalman":  # (the Kalman loop is model-free already: its matrices are data)
        steps, entry = build.steps(kind, fns, key, scalar=scalar, dims=dims)
        return kind, steps, scalar, dims, (entry,)
    steps, entry = template.loop(kind, scalar, dims)
    fargs, fentry = template.functions({s: fns[s] for s in build.loop_functions(kind, scalar, dims)}, key, scalar)
    if batch_loop.is_batch(dims):  # the EKF's batch-inner loop: the tables of its Jacobians' zeros too
        fargs = (*fargs, *batch_loop.tables(fns))
    return kind, functools.partial(steps, *fargs), scalar, dims, (entry, fentry)


def _run(flt, yf, batch, m0, P0, on, loglik, progress, shared=False):
    """:func:`run_compiled` after its checks (a TypingError: the model's functions do not compile)."""
    md = flt.model
    B, T, mdim = yf.shape
    n = md.n
    prior = flt.init(m0, P0, batch)
    kind, steps, scalar, dims, entries = _loop(flt, B, shared)
    sqrt = kind in build.SQRT_KINDS  # the loop's P holds the factor S (P = S Sᵀ)
    mean0 = _plain(prior.mean).reshape(B, n)
    cov0 = _plain(prior.factor if sqrt else prior.cov).reshape(B, n, n)
    ys = _plain(yf)
    offset = 0 if flt.start == "update" else 1
    absent = np.isnan(ys).all(axis=(0, 2)) if B and kind != "ito" else np.zeros(T, bool)  # Itô: every step steps
    means = np.empty((B, T, n))
    covs = np.empty((B, T, n, n))
    want = bool(loglik)
    ll = np.empty((B, T) if want else (0, 0))
    inn = np.empty((B, T, mdim) if want else (0, 0, 0))
    icov = np.empty((B, T, mdim, mdim) if want else (0, 0, 0, 0))
    step = np.full(B, -1, np.int64)
    R = _plain(md.R)
    if kind == "kalman":  # the model's matrices as data (F, b, H, d, G Q Gᵀ): no code per model
        ks = matrices(flt, T + offset)
        if ks is None:  # pragma: no cover - unsupported refuses parameters per path
            raise TypeError("backend: 'numba' takes one F, b, H, d, G Q Gᵀ per time; use backend='numpy'")
        if not scalar:  # the template with the Kalman kernels, compiled once for every linear model
            nil = np.empty((0, 0))  # p, Q, GQG0: read by the rule kernels only
            steps(ys, mean0, cov0, np.empty(0), nil, R, nil, False, offset, absent, PSD_TOL, means, covs, ll, inn, icov,
                  want, step, ks, ALLOC[kind](n, mdim), *alloc_path(n, mdim))
            _seal(entries)
            return finish(flt, on, step, batch, means, covs, want, ll, inn, icov)
        p, Q, GQG0, G_const = scalar_parameters(ks)  # the scalar batch loop's f, h, G read the matrices in p
    else:
        vals = md._values.values
        p = np.array([float(vals[s]) for s in md._psyms], float)
        Q = _plain(md.Q)
        G_const = bool(md.G_constant if sqrt else md._G_fixed)  # the square-root rule: G(m) where G is free of x
        GQG0 = _plain(md.GQGT(np.zeros(n))) if G_const else np.zeros((n, n))
    if scalar:  # the scalar batch loop, time-major outputs
        outm, outP = np.empty((T, B)), np.empty((T, B))
        sll, sinn, sicov = (np.empty((T, B)), np.empty((T, B)), np.empty((T, B))) if want else (ll, ll, ll)
        steps(ys, mean0, cov0, p, Q, R, GQG0, G_const, offset, absent, PSD_TOL, outm, outP, sll, sinn, sicov, want,
              step, np.empty(B), np.empty(B))
        _seal(entries)
        means, covs = outm.T[:, :, None], outP.T[:, :, None, None]  # (B, T, 1) views
        if want:
            ll, inn, icov = sll.T, sinn.T[:, :, None], sicov.T[:, :, None, None]
        return finish(flt, on, step, batch, means, covs, want, ll, inn, icov)
    if sqrt:  # the roots of Q and R the NumPy filter takes; the nodes' table
        roots = (_plain(flt._root("Q", md.Q)), _plain(flt._root("R", md.R)))
        ks, N = ((*_nodes(flt, n), *roots), len(_nodes(flt, n)[0])) if kind == "sqrt-nodes" else (roots, 0)
    elif kind in ("nodes", "cd-nodes"):  # the rule's table (and the continuous-discrete integrator)
        z, wm, wc = _nodes(flt, n)
        ks, N = (z, wm, wc), z.shape[0]
        if kind == "cd-nodes":
            ks = (*ks, cd_constants(flt.dt, flt.substeps, flt.scheme, n, md.r))
    elif kind == "taylor1":
        ks, N = (), 0
    elif kind == "ito":  # R⁻¹, G Q Gᵀ where G is fixed, the integrator and the rule's switches (.ito_kernels)
        rule = flt.rule
        force = _FORCE[FORM_TABLE[rule.form].forcing] if rule.second else 0
        gfix = bool(md._G_fixed)
        meas = _KIND[FORM_TABLE[rule.form].innovation] if rule.second else 0
        ks, N = (_plain(flt._Rinv), GQG0 if gfix else np.zeros((n, n)), Q, float(flt.dt), int(flt.substeps),
                 flt.scheme == "rk4", bool(rule.second), force, gfix, _plain(R / flt.dt), meas), 0
    else:  # the Taylor-2 update's switches (the Taylor-1 rule: none, the first-order form's); the
        rule = flt.rule  # continuous-discrete kinds: then the integrator and its work arrays (.cd_kernels)
        spec = FORM_TABLE[getattr(rule, "form", "first-order")]
        second = bool(getattr(rule, "second", False))
        kinds = ((_KIND[spec[0]], _KIND[spec[1]], _FORCE[spec[2]]) if second else (0, 0, 0))
        ks, N = (second, *kinds, spec[1] == "none"), 0
        if kind in ("cd-taylor1", "cd-taylor2"):
            ks = (*ks, cd_constants(flt.dt, flt.substeps, flt.scheme, n, md.r))
    ws = ALLOC[kind](n, mdim, md.r, N)
    if batch_loop.is_batch(dims):  # the batch-inner loop: the one-path kernels' work arrays and its own
        ws = (ws, batch_loop.alloc(n, mdim, md.r))
    own = alloc_path(n, mdim)

    def block(lo, hi):
        common = (offset, absent, PSD_TOL, means[lo:hi], covs[lo:hi], ll[lo:hi] if want else ll,
                  inn[lo:hi] if want else inn, icov[lo:hi] if want else icov, want, step[lo:hi])
        steps(ys[lo:hi], mean0[lo:hi], cov0[lo:hi], p, Q, R, GQG0, G_const, *common, ks, ws, *own)

    if progress and B > 1:
        from tqdm.auto import tqdm
        size = max(1, -(-B // 20))
        for lo in tqdm(range(0, B, size), desc=f"{flt.name} (numba)", leave=False):
            block(lo, min(B, lo + size))
    else:
        block(0, B)
    _seal(entries)
    if sqrt:  # what the square-root filters report: S Sᵀ, symmetrized (their summary)
        covs = symmetrize(mm(covs, covs.swapaxes(-1, -2)))
    return finish(flt, on, step, batch, means, covs, want, ll, inn, icov)


def _seal(entries):
    for entry in entries:
        seal(entry)


def finish(flt, on, step, batch, means, covs, want, ll, inn, icov):
    """Raise or return the :class:`~nlfilter.filters.estimates.Estimates` of a compiled run. As the
    run loop (:meth:`~nlfilter.filters.recorder.Recorder.record`), a path whose log-likelihood term is
    not finite before any other failure diverges there (raised, or marked with
    ``extras["loglik_failed"]``; its outputs from that step on NaN)."""
    failed = None
    if want and np.isfinite(ll).all():  # (the common case: no term lost)
        failed = np.zeros(ll.shape, bool)
    elif want:
        T = ll.shape[1]
        llbad = ~np.isfinite(ll)
        first = np.where(llbad.any(axis=1), np.argmax(llbad, axis=1), T) if T else np.zeros(len(ll), int)  # no step: none failed
        lost = (first < T) & ((step < 0) | (first < step))
        failed = np.zeros(ll.shape, bool)
        if lost.any():
            idx = np.flatnonzero(lost)
            k = int(first[idx].min())
            if on == "raise" and not (step[step >= 0] <= k).any():
                raise loglik_divergence(flt.name, k, idx[first[idx] == k])
            failed[idx, first[idx]] = True
            step[idx] = first[idx]
            after = np.arange(T)[None, :] >= first[idx][:, None]  # (paths, T)
            for a in (means, covs, ll, inn, icov):
                a[idx] = np.where(after.reshape(*after.shape, *(1,) * (a.ndim - 2)), np.nan, a[idx])
    diverged = step >= 0
    if on == "raise" and diverged.any():
        k = int(step[diverged].min())
        idx = np.flatnonzero(step == k)
        raise DivergenceError(
            f"{flt.name}: covariance lost positive definiteness or a value became non-finite "
            f"at step {k} on {idx.size} path(s), first {idx[:5].tolist()}; pass "
            "on_divergence='mark' to record such paths and go on", step=k, paths=idx, what="covariance")

    def out(a):
        return a.reshape(*batch, *a.shape[1:])
    extras = {}
    if want:
        extras = {"loglik": out(ll), "innovation": out(inn), "innovation_cov": out(icov), "loglik_failed": out(failed)}
    return flt.output(Estimates(out(means), out(covs), diverged.reshape(batch), step.reshape(batch),
                                MappingProxyType(extras)))
