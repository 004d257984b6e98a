"""The two kernels of the square-root filters (:mod:`nlfilter.filters.square_root`): ``tria``, a
lower-triangular factor of ``A Aᵀ`` by QR (Householder, backward stable), and rank-one Cholesky
downdates (the terms with negative weights, which no QR column can carry). Batch-first and pure,
as :mod:`nlfilter.filters.linalg`."""

from __future__ import annotations

import numpy as np

__all__ = ["tria", "downdate"]


def tria(A: np.ndarray) -> np.ndarray:
    """The lower-triangular ``L (..., p, p)`` with ``L Lᵀ = A Aᵀ`` and ``L_ii ≥ 0``, for ``A (..., p, q)``:
    ``Lᵀ`` is the R of a QR factorization of ``Aᵀ`` (Householder, backward stable), its columns' signs
    made non-negative on the diagonal (for a positive definite ``A Aᵀ`` this is its Cholesky factor).
    Non-finite entries give NaN (the caller's path check reports them).

    >>> A = np.array([[1.0, 2.0, 0.5], [0.0, 1.0, 3.0]])
    >>> L = tria(A)
    >>> bool(np.allclose(L @ L.T, A @ A.T)), bool(L[0, 1] == 0), bool((np.diag(L) >= 0).all())
    (True, True, True)
    """
    p, q = A.shape[-2:]
    if q < p:  # fewer columns than rows: zero columns change nothing in A Aᵀ
        A = np.concatenate([A, np.zeros((*A.shape[:-1], p - q))], axis=-1)
    L = np.linalg.qr(A.swapaxes(-1, -2), mode="r").swapaxes(-1, -2)
    d = np.diagonal(L, axis1=-2, axis2=-1)
    return L * np.where(d < 0, -1.0, 1.0)[..., None, :]


def downdate(L: np.ndarray, vs) -> tuple:
    """``(L', failed)``: the lower-triangular ``L'`` with ``L' L'ᵀ = L Lᵀ − Σ_j v_j v_jᵀ`` for the
    vectors ``vs`` (each ``(..., p)``), by rank-one Cholesky downdates (hyperbolic rotations, column
    by column: ``r = √(L_kk² − x_k²)``, ``c = r/L_kk``, ``s = x_k/L_kk``; Golub & Van Loan, *Matrix
    Computations*, §6.5.4); ``L`` lower-triangular with ``L_kk ≥ 0``. ``failed (...)``: the paths where
    the result is not positive definite (``L_kk² ≤ x_k²`` with ``x_k ≠ 0``); their factor is NaN.
    None for no vector.

    >>> L = np.linalg.cholesky(np.array([[4.0, 2.0], [2.0, 3.0]]))
    >>> Ld, failed = downdate(L, [np.array([1.0, 0.5])])
    >>> bool(np.allclose(Ld @ Ld.T, [[3.0, 1.5], [1.5, 2.75]])), bool(failed)
    (True, False)
    """
    if not vs:
        return L, None
    p = L.shape[-1]
    L = np.array(L, dtype=float)  # a copy: updated column by column
    failed = np.zeros(L.shape[:-2], bool)
    for v in vs:
        x = np.array(np.broadcast_to(v, L.shape[:-1]), dtype=float)
        for k in range(p):
            Lkk, xk = L[..., k, k], x[..., k]
            r2 = Lkk * Lkk - xk * xk
            skip = xk == 0  # nothing to remove along this column: the identity rotation
            ok = skip | (r2 > 0)
            failed |= ~ok
            go = ok & ~skip
            Ls = np.where(go, Lkk, 1.0)
            r = np.sqrt(np.where(go, r2, 1.0))
            c, s = np.where(go, r / Ls, 1.0), np.where(go, xk / Ls, 0.0)
            L[..., k, k] = np.where(go, r, Lkk)
            col = (L[..., k + 1:, k] - s[..., None] * x[..., k + 1:]) / c[..., None]
            L[..., k + 1:, k] = col
            x[..., k + 1:] = c[..., None] * x[..., k + 1:] - s[..., None] * col
    if failed.any():
        L[failed] = np.nan
    return L, failed
