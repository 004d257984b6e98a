"""Numerical steps shared by the Gaussian filters: symmetric square roots, the PSD screen, the
Kalman update with missing components (Joseph form), the observed block of a precision, and the
log-likelihood of a partly missing measurement.

Every function here is batch-first (``(..., n)`` means, ``(..., n, n)`` covariances) and pure.
"""

from __future__ import annotations

import functools
import math
import weakref

import numpy as np

from .._npcall import dot as _dot, einsum as _einsum, one_path, quiet as _quiet
from ..noise import Gaussian, Independent
from .beliefs import GaussianState

try:  # the gufuncs behind numpy.linalg: the same numbers without its Python wrapper (µs a call)
    from numpy.linalg import _umath_linalg as _gufuncs
except ImportError:  # pragma: no cover - a NumPy without them: the public functions
    _gufuncs = None

PSD_TOL = 1e-9
_F8 = np.dtype(float)


def symmetrize(P: np.ndarray) -> np.ndarray:
    if P.shape[-1] == 1:
        return P
    return 0.5 * (P + P.swapaxes(-1, -2))


@functools.cache
def _eye(n: int, ndim: int = 2) -> np.ndarray:
    """The read-only identity of size ``n`` with ``ndim`` axes (leading ones: an operand of the batch's rank, which
    NumPy's elementwise loops take without broadcasting a rank up, half the cost of a subtraction on one path)."""
    e = np.eye(n).reshape((1,) * (ndim - 2) + (n, n))
    e.flags.writeable = False
    return e


def mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for batches of small matrices; an outer product (a broadcast multiply, several
    times faster than a batched matmul) when the inner dimension is 1."""
    if A.shape[-1] == 1:
        return A * B
    return A @ B


def matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for batches of small matrices, the same numbers: two batches of 1 x 1 matrices as
    a broadcast multiply plus 0.0 (what the matmul loop computes, ``0 + a b``: a zero product is
    +0, NaN and inf as they come; several times cheaper than a batched matmul of 1 x 1 matrices)."""
    if A.shape[-2:] == B.shape[-2:] == (1, 1) and A.dtype == B.dtype == _F8:
        return A * B + 0.0
    return A @ B


def _cholesky(A: np.ndarray) -> np.ndarray:
    """``np.linalg.cholesky(A)`` of a float64 batch where every factorization succeeds; NaN in the factors of the
    paths where one fails (the gufunc's fill) instead of the LinAlgError. Called with NumPy's invalid/overflow
    warnings off (the run loop's, or the caller's errstate)."""
    if _gufuncs is None or A.dtype != _F8:
        try:
            return np.linalg.cholesky(A)
        except np.linalg.LinAlgError:
            return np.full(A.shape, np.nan)
    return _gufuncs.cholesky_lo(A)  # (float64: its 'd->d' loop, as signature="d->d" would name it; a kwarg less)


def _solve(A: np.ndarray, B: np.ndarray) -> np.ndarray | None:
    """``np.linalg.solve(A, B)`` (``B (..., m, k)``) of float64 batches, or None where it would raise or a path's
    solution is not finite (the caller then takes ``np.linalg.solve``'s own path: the same numbers and exceptions)."""
    if _gufuncs is None or A.dtype != _F8 or B.dtype != _F8:
        return None
    X = _quiet(_gufuncs.solve, A, B)  # (float64: the 'dd->d' loop, without naming it: a kwarg less)
    return X if math.isfinite(_total(X)) else None


_AXIS_GATHER = {}


def axis_gather(z):
    """``(col (N,), zc (N, 1))`` when every node of a rule's table ``z (N, n)`` lies on an axis
    (``z_p = zc_p e_{col_p}``: unscented, cubature; :meth:`~nlfilter.filters.rules.NodeRule.nodes`
    then gathers columns of L), else None; kept per read-only table (the tables are cached; an
    entry is checked by a weak reference and dropped with its table)."""
    hit = _AXIS_GATHER.get(id(z))
    if hit is not None and hit[0]() is z:
        return hit[1]
    val = None
    if (np.count_nonzero(z, axis=1) <= 1).all():
        col = np.argmax(z != 0, axis=1)
        val = (col, z[np.arange(len(z)), col][:, None])
    if z.flags.writeable:  # a table that may change: not kept
        return val
    key = id(z)
    _AXIS_GATHER[key] = (weakref.ref(z, lambda _, key=key: _AXIS_GATHER.pop(key, None)), val)
    return val


def bad_paths(mean: np.ndarray, cov: np.ndarray, tol: float = PSD_TOL) -> np.ndarray:
    """Boolean ``(...)``: paths whose mean/cov is non-finite or whose cov is not PSD (an eigenvalue of the
    symmetrized cov below ``−tol·scale``, ``scale = max(1, max |cov|)``; a PSD but singular cov passes). The exact
    per-path test runs only when the one-call screen ``_screen_ok`` cannot clear the whole batch (it never clears a
    batch this test flags)."""
    if cov.shape[-1] > 2:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # a sum of infinities is NaN: no warning
            if _screen_ok(mean, cov, tol):
                return np.zeros(cov.shape[:-2], bool)
    return _bad_paths_exact(mean, cov, tol)


def _bad_paths_exact(mean: np.ndarray, cov: np.ndarray, tol: float = PSD_TOL) -> np.ndarray:
    """:func:`bad_paths` path by path: the smallest eigenvalue of every covariance."""
    ok = np.all(np.isfinite(mean), axis=-1) & np.all(np.isfinite(cov), axis=(-1, -2))
    safe = np.where(ok[..., None, None], cov, np.eye(cov.shape[-1]))
    return ~ok | _below(safe, tol)


def _below(cov: np.ndarray, tol: float) -> np.ndarray:
    """Boolean ``(...)``: finite covariances with an eigenvalue below ``−tol·scale`` (:func:`bad_paths`)."""
    n = cov.shape[-1]
    if n == 1:
        low = cov[..., 0, 0]
    elif n == 2:  # closed-form smallest eigenvalue of a symmetric 2x2
        a, b, c = cov[..., 0, 0], 0.5 * (cov[..., 0, 1] + cov[..., 1, 0]), cov[..., 1, 1]
        low = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    else:
        low = np.linalg.eigvalsh(symmetrize(cov))[..., 0]
    scale = np.maximum(1.0, _max(np.abs(cov), axis=(-1, -2)))
    return low < -tol * scale


#: the largest dimension the Cholesky screen serves (its rounding stays far inside the margin)
SCREEN_MAX_N = 64


def _screen_ok(mean: np.ndarray, cov: np.ndarray, tol: float = PSD_TOL) -> bool:
    """True only if :func:`_bad_paths_exact` flags no path, in two batched calls: one reduction
    (a NaN or inf anywhere makes the sum non-finite) and one Cholesky factorization of
    ``cov + covᵀ + tol·d·I``, ``d = max(1, max_i cov_ii)`` per path, i.e. of twice the symmetrized
    cov shifted by half the tolerance. Why it is never weaker: if that factorization succeeds, the
    symmetrized cov has no eigenvalue below ``−tol·d/2`` up to rounding (Cholesky is backward
    stable, error ≲ n³·eps·d ≪ tol·d/2 for n ≤ :data:`SCREEN_MAX_N`), and the exact test's
    threshold ``−tol·scale ≤ −tol·d`` lies below that; a factorization of A itself, tried first,
    says more still (no eigenvalue below ``−n³·eps·d``). A PSD-but-singular cov (a known state
    component) becomes positive definite with the shift, so it passes as it does the exact test.
    False (some path may fail, the sum overflowed, or n is too large): the exact test decides.
    Called with NumPy's invalid/overflow warnings off (the run loop's errstate, :func:`bad_paths`'):
    the factorization fails where its factor is NaN (:func:`_cholesky`), and a non-finite cov
    leaves a non-finite factor (NaN, or the inf it carried)."""
    n = cov.shape[-1]
    if n > SCREEN_MAX_N:
        return False
    A = cov + cov.swapaxes(-1, -2)
    if math.isfinite(_total(_cholesky(A)) + _total(mean)):  # A itself positive definite: the stronger
        return True  # statement (the common case: no shift to build; a singular cov needs the shift below)
    d = A.reshape(*A.shape[:-2], n * n)[..., ::n + 1]  # A's diagonal (2 cov_ii), a view: shifted in place
    if d.size == n:  # one path: its shift a number (max(2, nan) is 2 where np.maximum is NaN: A has the NaN)
        d += (0.5 * tol) * max(2.0, _max(d, axis=None))
    else:
        d += (0.5 * tol) * np.maximum(2.0, _max(d, axis=-1))[..., None]
    # a NaN or inf in cov (A's lower triangle: A is symmetric) or mean leaves a non-finite sum: no
    # separate test of cov (a factor whose sum overflows defers to the exact test, as ever)
    return math.isfinite(_total(_cholesky(A)) + _total(mean))


def sqrt_psd(P: np.ndarray, tol: float = PSD_TOL):
    """``(L, bad)`` with ``L Lᵀ = P`` on every path of ``P (..., n, n)``: the lower Cholesky factor
    where P is positive definite; where it is only semi-definite (rank-deficient, e.g. a known
    initial state) the eigen root ``U √w`` (any root serves sigma points and quadrature nodes);
    the identity where P is non-finite or has an eigenvalue below ``−tol·scale`` (``bad``: the
    caller poisons those paths, so that ``run`` raises or marks them)."""
    L, bad = psd_root(P, tol)
    return L, (np.zeros(P.shape[:-2], bool) if bad is None else bad)


def psd_root(P: np.ndarray, tol: float = PSD_TOL):
    """:func:`sqrt_psd` with ``bad`` None where every path has its Cholesky factor (the node
    rules' common case, without an all-False array to build and test)."""
    L = _quiet(_cholesky, P)
    if math.isfinite(_total(L)):  # every factorization succeeded: np.linalg.cholesky's factor
        return L, None
    try:
        return np.linalg.cholesky(P), None
    except np.linalg.LinAlgError:
        pass
    eye = np.eye(P.shape[-1])
    finite = np.all(np.isfinite(P), axis=(-1, -2))
    safe = np.where(finite[..., None, None], P, eye)
    w, U = np.linalg.eigh(symmetrize(safe))
    pd = finite & (w[..., 0] > 0)
    bad = ~finite | (w[..., 0] < -tol * np.maximum(1.0, np.max(np.abs(safe), axis=(-1, -2))))
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        L = _cholesky(np.where(pd[..., None, None], safe, eye))  # the same factor as alone
    pd = pd & np.all(np.isfinite(L), axis=(-1, -2))  # eigh's λ_min > 0 but a pivot ≤ 0 (λ_min ~ eps): the root
    root = U * np.sqrt(np.maximum(w, 0.0))[..., None, :]
    return np.where(pd[..., None, None], L, np.where(bad[..., None, None], eye, root)), (bad if bad.any() else None)


def screened(run):
    """Decorator for a ``run`` that checks its own results (raises or marks a failing path, never
    returns NaN silently): NumPy's overflow/invalid/divide warnings are off inside it, as they are
    in the protocol's run loops, so a caught failure is reported once, by the filter."""

    @functools.wraps(run)
    def wrapper(*args, **kwargs):
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return run(*args, **kwargs)

    return wrapper


def poison(state: GaussianState, bad) -> GaussianState:
    """NaN on the paths in ``bad`` so that ``run``'s divergence check records them (never
    silent: ``run`` raises or marks them)."""
    if bad is None or not np.any(bad):
        return state
    return GaussianState(np.where(bad[..., None], np.nan, state.mean),
                         np.where(bad[..., None, None], np.nan, state.cov))


def _all_ok(mean: np.ndarray, cov: np.ndarray) -> bool:
    """Quick test that every path is finite with PSD covariance (exact for n ≤ 2; for n > 2 the Cholesky screen
    ``_screen_ok``, which may only answer False too often, and then :func:`bad_paths` decides path by path)."""
    n = cov.shape[-1]
    if 2 < n <= SCREEN_MAX_N and cov.dtype is _F8 and _gufuncs is not None:  # _screen_ok's first try, inline: a
        L = _gufuncs.cholesky_lo(cov + cov.swapaxes(-1, -2))  # call less twice a step (the 'd->d' loop)
        return math.isfinite(_total(L) + _total(mean)) or _screen_ok(mean, cov)
    if n == 2:  # every path finite (one reduction): the exact test without its masking
        if math.isfinite(_total(cov) + _total(mean)):
            return not _below(cov, PSD_TOL).any()
        return not _bad_paths_exact(mean, cov).any()
    if n != 1:
        return _screen_ok(mean, cov)
    # ufunc reductions and Python floats: this runs twice a step, and method calls cost here
    if cov.size == 1:  # one path: its numbers
        c = cov.item()
        return c >= 0.0 and math.isfinite(c + mean.item())
    if _min(cov, axis=None) >= 0.0:  # no NaN, no −inf in cov; then Σ cov_i mean_i, one call for both (a NaN or
        if cov.size == mean.size:  # ±inf in either makes it NaN or ±inf: 0·inf is NaN, inf − inf too)
            return math.isfinite(_dot(cov.reshape(-1), mean.reshape(-1)))
        return math.isfinite(_sum(cov, axis=None) + _sum(mean, axis=None))
    return False


_min, _max, _sum = np.minimum.reduce, np.maximum.reduce, np.add.reduce


_TOTAL_SMALL = 32  # the largest array _total sums as Python floats (a list and sum: a third of a reduction's call)


def _total(a: np.ndarray):
    """The sum of the entries of ``a`` for a finiteness test (a NaN or inf anywhere makes it NaN or
    inf): one reduction, the entry itself when there is one (a scalar on one trajectory), or a
    Python ``sum`` of at most 32 entries (a single trajectory's matrices; a third of a reduction's
    call). Huge finite entries may overflow to inf in one order of the additions and not in another:
    every caller then takes its general path, which decides as it ever did."""
    size = a.size
    if size == 1:
        return a.item()
    return sum(a.ravel().tolist()) if size <= _TOTAL_SMALL else _sum(a, axis=None)


def gaussian_update(state: GaussianState, y: np.ndarray, y_pred: np.ndarray, S: np.ndarray,
                    C: np.ndarray, H: np.ndarray | None = None, R: np.ndarray | None = None
                    ) -> GaussianState:
    """Condition a Gaussian belief on ``y`` given the predicted measurement moments.

    ``y_pred`` (..., m) = E[h], ``S`` (..., m, m) = Cov[h] + R (innovation covariance),
    ``C`` (..., n, m) = Cov[x, h]. With a linearization ``H`` (..., m, n) and ``R`` the covariance
    is updated in Joseph form, ``(I − K H) P (I − K H)ᵀ + K R Kᵀ`` (symmetric PSD by
    construction); otherwise ``P − K S Kᵀ``, symmetrized. NaN components of ``y`` are missing.
    Paths whose ``S`` is singular come back as NaN (:func:`poison`: ``run`` raises or marks them)."""
    m, P = state
    if m.shape == y.shape == _ONE and S.shape == C.shape == P.shape == _ONE3 and y_pred.size == 1 and (
            H is None or (H.shape == _ONE3 and R.size == 1 and R.ndim <= 3)):  # one scalar trajectory
        new = _scalar_update(m, P, y, y_pred, S, C, H, R)
        if new is not None:
            return new
    # a NaN anywhere makes the sum NaN: one reduction screens the common complete case
    miss = np.isnan(y) if math.isnan(_total(y)) else None
    if miss is not None and miss.any():
        e = np.where(miss, 0.0, y - y_pred)
        C = np.where(miss[..., None, :], 0.0, C)
        both = miss[..., :, None] | miss[..., None, :]
        eye = np.eye(y.shape[-1], dtype=bool)
        S = np.where(both, np.where(eye & miss[..., None, :], 1.0, 0.0), S)
        if H is not None:
            H = np.where(miss[..., :, None], 0.0, H)
    else:
        e = y - y_pred
    if S.shape[-1] == 1 and m.shape[-1] == 1:  # scalar state and measurement: elementwise
        K = C / S
        mean = m + K[..., 0] * e
        if H is not None:  # Joseph form (1 − K H)² P + K² R
            IKH = 1.0 - K * H
            return GaussianState(mean, IKH * IKH * P + K * K * R)
        return GaussianState(mean, P - K * K * S)
    singular = None
    if S.shape[-1] == 1:  # scalar measurement: no solve needed
        K = C / S
    else:
        Ct = C.swapaxes(-1, -2)
        K = _solve(S, Ct)  # K = C S⁻¹ (S symmetric)
        if K is not None:
            K = K.swapaxes(-1, -2)
        else:
            try:
                K = np.swapaxes(np.linalg.solve(S, Ct), -1, -2)
            except np.linalg.LinAlgError:  # a (numerically) singular S on some path: poison those paths only
                K, singular = _solve_paths(S, C)
    mean = m + (K[..., 0] * e if e.shape[-1] == 1 else _einsum("...ij,...j->...i", K, e))
    if (one := one_path(K, P, S, None) if H is None else one_path(K, P, H, R)) is not None:  # one path, n, m ≥ 2:
        return poison(GaussianState(mean, _posterior(*one, H is not None, _dot)[None]), singular)
    return poison(GaussianState(mean, _posterior(K, P, S if H is None else H, R, H is not None, mm)), singular)


def _posterior(K, P, X, R, joseph, prod):
    """``(I − K X) P (I − K X)ᵀ + K R Kᵀ`` (Joseph, ``X = H``: K's missing columns are zero, R's missing rows never
    enter) or ``P − K X Kᵀ`` (``X = S``), symmetrized; ``prod``: :func:`mm`, or ``np.dot`` on one path's 2-D matrices."""
    Kt = K.swapaxes(-1, -2)
    if joseph:
        KH = prod(K, X)
        IKH = _eye(KH.shape[-1], KH.ndim) - KH
        return symmetrize(prod(prod(IKH, P), IKH.swapaxes(-1, -2)) + prod(prod(K, R), Kt))
    return symmetrize(P - prod(prod(K, X), Kt))


_ONE, _ONE3 = (1, 1), (1, 1, 1)


def _scalar_update(m, P, y, y_pred, S, C, H, R):
    """:func:`gaussian_update` of one path with a scalar state and measurement (a single scalar
    trajectory): the same operations, in the same order, on Python floats (IEEE doubles, as
    NumPy's float64), a missing y masked as there (C = 0, S = 1, H = 0, innovation 0); None for
    S = 0 (a Python float division raises where NumPy's gives inf or NaN: the array path)."""
    y_, s_ = y.item(), S.item()
    if math.isnan(y_):
        c_, s_, h_, e_ = 0.0, 1.0, 0.0, 0.0
    elif s_ == 0.0:
        return None
    else:
        c_, h_, e_ = C.item(), (None if H is None else H.item()), y_ - y_pred.item()
    K = c_ / s_
    mean = np.array([[m.item() + K * e_]])
    if H is not None:  # Joseph form (1 − K H)² P + K² R
        IKH = 1.0 - K * h_
        return GaussianState(mean, np.array([[[IKH * IKH * P.item() + K * K * R.item()]]]))
    return GaussianState(mean, np.array([[[P.item() - K * K * s_]]]))


def observed_precision(R: np.ndarray, Rinv: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """Precision of the observed components of a measurement with noise covariance ``R (m, m)``:
    ``Rinv`` when ``obs (..., m)`` is all True, else ``(..., m, m)`` holding the inverse of R's
    observed block (the Gaussian marginal of the observed components) and zeros in the missing
    rows and columns. (With correlated noise this is not R⁻¹ with rows zeroed.)"""
    if obs.all():
        return Rinv
    both = obs[..., :, None] & obs[..., None, :]
    return np.where(both, np.linalg.inv(np.where(both, R, np.eye(R.shape[-1]))), 0.0)


def decorrelation(S: np.ndarray, R: np.ndarray, Rinv: np.ndarray, obs: np.ndarray):
    """``(K_w, K_w Sᵀ)`` for correlated noise ``E[w vᵀ] = S (r, m)`` measured on the components
    ``obs (..., m)``: ``K_w = S_o R_oo⁻¹`` ``(r, m)`` or ``(..., r, m)`` (zero columns where a
    component is missing), so that ``E[w | v_o] = K_w v`` and ``Cov[w | v_o] = Q − K_w Sᵀ``
    (Anderson & Moore 1979, §5.5; Simon 2006, §7.1; nothing observed: ``K_w = 0``)."""
    Kw = S @ observed_precision(R, Rinv, obs)
    return Kw, Kw @ S.T


def measurement_loglik(law, resid, obs=None):
    """log p_v(resid) ``(..., N)`` for residuals ``(..., N, m)`` under the noise law ``law``;
    ``obs (..., m)`` marks the observed components of each path: a partly missing measurement has
    the marginal law of its observed components (exact for Gaussian and Independent laws; a fully
    missing one has log-likelihood 0)."""
    if obs is None or obs.all():
        return law.logpdf(resid)
    if isinstance(law, Independent):
        return sum(np.where(obs[..., None, i], d.logpdf(resid[..., i]), 0.0) for i, d in enumerate(law.dists))
    if isinstance(law, Gaussian):
        both = obs[..., :, None] & obs[..., None, :]
        _, logdet = np.linalg.slogdet(np.where(both, law.cov, np.eye(law.dim)))  # log det of the observed block
        d = np.where(obs[..., None, :], resid - law.mean, 0.0)
        quad = np.einsum("...pi,...ij,...pj->...p", d, observed_precision(law.cov, None, obs), d)
        return -0.5 * quad - 0.5 * (logdet + obs.sum(axis=-1) * np.log(2 * np.pi))[..., None]
    raise ValueError("measurement_noise: partly missing measurements need a Gaussian or Independent law")


LOG_2PI = math.log(2 * math.pi)


def gaussian_loglik(resid: np.ndarray, R: np.ndarray, obs: np.ndarray | None = None) -> np.ndarray:
    """``log N(resid; 0, R)`` ``(...)`` for residuals ``resid (..., m)`` and covariances
    ``R (..., m, m)`` that differ from point to point (a state-dependent R(x) at each grid point
    or particle; broadcast against ``resid``); ``obs`` (broadcastable to ``resid``) marks the
    observed components: the density of their marginal (R's observed block), 0 where none is.
    R must be positive definite (:meth:`~nlfilter.models.Model.R_of` checks it).

    >>> R = np.array([[[2.0, 0.5], [0.5, 1.0]]])
    >>> ll = gaussian_loglik(np.array([[1.0, 3.0]]), R, np.array([True, False]))
    >>> bool(np.isclose(ll[0], -0.5 * (1 / 2 + np.log(2 * np.pi * 2)), rtol=0, atol=1e-14))
    True
    """
    m = resid.shape[-1]
    if obs is not None and not np.all(obs):
        obs = np.broadcast_to(obs, np.broadcast_shapes(np.shape(obs), resid.shape))
        both = obs[..., :, None] & obs[..., None, :]
        R = np.where(both, R, np.eye(m))  # the observed block, the identity elsewhere
        resid = np.where(obs, resid, 0.0)
        k = obs.sum(axis=-1)
    else:
        k = m
    if m == 1:
        r = R[..., 0, 0]
        return -0.5 * (resid[..., 0] ** 2 / r + np.log(r) + k * LOG_2PI)
    R, resid = np.broadcast_arrays(R, resid[..., None])
    _, logdet = np.linalg.slogdet(R)
    quad = np.einsum("...i,...i->...", resid[..., 0], np.linalg.solve(R, resid)[..., 0])
    return -0.5 * (quad + logdet + k * LOG_2PI)


def innovation_info(y: np.ndarray, y_pred: np.ndarray, S: np.ndarray, *, scale: float = 1.0) -> dict:
    """The step's likelihood output ``{"loglik": (...,), "innovation": (..., m), "innovation_cov":
    (..., m, m)}`` of a measurement ``y (..., m)`` predicted as ``N(y_pred, S)`` — the
    prediction-error decomposition of the log-likelihood (Schweppe 1965; Harvey 1989, eq. 3.4.7)::

        log p(y_k | y_0..y_{k-1}) = −½ [ eᵀ S⁻¹ e + log det S + m log 2π ],   e = y − ŷ

    over the *observed* components only (a NaN component of ``y`` is missing: the marginal of
    the others, exactly; 0 when all are missing). ``scale``: the measurement is reported as
    ``scale · y`` (a continuous filter's increment ``dy = y dt``): innovation ``scale · e``,
    covariance ``scale² S`` and the density of ``dy``, ``log p(y) − m_obs log scale``. A path
    whose observed block of S is not positive definite gets NaN (its belief is poisoned too); a
    path with nothing measured gets a NaN covariance (as a step measured on no path).

    >>> info = innovation_info(np.array([1.0, np.nan]), np.zeros(2), np.array([[2.0, 0.5], [0.5, 1.0]]))
    >>> bool(np.isclose(info["loglik"], -0.5 * (1 / 2 + np.log(2 * np.pi * 2)), rtol=0, atol=1e-14))
    True
    """
    m = y.shape[-1]
    if S.shape[:-1] != y.shape:
        S = np.broadcast_to(S, (*y.shape, m))
    if m == 1 and not math.isnan(_total(y)):  # the common case: one complete component
        e = y - y_pred
        s = S[..., 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            ll = -0.5 * (e * e / s + np.log(s) + LOG_2PI)
        ll = np.where(s > 0, ll, np.nan)[..., 0]
        if scale != 1.0:
            return {"loglik": ll - math.log(scale), "innovation": scale * e, "innovation_cov": (scale * scale) * S}
        return {"loglik": ll, "innovation": e, "innovation_cov": S}
    miss = np.isnan(y)
    e = np.where(miss, 0.0, y - y_pred)
    if y.shape[-1] == 1:
        s = S[..., 0, 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            ll = -0.5 * (e[..., 0] ** 2 / s + np.log(s) + LOG_2PI)
        ll = np.where(miss[..., 0], 0.0, np.where(s > 0, ll, np.nan))
    else:
        So = S
        if miss.any():
            both = miss[..., :, None] | miss[..., None, :]
            So = np.where(both, np.where(np.eye(y.shape[-1], dtype=bool), 1.0, 0.0), S)
        finite = np.all(np.isfinite(So), axis=(-1, -2))
        So = np.where(finite[..., None, None], So, np.eye(y.shape[-1]))
        sign, logdet = np.linalg.slogdet(So)
        ok = finite & (sign > 0)
        safe = np.where(ok[..., None, None], So, np.eye(y.shape[-1]))
        quad = np.einsum("...i,...i->...", e, np.linalg.solve(safe, e[..., None])[..., 0])
        ll = np.where(ok, -0.5 * (quad + logdet + (~miss).sum(axis=-1) * LOG_2PI), np.nan)
    if scale != 1.0:
        ll = ll - (~miss).sum(axis=-1) * math.log(scale)
    none = miss.all(axis=-1)[..., None, None]  # nothing measured on the path: NaN, as a step measured nowhere
    return {"loglik": ll, "innovation": np.where(miss, np.nan, scale * e),
            "innovation_cov": np.where(none, np.nan, (scale * scale) * S)}


def no_information(B: int, m: int) -> dict:
    """:func:`innovation_info` of a step measured on no path: log-likelihood 0, innovation NaN."""
    return {"loglik": np.zeros(B), "innovation": np.full((B, m), np.nan), "innovation_cov": np.full((B, m, m), np.nan)}


def _solve_paths(S, C):
    """``(K = C S⁻¹, singular)`` when a batched solve failed: the paths whose innovation covariance
    ``S`` is non-finite or singular (LU determinant sign ≤ 0; S must be positive definite) get
    ``S = I`` here and are returned in ``singular`` (the caller poisons them, so that ``run``
    raises or marks them); the other paths are solved as usual."""
    eye = np.eye(S.shape[-1])
    ok = np.all(np.isfinite(S), axis=(-1, -2))
    sign, _ = np.linalg.slogdet(np.where(ok[..., None, None], S, eye))
    singular = ~ok | ~(sign > 0)
    safe = np.where(singular[..., None, None], eye, S)
    return np.swapaxes(np.linalg.solve(safe, np.swapaxes(C, -1, -2)), -1, -2), singular


