"""One-path linear algebra of the compiled loop, allocating nothing (work arrays come from the
caller): Cholesky, the divergence test of :func:`~nlfilter.filters.linalg.bad_paths` (a Cholesky
screen, then cyclic Jacobi eigenvalues where it cannot decide), the square root of
:func:`~nlfilter.filters.linalg.sqrt_psd`, LU with partial pivoting, products and transposes.

Each kernel is written as Python (``name_``, whose source :mod:`.build` compiles again inlined
for the specialized loops) and compiled as ``name`` (numba, without reference counting).
"""

from __future__ import annotations

import math

from .support import jit

__all__ = ["SOURCES", "chol", "pd_ok", "psd_ok", "jacobi", "psd_check", "psd_root", "psd_exact", "sqrt_check", "sqrt_psd", "lu",
           "lu_solve", "mm", "symmetrize", "transpose"]


def chol_(A, L, n):
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


def pd_ok_(A, n):
    """Whether the symmetric ``A[:n, :n]`` is positive definite as its Cholesky factorization
    (:func:`chol_`) decides it — every pivot > 0 — by symmetric elimination on its lower triangle
    (overwritten) without square roots: the same pivots to rounding, at about half the latency of
    the factor's square roots and divisions (a decision only: no factor kept)."""
    for j in range(n):
        d = A[j, j]
        if not d > 0.0:  # also False for NaN
            return False
        inv = 1.0 / d
        for i in range(j + 1, n):
            f = A[i, j] * inv
            for k in range(j + 1, i + 1):
                A[i, k] -= f * A[k, j]
    return True


def psd_ok_(m, P, n, tol, W):
    """Not :func:`~nlfilter.filters.linalg.bad_paths`: finite, and the smallest eigenvalue of the
    symmetrized ``P`` ≥ ``−tol·max(1, max|P|)``. 1.0 yes, 0.0 no, ``−scale`` undecided (W then
    holds the symmetrized P, for :func:`psd_check_`)."""
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
    # the Cholesky screen of linalg._screen_ok (never weaker than the exact test: where it passes,
    # the smallest eigenvalue of the symmetrized P is above −tol·max(1, max P_ii)/2 but for the
    # factorization's rounding, ~n·eps·max|P|), decided by pd_ok_; then exact
    dmax = 2.0
    for i in range(n):
        if 2.0 * P[i, i] > dmax:
            dmax = 2.0 * P[i, i]
    for i in range(n):
        for j in range(i):
            W[i, j] = P[i, j] + P[j, i]
        W[i, i] = P[i, i] + P[i, i] + 0.5 * tol * dmax
    if pd_ok(W, n):
        return 1.0
    for i in range(n):
        for j in range(n):
            W[i, j] = 0.5 * (P[i, j] + P[j, i])
    return -scale  # undecided: the caller takes the eigenvalues of W


def jacobi_(A, w, V, n):
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


def psd_check_(m, P, n, tol, W, L, ev):
    """:func:`psd_ok_`, with the eigenvalues (:func:`jacobi_`) where its screen cannot decide."""
    code = psd_ok(m, P, n, tol, W)
    if code >= 0.0:
        return code > 0.5
    jacobi(W, ev, L, n)
    return not (ev[0] < tol * code)  # code = −scale


def psd_root_(m, P, n, tol, W, L, ev, R, Pc):
    """:func:`psd_check_`, keeping the Cholesky factor of ``P`` for the next kernel's square root
    (:func:`~.step_kernels.nodes_points_`): ``R`` the factor of ``P``'s lower triangle (what
    :func:`chol_` reads) and ``Pc`` that lower triangle, where the factorization succeeds (``Pc[0, 0]``
    NaN where it does not). Its success decides as :func:`psd_ok_`'s screen does (never weaker than
    the exact test: the factor says the lower triangle's matrix has no eigenvalue below
    ``−n³·eps·max|P|``, and the symmetrized ``P`` differs from it by at most ``n·d/2``, ``d`` the
    largest ``|P_ij − P_ji|``, ≤ ``tol/2`` when ``d ≤ tol/n``, inside the exact threshold
    ``−tol·max(1, max|P|)``); m and P finite (their sum: an overflow defers to :func:`psd_check_`).
    For ``n ≤ 2``, :func:`psd_check_` itself (its closed forms; no factor kept)."""
    if n <= 2:
        return psd_check(m, P, n, tol, W, L, ev)
    s, d = 0.0, 0.0
    for i in range(n):
        s += m[i]
        for j in range(n):
            s += P[i, j]
        for j in range(i):
            d = max(d, abs(P[i, j] - P[j, i]))
    if chol(P, R, n):
        for i in range(n):
            for j in range(i + 1):
                Pc[i, j] = P[i, j]
        if math.isfinite(s) and n * d <= tol and n <= 64:  # 64: linalg.SCREEN_MAX_N
            return True
    else:
        Pc[0, 0] = math.nan
    return psd_exact(m, P, n, tol, W, L, ev)


def psd_exact_(m, P, n, tol, W, L, ev):
    """:func:`psd_check_` where :func:`psd_root_` cannot decide (rare): a function of its own in the
    specialized loops, not expanded into their text (``build._CALLED``: a shorter compile)."""
    return psd_check(m, P, n, tol, W, L, ev)


def sqrt_check_(P, L, n, tol, W, ev, V):
    """:func:`sqrt_psd_`, with the eigen root ``U √max(w, 0)`` where P is not positive definite."""
    code = sqrt_psd(P, L, n, tol, W)
    if code >= 0.0:
        return code > 0.5
    jacobi(W, ev, V, n)
    if ev[0] < tol * code:  # code = −scale
        return False
    for i in range(n):
        for j in range(n):
            L[i, j] = V[i, j] * math.sqrt(max(ev[j], 0.0))
    return True


def sqrt_psd_(P, L, n, tol, W):
    """``L Lᵀ = P`` (:func:`~nlfilter.filters.linalg.sqrt_psd`): Cholesky; the eigen root where P is
    only semi-definite; False where P is non-finite or not PSD. 1.0 done, 0.0 failed, ``−scale``:
    W holds the symmetrized P for the eigen root (:func:`sqrt_check_`)."""
    if chol(P, L, n):
        return 1.0
    scale = 1.0
    for i in range(n):
        for j in range(n):
            if not math.isfinite(P[i, j]):
                return 0.0
            scale = max(scale, abs(P[i, j]))
            W[i, j] = 0.5 * (P[i, j] + P[j, i])
    return -scale  # not positive definite: the caller takes the eigen root of W


def lu_(A, piv, k):
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


def lu_solve_(A, piv, k, b):
    """Solve ``A x = b`` in place in ``b[:k]`` with the factors of :func:`lu_`."""
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


def mm_(A, B, C, ni, nk, nj, acc):
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


def symmetrize_(P, n):
    """``P[:n, :n] = ½ (P + Pᵀ)`` in place."""
    for i in range(n):
        for j in range(i):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v


def transpose_(A, At, ni, nj):
    """``At[:nj, :ni] = A[:ni, :nj]ᵀ``."""
    for i in range(ni):
        for j in range(nj):
            At[j, i] = A[i, j]


#: the Python sources of this module's kernels (compiled below; inlined by :mod:`.build`)
SOURCES = (chol_, pd_ok_, psd_ok_, jacobi_, psd_check_, psd_root_, psd_exact_, sqrt_check_, sqrt_psd_, lu_, lu_solve_, mm_,
           symmetrize_, transpose_)

# raw functions (_nrt=False): no reference counting; with it, every array argument of a call costs
# an atomic incref/decref pair (~60 ns a call, measured), and a raw function can call raw ones only
chol = jit(chol_, _nrt=False)
pd_ok = jit(pd_ok_, _nrt=False)
psd_ok = jit(psd_ok_, _nrt=False)
jacobi = jit(jacobi_, _nrt=False)
psd_check = jit(psd_check_, _nrt=False)
psd_root = jit(psd_root_, _nrt=False)
psd_exact = jit(psd_exact_, _nrt=False)
sqrt_check = jit(sqrt_check_, _nrt=False)
sqrt_psd = jit(sqrt_psd_, _nrt=False)
lu = jit(lu_, _nrt=False)
lu_solve = jit(lu_solve_, _nrt=False)
mm = jit(mm_, _nrt=False)
symmetrize = jit(symmetrize_, _nrt=False)
transpose = jit(transpose_, _nrt=False)
