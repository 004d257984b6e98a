"""The filter protocol, its state containers and the shared numerical steps.

Every filter offers ``run(ys, m0, P0) -> Estimates`` over a whole batch of measurement sequences,
and the step functions ``predict``/``update`` (discrete time) or ``step`` (continuous time, one
measurement increment). A filter object holds only configuration and the model's numeric
functions; the evolving state is a :class:`GaussianState` passed in and returned.

Step convention (discrete time)
-------------------------------
``start="update"`` (default, as dynamax): ``ys[..., 0, :]`` measures the state whose prior is
``(m0, P0)``; the filter updates first, then predicts. ``start="predict"`` (as filterpy):
``(m0, P0)`` is the prior one step *before* the state that ``ys[..., 0, :]`` measures; the filter
predicts first. ``simulate(..., start=...)`` takes the same option. In both conventions
``Estimates.means[..., k, :]`` is the filtered mean of the state measured by ``ys[..., k, :]``.

Missing data: a NaN component of ``y`` is missing; a fully missing ``y`` only predicts, a partly
missing one updates with the observed components only (exactly: the missing rows of the
innovation, gain and cross-covariance are zero).

Divergence: after each step the mean and covariance are checked (finite; covariance symmetric
with eigenvalues ≥ −tol·scale). ``on_divergence="raise"`` raises :class:`DivergenceError`
naming the step and paths; ``"mark"`` records the paths in ``Estimates.diverged`` /
``diverged_step``, fills their later estimates with NaN (flagged, never silent) and goes on with
the others.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

from .. import _validate as V
from ..errors import DivergenceError
from ..noise import Gaussian, Independent

PSD_TOL = 1e-9


class GaussianState(NamedTuple):
    """Mean ``(..., n)`` and covariance ``(..., n, n)`` of a batch of Gaussian beliefs."""

    mean: np.ndarray
    cov: np.ndarray


class Estimates(NamedTuple):
    """Filter output over a batch: ``means (..., T, n)``, ``covs (..., T, n, n)``,
    ``diverged (...,)`` bool, ``diverged_step (...,)`` int (−1 where not diverged)."""

    means: np.ndarray
    covs: np.ndarray
    diverged: np.ndarray
    diverged_step: np.ndarray

    @property
    def divergence_rate(self) -> float:
        return float(np.mean(self.diverged)) if self.diverged.size else 0.0


def symmetrize(P: np.ndarray) -> np.ndarray:
    if P.shape[-1] == 1:
        return P
    return 0.5 * (P + np.swapaxes(P, -1, -2))


@functools.lru_cache(maxsize=None)
def _eye(n: int) -> np.ndarray:
    e = np.eye(n)
    e.flags.writeable = False
    return e


def mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` for batches of small matrices; an outer product (a broadcast multiply, several
    times faster than a batched matmul) when the inner dimension is 1."""
    if A.shape[-1] == 1:
        return A * B
    return A @ B


def bad_paths(mean: np.ndarray, cov: np.ndarray, tol: float = PSD_TOL) -> np.ndarray:
    """Boolean ``(...)``: paths whose mean/cov is non-finite or whose cov is not PSD."""
    n = cov.shape[-1]
    ok = np.all(np.isfinite(mean), axis=-1) & np.all(np.isfinite(cov), axis=(-1, -2))
    safe = np.where(ok[..., None, None], cov, np.eye(n))
    if n == 1:
        low = safe[..., 0, 0]
    elif n == 2:  # closed-form smallest eigenvalue of a symmetric 2x2
        a, b, c = safe[..., 0, 0], 0.5 * (safe[..., 0, 1] + safe[..., 1, 0]), safe[..., 1, 1]
        low = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
    else:
        low = np.linalg.eigvalsh(symmetrize(safe))[..., 0]
    scale = np.maximum(1.0, np.max(np.abs(safe), axis=(-1, -2)))
    return ~ok | (low < -tol * scale)


def sqrt_psd(P: np.ndarray, tol: float = PSD_TOL):
    """``(L, bad)`` with ``L Lᵀ = P`` on every path of ``P (..., n, n)``: the lower Cholesky factor
    where P is positive definite; where it is only semi-definite (rank-deficient, e.g. a known
    initial state) the eigen root ``U √w`` (any root serves sigma points and quadrature nodes);
    the identity where P is non-finite or has an eigenvalue below ``−tol·scale`` (``bad``: the
    caller poisons those paths, so that ``run`` raises or marks them)."""
    try:
        return np.linalg.cholesky(P), np.zeros(P.shape[:-2], bool)
    except np.linalg.LinAlgError:
        pass
    eye = np.eye(P.shape[-1])
    finite = np.all(np.isfinite(P), axis=(-1, -2))
    safe = np.where(finite[..., None, None], P, eye)
    w, U = np.linalg.eigh(symmetrize(safe))
    pd = finite & (w[..., 0] > 0)
    bad = ~finite | (w[..., 0] < -tol * np.maximum(1.0, np.max(np.abs(safe), axis=(-1, -2))))
    L = np.linalg.cholesky(np.where(pd[..., None, None], safe, eye))  # the same factor as alone
    root = U * np.sqrt(np.maximum(w, 0.0))[..., None, :]
    return np.where(pd[..., None, None], L, np.where(bad[..., None, None], eye, root)), bad


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
    """Quick test that every path is finite with PSD covariance (exact for n = 1; for n > 1
    it only screens, and :func:`bad_paths` decides)."""
    if cov.shape[-1] != 1:
        return not bad_paths(mean, cov).any()
    # ufunc reductions and Python floats: this runs twice a step, and method calls cost here
    return bool(_min(cov, axis=None) >= 0.0) and math.isfinite(_sum(cov, axis=None) + _sum(mean, axis=None))


_min, _sum = np.minimum.reduce, np.add.reduce


def gaussian_update(state: GaussianState, y: np.ndarray, y_pred: np.ndarray, S: np.ndarray,
                    C: np.ndarray, H: np.ndarray | None = None, R: np.ndarray | None = None
                    ) -> GaussianState:
    """Condition a Gaussian belief on ``y`` given the predicted measurement moments.

    ``y_pred`` (..., m) = E[h], ``S`` (..., m, m) = Cov[h] + R (innovation covariance),
    ``C`` (..., n, m) = Cov[x, h]. With a linearization ``H`` (..., m, n) and ``R`` the covariance
    is updated in Joseph form, ``(I − K H) P (I − K H)ᵀ + K R Kᵀ`` (symmetric PSD by
    construction); otherwise ``P − K S Kᵀ``, symmetrized. NaN components of ``y`` are missing.
    Paths whose ``S`` is singular come back as NaN (:func:`poison`: ``run`` raises or marks them).
    """
    m, P = state
    # a NaN anywhere makes the sum NaN: one reduction screens the common complete case
    miss = np.isnan(y) if math.isnan(_sum(y, axis=None)) else None
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
        try:
            K = np.swapaxes(np.linalg.solve(S, np.swapaxes(C, -1, -2)), -1, -2)  # K = C S⁻¹ (S symmetric)
        except np.linalg.LinAlgError:  # a (numerically) singular S on some path: poison those paths only
            K, singular = _solve_paths(S, C)
    mean = m + (K[..., 0] * e if e.shape[-1] == 1 else np.einsum("...ij,...j->...i", K, e))
    Kt = np.swapaxes(K, -1, -2)
    if H is not None:  # Joseph form; K's missing columns are zero, so R's missing rows never enter
        IKH = _eye(m.shape[-1]) - mm(K, H)
        cov = mm(mm(IKH, P), np.swapaxes(IKH, -1, -2)) + mm(mm(K, R), Kt)
    else:
        cov = P - mm(mm(K, S), Kt)
    return poison(GaussianState(mean, symmetrize(cov)), singular)


def observed_precision(R: np.ndarray, Rinv: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """Precision of the observed components of a measurement with noise covariance ``R (m, m)``:
    ``Rinv`` when ``obs (..., m)`` is all True, else ``(..., m, m)`` holding the inverse of R's
    observed block (the Gaussian marginal of the observed components) and zeros in the missing
    rows and columns. (With correlated noise this is not R⁻¹ with rows zeroed.)"""
    if obs.all():
        return Rinv
    both = obs[..., :, None] & obs[..., None, :]
    return np.where(both, np.linalg.inv(np.where(both, R, np.eye(R.shape[-1]))), 0.0)


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


def _prepare(name_ys, ys, m0, P0, n, m):
    ys = V.as_float_array(name_ys, ys, ndim_min=2, shape_tail=(None, m))
    V.finite(name_ys, ys, allow_nan=True)
    m0 = V.as_float_array("m0", m0, shape_tail=(n,)) if np.ndim(m0) else np.full(n, float(m0))
    V.finite("m0", m0)
    P0 = V.covariance("P0", P0, n, batch=True)
    batch = ys.shape[:-2]
    try:
        mean = np.broadcast_to(m0, (*batch, n)).copy()
        cov = np.broadcast_to(P0, (*batch, n, n)).copy()
    except ValueError:
        raise ValueError(f"m0/P0: shapes {m0.shape}, {P0.shape} do not broadcast to the batch "
                         f"{batch} of {name_ys}") from None
    return ys, GaussianState(mean, cov), batch


def screen_outputs(name: str, values: np.ndarray, diverged=None, step=None, on_divergence: str = "raise"):
    """Screen estimates ``values (..., T, k)`` computed after a run's own checks (a post-processor
    of its means, a filter without covariances): a path with a non-finite value that is not yet
    flagged diverges at its first such step. ``"raise"``: :class:`DivergenceError` naming the step
    and paths; ``"mark"``: returns ``(values, diverged, step)`` with the path flagged and its values
    NaN from that step on (never silent)."""
    V.choice("on_divergence", on_divergence, {"raise", "mark"})
    batch, T = values.shape[:-2], values.shape[-2]
    diverged = np.zeros(batch, bool) if diverged is None else diverged
    step = np.full(batch, -1) if step is None else step
    fin = np.all(np.isfinite(values), axis=-1)  # (..., T)
    new = ~np.all(fin, axis=-1) & ~diverged
    if not new.any():
        return values, diverged, step
    first = np.argmin(fin, axis=-1)
    if on_divergence == "raise":
        idx = np.flatnonzero(new.ravel())
        k = int(first[new].min())
        raise DivergenceError(f"{name}: an estimate became non-finite at step {k} on {idx.size} path(s), first "
                              f"{idx[:5].tolist()}", step=k, paths=idx, what="mean")
    diverged = diverged | new
    step = np.where(new, first, step)
    after = diverged[..., None] & (np.arange(T) >= step[..., None])  # (..., T)
    return np.where(after[..., None], np.nan, values), diverged, step


class _Runner:
    """Shared bookkeeping of ``run``: output arrays, divergence checks, marking."""

    def __init__(self, batch, T, n, on_divergence, name):
        self.on = V.choice("on_divergence", on_divergence, {"raise", "mark"})
        self.means = np.empty((T, *batch, n))  # time-major while filling (contiguous writes)
        self.covs = np.empty((T, *batch, n, n))
        self.diverged = np.zeros(batch, dtype=bool)
        self.step = np.full(batch, -1)
        self.any_diverged = False
        self.name = name

    def record(self, k, state, reset: GaussianState, *, write: bool = True) -> GaussianState:
        """Check step ``k``'s state (raise or mark), write it unless ``write`` is False, and
        return it with diverged paths reset to ``reset``."""
        if not self.any_diverged and _all_ok(state.mean, state.cov):  # the common case
            if write:
                self.means[k] = state.mean
                self.covs[k] = state.cov
            return state
        bad = bad_paths(state.mean, state.cov)
        bad &= ~self.diverged
        if bad.any():
            if self.on == "raise":
                idx = np.flatnonzero(bad.ravel())
                raise DivergenceError(
                    f"{self.name}: covariance lost positive definiteness or a value became non-finite "
                    f"at step {k} on {idx.size} path(s), first {idx[:5].tolist()}; pass "
                    "on_divergence='mark' to record such paths and go on", step=k, paths=idx,
                    what="covariance")
            self.diverged |= bad
            self.step[bad] = k
            self.any_diverged = True
        # diverged paths restart from a harmless state; their outputs are NaN (flagged)
        d = self.diverged
        state = GaussianState(np.where(d[..., None], reset.mean, state.mean),
                              np.where(d[..., None, None], reset.cov, state.cov))
        if write:
            self.means[k] = np.where(d[..., None], np.nan, state.mean)
            self.covs[k] = np.where(d[..., None, None], np.nan, state.cov)
        return state

    def result(self) -> Estimates:
        return Estimates(np.ascontiguousarray(np.moveaxis(self.means, 0, -2)),
                         np.ascontiguousarray(np.moveaxis(self.covs, 0, -3)), self.diverged, self.step)


class DiscreteFilter:
    """Base of discrete-time filters: subclasses give ``predict(state, k)`` and
    ``update(state, y, k)``; ``run`` loops over time for the whole batch at once."""

    name = "filter"

    def __init__(self, model, *, start: str = "update"):
        if getattr(model, "kind", None) != "discrete":
            raise TypeError(f"model: {type(self).__name__} expects a DiscreteModel, got {type(model).__name__}")
        self.model = model
        self.start = V.choice("start", start, {"update", "predict"})

    def predict(self, state: GaussianState, k) -> GaussianState:  # pragma: no cover
        raise NotImplementedError

    def update(self, state: GaussianState, y, k) -> GaussianState:  # pragma: no cover
        raise NotImplementedError

    # run() calls these; a filter whose step functions raise on failure overrides them to
    # return ``(state, bad paths)`` instead, so that a batch run can mark paths and go on.
    def _predict_unchecked(self, state, k):
        return self.predict(state, k), None

    def _update_unchecked(self, state, y, k):
        return self.update(state, y, k), None

    def run(self, ys, m0, P0, *, on_divergence: str = "raise") -> Estimates:
        """Filter a batch ``ys (..., T, m)`` from the prior ``(m0, P0)``; see the module docstring
        for the step convention. Divergence is checked after the prediction and after the update.
        Returns :class:`Estimates`."""
        model = self.model
        ys, state, batch = _prepare("ys", ys, m0, P0, model.n, model.m)
        init = GaussianState(state.mean.copy(), state.cov.copy())
        T = ys.shape[-2]
        out = _Runner(batch, T, model.n, on_divergence, self.name)
        offset = 0 if self.start == "update" else 1
        absent = np.isnan(ys).all(axis=(*range(len(batch)), -1))  # (T,): steps with no measurement
        with np.errstate(over="ignore", invalid="ignore"):  # a failing path is caught by record
            for k in range(T):
                if k > 0 or offset:
                    state = poison(*self._predict_unchecked(state, k + offset - 1))
                    state = out.record(k, state, init, write=False)
                if not absent[k]:
                    state = poison(*self._update_unchecked(state, ys[..., k, :], k + offset))
                state = out.record(k, state, init)
        return out.result()


class ContinuousFilter:
    """Base of continuous-time filters on an :class:`SDEModel` observed through increments
    ``dy`` on a grid of step ``dt``. Subclasses give ``step(state, dy, t)``: the belief at
    ``t + dt`` after the increment over ``[t, t + dt]``. ``run`` returns estimates at
    ``t_1 .. t_T`` (``t_k = t0 + k dt``), aligned with ``Simulation.xs``."""

    name = "filter"

    def __init__(self, model, dt: float, *, scheme: str = "rk4", substeps: int = 1):
        if getattr(model, "kind", None) != "sde":
            raise TypeError(f"model: {type(self).__name__} expects an SDEModel, got {type(model).__name__}")
        self.model = model
        self.dt = float(V.positive("dt", dt))
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        self.substeps = V.positive("substeps", substeps, integer=True)

    def step(self, state: GaussianState, dy, t) -> GaussianState:  # pragma: no cover
        raise NotImplementedError

    def _step_unchecked(self, state, dy, t):
        return self.step(state, dy, t), None

    def run(self, dys, m0, P0, *, t0: float = 0.0, on_divergence: str = "raise") -> Estimates:
        """Filter increments ``dys (..., T, m)``; estimates at ``t0 + dt .. t0 + T dt``."""
        model = self.model
        dys, state, batch = _prepare("dys", dys, m0, P0, model.n, model.m)
        init = GaussianState(state.mean.copy(), state.cov.copy())
        T = dys.shape[-2]
        out = _Runner(batch, T, model.n, on_divergence, self.name)
        with np.errstate(over="ignore", invalid="ignore"):  # a failing path is caught by record
            for k in range(T):
                state = poison(*self._step_unchecked(state, dys[..., k, :], t0 + k * self.dt))
                state = out.record(k, state, init)
        return out.result()

    def integrate(self, rhs, state: GaussianState, z, t) -> GaussianState:
        """Integrate ``d(m, P)/dt = rhs(m, P, z, t)`` over one measurement step with the
        measurement derivative ``z = dy/dt`` held constant (``scheme``: Euler or classical RK4)."""
        h = self.dt / self.substeps
        m, P = state
        for j in range(self.substeps):
            s = t + j * h
            if self.scheme == "euler":
                dm, dP = rhs(m, P, z, s)
                m, P = m + h * dm, P + h * dP
            else:
                k1m, k1P = rhs(m, P, z, s)
                k2m, k2P = rhs(m + 0.5 * h * k1m, P + 0.5 * h * k1P, z, s + 0.5 * h)
                k3m, k3P = rhs(m + 0.5 * h * k2m, P + 0.5 * h * k2P, z, s + 0.5 * h)
                k4m, k4P = rhs(m + h * k3m, P + h * k3P, z, s + h)
                m = m + h / 6 * (k1m + 2 * k2m + 2 * k3m + k4m)
                P = P + h / 6 * (k1P + 2 * k2P + 2 * k3P + k4P)
            P = symmetrize(P)
        return GaussianState(m, P)
