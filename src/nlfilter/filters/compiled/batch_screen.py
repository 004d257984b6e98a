"""The divergence test of the EKF's batch-inner loop (:mod:`.batch_loop`, :mod:`.batch_kernels`): a
block of paths, the paths last (``m (n, NB)``, ``P (n, n, NB)``) — the screen of
:func:`~.path_linalg.psd_ok_` on every lane at once (finite, and ``P + Pᵀ`` with a ``tol``-sized
diagonal boost positive definite, decided as :func:`~.path_linalg.pd_ok_` decides it), the one-path
test (:func:`~.path_linalg.psd_check_`) on a lane the screen does not pass, and a failed lane taken
out of the block.

Sources, never called as Python: compiled in the batch-inner loop's module (:mod:`.batch_loop`:
``psd_check``, ``ns`` and these kernels without their trailing underscore are names of that module)."""

from __future__ import annotations

__all__ = ["SOURCES"]


def bpd_ok_(A, n, nb, d, f, ok):
    """``ok[b]`` set to 0.0 where lane ``b`` of the symmetric ``A`` has no Cholesky factor: :func:`~.batch_kernels.bchol_`'s
    decision by symmetric elimination without square roots on A's lower triangle (overwritten), as
    :func:`~.path_linalg.pd_ok_` (``d``, ``f``: work vectors)."""
    for j in range(n):
        for b in range(nb):
            ok[b] = ok[b] if A[j, j, b] > 0.0 else 0.0
        for b in range(nb):
            s = A[j, j, b]
            d[b] = 1.0 / s if s > 0.0 else 0.0
        for i in range(j + 1, n):
            for b in range(nb):
                f[b] = A[i, j, b] * d[b]
            for k in range(j + 1, i + 1):
                for b in range(nb):
                    A[i, k, b] -= f[b] * A[k, j, b]


def bscreen_(M, P, n, nb, tol, W, L, d, acc, ok):
    """``ok[b] = 1.0`` where lane ``b`` passes the Cholesky screen of :func:`~.path_linalg.psd_ok_`
    (finite ``m`` and ``P``, ``P + Pᵀ + ½ tol·max(2, 2 max P_ii) I`` positive definite), else 0.0
    (failed or undecided: :func:`~.path_linalg.psd_check_` decides, on that lane alone)."""
    big = 1.7976931348623157e308
    for b in range(nb):
        ok[b] = 1.0
        d[b] = 2.0
    for i in range(n):  # (one array stored per loop body: the loops vectorize)
        for b in range(nb):
            ok[b] = ok[b] if abs(M[i, b]) <= big else 0.0
        for b in range(nb):
            d[b] = max(d[b], 2.0 * P[i, i, b])
        for j in range(n):
            for b in range(nb):
                ok[b] = ok[b] if abs(P[i, j, b]) <= big else 0.0
    for i in range(n):
        for j in range(i + 1):
            for b in range(nb):
                W[i, j, b] = P[i, j, b] + P[j, i, b]
    for i in range(n):
        for b in range(nb):
            W[i, i, b] += 0.5 * tol * d[b]
    bpd_ok(W, n, nb, d, acc, ok)


def bgather_(M, P, b, m1, P1, n):
    """Lane ``b`` of ``M``, ``P`` into the one-path ``m1``, ``P1``."""
    for i in range(n):
        m1[i] = M[i, b]
        for j in range(n):
            P1[i, j] = P[i, j, b]


def kill_(Mb, Pb, b, n, dead, step, lo, k):
    """Lane ``b`` fails at step ``k``: recorded, its state reset to ``0, I`` (no more work on it)."""
    dead[b] = 1
    step[lo + b] = k
    for i in range(n):
        Mb[i, b] = 0.0
        for j in range(n):
            Pb[i, j, b] = 1.0 if i == j else 0.0


def settle_(Mb, Pb, n, nb, tol, W, L, d, acc, ok, dead, irr, step, lo, k, m, P, W1, L1, ev1):
    """The divergence test of every live lane not judged already (``irr``: by the one-path update):
    the block's screen, :func:`~.path_linalg.psd_check_` where it does not pass; a lane that fails
    dies at step ``k``."""
    bscreen(Mb, Pb, n, nb, tol, W, L, d, acc, ok)
    for b in range(nb):
        if ok[b] == 0.0 and dead[b] == 0 and irr[b] == 0.0:
            bgather(Mb, Pb, b, m, P, ns)
            if not psd_check(m, P, ns, tol, W1, L1, ev1):
                kill(Mb, Pb, b, ns, dead, step, lo, k)


#: the kernels, in the order the generated module defines them (:data:`.batch_kernels.SOURCES`)
SOURCES = (bpd_ok_, bscreen_, bgather_, kill_, settle_)
