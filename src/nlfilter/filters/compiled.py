"""The compiled run loop (``run(..., backend="numba")``): the discrete Gaussian filters in one
numba-compiled loop over paths and steps.

The NumPy loop of :meth:`~nlfilter.filters.base.Filter.run` is the reference; this is the same
filter, step for step, with the model's f, h, G and their derivatives generated from its SymPy
expressions as scalar code (:func:`model_kernels`) and the predict/update of the skeleton of
:mod:`nlfilter.filters.gaussian` written out for one path at a time, without temporaries:

==============================  ================================================================
rule (filters)                  compiled step
==============================  ================================================================
Taylor-1 (``ekf``)              ``m⁻ = f(m)``, ``P⁻ = F P Fᵀ + G Q Gᵀ``; Joseph-form update
node rules (``ukf``, ``ckf``,   ``X_i = m + L z_i`` (``P = L Lᵀ``, Cholesky; eigen root where P is
``ghkf``, ``slf``)              only semi-definite), weighted sums as :class:`~nlfilter.filters.rules.NodeRule`
Taylor-2 (``truncated``, …,     seed 004 eqs. 18-23 in every form of :data:`~nlfilter.filters.rules.FORMS`:
``modified-gaussian``)          ½(P g_xx), the fourth-moment terms, the forcing tensor, S screened
==============================  ================================================================

A model with one state, one measurement and one noise runs the EKF's scalar batch loop
(:func:`_steps_scalar_`: every path at each step, the arithmetic of NumPy's scalar branch, bit for
bit); models up to :data:`SPECIALIZE_UP_TO` states and measurements get loops with their
dimensions compiled in and the helpers inlined (the same bits, faster, longer to compile).

The same conventions as the NumPy loop, which the tests hold it to (1e-12): both starts, partly
missing measurements (the observed block, exactly; a step missing on every path only predicts),
the divergence test after each predict and update (finite, smallest eigenvalue of the
symmetrized covariance ≥ −1e-9·max(1, max|P|); a failed square root, a singular or, for Taylor-2,
indefinite innovation covariance), ``on_divergence`` raise/mark with NaN from the step on, and
``loglik=True`` (:func:`~nlfilter.filters.linalg.innovation_info`'s outputs). Where a covariance
is only semi-definite the node rules take the eigen root ``U √w`` of cyclic Jacobi rotations
(:func:`_jacobi_`, no LAPACK inside the loop): the same points as NumPy's root up to the signs of
the eigenvectors, which a symmetric rule does not see; only repeated nonzero eigenvalues leave a
rotation free (then any root is as right, and the moments agree to the rule's exactness).

What it takes: a :class:`~nlfilter.models.DiscreteModel` stated in SymPy, additive noise, constant
Q and R, no correlated noise, parameters with one value each (arrays over time, inputs: the NumPy
loop); Taylor-2 also a G free of the states. :func:`unsupported` names what a filter or model
lacks; ``run`` then raises a TypeError naming ``backend``. Compilation (numba) happens at the first
run of each model and rule kind (seconds), shared by every :meth:`~nlfilter.models.Model.with_params`
copy; later runs reuse it.
"""

from __future__ import annotations

import inspect
import math
import weakref
from types import MappingProxyType

import numpy as np
import sympy as sp
from sympy.printing.pycode import PythonCodePrinter

from ..errors import DivergenceError
from .linalg import PSD_TOL

__all__ = ["available", "unsupported", "model_kernels", "run_compiled"]

BACKENDS = ("numpy", "numba")

try:  # numba is a core dependency; a broken install leaves the NumPy loop
    import numba as _nb
except Exception as _exc:  # pragma: no cover - exercised only without numba
    _nb, _IMPORT_ERROR = None, _exc
else:
    _IMPORT_ERROR = None


def available() -> bool:
    """Whether numba imports (the ``"numba"`` backend can run)."""
    return _nb is not None


def _jit(fn, **kw):
    # error_model="numpy": a division by zero gives inf/NaN (caught by the divergence test), as in
    # NumPy, instead of raising ZeroDivisionError
    return _nb.njit(error_model="numpy", nogil=True, **kw)(fn)


# ---------------------------------------------------------------------------------------------
# the model's functions as scalar code
# ---------------------------------------------------------------------------------------------
class _ScalarPrinter(PythonCodePrinter):
    """Python scalar code (``math.sin``) with float constants in full double precision."""

    def _print_Float(self, expr):
        value = float(expr)
        return repr(value) if math.isfinite(value) else super()._print_Float(expr)


def _source(name, exprs, shape, states, time, psyms) -> str:
    """``def name(x, t, p, out)``: writes ``out[idx] = expr`` for every entry of ``exprs`` (flat,
    row-major over ``shape``), with common subexpressions computed once."""
    xs = {s: sp.Symbol(f"x_{i}") for i, s in enumerate(states)}
    ps = {s: sp.Symbol(f"p_{j}") for j, s in enumerate(psyms)}
    sub = {**xs, **ps}
    if time is not None:
        sub[time] = sp.Symbol("t_")
    flat = [sp.sympify(e).xreplace(sub) for e in exprs]
    pr = _ScalarPrinter({"fully_qualified_modules": True, "inline": True, "allow_unknown_functions": False})
    used = set().union(*(e.free_symbols for e in flat)) if flat else set()
    lines = [f"def {name}(x, t, p, out):"]
    lines += [f"    x_{i} = x[{i}]" for i, s in enumerate(states) if xs[s] in used]
    lines += [f"    p_{j} = p[{j}]" for j, s in enumerate(psyms) if ps[s] in used]
    if time is not None and sp.Symbol("t_") in used:
        lines.append("    t_ = t")
    nonzero = [(i, e) for i, e in enumerate(flat) if e != 0]
    if nonzero:
        reps, red = sp.cse([e for _, e in nonzero], symbols=sp.numbered_symbols("c_"))
        lines += [f"    {s} = {pr.doprint(v)}" for s, v in reps]
    else:
        red = []
    zeros = [i for i, e in enumerate(flat) if e == 0]
    if len(zeros) > 8:  # a sparse Hessian: one loop of zeros, then the nonzero entries (compact code)
        ix = [f"i{d}" for d in range(len(shape))]
        for d, (v, size) in enumerate(zip(ix, shape)):
            lines.append("    " + "    " * d + f"for {v} in range({size}):")
        lines.append("    " + "    " * len(shape) + f"out[{', '.join(ix)}] = 0.0")
    else:
        for i in zeros:
            lines.append(f"    out[{', '.join(map(str, np.unravel_index(i, shape)))}] = 0.0")
    for (i, _), e in zip(nonzero, red):
        lines.append(f"    out[{', '.join(map(str, np.unravel_index(i, shape)))}] = {pr.doprint(e)}")
    if len(lines) == 1:
        lines.append("    pass")
    return "\n".join(lines)


def _scalar_source(name, expr, state, time, psyms) -> str:
    """``def name(x_0, t, p)`` returning the one entry ``expr`` of a scalar model's function."""
    sub = {state: sp.Symbol("x_0"), **{s: sp.Symbol(f"p_{j}") for j, s in enumerate(psyms)}}
    if time is not None:
        sub[time] = sp.Symbol("t_")
    e = sp.sympify(expr).xreplace(sub)
    pr = _ScalarPrinter({"fully_qualified_modules": True, "inline": True, "allow_unknown_functions": False})
    lines = [f"def {name}(x_0, t, p):"]
    lines += [f"    p_{j} = p[{j}]" for j, s in enumerate(psyms) if sp.Symbol(f"p_{j}") in e.free_symbols]
    if time is not None and sp.Symbol("t_") in e.free_symbols:
        lines.append("    t_ = t")
    reps, (red,) = sp.cse([e], symbols=sp.numbered_symbols("c_"))
    lines += [f"    {c} = {pr.doprint(v)}" for c, v in reps]
    lines.append(f"    return float({pr.doprint(red)})")
    return "\n".join(lines)


def scalar_kernels(model) -> dict:
    """``{"f", "f_x", "h", "h_x", "G"}`` of a model with one state, one measurement and one noise
    as numba functions ``fn(x, t, p) -> float`` (the scalar batch loop's)."""
    from ..models import _jacobian
    key = model._kernels["f"]
    store = _KERNELS.setdefault(key, {})
    if "scalar" not in store:
        ex = model.expressions
        (x,), time, psyms = model.states, model.time, model._psyms
        exprs = {"f": ex["f"][0], "f_x": _jacobian(ex["f"], [x])[0, 0], "h": ex["h"][0],
                 "h_x": _jacobian(ex["h"], [x])[0, 0], "G": ex["G"][0, 0]}
        out = {}
        for w, e in exprs.items():
            name = "s_" + w.replace("_", "")
            ns = {"math": math}
            exec(compile(_scalar_source(name, e, x, time, psyms), f"<nlfilter.compiled scalar {w}>", "exec"), ns)  # noqa: S102
            out[w] = _jit(ns[name], _nrt=False, inline="always")
        store["scalar"] = out
    return store["scalar"]


_KERNELS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def model_kernels(model, *, second: bool = False) -> dict:
    """``{"f", "f_x", "h", "h_x", "G"[, "f_xx", "h_xx"]}``: the model's functions compiled by numba
    as ``fn(x (n,), t, p, out)`` writing ``out`` (shape as the model's function, one path), the
    parameters read from ``p`` in the order of the model's parameter symbols. Generated once per
    model (shared by its :meth:`~nlfilter.models.Model.with_params` copies); ``second`` adds the
    Hessians (the Taylor-2 rule)."""
    from ..models import _first, _jacobian  # the model's own differentiation (the same entries)
    key = model._kernels["f"]  # shared by every with_params copy
    store = _KERNELS.setdefault(key, {})
    want = ("f", "f_x", "h", "h_x", "G") + (("f_xx", "h_xx") if second else ())
    missing = [w for w in want if w not in store]
    if missing:
        ex = model.expressions
        states, time, psyms = model.states, model.time, model._psyms
        n, m, r = model.n, model.m, model.r
        fM, hM, GM = ex["f"], ex["h"], ex["G"]
        if "_fx" not in store:
            store["_fx"], store["_hx"] = _jacobian(fM, states), _jacobian(hM, states)
        fx, hx = store["_fx"], store["_hx"]
        specs = {"f": (list(fM), (n,)), "f_x": (list(fx), (n, n)), "h": (list(hM), (m,)),
                 "h_x": (list(hx), (m, n)), "G": (list(GM), (n, r))}
        if second:
            specs["f_xx"] = (_first(list(fx), states), (n, n, n))
            specs["h_xx"] = (_first(list(hx), states), (m, n, n))
        for w in missing:
            exprs, shape = specs[w]
            name = "g_" + w.replace("_", "")
            src = _source(name, exprs, shape, states, time, psyms)
            ns = {"math": math}
            exec(compile(src, f"<nlfilter.compiled {w}>", "exec"), ns)  # noqa: S102 - code we generated
            # scalar code: no reference counting; small functions inlined into the loops (a
            # Hessian of 16 states, 4096 entries, inlined took 18 minutes to compile)
            store[w] = _jit(ns[name], _nrt=False, inline="always" if len(exprs) <= 64 else "never")
            store["src_" + w] = src
    return {w: store[w] for w in want}


# ---------------------------------------------------------------------------------------------
# what the compiled loop takes
# ---------------------------------------------------------------------------------------------
def _rule_kind(flt):
    """The rule's step kernel (``rule.kind``: ``"taylor1"``, ``"nodes"``, ``"taylor2"``), or None."""
    kind = getattr(getattr(flt, "rule", None), "kind", None)
    return kind if kind in _FUNCTION_ARGS else None


def unsupported(flt) -> str | None:
    """Why ``flt`` cannot run on the compiled loop, or None when it can."""
    from .gaussian import ContinuousDiscreteGaussianFilter, GaussianFilter
    if _nb is None:
        return f"numba does not import here ({_IMPORT_ERROR!r})"
    name = type(flt).__name__
    if (not isinstance(flt, GaussianFilter) or isinstance(flt, ContinuousDiscreteGaussianFilter)
            or hasattr(flt, "iterations")):  # the iterated update (IteratedEKF) is not compiled
        return (f"{name} has no compiled loop; it runs the discrete Gaussian filters (ekf, ukf, ckf, ghkf, slf, "
                "the discrete second-order forms)")
    kind = _rule_kind(flt)
    if kind is None:
        return f"{name}'s rule {type(getattr(flt, 'rule', None)).__name__} has no compiled form"
    if getattr(flt, "augmented", False):
        return f"{name} with augmented sigma points has no compiled form"
    md = flt.model
    if getattr(md, "kind", None) != "discrete" or md.expressions is None:
        return "the model must be a DiscreteModel stated in SymPy (not from_functions)"
    if not (md.additive and md.additive_measurement):
        return "the model's noise enters f or h non-additively (noise=, meas_noise=)"
    if md.piecewise:
        return (f"the model uses {', '.join(sorted(md.piecewise))}, which the compiled code does not take (NumPy evaluates them, "
                "with the derivative convention of nlfilter.models)")
    if md.cross_noise is not None:
        return "the model has correlated process and measurement noise (cross_noise)"
    if not md.R_constant:
        return "the model's R depends on the state"
    vals = md._values
    if vals.arrays or vals.unset or md._fold:
        return "the model has parameters or inputs that vary over time (arrays) or are not given"
    if kind == "taylor2" and not md._G_fixed:
        return "the second-order filters' compiled loop needs a G that depends on neither the state nor the time"
    return None


# ---------------------------------------------------------------------------------------------
# one-path linear algebra (no allocation: work arrays come from the caller)
# ---------------------------------------------------------------------------------------------
def _chol_(A, L, n):
    """Lower Cholesky factor of ``A[:n, :n]`` into ``L``; False if A is not positive definite."""
    for j in range(n):
        s = A[j, j]
        for q in range(j):
            s -= L[j, q] * L[j, q]
        if not s > 0.0:  # also False for NaN
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for q in range(j):
                s -= L[i, q] * L[j, q]
            L[i, j] = s / d
        for i in range(j):
            L[i, j] = 0.0
    return True


def _psd_ok_(m, P, n, tol, W, L):
    """Not :func:`~nlfilter.filters.linalg.bad_paths`: finite, and the smallest eigenvalue of the
    symmetrized ``P`` ≥ ``−tol·max(1, max|P|)``. 1.0 yes, 0.0 no, ``−scale`` undecided (W then
    holds the symmetrized P, for :func:`_psd_check_`)."""
    scale = 1.0
    for i in range(n):
        if not math.isfinite(m[i]):
            return 0.0
        for j in range(n):
            a = P[i, j]
            if not math.isfinite(a):
                return 0.0
            if abs(a) > scale:
                scale = abs(a)
    if n == 1:
        return 0.0 if P[0, 0] < -tol * scale else 1.0
    if n == 2:
        a, b, c = P[0, 0], 0.5 * (P[0, 1] + P[1, 0]), P[1, 1]
        low = 0.5 * (a + c) - math.sqrt(0.25 * (a - c) ** 2 + b * b)
        return 0.0 if low < -tol * scale else 1.0
    # the Cholesky screen of linalg._screen_ok (never weaker than the exact test), then exact
    dmax = 2.0
    for i in range(n):
        if 2.0 * P[i, i] > dmax:
            dmax = 2.0 * P[i, i]
    for i in range(n):
        for j in range(n):
            W[i, j] = P[i, j] + P[j, i]
        W[i, i] += 0.5 * tol * dmax
    if _chol(W, L, n):
        return 1.0
    for i in range(n):
        for j in range(n):
            W[i, j] = 0.5 * (P[i, j] + P[j, i])
    return -scale  # undecided: the caller takes the eigenvalues of W


def _jacobi_(A, w, V, n):
    """Eigenvalues ``w`` (ascending) and eigenvectors (columns of ``V``) of the symmetric
    ``A[:n, :n]`` by cyclic Jacobi rotations (destroys A; allocates nothing). Used only where the
    Cholesky screens cannot decide (a semi-definite or failing covariance)."""
    for i in range(n):
        for j in range(n):
            V[i, j] = 1.0 if i == j else 0.0
    for sweep in range(100):
        off, tot = 0.0, 0.0
        for i in range(n):
            for j in range(n):
                if i != j:
                    off += A[i, j] * A[i, j]
                tot += A[i, j] * A[i, j]
        if not off > 1e-32 * tot:  # converged (also stops on NaN)
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                sn = t * c
                for k in range(n):  # A ← Jᵀ A J
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - sn * akq
                    A[k, q] = sn * akp + c * akq
                for k in range(n):
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - sn * aqk
                    A[q, k] = sn * apk + c * aqk
                for k in range(n):  # V ← V J
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - sn * vkq
                    V[k, q] = sn * vkp + c * vkq
    for i in range(n):
        w[i] = A[i, i]
    for i in range(1, n):  # insertion sort, columns of V with their eigenvalues
        j = i
        while j > 0 and w[j - 1] > w[j]:
            w[j - 1], w[j] = w[j], w[j - 1]
            for k in range(n):
                V[k, j - 1], V[k, j] = V[k, j], V[k, j - 1]
            j -= 1


def _psd_check_(m, P, n, tol, W, L, ev):
    """:func:`_psd_ok_`, with the eigenvalues (:func:`_jacobi_`) where its screen cannot decide."""
    code = _psd_ok(m, P, n, tol, W, L)
    if code >= 0.0:
        return code > 0.5
    _jacobi(W, ev, L, n)
    return not (ev[0] < tol * code)  # code = −scale


def _sqrt_check_(P, L, n, tol, W, ev, V):
    """:func:`_sqrt_psd_`, with the eigen root ``U √max(w, 0)`` where P is not positive definite."""
    code = _sqrt_psd(P, L, n, tol, W)
    if code >= 0.0:
        return code > 0.5
    _jacobi(W, ev, V, n)
    if ev[0] < tol * code:  # code = −scale
        return False
    for i in range(n):
        for j in range(n):
            L[i, j] = V[i, j] * math.sqrt(max(ev[j], 0.0))
    return True


def _sqrt_psd_(P, L, n, tol, W):
    """``L Lᵀ = P`` (:func:`~nlfilter.filters.linalg.sqrt_psd`): Cholesky; the eigen root where P is
    only semi-definite; False where P is non-finite or not PSD. 1.0 done, 0.0 failed, ``−scale``:
    W holds the symmetrized P for the eigen root (:func:`_sqrt_check_`)."""
    if _chol(P, L, n):
        return 1.0
    scale = 1.0
    for i in range(n):
        for j in range(n):
            if not math.isfinite(P[i, j]):
                return 0.0
            scale = max(scale, abs(P[i, j]))
            W[i, j] = 0.5 * (P[i, j] + P[j, i])
    return -scale  # not positive definite: the caller takes the eigen root of W


def _lu_(A, piv, k):
    """LU factorization with partial pivoting of ``A[:k, :k]`` in place; returns ``(ok, sign, logabsdet)``
    (ok False: a zero or non-finite pivot, i.e. singular)."""
    sign, logdet = 1.0, 0.0
    for j in range(k):
        p, best = j, abs(A[j, j])
        for i in range(j + 1, k):
            if abs(A[i, j]) > best:
                p, best = i, abs(A[i, j])
        piv[j] = p
        if not (best > 0.0) or not math.isfinite(best):
            return False, 0.0, 0.0
        if p != j:
            sign = -sign
            for q in range(k):
                A[j, q], A[p, q] = A[p, q], A[j, q]
        d = A[j, j]
        if d < 0:
            sign = -sign
        logdet += math.log(abs(d))
        for i in range(j + 1, k):
            A[i, j] /= d
            a = A[i, j]
            for q in range(j + 1, k):
                A[i, q] -= a * A[j, q]
    return True, sign, logdet


def _lu_solve_(A, piv, k, b):
    """Solve ``A x = b`` in place in ``b[:k]`` with the factors of :func:`_lu_`."""
    for j in range(k):
        p = piv[j]
        if p != j:
            b[j], b[p] = b[p], b[j]
    for i in range(k):
        s = b[i]
        for q in range(i):
            s -= A[i, q] * b[q]
        b[i] = s
    for i in range(k - 1, -1, -1):
        s = b[i]
        for q in range(i + 1, k):
            s -= A[i, q] * b[q]
        b[i] = s / A[i, i]


def _mm_(A, B, C, ni, nk, nj, acc):
    """``C[:ni, :nj] (+)= A[:ni, :nk] @ B[:nk, :nj]`` row by row (axpy: the inner loop runs along
    contiguous rows, which the compiler vectorizes)."""
    for i in range(ni):
        if not acc:
            for j in range(nj):
                C[i, j] = 0.0
        for q in range(nk):
            v = A[i, q]
            if v != 0.0:
                for j in range(nj):
                    C[i, j] += v * B[q, j]


def _tr_(A, At, ni, nj):
    """``At[:nj, :ni] = A[:ni, :nj]ᵀ``."""
    for i in range(ni):
        for j in range(nj):
            At[j, i] = A[i, j]


def _predict_cov_(F, P, N, out, T1, T2, n):
    """``out = F P Fᵀ + N`` (``out`` may be ``P``; ``T1``, ``T2`` scratch)."""
    _tr(F, T1, n, n)
    _mm(P, T1, T2, n, n, n, False)  # P Fᵀ
    for i in range(n):
        for j in range(n):
            out[i, j] = N[i, j]
    _mm(F, T2, out, n, n, n, True)


def _meas_cov_(P, H, R, Ht, C, S, n, mdim):
    """``C = P Hᵀ`` and ``S = H C + R`` (the linearized measurement moments)."""
    _tr(H, Ht, mdim, n)
    _mm(P, Ht, C, n, n, mdim, False)
    for a in range(mdim):
        for c in range(mdim):
            S[a, c] = R[a, c]
    _mm(H, C, S, mdim, n, mdim, True)


def _add_gqg_(G, Q, GQ, out, w, n, r):
    """``out += w · G Q Gᵀ`` (``GQ`` scratch)."""
    for i in range(n):
        for a in range(r):
            s = 0.0
            for c in range(r):
                s += G[i, c] * Q[c, a]
            GQ[i, a] = s
    for i in range(n):
        for j in range(n):
            s = 0.0
            for a in range(r):
                s += GQ[i, a] * G[j, a]
            out[i, j] += w * s


def _condition_(m, P, y, yhat, S, C, H, R, joseph, M, forcing, screen, n, mdim, w, want, ll_out, inn_out, cov_out):
    """The update of :func:`~nlfilter.filters.linalg.gaussian_update` on one path (``m``, ``P`` in
    place): the observed components ``o`` of ``y``, ``K = C_o S_oo⁻¹`` (row by row: ``K_i =
    S_oo⁻¹ C_o,i``, S symmetric, as NumPy's ``solve(S, Cᵀ)ᵀ``), Joseph form ``(I − K H_o) P (I − K
    H_o)ᵀ + K R_oo Kᵀ`` with ``H`` or ``P − K S_oo Kᵀ``, symmetrized; the forcing ``Σ_k M_ijk
    [S⁻¹e]_k`` when ``forcing``; ``screen``: S must be positive definite (Taylor-2). Writes the
    likelihood outputs when ``want``. Returns False for a failed path (singular or screened-out S)."""
    idx, So, Sc, Co, Ho, Ro, K, Kt, KR, e, piv, u, IKH, IKHt, T1 = w
    mo = 0
    for i in range(mdim):
        if not math.isnan(y[i]):
            mo += 1
    if mo == mdim:  # the common case: every component observed
        for i in range(mdim):
            idx[i] = i
    else:  # (filling idx in the counting loop above costs ~60 ns a call: a store-to-load stall)
        q = 0
        for i in range(mdim):
            if not math.isnan(y[i]):
                idx[q] = i
                q += 1
    if screen:  # the innovation covariance must be positive definite (gaussian._pd_mask)
        if mdim == 1:
            if not S[0, 0] > 0.0:
                return False
        else:
            for i in range(mdim):
                for j in range(mdim):
                    So[i, j] = 0.5 * (S[i, j] + S[j, i])
            if not _chol(So, T1, mdim):
                return False
    if want:
        for i in range(mdim):
            inn_out[i] = y[i] - yhat[i]  # NaN where missing
            for j in range(mdim):
                cov_out[i, j] = S[i, j] if mo > 0 else np.nan
    if mo == 0:  # nothing measured on this path: K = 0 (P symmetrized, as the batched update does)
        if want:
            ll_out[0] = 0.0
        for i in range(n):
            for j in range(i):
                v = 0.5 * (P[i, j] + P[j, i])
                P[i, j] = v
                P[j, i] = v
        return True
    for a in range(mo):  # the observed blocks
        ia = idx[a]
        e[a] = y[ia] - yhat[ia]
        for c in range(mo):
            So[a, c] = S[ia, idx[c]]
            Sc[a, c] = So[a, c]
            Ro[a, c] = R[ia, idx[c]]
        for j in range(n):
            Ho[a, j] = H[ia, j]
    for i in range(n):
        for a in range(mo):
            Co[i, a] = C[i, idx[a]]
    ok, sign, logdet = _lu(So, piv, mo)
    if not ok:
        return False
    for i in range(n):  # K_i = S_oo⁻¹ C_o,i
        for a in range(mo):
            u[a] = Co[i, a]
        _lu_solve(So, piv, mo, u)
        for a in range(mo):
            K[i, a] = u[a]
            Kt[a, i] = u[a]
    if want or forcing:
        for a in range(mo):
            u[a] = e[a]
        _lu_solve(So, piv, mo, u)  # S_oo⁻¹ e
        if want:
            if sign > 0:
                q = 0.0
                for a in range(mo):
                    q += e[a] * u[a]
                ll_out[0] = -0.5 * (q + logdet + mo * _LOG_2PI)
            else:
                ll_out[0] = np.nan
    for i in range(n):
        v = 0.0
        for a in range(mo):
            v += K[i, a] * e[a]
        m[i] += v
    if joseph:  # (I − K H_o) P (I − K H_o)ᵀ + K R_oo Kᵀ
        for i in range(n):
            for j in range(n):
                IKH[i, j] = 1.0 if i == j else 0.0
            for a in range(mo):
                v = K[i, a]
                for j in range(n):
                    IKH[i, j] -= v * Ho[a, j]
        _mm(IKH, P, T1, n, n, n, False)
        _tr(IKH, IKHt, n, n)
        _mm(T1, IKHt, P, n, n, n, False)
        _mm(K, Ro, KR, n, mo, mo, False)
        _mm(KR, Kt, P, n, mo, n, True)
    else:  # P − K S_oo Kᵀ
        _mm(K, Sc, KR, n, mo, mo, False)
        for i in range(n):
            for a in range(mo):
                v = KR[i, a]
                for j in range(n):
                    P[i, j] -= v * Kt[a, j]
    if forcing:  # P += Σ_k M_ijk u_k (u = S⁻¹ e on the observed components)
        for i in range(n):
            for j in range(n):
                v = 0.0
                for a in range(mo):
                    v += M[i, j, idx[a]] * u[a]
                P[i, j] += v
    for i in range(n):
        for j in range(i):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v
    return True


_LOG_2PI = math.log(2 * math.pi)


def _write_(means, covs, ll, inn, icov, b, k, m, P, want, absent, l1, i1, c1):
    """Step ``k``'s outputs of path ``b`` (a step measured on no path: log-likelihood 0, NaN innovation)."""
    n = m.shape[0]
    for i in range(n):
        means[b, k, i] = m[i]
        for j in range(n):
            covs[b, k, i, j] = P[i, j]
    if want:
        mdim = i1.shape[0]
        ll[b, k] = 0.0 if absent else l1[0]
        for i in range(mdim):
            inn[b, k, i] = np.nan if absent else i1[i]
            for j in range(mdim):
                icov[b, k, i, j] = np.nan if absent else c1[i, j]


def _mark_(means, covs, ll, inn, icov, want, b, k0):
    """NaN on path ``b`` from step ``k0`` on (a diverged path)."""
    T, n = means.shape[1], means.shape[2]
    for k in range(k0, T):
        for i in range(n):
            means[b, k, i] = np.nan
            for j in range(n):
                covs[b, k, i, j] = np.nan
        if want:
            mdim = inn.shape[2]
            ll[b, k] = np.nan
            for i in range(mdim):
                inn[b, k, i] = np.nan
                for j in range(mdim):
                    icov[b, k, i, j] = np.nan


def _work(n, mdim):
    """The work arrays of :func:`_condition_`."""
    e = np.zeros
    return (e(mdim, np.int64), e((mdim, mdim)), e((mdim, mdim)), e((n, mdim)), e((mdim, n)), e((mdim, mdim)),
            e((n, mdim)), e((mdim, n)), e((n, mdim)), e(mdim), e(mdim, np.int64), e(max(mdim, n)), e((n, n)),
            e((n, n)), e((n, n)))


# ---------------------------------------------------------------------------------------------
# the loops, one per rule kind
# ---------------------------------------------------------------------------------------------
def _alloc_taylor1(ys, m0, Q, N=0):
    """The work arrays of :func:`_steps_taylor1_` (allocated once per run, in NumPy)."""
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    m, P, mp = np.empty(n), np.empty((n, n)), np.empty(n)
    F, C, Hm, S = np.empty((n, n)), np.empty((n, mdim)), np.empty((mdim, n)), np.empty((mdim, mdim))
    Gm, GQ, N = np.empty((n, r)), np.empty((n, r)), np.empty((n, n))
    yhat, FP = np.empty(mdim), np.empty((n, n))
    W, L, ev, V = np.empty((n, n)), np.empty((n, n)), np.empty(n), np.empty((n, n))
    w = _work(n, mdim)
    M0 = np.empty((1, 1, 1))
    yk, l1, i1, c1 = np.empty(mdim), np.empty(1), np.empty(mdim), np.empty((mdim, mdim))
    return (m, P, mp, F, C, Hm, S, Gm, GQ, N, yhat, FP, W, L, ev, V, w, M0, yk, l1, i1, c1, np.empty((n, mdim)))


def _steps_taylor1_(f, fx, h, hx, G, ys, m0, P0, p, Q, R, GQG0, G_const, offset, absent, tol, means, covs, ll, inn, icov, want, step, m, P, mp, F, C, Hm, S, Gm, GQ, N, yhat, FP, W, L, ev, V, w, M0, yk, l1, i1, c1, Ht):
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    for b in range(B):
        for i in range(n):
            m[i] = m0[b, i]
            for j in range(n):
                P[i, j] = P0[b, i, j]
        fail = -1
        for k in range(T):
            if k > 0 or offset:
                t = float(k + offset - 1)
                f(m, t, p, mp)
                fx(m, t, p, F)
                if G_const:
                    for i in range(n):
                        for j in range(n):
                            N[i, j] = GQG0[i, j]
                else:  # G(m) Q G(m)ᵀ
                    G(m, t, p, Gm)
                    for i in range(n):
                        for j in range(n):
                            N[i, j] = 0.0
                    _add_gqg(Gm, Q, GQ, N, 1.0, n, r)
                _predict_cov(F, P, N, P, FP, W, n)  # F P Fᵀ + G Q Gᵀ
                for i in range(n):
                    m[i] = mp[i]
                if not _psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            if not absent[k]:
                t = float(k + offset)
                h(m, t, p, yhat)
                hx(m, t, p, Hm)
                _meas_cov(P, Hm, R, Ht, C, S, n, mdim)  # C = P Hᵀ, S = H C + R
                for a in range(mdim):
                    yk[a] = ys[b, k, a]
                ok = _condition(m, P, yk, yhat, S, C, Hm, R, True, M0, False, False, n, mdim, w, want, l1, i1, c1)
                if not ok or not _psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            _write(means, covs, ll, inn, icov, b, k, m, P, want, absent[k], l1, i1, c1)
        step[b] = fail
        if fail >= 0:
            _mark(means, covs, ll, inn, icov, want, b, fail)


def _steps_scalar_(f, fx, h, hx, G, ys, m0, P0, p, Q, R, GQG0, G_const, offset, absent, tol, outm, outP, ll, inn,
                   icov, want, step, mB, PB):
    """The EKF on one state, one measurement and one noise (``n = m = r = 1``), all paths at each
    step (the paths are independent, so the processor overlaps them: ~20× the one-path loop's
    throughput). The arithmetic of the batched NumPy EKF's scalar branch, in its order:
    ``P⁻ = F (P F) + G Q G``; ``C = P H``, ``S = H C + R``, ``K = C / S``, ``m⁺ = m⁻ + K e``,
    ``P⁺ = (1 − K H)² P⁻ + K² R``. Outputs time-major ``(T, B)`` (contiguous at each step)."""
    B, T = ys.shape[0], ys.shape[1]
    q, r = Q[0, 0], R[0, 0]
    nan = np.nan
    for b in range(B):
        mB[b] = m0[b, 0]
        PB[b] = P0[b, 0, 0]
        step[b] = -1
    for k in range(T):
        pred = k > 0 or offset
        upd = not absent[k]
        tp = float(k + offset - 1)
        tu = float(k + offset)
        for b in range(B):
            if step[b] >= 0:  # diverged earlier: NaN from its step on
                outm[k, b] = nan
                outP[k, b] = nan
                if want:
                    ll[k, b] = nan
                    inn[k, b] = nan
                    icov[k, b] = nan
                continue
            m = mB[b]
            P = PB[b]
            ok = True
            if pred:
                F = fx(m, tp, p)
                if G_const:
                    N = GQG0[0, 0]
                else:
                    g = G(m, tp, p)
                    N = g * q * g
                m = f(m, tp, p)
                P = F * (P * F) + N
                ok = math.isfinite(m) and math.isfinite(P) and not (P < -tol * max(1.0, abs(P)))
            lk, ek, sk = 0.0, nan, nan
            if ok and upd:
                y = ys[b, k, 0]
                if not math.isnan(y):
                    H = hx(m, tu, p)
                    C = P * H
                    S = H * C + r
                    K = C / S
                    e = y - h(m, tu, p)
                    m = m + K * e
                    IKH = 1.0 - K * H
                    P = IKH * IKH * P + K * K * r
                    ok = math.isfinite(m) and math.isfinite(P) and not (P < -tol * max(1.0, abs(P)))
                    if want:
                        lk = -0.5 * (e * e / S + math.log(S) + _LOG_2PI) if S > 0.0 else nan
                        ek, sk = e, S
            if not ok:
                step[b] = k
                m, P, lk, ek, sk = nan, nan, nan, nan, nan
            mB[b] = m
            PB[b] = P
            outm[k, b] = m
            outP[k, b] = P
            if want:
                ll[k, b] = lk
                inn[k, b] = ek
                icov[k, b] = sk


def _nodes_moments_(g, X, GX, wm, wc, m, t, p, N, pdim, n, mean, D, Cov, Cross, cross):
    """``E[g] = Σ w_i g(X_i)``, ``Cov[g] = Σ wc_i D_i D_iᵀ``, ``Cov[x, g] = Σ wc_i (X_i − m) D_iᵀ``
    (``D_i = g(X_i) − E[g]``; node by node, rows contiguous)."""
    for i in range(N):
        g(X[i], t, p, GX[i])
    for a in range(pdim):
        mean[a] = 0.0
    for i in range(N):
        wi = wm[i]
        for a in range(pdim):
            mean[a] += wi * GX[i, a]
    for a in range(pdim):
        for c in range(pdim):
            Cov[a, c] = 0.0
    if cross:
        for j in range(n):
            for a in range(pdim):
                Cross[j, a] = 0.0
    for i in range(N):
        for a in range(pdim):
            D[i, a] = GX[i, a] - mean[a]
        wi = wc[i]
        for a in range(pdim):
            v = wi * D[i, a]
            for c in range(pdim):
                Cov[a, c] += v * D[i, c]
        if cross:
            for j in range(n):
                v = wi * (X[i, j] - m[j])
                if v != 0.0:
                    for a in range(pdim):
                        Cross[j, a] += v * D[i, a]


def _alloc_nodes(ys, m0, Q, N=0):
    """The work arrays of :func:`_steps_nodes_` (allocated once per run, in NumPy)."""
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    pmax = max(n, mdim)
    m, P, L, W, L2 = np.empty(n), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    ev, V = np.empty(n), np.empty((n, n))
    X, GX, D = np.empty((N, n)), np.empty((N, pmax)), np.empty((N, pmax))
    mean, Cov, Cross = np.empty(pmax), np.empty((pmax, pmax)), np.empty((n, pmax))
    Gm, GQ, Nz = np.empty((n, r)), np.empty((n, r)), np.empty((n, n))
    S, C, yhat = np.empty((mdim, mdim)), np.empty((n, mdim)), np.empty(mdim)
    H0, M0 = np.empty((1, 1)), np.empty((1, 1, 1))
    yk, l1, i1, c1 = np.empty(mdim), np.empty(1), np.empty(mdim), np.empty((mdim, mdim))
    w = _work(n, mdim)
    return (m, P, L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz, S, C, yhat, H0, M0, yk, l1, i1, c1, w)


def _steps_nodes_(f, h, G, z, wm, wc, ys, m0, P0, p, Q, R, GQG0, G_const, screen, offset, absent, tol, means, covs, ll, inn, icov, want, step, m, P, L, W, L2, ev, V, X, GX, D, mean, Cov, Cross, Gm, GQ, Nz, S, C, yhat, H0, M0, yk, l1, i1, c1, w):
    B, T, mdim = ys.shape
    n = m0.shape[1]
    r = Q.shape[0]
    N = z.shape[0]
    for b in range(B):
        for i in range(n):
            m[i] = m0[b, i]
            for j in range(n):
                P[i, j] = P0[b, i, j]
        fail = -1
        for k in range(T):
            for phase in range(2):
                if phase == 0 and not (k > 0 or offset):
                    continue
                if phase == 1 and absent[k]:
                    continue
                if not _sqrt_check(P, L, n, tol, W, ev, V):
                    fail = k
                    break
                _tr(L, W, n, n)  # the columns of L as rows (W as scratch)
                for i in range(N):  # X_i = m + L z_i (the sigma and cubature z_i have one nonzero)
                    for j in range(n):
                        X[i, j] = m[j]
                    for q in range(n):
                        v = z[i, q]
                        if v != 0.0:
                            for j in range(n):
                                X[i, j] += v * W[q, j]
                if phase == 0:
                    t = float(k + offset - 1)
                    _nodes_moments(f, X, GX, wm, wc, m, t, p, N, n, n, mean, D, Cov, Cross, False)
                    if G_const:
                        for i in range(n):
                            for j in range(n):
                                Nz[i, j] = GQG0[i, j]
                    else:  # Σ w_i G(X_i) Q G(X_i)ᵀ
                        for i in range(n):
                            for j in range(n):
                                Nz[i, j] = 0.0
                        for i2 in range(N):
                            G(X[i2], t, p, Gm)
                            _add_gqg(Gm, Q, GQ, Nz, wm[i2], n, r)
                    for i in range(n):
                        m[i] = mean[i]
                        for j in range(n):
                            P[i, j] = Cov[i, j] + Nz[i, j]
                    if not _psd_check(m, P, n, tol, W, L2, ev):
                        fail = k
                        break
                else:
                    t = float(k + offset)
                    _nodes_moments(h, X, GX, wm, wc, m, t, p, N, mdim, n, mean, D, Cov, Cross, True)
                    for a in range(mdim):
                        yhat[a] = mean[a]
                        for c in range(mdim):
                            S[a, c] = Cov[a, c] + R[a, c]
                        for j in range(n):
                            C[j, a] = Cross[j, a]
                    for a in range(mdim):
                        yk[a] = ys[b, k, a]
                    ok = _condition(m, P, yk, yhat, S, C, H0, R, False, M0, False, screen, n, mdim, w, want, l1, i1, c1)
                    if not ok or not _psd_check(m, P, n, tol, W, L2, ev):
                        fail = k
                        break
            if fail >= 0:
                break
            _write(means, covs, ll, inn, icov, b, k, m, P, want, absent[k], l1, i1, c1)
        step[b] = fail
        if fail >= 0:
            _mark(means, covs, ll, inn, icov, want, b, fail)


def _hess_trace_(P, A, n, pdim, out):
    """``out_i = Σ_jl P_jl A_ijl`` (004 eqs. 9, 23)."""
    for i in range(pdim):
        s = 0.0
        for j in range(n):
            for q in range(n):
                s += P[j, q] * A[i, j, q]
        out[i] = s


def _quartic_(kind, P, A, tr, n, pdim, AP, out):
    """The fourth-moment term added to ``out (pdim, pdim)``: 1 = −¼ tr tᵀ, 2 = ½ tr(A_i P A_j P)."""
    if kind == 1:
        for i in range(pdim):
            for j in range(pdim):
                out[i, j] -= 0.25 * tr[i] * tr[j]
    elif kind == 2:
        for i in range(pdim):  # (A_i P)_ac
            for a in range(n):
                for c in range(n):
                    s = 0.0
                    for q in range(n):
                        s += A[i, a, q] * P[q, c]
                    AP[i, a, c] = s
        for i in range(pdim):
            for j in range(pdim):
                s = 0.0
                for a in range(n):
                    for c in range(n):
                        s += AP[i, a, c] * AP[j, c, a]
                out[i, j] += 0.5 * s


def _alloc_taylor2(ys, m0, Q, N=0):
    """The work arrays of :func:`_steps_taylor2_` (allocated once per run, in NumPy)."""
    B, T, mdim = ys.shape
    n = m0.shape[1]
    pmax = max(n, mdim)
    m, P, mp = np.empty(n), np.empty((n, n)), np.empty(n)
    F, Hm, C, S, FP = np.empty((n, n)), np.empty((mdim, n)), np.empty((n, mdim)), np.empty((mdim, mdim)), np.empty((n, n))
    Af, Ah = np.empty((n, n, n)), np.empty((mdim, n, n))
    tr, AP = np.empty(pmax), np.empty((pmax, n, n))
    Cf = np.empty((n, n))
    M = np.empty((n, n, mdim))
    yhat = np.empty(mdim)
    W, L, ev, V = np.empty((n, n)), np.empty((n, n)), np.empty(n), np.empty((n, n))
    w = _work(n, mdim)
    yk, l1, i1, c1 = np.empty(mdim), np.empty(1), np.empty(mdim), np.empty((mdim, mdim))
    return (m, P, mp, F, Hm, C, S, FP, Af, Ah, tr, AP, Cf, M, yhat, W, L, ev, V, w, yk, l1, i1, c1, np.empty((n, mdim)))


def _steps_taylor2_(f, fx, fxx, h, hx, hxx, ys, m0, P0, p, R, GQG0, second, dyn_kind, meas_kind, force_kind, joseph, offset, absent, tol, means, covs, ll, inn, icov, want, step, m, P, mp, F, Hm, C, S, FP, Af, Ah, tr, AP, Cf, M, yhat, W, L, ev, V, w, yk, l1, i1, c1, Ht):
    B, T, mdim = ys.shape
    n = m0.shape[1]
    for b in range(B):
        for i in range(n):
            m[i] = m0[b, i]
            for j in range(n):
                P[i, j] = P0[b, i, j]
        fail = -1
        for k in range(T):
            if k > 0 or offset:
                t = float(k + offset - 1)
                f(m, t, p, mp)
                fx(m, t, p, F)
                if second:
                    fxx(m, t, p, Af)
                    _hess_trace(P, Af, n, n, tr)
                    for i in range(n):
                        mp[i] += 0.5 * tr[i]
                _predict_cov(F, P, GQG0, Cf, FP, W, n)  # F P Fᵀ + G Q Gᵀ (004 eq. 19)
                if second:
                    _quartic(dyn_kind, P, Af, tr, n, n, AP, Cf)
                for i in range(n):  # symmetrized (Taylor-2)
                    for j in range(n):
                        P[i, j] = 0.5 * (Cf[i, j] + Cf[j, i])
                for i in range(n):
                    m[i] = mp[i]
                if not _psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            if not absent[k]:
                t = float(k + offset)
                h(m, t, p, yhat)
                hx(m, t, p, Hm)
                if second:
                    hxx(m, t, p, Ah)
                    _hess_trace(P, Ah, n, mdim, tr)
                    for a in range(mdim):
                        yhat[a] += 0.5 * tr[a]
                _meas_cov(P, Hm, R, Ht, C, S, n, mdim)  # C = P Hᵀ, S = H C + R
                force = False
                if second:
                    _quartic(meas_kind, P, Ah, tr, n, mdim, AP, S)
                    if force_kind == 1:  # M_ijk = −½ P_ij (P h_xx)_k
                        force = True
                        for i in range(n):
                            for j in range(n):
                                for a in range(mdim):
                                    M[i, j, a] = -0.5 * P[i, j] * tr[a]
                    elif force_kind == 2:  # M_ijk = (P h_xx^(k) P)_ij
                        force = True
                        for a in range(mdim):
                            for i in range(n):
                                for c in range(n):
                                    s = 0.0
                                    for q in range(n):
                                        s += P[i, q] * Ah[a, q, c]
                                    FP[i, c] = s
                            for i in range(n):
                                for j in range(n):
                                    s = 0.0
                                    for c in range(n):
                                        s += FP[i, c] * P[c, j]
                                    M[i, j, a] = s
                for a in range(mdim):
                    yk[a] = ys[b, k, a]
                ok = _condition(m, P, yk, yhat, S, C, Hm, R, joseph, M, force, True, n, mdim, w, want, l1, i1, c1)
                if not ok or not _psd_check(m, P, n, tol, W, L, ev):
                    fail = k
                    break
            _write(means, covs, ll, inn, icov, b, k, m, P, want, absent[k], l1, i1, c1)
        step[b] = fail
        if fail >= 0:
            _mark(means, covs, ll, inn, icov, want, b, fail)


if _nb is not None:  # compiled on first use (lazily, by numba)
    # the steps and their one-path helpers allocate nothing and run without reference counting
    # (_nrt=False): with it, every array argument of a call costs an atomic incref/decref pair
    # (~60 ns a call, measured), and a raw function can call raw functions only. The helpers are
    # not inlined (numba's inline="always" gains 30 % at n ≤ 2, nothing from n = 4, and triples
    # the compile time: 10-20 s per model and rule kind against 3-7 s); the model's functions are
    # (model_kernels: small)
    _chol = _jit(_chol_, _nrt=False)
    _psd_ok = _jit(_psd_ok_, _nrt=False)
    _sqrt_psd = _jit(_sqrt_psd_, _nrt=False)
    _lu = _jit(_lu_, _nrt=False)
    _lu_solve = _jit(_lu_solve_, _nrt=False)
    _mm = _jit(_mm_, _nrt=False)
    _predict_cov = _jit(_predict_cov_, _nrt=False)
    _add_gqg = _jit(_add_gqg_, _nrt=False)
    _meas_cov = _jit(_meas_cov_, _nrt=False)
    _tr = _jit(_tr_, _nrt=False)
    _condition = _jit(_condition_, _nrt=False)
    _write = _jit(_write_, _nrt=False)
    _nodes_moments = _jit(_nodes_moments_, _nrt=False)
    _hess_trace = _jit(_hess_trace_, _nrt=False)
    _quartic = _jit(_quartic_, _nrt=False)
    _jacobi = _jit(_jacobi_, _nrt=False)
    _psd_check = _jit(_psd_check_, _nrt=False)
    _sqrt_check = _jit(_sqrt_check_, _nrt=False)
    _mark = _jit(_mark_, _nrt=False)



# ---------------------------------------------------------------------------------------------
# the entry point of Filter.run(..., backend="numba")
# ---------------------------------------------------------------------------------------------
_FUNCTION_ARGS = {"taylor1": ("f", "fx", "h", "hx", "G"), "nodes": ("f", "h", "G"),
                  "taylor2": ("f", "fx", "fxx", "h", "hx", "hxx")}


#: loops of models up to this state and measurement dimension are specialized: the dimensions
#: compiled in as constants and the helpers inlined (the compiler then unrolls the small loops:
#: 2-5× faster at n ≤ 4 than the general loop, at a compile time of 15-45 s per model and rule
#: kind instead of 3-7 s); larger models take the general loop. The arithmetic is the same
#: (no fast-math), so both give the same numbers to the last bit.
SPECIALIZE_UP_TO = 4

_HELPERS = ("_add_gqg_", "_predict_cov_", "_meas_cov_", "_chol_", "_psd_ok_", "_psd_check_", "_sqrt_psd_", "_sqrt_check_", "_jacobi_", "_lu_", "_lu_solve_",
            "_mm_", "_tr_", "_condition_", "_write_", "_mark_", "_nodes_moments_", "_hess_trace_", "_quartic_")
_STEPS = ("_steps_taylor1_", "_steps_nodes_", "_steps_taylor2_", "_steps_scalar_")
_SOURCE = {}  # read once at import: later edits of this file cannot skew the compiled code


def _source_of(name):
    if name not in _SOURCE:
        _SOURCE[name] = inspect.getsource(globals()[name])
    return _SOURCE[name]


def _inlined():
    """A namespace with every helper compiled ``inline="always"`` (calling each other inlined)."""
    ns = dict(globals())
    for h in _HELPERS:
        exec(compile(_source_of(h), f"<nlfilter.compiled {h}>", "exec"), ns)  # noqa: S102 - this module's code
    for h in _HELPERS:
        ns[h[:-1]] = _jit(ns[h], _nrt=False, inline="always")
    return ns


def _steps(kind: str, fns: dict, key, scalar: bool = False, dims=None):
    """The raw steps of ``kind`` with the model's functions bound as globals (numba then calls
    them directly and can inline them; passed as arguments they would be first-class function
    pointers), compiled once per model (``key``: its kernel store) and kind. ``dims``: ``(n, m,
    r, N)`` compiled in as constants (``N`` None: read from the nodes), with the helpers inlined
    (:data:`SPECIALIZE_UP_TO`)."""
    store = _KERNELS[key]
    name = ("steps", kind, fns["fxx"] is _unused3 if kind == "taylor2" else scalar, dims)
    if name not in store:
        py = "_steps_scalar_" if scalar else {"taylor1": "_steps_taylor1_", "nodes": "_steps_nodes_",
                                              "taylor2": "_steps_taylor2_"}[kind]
        src = _source_of(py)
        head, rest = src.split("(", 1)
        params, body = rest.split("):\n", 1)
        plist = [x.strip() for x in params.replace("\n", " ").split(",") if x.strip()]
        drop = _FUNCTION_ARGS[kind]
        if tuple(plist[:len(drop)]) != drop:  # pragma: no cover - a guard on this module's own code
            raise RuntimeError(f"_steps: {py} does not start with {drop}")
        if dims is not None:
            n, m, r, N = dims
            for old, new in (("    B, T, mdim = ys.shape\n", f"    B, T = ys.shape[0], ys.shape[1]\n    mdim = {m}\n"),
                             ("    n = m0.shape[1]\n", f"    n = {n}\n"), ("    r = Q.shape[0]\n", f"    r = {r}\n"),
                             ("    N = z.shape[0]\n", f"    N = {N}\n" if N is not None else "    N = z.shape[0]\n")):
                body = body.replace(old, new, 1)
        src = head + "(" + ", ".join(plist[len(drop):]) + "):\n" + body
        ns = _inlined() if dims is not None else dict(globals())
        ns.update({a: fns[{"fx": "f_x", "hx": "h_x"}.get(a, a)] if scalar else fns[a] for a in drop})
        exec(compile(src, f"<nlfilter.compiled steps {kind}>", "exec"), ns)  # noqa: S102 - this module's code
        store[name] = _jit(ns[py], _nrt=False)
    return store[name]


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


def run_compiled(flt, yf, batch, m0, P0, on, loglik, progress=False):
    """:meth:`Filter.run` of ``flt`` on ``yf (B, T, m)`` by the compiled loop: the same
    :class:`~nlfilter.filters.estimates.Estimates` (path-major ``(B, T, ...)``, reshaped to ``batch``);
    ``progress``: a bar over blocks of paths."""
    from .rules import FORM_TABLE
    reason = unsupported(flt)
    if reason is not None:
        raise TypeError(f"backend: 'numba' cannot run {type(flt).__name__} here: {reason}; use backend='numpy'")
    md = flt.model
    B, T, mdim = yf.shape
    n = md.n
    prior = flt.init(m0, P0, batch)
    mean0 = _plain(prior.mean).reshape(B, n)
    cov0 = _plain(prior.cov).reshape(B, n, n)
    ys = _plain(yf)
    offset = 0 if flt.start == "update" else 1
    absent = np.isnan(ys).all(axis=(0, 2)) if B else np.zeros(T, bool)
    vals = md._values.values
    p = np.array([float(vals[s]) for s in md._psyms], float)
    Q = _plain(md.Q)
    R = _plain(md.R)
    G_const = bool(md._G_fixed)
    GQG0 = _plain(md.GQGT(np.zeros(n))) if G_const else np.zeros((n, n))
    means = np.empty((B, T, n))
    covs = np.empty((B, T, n, n))
    want = bool(loglik)
    ll = np.empty((B, T) if want else (0, 0))
    inn = np.empty((B, T, mdim) if want else (0, 0, 0))
    icov = np.empty((B, T, mdim, mdim) if want else (0, 0, 0, 0))
    step = np.full(B, -1, np.int64)
    kind = _rule_kind(flt)
    fns = model_kernels(md, second=kind == "taylor2" and flt.rule.second)
    key = md._kernels["f"]

    def dims(N):
        return (n, mdim, md.r, None) if max(n, mdim) <= SPECIALIZE_UP_TO else None  # N stays: UKF/CKF/GHKF share

    if kind == "taylor1" and n == mdim == md.r == 1:  # the scalar batch loop, time-major outputs
        sk = scalar_kernels(md)
        steps = _steps(kind, sk, key, scalar=True)
        outm, outP = np.empty((T, B)), np.empty((T, B))
        sll, sinn, sicov = (np.empty((T, B)), np.empty((T, B)), np.empty((T, B))) if want else (ll, ll, ll)
        steps(ys, mean0, cov0, p, Q, R, GQG0, G_const, offset, absent, PSD_TOL, outm, outP, sll, sinn, sicov, want,
              step, np.empty(B), np.empty(B))
        means, covs = outm.T[:, :, None], outP.T[:, :, None, None]  # (B, T, 1) views
        if want:
            ll, inn, icov = sll.T, sinn.T[:, :, None], sicov.T[:, :, None, None]
        return _finish(flt, on, step, batch, means, covs, want, ll, inn, icov)
    if kind == "taylor1":
        steps = _steps(kind, {"f": fns["f"], "fx": fns["f_x"], "h": fns["h"], "hx": fns["h_x"], "G": fns["G"]}, key,
                       dims=dims(0))
        ws = _alloc_taylor1(ys, mean0, Q)
        head = (Q, R, GQG0, G_const)
    elif kind == "nodes":
        z, wm, wc = _nodes(flt, n)
        steps = _steps(kind, {"f": fns["f"], "h": fns["h"], "G": fns["G"]}, key, dims=dims(None))
        ws = _alloc_nodes(ys, mean0, Q, z.shape[0])
        head = (Q, R, GQG0, G_const, bool(getattr(flt.rule, "screen", False)))  # a table with negative weights
    else:
        rule = flt.rule
        spec = FORM_TABLE[rule.form]
        second = rule.second
        # first-order: the Hessian slots are never called; a compiled no-op fills them
        fxx, hxx = (fns["f_xx"], fns["h_xx"]) if second else (_unused3, _unused3)
        kinds = ((_KIND[spec[0]], _KIND[spec[1]], _FORCE[spec[2]]) if second else (0, 0, 0))
        steps = _steps(kind, {"f": fns["f"], "fx": fns["f_x"], "fxx": fxx, "h": fns["h"], "hx": fns["h_x"],
                              "hxx": hxx}, key, dims=dims(0))
        ws = _alloc_taylor2(ys, mean0, Q)
        head = (R, GQG0, second, *kinds, spec[1] == "none")

    def block(lo, hi):
        common = (offset, absent, PSD_TOL, means[lo:hi], covs[lo:hi], ll[lo:hi] if want else ll,
                  inn[lo:hi] if want else inn, icov[lo:hi] if want else icov, want, step[lo:hi])
        pre = (z, wm, wc) if kind == "nodes" else ()
        steps(*pre, ys[lo:hi], mean0[lo:hi], cov0[lo:hi], p, *head, *common, *ws)

    try:
        if progress and B > 1:
            from tqdm.auto import tqdm
            size = max(1, -(-B // 20))
            for lo in tqdm(range(0, B, size), desc=f"{flt.name} (numba)", leave=False):
                block(lo, min(B, lo + size))
        else:
            block(0, B)
    except _nb.core.errors.TypingError as exc:  # a function of the model numba cannot compile
        raise TypeError(f"backend: numba cannot compile {type(flt).__name__} on this model ({str(exc).splitlines()[0]}); "
                        "use backend='numpy'") from exc
    return _finish(flt, on, step, batch, means, covs, want, ll, inn, icov)


def _finish(flt, on, step, batch, means, covs, want, ll, inn, icov):
    """Raise or return the :class:`~nlfilter.filters.estimates.Estimates` of a compiled run. As the
    run loop (:meth:`~nlfilter.filters.recorder.Recorder.record`), a path whose log-likelihood term is
    not finite before any other failure diverges there (raised, or marked with
    ``extras["loglik_failed"]``; its outputs from that step on NaN)."""
    from .base import Estimates, loglik_divergence
    failed = None
    if want:
        T = ll.shape[1]
        llbad = ~np.isfinite(ll)
        first = np.where(llbad.any(axis=1), np.argmax(llbad, axis=1), T)
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


def _unused3_(x, t, p, out):  # pragma: no cover - never called (first-order form)
    pass


if _nb is not None:
    _unused3 = _jit(_unused3_, _nrt=False)


for _name in _HELPERS + _STEPS:  # the sources, read now (see _SOURCE)
    _source_of(_name)
