"""NumPy's calls without their Python wrappers, for the filters' per-step hot paths: the same C
functions, the same numbers, microseconds less a call. Standard NumPy where a version lacks them."""

from __future__ import annotations

import numpy as np

try:  # np.einsum without ``optimize`` calls this, after its Python wrapper: the same numbers
    from numpy._core._multiarray_umath import c_einsum as einsum
except ImportError:  # pragma: no cover - a NumPy without it
    einsum = np.einsum

try:  # np.dot calls this, after its Python dispatcher: the same numbers
    from numpy._core._multiarray_umath import dot
except ImportError:  # pragma: no cover - a NumPy without it
    dot = np.dot

try:  # np.errstate's context variable, set and reset without its Python wrapper (µs a call)
    from numpy._core._multiarray_umath import _make_extobj
    from numpy._core._ufunc_config import _extobj_contextvar
except ImportError:  # pragma: no cover - a NumPy without them: np.errstate
    _extobj_contextvar = None

__all__ = ["dot", "einsum", "one_path", "quiet"]

_QUIET = (None, None)  # (the error state it was made from, that state with over/invalid/divide ignored,
#                        or None when it ignores them already)
_OFF = ("over", "invalid", "divide")


def quiet(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` with NumPy's overflow/invalid/divide warnings off, as under
    ``np.errstate(over="ignore", invalid="ignore", divide="ignore")`` (the same state: made from
    the current one, kept while that one is current; ``fn`` called as it comes when the current
    state ignores the three already: the run loops')."""
    if _extobj_contextvar is None:  # pragma: no cover
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return fn(*args, **kwargs)
    global _QUIET
    cur, q = _extobj_contextvar.get(), _QUIET  # one pair, read and replaced whole (threads)
    if q[0] is not cur:
        err = np.geterr()
        off = all(err[k] == "ignore" for k in _OFF)
        q = _QUIET = (cur, None if off else _make_extobj(over="ignore", invalid="ignore", divide="ignore"))
    if q[1] is None:
        return fn(*args, **kwargs)
    token = _extobj_contextvar.set(q[1])
    try:
        return fn(*args, **kwargs)
    finally:
        _extobj_contextvar.reset(token)


_F8 = np.dtype(float)


def one_path(first, *arrays):
    """The 2-D matrices of one path's operands — ``first (1, r, c)`` with r, c ≥ 2, the others ``(1, r, c)``
    or ``(r, c)`` (None: kept None) — which :func:`dot` multiplies as ``@`` does; None where ``first`` is
    not such, one is a batch, or ``np.dot`` would copy or convert one (not C- or Fortran-contiguous,
    unaligned, not float64): then ``@``. For matrices of at least 2 x 2, ``dot`` of two such makes the
    BLAS call of matmul's loop (``gemm``, or ``syrk`` for ``A Aᵀ``, with the same transposition flags,
    leading dimensions and scalars: NumPy's ``cblas_matrixproduct``), the same numbers for about half
    matmul's call cost."""
    s = first.shape
    if len(s) != 3 or s[0] != 1 or s[1] < 2 or s[2] < 2:
        return None
    out = []
    for A in (first, *arrays):
        if A is not None:
            if A.dtype is not _F8 or A.flags.num & _LAYOUT <= _ALIGNED:  # (relaxed strides: a length-1 axis is
                return None  # no obstacle to contiguity)
            if A.ndim == 3:
                if A.shape[0] != 1:
                    return None
                A = A[0]
            elif A.ndim != 2:
                return None
        out.append(A)
    return out


_ALIGNED, _LAYOUT = 0x100, 0x103  # NumPy's flag bits: aligned, and C- or Fortran-contiguous
