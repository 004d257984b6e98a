"""Monte Carlo evaluation: MSE per step and over a window with standard errors, NEES, paired
differences between filters run on common random numbers.

Standard errors treat the paths as independent replicates: a window average is first taken
within each path, then the mean and standard error are taken across paths (so the serial
correlation of the errors within a path is accounted for). Diverged paths (``Estimates.diverged``)
are left out and counted.
"""

from __future__ import annotations

import contextlib
import contextvars
from typing import NamedTuple

import numpy as np

from . import _validate as V
from .angles import near
from . import streams
from .filters.estimates import Estimates
from .simulation import Simulation


class Summary(NamedTuple):
    """A Monte Carlo mean with its standard error, over ``paths`` paths (``diverged`` left out)."""

    value: float
    stderr: float
    paths: int
    diverged: int


def _means_and_mask(est, xs, angles=()):
    """The estimates' means, the truth ``xs (..., T, n)`` and the paths that did not diverge, checked:
    a truth with NaN/inf (a simulation's diverged paths: drop them first) or an empty batch would
    give a NaN summary, and a non-finite mean on a path that did not diverge is not an estimate.
    ``angles``: the angular state components, whose means are moved by whole turns to the branch of
    the truth (:func:`~nlfilter.angles.near`), so that every error ``mean − x`` is wrapped."""
    means = est.means if hasattr(est, "means") else V.as_float_array("estimates", est)
    xs = V.finite("xs", V.as_float_array("xs", xs, ndim_min=2))
    if means.shape != xs.shape:
        raise ValueError(f"estimates: expected the shape of xs {xs.shape}, got {means.shape}")
    if xs.size == 0:
        raise ValueError(f"xs: expected at least one path and one step, got shape {xs.shape}")
    div = getattr(est, "diverged", None)
    ok = np.ones(means.shape[:-2], dtype=bool) if div is None else ~np.asarray(div)
    bad = ok & ~np.isfinite(means).all(axis=(-2, -1))
    if bad.any():
        raise ValueError(f"estimates: expected finite means on the paths that did not diverge, got non-finite "
                         f"ones on {int(bad.sum())} path(s) (first {np.argwhere(bad)[0].tolist()})")
    return near(means, xs, tuple(angles)), xs, ok


def _component(component, n: int) -> int:
    """``component`` checked as an index of the state's ``n`` components."""
    if isinstance(component, (bool, np.bool_)) or not isinstance(component, (int, np.integer)):
        raise TypeError(f"component: expected an integer index of the state, got {component!r}")
    if not -n <= component < n:
        raise ValueError(f"component: expected an index from 0 to {n - 1}, got {component}")
    return int(component)


def _window(T, window):
    if window is None:
        return slice(None)
    if isinstance(window, slice):
        return window
    if isinstance(window, float) and 0.0 <= window < 1.0:  # fraction of the run to discard
        return slice(int(round(window * T)), None)
    raise TypeError(f"window: expected None, a slice, or the fraction in [0, 1) of the run to skip, got {window!r}")


def _summary(per_path: np.ndarray, ok: np.ndarray) -> Summary:
    vals = per_path[ok]
    npaths = vals.size
    if npaths == 0:
        return Summary(float("nan"), float("nan"), 0, int((~ok).sum()))
    se = float(np.std(vals, ddof=1) / np.sqrt(npaths)) if npaths > 1 else float("nan")
    return Summary(float(np.mean(vals)), se, npaths, int((~ok).sum()))


def squared_errors(est, xs, component=None, *, angles=()) -> np.ndarray:
    """Squared errors ``(paths, T)`` of one component (or ``(paths, T, n)`` when ``None``);
    ``angles``: the angular state components, their errors wrapped (:mod:`nlfilter.angles`; every
    function of this module takes it)."""
    means, xs, _ = _means_and_mask(est, xs, angles)
    e2 = (means - xs) ** 2
    return e2 if component is None else e2[..., _component(component, e2.shape[-1])]


def mse(est, xs, *, component: int = 0, window=None, angles=()) -> Summary:
    """Window-averaged MSE of ``component`` over paths, with its standard error.

    ``window``: ``None`` (whole run), a ``slice`` of steps, or a fraction in ``[0, 1)`` of the
    run to discard (``0.5`` = second half).

    >>> xs = np.zeros((4, 10, 1)); m = np.ones((4, 10, 1)) * np.arange(4)[:, None, None]
    >>> mse(m, xs).value
    3.5
    """
    means, xs, ok = _means_and_mask(est, xs, angles)
    component = _component(component, xs.shape[-1])
    e2 = (means[..., component] - xs[..., component]) ** 2
    w = _window(e2.shape[-1], window)
    per_path = np.mean(e2[..., w], axis=-1) if e2.shape[-1] else e2
    return _summary(np.reshape(per_path, -1), np.reshape(ok, -1))


def mse_per_step(est, xs, *, component: int = 0, angles=()):
    """MSE at each step ``(T,)`` and its standard error ``(T,)`` (diverged paths left out)."""
    means, xs, ok = _means_and_mask(est, xs, angles)
    component = _component(component, xs.shape[-1])
    e2 = ((means[..., component] - xs[..., component]) ** 2).reshape(-1, means.shape[-2])
    return _per_step(e2, np.reshape(ok, -1))


def _per_step(e2: np.ndarray, ok: np.ndarray):
    """:func:`mse_per_step` from the squared errors ``e2 (paths, T)`` and the paths ``ok (paths,)``
    that did not diverge (e.g. per-path arrays of Monte Carlo blocks, :mod:`nlfilter.montecarlo`)."""
    e2 = e2[ok]
    if e2.shape[0] < 2:
        raise ValueError(f"estimates: need at least 2 non-diverged paths, got {e2.shape[0]}")
    return e2.mean(axis=0), e2.std(axis=0, ddof=1) / np.sqrt(e2.shape[0])


def nees(est, xs, *, window=None, label: str = "estimates", angles=()) -> Summary:
    """Average normalized estimation error squared ``eᵀ P⁻¹ e`` (≈ n for a consistent filter).

    Meaningful only where ``est.covs`` is the filter's own error covariance (a filter's
    ``covariance == "posterior"``). A covariance in the window that is not finite and positive
    definite on a path that did not diverge makes NEES undefined: a ``ValueError`` names
    ``label``, the path and the step (never a bare ``LinAlgError``).

    >>> from nlfilter.filters.base import Estimates
    >>> e = Estimates(np.zeros((2, 3, 1)), np.ones((2, 3, 1, 1)), np.zeros(2, bool), np.full(2, -1))
    >>> nees(e, np.ones((2, 3, 1))).value
    1.0
    >>> e.covs[1, 2] = 0.0
    >>> nees(e, np.ones((2, 3, 1)), label="ukf")
    Traceback (most recent call last):
    ...
    ValueError: ukf: NEES undefined: the covariance at path 1, step 2 is not positive definite (smallest eigenvalue 0)
    """
    return _summary(*nees_per_path(est, xs, window=window, label=label, angles=angles))


def nees_per_path(est, xs, *, window=None, label: str = "estimates", angles=()):
    """The per-path window means of :func:`nees` and the flags of the paths that did not diverge ->
    ``(per_path (paths,), ok (paths,))``, whose mean over the paths ``ok`` is :func:`nees` (for the
    per-path arrays of Monte Carlo blocks, :mod:`nlfilter.montecarlo`); errors as :func:`nees`."""
    means, xs, ok = _means_and_mask(est, xs, angles)
    covs = np.asarray(est.covs, dtype=float)
    w = _window(means.shape[-2], window)
    e = (xs - means)[..., w, :]
    P = covs[..., w, :, :]
    okP = np.broadcast_to(ok[..., None], P.shape[:-2])
    safe = np.where(okP[..., None, None] & np.isfinite(P).all(axis=(-1, -2))[..., None, None], P, np.eye(P.shape[-1]))
    lam = np.linalg.eigvalsh(0.5 * (safe + np.swapaxes(safe, -1, -2)))
    bad = okP & ~(np.isfinite(P).all(axis=(-1, -2)) & (lam[..., 0] > 0))
    if bad.any():
        where = np.argwhere(bad)[0]
        step = int(where[-1]) + (w.start or 0) % max(means.shape[-2], 1)
        path = ", ".join(str(int(i)) for i in where[:-1]) or "0"
        raise ValueError(f"{label}: NEES undefined: the covariance at path {path}, step {step} is not positive "
                         f"definite (smallest eigenvalue {lam[tuple(where)][0]:.3g})")
    sol = np.linalg.solve(safe, np.where(okP[..., None], e, 0.0)[..., None])[..., 0]
    q = np.einsum("...i,...i->...", np.where(okP[..., None], e, 0.0), sol)
    return np.reshape(np.mean(q, axis=-1), -1), np.reshape(ok, -1)


def paired_difference(est_a, est_b, xs, *, component: int = 0, window=None, angles=()) -> Summary:
    """MSE(a) − MSE(b) on the same paths (common random numbers), with its standard error."""
    ma, xs_, ok_a = _means_and_mask(est_a, xs, angles)
    mb, _, ok_b = _means_and_mask(est_b, xs, angles)
    component = _component(component, xs_.shape[-1])
    d = (ma[..., component] - xs_[..., component]) ** 2 - (mb[..., component] - xs_[..., component]) ** 2
    w = _window(d.shape[-1], window)
    return _summary(np.reshape(np.mean(d[..., w], axis=-1), -1), np.reshape(ok_a & ok_b, -1))


class LogLik(NamedTuple):
    """A record's log-likelihood ``value (...,)`` (per path of ``ys``), the standard error of that
    value over ``replicates`` independent runs of a random filter (0 for a deterministic one), and
    the spread (standard deviation) of a single run's estimate; ``diverged (...,)``: the records
    on which the filter (any replicate) diverged (``run_kw`` ``on_divergence="mark"``: their value
    is NaN, flagged here; a log-likelihood term that is not finite is such a divergence)."""

    value: np.ndarray
    stderr: np.ndarray
    spread: np.ndarray
    replicates: int
    diverged: np.ndarray | None = None


def loglik(flt, ys, m0=None, P0=None, *, replicates: int = 1, rng=0, **run_kw) -> LogLik:
    """``log p(y_0..y_{T-1})`` of each record ``ys (..., T, m)`` by ``flt`` (``run(..., loglik=True)``);
    ``ys`` may be a :class:`~nlfilter.simulation.Simulation` (its timing convention is read).

    A random filter (the particle filter: ``Filter.likelihood == "estimate"``) is run
    ``replicates`` times on independent streams in one batch (the records tiled along a new
    leading axis: replicate ``j`` of path ``p`` is path ``j·P + p`` of the run, :mod:`nlfilter.streams`):
    ``value`` is the mean of the log-estimates, ``stderr`` its standard error, ``spread`` the
    standard deviation of one run's log-estimate (the log of the unbiased likelihood estimate is
    biased low by about spread²/2). A deterministic filter runs once (``replicates`` must be 1)."""
    R = V.positive("replicates", replicates, integer=True)
    if flt.likelihood is None:
        raise TypeError(f"flt: {type(flt).__name__} defines no log-likelihood (its likelihood attribute is None)")
    if not flt.random and R != 1:
        raise ValueError(f"replicates: {type(flt).__name__} is deterministic: its log-likelihood has no spread; "
                         f"expected 1, got {R}")
    sim = ys if isinstance(ys, Simulation) else None  # run reads its timing (Filter.for_timing)
    ys = V.as_float_array("ys", sim.ys if sim is not None else ys)  # complex data is refused, not cut to its real part
    tiled = np.broadcast_to(ys, (R, *ys.shape)) if R > 1 else ys
    data = tiled if sim is None else sim._replace(ys=tiled)
    est = flt.run(data, m0, P0, rng=rng, loglik=True, **run_kw)
    ll = est.loglik
    if R == 1:
        zero = np.zeros(np.shape(ll))
        return LogLik(ll, zero, zero, 1, est.diverged)
    sd = ll.std(axis=0, ddof=1)
    return LogLik(ll.mean(axis=0), sd / np.sqrt(R), sd, R, est.diverged.any(axis=0))


def stream(seed: int, k: int) -> np.random.SeedSequence:
    """The root of case ``k`` of ``seed``: ``SeedSequence(seed).spawn(k + 1)[k]``, computed without
    state (:func:`nlfilter.streams.child`); one per experiment case, so cases do not depend on each
    other's sizes. Path ``p`` of the case is then simulated from ``stream(seed, k).spawn(...)[p]``
    and a random filter on it draws from that path's sub-stream ``streams.FILTER``
    (:mod:`nlfilter.streams`): the rows depend on the seed and the path index only."""
    V.positive("k", k + 1, integer=True)
    return streams.child(streams.root(seed), k)


_CHUNK: contextvars.ContextVar = contextvars.ContextVar("chunk", default=None)


def chunk() -> int | None:
    """Paths per batch of the running experiment (``Experiment.run(chunk=)``, CLI ``--chunk``), or
    None (all at once): what the experiments pass to :func:`in_chunks` and ``Filter.run(chunk=)``.
    An execution option: it never changes a number."""
    return _CHUNK.get()


@contextlib.contextmanager
def chunked(n: int | None):
    """Run the block with :func:`chunk` ``= n`` (None: all paths at once)."""
    if n is not None:
        V.positive("chunk", n, integer=True)
    token = _CHUNK.set(n)
    try:
        yield
    finally:
        _CHUNK.reset(token)


def _concat(parts):
    first = parts[0]
    if isinstance(first, np.ndarray):
        return np.concatenate(parts)
    if isinstance(first, Estimates):
        return Estimates.concatenate(parts)
    if isinstance(first, Simulation):  # one time grid
        return first._replace(**{f: np.concatenate([getattr(p, f) for p in parts]) for f in first._fields if f != "t"})
    if isinstance(first, dict):
        return {k: _concat([p[k] for p in parts]) for k in first}
    if isinstance(first, tuple):
        return tuple(_concat(list(c)) for c in zip(*parts))
    raise TypeError(f"fn: expected arrays, Simulations, Estimates or tuples/dicts of them, got {type(first).__name__}")


def in_chunks(fn, paths: int, size: int | None = None):
    """``fn(rows)`` for the path ranges ``rows = range(a, b)`` of ``paths`` paths in chunks of
    ``size`` (default :func:`chunk`; None: one range), concatenated along the paths axis (arrays,
    :class:`~nlfilter.simulation.Simulation`, Estimates, and tuples or dicts of them). With per-path
    streams (``simulate(paths=rows, rng=root)``) the result does not depend on ``size``."""
    V.positive("paths", paths, integer=True)
    size = chunk() if size is None else V.positive("size", size, integer=True)
    size = paths if size is None else size
    return _concat([fn(range(a, min(a + size, paths))) for a in range(0, paths, size)])
