"""The filter protocol: every filter of every family, one run loop over any belief.

A filter is a small object holding configuration and the model's numeric functions, plus a
handful of pure functions over a *belief* (a frozen container, :mod:`~nlfilter.filters.beliefs`):

==============================  ========================================================================
``init(m0, P0, batch, ...)``    the belief at the start, for ``B = prod(batch)`` paths (leading axis B)
``predict(belief, k)``          discrete time: the belief of step ``k + 1`` from that of step ``k``
``update(belief, y, k)``        discrete time: condition on ``y (B, m)``; NaN components are missing
``step(belief, dy, t)``         continuous time: the belief at ``t + dt`` after the increment ``dy``
``summary(belief)``             ``(mean (B, n), cov (B, n, n) or None)``: what ``run`` reports and checks
``reset(belief, paths, b0)``    the belief with ``paths`` restarted from ``b0`` (after a divergence)
``extras(belief)``              optional per-step extra outputs ``{name: (B, ...)}`` (family-specific)
``output(estimates)``           optional output map applied once at the end (a post-processor)
==============================  ========================================================================

:meth:`Filter.run` is the one loop. It alone handles the input checks, the batch, the start convention,
fully missing steps, divergence (raise / mark), the progress bar and the output :class:`Estimates`.

Step convention (discrete time)
-------------------------------
``start="update"`` (default, as dynamax): ``ys[..., 0, :]`` measures the state whose prior is
``(m0, P0)``; the filter updates first, then predicts. ``start="predict"`` (as filterpy):
``(m0, P0)`` is the prior one step *before* the state that ``ys[..., 0, :]`` measures; the filter
predicts first. ``simulate(..., start=...)`` takes the same option. In both conventions
``Estimates.means[..., k, :]`` is the filtered mean of the state measured by ``ys[..., k, :]``.
The continuous-discrete filters (an SDE measured at discrete times) default to ``"predict"``:
the prior at ``t0``, the first measurement at ``t0 + dt``, as
:func:`~nlfilter.simulate.simulate_continuous_discrete` makes them.

The data's convention: ``run``/``smooth`` take a :class:`~nlfilter.simulation.Simulation` in place
of ``ys`` and read its :class:`~nlfilter.simulation.Timing` (:meth:`Filter.for_timing`): a filter
built without ``start`` (or, continuous-discrete, ``t0``) takes the Simulation's; one built with
a different one, or with another ``dt``, is refused (ValueError naming both).

Continuous time: ``ys`` are the measurement increments ``dy = h dt + dη`` over ``[t_k, t_k + dt]``,
``t_k = t0 + k dt``; ``means[..., k, :]`` estimates the state at ``t_k + dt`` (aligned with
``Simulation.xs``).

Missing data: a NaN component of ``y`` is missing. A step missing on every path only predicts
(discrete time); otherwise the filter's ``update``/``step`` sees the NaN and uses the observed
components only (exactly: their marginal law, correlated noise included).

Divergence: after each predict and update the summary is checked (finite; covariance symmetric
with eigenvalues ≥ −tol·scale), together with the paths a step reports as failed.
``on_divergence="raise"`` raises :class:`DivergenceError` naming the step and paths; ``"mark"``
records the paths in ``Estimates.diverged`` / ``diverged_step``, fills their later estimates
with NaN (flagged, never silent), restarts them harmlessly from the initial belief and goes on
with the others, whose estimates are those of a run without them.

Backends: ``"numba"`` (or ``"auto"``, the default, where it pays) hands the run to the compiled loop
(``nlfilter.filters.compiled``), which keeps every convention above; this loop is its reference.
"""

from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

from .. import _validate as V
from ..errors import CompileError, DivergenceError
from ..sde_step import ITO_EULER
from ..ode import ode_step  # noqa: F401  (re-exported: it moved to nlfilter.ode)
from ..simulation import Simulation
from ..streams import FILTER, PathRNG
from .backends import AUTO, BACKENDS, load, refusal
from .beliefs import GaussianState, where_paths
from .checks import check_structure, continuous_precision, gaussian_prior, noise_horizon  # noqa: F401  (re-exported)
from .estimates import Estimates
from .linalg import no_information, symmetrize
from .recorder import Recorder, Rows, _blas_limit, loglik_divergence  # noqa: F401  (loglik_divergence re-exported)
from .timing import for_timing, set_start, set_t0  # noqa: F401  (re-exported)


class Filter:
    """Base of every filter: the one run loop over any belief (see the module docstring).

    Subclasses set the class attributes the registry (:data:`nlfilter.filters.REGISTRY`) reads —
    ``family``, ``source`` (seed and equations), ``accepts`` (model kinds), ``needs`` (what the
    model must offer), ``time`` (``"discrete"``: predict/update on ``ys``; ``"continuous"``:
    ``step`` on increments), ``random`` (draws: takes ``rng``), ``covariance`` (what ``covs`` is:
    ``"posterior"``, ``"off-line"``, ``"model"`` or ``"none"``; ``compare`` reports NEES only for
    ``"posterior"``) — and the belief functions."""

    name = "filter"
    family = ""
    source = ""
    accepts: tuple = ()
    needs: tuple = ()
    time = "discrete"
    random = False
    own_prior = False  # True: the filter starts from a prior of its own (run takes m0 = P0 = None)
    # run checks the belief after predict too; a filter whose prediction cannot fail on its own
    # (a density pushed through a kernel) skips that check: a failure shows after the update, same step
    screen_predict = True
    start = "update"
    # what ``Estimates.covs`` is: "posterior" (the filter's own conditional covariance: what NEES
    # tests), "off-line" (the off-line error covariance of the estimator, the same law for every
    # path: its predicted MSE), "model" (a covariance of the filter's model, not of its error),
    # "none" (NaN)
    covariance = "posterior"
    # what ``run(..., loglik=True)`` gives in ``extras["loglik"]``: None (no likelihood),
    # "prediction-error" (the Gaussian filters: log N(y_k; ŷ_k, S_k) of their own predictive
    # moments; exact for a linear-Gaussian model), "exact" (the grid filter: the log-evidence of
    # the grid approximation), "estimate" (the particle filter: log of an unbiased estimate)
    likelihood = None
    # continuous-time filters: how the increment dy of one interval is read, and to what order in
    # dt that is the simulator's convention (the constants of :mod:`nlfilter.sde_step`); "" for
    # discrete-time filters
    measurement_convention = ""
    # the backward pass of :meth:`smooth`: None (no smoother), "rts" (Rauch–Tung–Striebel through
    # the moment rule), "forward-backward" (grid), "particle" (FFBSm); ``smoother_keeps``: the
    # backward pass needs the forward beliefs of every step (not only their summaries)
    smoother = None
    smoother_keeps = False
    # BLAS threads for the run loop: None leaves the BLAS library as it is; a number limits it for
    # the run (threadpoolctl, set once per run): the grid filters' small matrix products lose several
    # times their cost to thread start-up on a few cores (benchmarks/bench_grid.py)
    blas_threads: int | None = None
    # the model structures beyond additive, uncorrelated noise with one constant R that the filter
    # handles (:attr:`~nlfilter.models.Model.structure`): "state-dependent R", "time-varying R" (R_k
    # per step), "cross noise", "non-additive noise", "non-additive measurement noise"; a model with
    # another is refused at construction (check_structure)
    structures: tuple = ()

    @classmethod
    def for_model(cls, model, *, dt: float | None = None, start: str | None = None):
        """An instance for ``model`` with the default options (what ``compare(model, "all")``
        builds): ``cls(model, dt)`` on a continuous-time model (an SDE, a continuous bilinear or
        phase model), ``cls(model)`` on a discrete one, with ``start=start`` for discrete-time
        filters (None: the filter's default, or the data's when run on a Simulation). Filters that
        need more (bounds, a model-specific option) override it."""
        continuous = getattr(model, "kind", None) in ("sde", "phase") or (
            getattr(model, "kind", None) == "bilinear" and not getattr(model, "discrete", False))
        args = (model, dt) if continuous else (model,)
        return cls(*args, start=start) if cls.time == "discrete" else cls(*args)

    def for_timing(self, timing, *, t0=None):
        """``(filter, t0)`` for data of the convention ``timing`` (a
        :class:`~nlfilter.simulation.Timing`, None: no check) and ``run``'s ``t0`` (None: not given):
        this filter, or a copy of it with the data's ``start`` (and, continuous-discrete, ``t0``)
        when it was built without one; the t0 of a continuous run is the data's when not given.
        A convention stated on both sides that differs — ``start``, ``t0``, ``dt``, or data of
        another kind (increments for a filter of discrete measurements, or the reverse) — is a
        ValueError naming both."""
        return for_timing(self, timing, t0=t0)

    # -- the belief functions ----------------------------------------------------------------------
    @property
    def state_dim(self) -> int:
        """Dimension of the reported mean."""
        return self.model.n

    @property
    def data_dim(self) -> int:
        """Dimension ``m`` of one measurement (the last axis of ``ys``)."""
        return self.model.m

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        """The belief at the start for ``prod(batch)`` paths; default the Gaussian prior N(m0, P0)."""
        if initial is not None:
            raise ValueError(f"initial: {type(self).__name__} starts from a Gaussian prior (m0, P0); "
                             f"expected None, got {type(initial).__name__}")
        return gaussian_prior(m0, P0, self.state_dim, batch, who=self)

    def _run_init(self, m0, P0, batch, initial, rng, steps, t0):
        """The run loop's start: :meth:`init`; a filter whose start depends on the run's horizon
        (``steps`` measurements from ``t0``: the off-line gains) overrides it to pass them on."""
        return self.init(m0, P0, batch, initial=initial, rng=rng)

    def predict(self, belief, k):  # pragma: no cover - abstract
        """Predict: the belief of step ``k + 1`` from the (filtered) belief of step ``k``."""
        raise NotImplementedError

    def update(self, belief, y, k):  # pragma: no cover - abstract
        """Update: condition the belief of step ``k`` on ``y (..., m)``; NaN components are
        missing (the update uses the observed components only)."""
        raise NotImplementedError

    def step(self, belief, dy, t):  # pragma: no cover - abstract
        """Continuous time: the belief at ``t + dt`` after the increment ``dy (..., m)`` over
        ``[t, t + dt]``; NaN components are missing (a missing increment leaves the prediction)."""
        raise NotImplementedError

    def summary(self, belief):
        """``(mean (..., n), cov (..., n, n) or None)`` of a belief: what ``run`` reports and checks."""
        return belief.mean, belief.cov

    def reset(self, belief, paths, start):
        """The belief with the paths ``paths`` restarted from ``start`` (field by field)."""
        return where_paths(paths, start, belief)

    def _divergence_reason(self, belief, paths):
        """What failed on the paths ``paths (B,)`` of a belief the run loop is about to report as
        diverged, for its message: ``(text, what, path indices)`` when the filter knows (the grid
        filter: the posterior left the grid), None for the generic message (a non-finite value or
        a covariance that lost positive definiteness)."""
        return None

    def extras(self, belief):
        """Per-step extra outputs ``{name: (B, ...)}`` collected into ``Estimates.extras``; none by default."""
        return None

    def _smooth(self, est: Estimates, beliefs, ys, t0):  # pragma: no cover - abstract
        """The backward pass: ``(means (B, T, n), covs (B, T, n, n))`` smoothed (optionally a third
        item, a dict of per-step extras ``(B, T, ...)``, e.g. the RTS lag-one covariances), from the forward
        estimates ``est`` over ``B`` paths, the forward beliefs of every step (a list of T, when
        ``smoother_keeps``; else None), the measurements ``ys (B, T, m)`` and ``t0``."""
        raise NotImplementedError

    def output(self, est: Estimates) -> Estimates:
        """Output map applied once to the whole run (a post-processor of the means); identity by default."""
        return est

    # ``run`` calls these: a filter whose step functions raise on failure overrides them to return
    # ``(belief, bad paths)`` instead, so that a batch run can mark paths and go on
    def _predict_unchecked(self, belief, k):
        return self.predict(belief, k), None

    def _update_unchecked(self, belief, y, k):
        return self.update(belief, y, k), None

    def _step_unchecked(self, belief, dy, t):
        return self.step(belief, dy, t), None

    def _run_steps(self):
        """``(predict, update)`` of the run loop, chosen once per run: :meth:`_predict_unchecked`,
        :meth:`_update_unchecked` (a configuration may skip the layers of the options it has off)."""
        return self._predict_unchecked, self._update_unchecked

    # ``run(..., loglik=True)`` calls these instead: ``(belief, bad paths, info)`` with ``info`` the
    # step's ``{"loglik": (B,), "innovation": (B, m), "innovation_cov": (B, m, m)}``
    # (:func:`~nlfilter.filters.linalg.innovation_info`); a filter that defines a likelihood
    # (``likelihood`` not None) overrides them
    def _update_info(self, belief, y, k):
        raise TypeError(f"loglik: {type(self).__name__} defines no log-likelihood (its likelihood attribute "
                        "is None); the Gaussian filters, the grid and the particle filters give one")

    _step_info = _update_info

    def check_data(self, ys):
        """``ys`` as a float array ``(..., T, m)``; NaN (missing) allowed, ±inf refused."""
        ys = V.as_float_array("ys", ys, ndim_min=2, shape_tail=(None, self.data_dim))
        B, T, n = math.prod(ys.shape[:-2]), ys.shape[-2], self.state_dim
        if B == 0:  # an empty batch: refused alike by every filter (reductions over paths have no identity)
            raise ValueError(f"ys: expected at least one path, got shape {ys.shape}")
        V.memory("ys", 8.0 * B * T * (n + n * n), f"{B} path(s) × {T} step(s) of estimates (means and covariances "
                 f"of dimension {n})")
        noise_horizon(self, T, B)  # a model's Q/R given per step: as long as the data, one row a path (checks.py)
        return V.finite("ys", ys, allow_nan=True)

    # -- the one loop ------------------------------------------------------------------------------
    def run(self, ys, m0=None, P0=None, *, initial=None, rng=None, t0: float | None = None,
            on_divergence: str = "raise", progress: bool = False, chunk: int | None = None,
            loglik: bool = False, backend: str = "auto") -> Estimates:
        """Filter a batch of measurement sequences ``ys (..., T, m)`` (increments for a
        continuous-time filter) from the prior ``(m0, P0)``.

        Parameters
        ----------
        ys : measurements ``(..., T, m)``; the leading axes are independent paths; NaN is missing;
            or a :class:`~nlfilter.simulation.Simulation`: its ``ys``, read with its timing convention
            (``start``, ``t0``, ``dt``; :meth:`for_timing`)
        m0, P0 : prior mean ``(n,)`` or ``(..., n)`` and covariance ``(n, n)`` or ``(..., n, n)``
            (filters with a prior of their own, e.g. a density on the support, take None)
        initial : a law with ``logpdf``/``sample`` for the filters that take a non-Gaussian prior
            (grid and particle filters); the others refuse it
        rng : the random streams of the filters that draw (``random``): a seed, ``SeedSequence``
            or ``Generator`` (the root: path ``p`` of the flattened batch draws from its stream
            ``FILTER``, :mod:`nlfilter.streams`), or a :class:`~nlfilter.streams.PathRNG` over the
            paths (e.g. ``PathRNG(seed, range(100, 200), key=FILTER)``: the streams of paths
            100..199, so the run gives those rows of the run on all paths); deterministic filters
            draw nothing and ignore it, so one call serves every filter
        t0 : continuous time: the time of the first increment's start (None: 0.0, or a
            Simulation's)
        on_divergence : ``"raise"`` (default) or ``"mark"``
        progress : show a progress bar over the steps (a string: the bar's label, default the
            filter's name)
        chunk : None (all paths at once) or the number of paths per batch: the loop runs the paths
            of the flattened batch in chunks and concatenates (the same numbers for any chunk)
        loglik : also record each step's log-likelihood ``extras["loglik"] (..., T)``, innovation
            ``extras["innovation"] (..., T, m)`` and its predicted covariance
            ``extras["innovation_cov"] (..., T, m, m)`` (``Estimates.loglik`` sums them over time;
            missing components drop out exactly: a step's term is the density of its observed
            components, 0 for a step missing entirely; 0 with no step); a term that is not
            finite (−inf, NaN: data far beyond its predictive law) is a divergence of its path,
            raised or marked as ``on_divergence`` says, the step flagged in the bool
            ``extras["loglik_failed"] (..., T)``; a filter whose ``likelihood`` is None refuses
            (TypeError)
        backend : ``"auto"`` (default: the compiled loop where it is loaded, on disk or repaid by
            the run, :meth:`backend_for`; else this loop), ``"numpy"`` or ``"numba"`` (KF, EKF, UKF,
            CKF, GHKF, SLF, second-order, ``sr-*``, continuous Itô EKF and second-order compiled,
            ``nlfilter.filters.compiled``: the same estimates to 1e-12, on disk, ``NLFILTER_CACHE``; refuses the rest)
            or ``"numba-shared"`` (the loop compiled once per rule and shape for every model, the
            model's functions passed to it: a new model in about a second; the same bits)

        Returns
        -------
        Estimates
            ``means[..., k, :]`` estimates the state measured by ``ys[..., k, :]``.
        """
        return self._drive(ys, m0, P0, initial, rng, t0, on_divergence, progress, chunk, loglik, False, backend)

    def smooth(self, ys, m0=None, P0=None, *, initial=None, rng=None, t0: float | None = None,
               on_divergence: str = "raise", progress: bool = False, chunk: int | None = None,
               backend: str = "auto") -> Estimates:
        """Smoothed estimates of a batch of measurement sequences: the filter's forward pass, then
        its family's backward pass (``smoother``: the Rauch–Tung–Striebel recursion of the Gaussian
        filters through their moment rule, the forward–backward grid smoother, the particle
        smoother). Arguments as :meth:`run`.

        Returns
        -------
        Estimates
            ``means[..., k, :]`` and ``covs[..., k]`` estimate the state measured by
            ``ys[..., k, :]`` given *all* of ``ys`` (``E[x_k | y_0..y_{T-1}]``); a path that
            diverged in the forward pass has NaN smoothed estimates at every step (``diverged``).
        """
        if self.smoother is None:
            raise TypeError(f"smooth: {type(self).__name__} has no smoother (its smoother attribute is None); "
                            "the Gaussian filters, the grid and the particle filters have one")
        return self._drive(ys, m0, P0, initial, rng, t0, on_divergence, progress, chunk, False, True, backend)

    def backend_for(self, B: int, T: int, *, repeats: int = 1, record: bool = False) -> tuple:
        """``(backend, why)`` of ``backend="auto"`` for ``B`` paths × ``T`` steps, ``repeats`` times
        (a fit's evaluations; ``record``: by a run): ``nlfilter.filters.compiled.choice.choose``."""
        if not getattr(self, "compiled", False):  # no class of this filter's declares a compiled loop
            return "numpy", f"{type(self).__name__} has no compiled loop"
        return tuple(load(AUTO)(self, B, T, repeats, record))

    def _drive(self, ys, m0, P0, initial, rng, t0, on_divergence, progress, chunk, loglik, smooth, backend="auto"):
        """The one loop behind :meth:`run` and :meth:`smooth`."""
        if isinstance(ys, Simulation):  # the data's convention (for_timing)
            flt, t0 = self.for_timing(ys.timing, t0=t0)
            ys = ys.ys
            if flt is not self:
                return flt._drive(ys, m0, P0, initial, rng, t0, on_divergence, progress, chunk, loglik, smooth, backend)
        t0 = 0.0 if t0 is None else t0
        on = V.choice("on_divergence", on_divergence, {"raise", "mark"})
        backend = V.choice("backend", backend, {*BACKENDS, "auto"})
        if backend not in ("numpy", "auto"):
            reason = refusal(backend, self)
            if reason is not None:
                raise TypeError(f"backend: {backend!r} cannot run {type(self).__name__}: {reason}; use backend='numpy'")
        if not isinstance(loglik, (bool, np.bool_)):
            raise TypeError(f"loglik: expected True or False, got {V.shown(loglik)}")
        if loglik and self.likelihood is None:
            Filter._update_info(self, None, None, 0)  # raises the TypeError naming loglik
        ys = self.check_data(ys)
        batch, T, m = ys.shape[:-2], ys.shape[-2], ys.shape[-1]
        B = math.prod(batch)
        yf = ys.reshape(B, T, m)
        auto = backend == "auto"  # decided after the data's checks: a run fails them alike on either loop
        backend = ("numpy" if initial is not None else self.backend_for(B, T, record=True)[0]) if auto else backend
        t0 = V.real("t0", t0)
        if self.time != "continuous" and t0 != 0.0:
            raise ValueError(f"t0: a discrete-time filter indexes steps by k; expected 0.0, got {t0!r}")
        if self.time == "continuous":
            V.time_grid(t0, self.dt, T)
        if self.random:
            rng = PathRNG.of(rng, B, key=FILTER)
        if chunk is not None and V.positive("chunk", chunk, integer=True) < B:
            def rows(a, tail, lo, hi):  # a per-path prior (*batch, ...) -> its rows lo..hi-1
                if a is None or np.ndim(a) <= tail:
                    return a
                a = np.asarray(a)
                return np.broadcast_to(a, (*batch, *a.shape[a.ndim - tail:])).reshape(B, *a.shape[a.ndim - tail:])[lo:hi]
            parts = [self._drive(yf[lo:lo + chunk], rows(m0, 1, lo, lo + chunk), rows(P0, 2, lo, lo + chunk),
                                 initial, rng.take(slice(lo, lo + chunk)) if self.random else rng, t0, on, progress,
                                 None, loglik, smooth, backend) for lo in range(0, B, chunk)]
            est = Estimates.concatenate(parts)
            out = lambda a: a.reshape(*batch, *a.shape[1:])  # noqa: E731
            return Estimates(*(out(a) for a in est[:4]), MappingProxyType({k: out(v) for k, v in est.extras.items()}))
        try:
            if backend != "numpy":
                est = load(BACKENDS[backend].run)(self, yf, batch if not smooth else (B,), m0, P0, on, loglik, progress)
                return self._smoothed(est, None, yf, t0, batch, on) if smooth else est
        except CompileError:  # auto: the model's functions do not compile; the NumPy loop runs them
            if not auto:
                raise
        with _blas_limit(self.blas_threads):
            return self._loop(yf, batch, m, m0, P0, initial, rng, t0, on, progress, loglik, smooth)

    def _loop(self, yf, batch, m, m0, P0, initial, rng, t0, on, progress, loglik, smooth):
        """The steps of :meth:`_drive` over ``yf (B, T, m)``, its checks done."""
        B, T = yf.shape[:2]
        belief = self._run_init(m0, P0, batch, initial, rng, T, t0)
        start = belief
        rec = Recorder(self, B, T, on, keep=smooth and self.smoother_keeps)
        steps = range(T)
        if progress:
            from tqdm.auto import tqdm
            steps = tqdm(steps, desc=progress if isinstance(progress, str) else self.name, leave=False)
        ys = Rows.of(yf)  # ys[k]: the step's measurements yf[:, k] (contiguous)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # failures are caught by record
            info = None
            if self.time == "continuous":
                dt = self.dt
                for k in steps:
                    if loglik:
                        belief, bad, info = self._step_info(belief, ys[k], t0 + k * dt)
                    else:
                        belief, bad = self._step_unchecked(belief, ys[k], t0 + k * dt)
                    belief = rec.record(k, belief, bad, start, info=info)
            else:
                offset = 0 if self.start == "update" else 1
                absent = np.isnan(yf).all(axis=(0, 2)).tolist()  # (T,): steps with no measurement on any path
                predict, update = self._run_steps()  # (looked up once: the loop's per-step calls)
                update_info, screen, record, check = self._update_info, self.screen_predict, rec.record, rec.check
                for k in steps:
                    bad = None
                    if k > 0 or offset:
                        belief, bad = predict(belief, k + offset - 1)
                        if screen:
                            belief, bad = check(k, belief, bad, start), None
                    if not absent[k]:
                        if loglik:
                            belief, bad_u, info = update_info(belief, ys[k], k + offset)
                        else:
                            belief, bad_u = update(belief, ys[k], k + offset)
                        bad = bad_u if bad is None else (bad if bad_u is None else bad | bad_u)
                    elif loglik:  # nothing measured: the step adds nothing to the likelihood
                        info = no_information(B, m)
                    belief = record(k, belief, bad, start, info=info)
        if loglik and T == 0:  # no step: an empty likelihood (Estimates.loglik sums to 0)
            rec.extras = {k: np.empty((B, 0, *v.shape[1:]), v.dtype)
                          for k, v in {**no_information(B, m), "loglik_failed": np.zeros(B, bool)}.items()}
        if not smooth:
            return self.output(rec.result(batch))
        return self._smoothed(rec.result((B,)), rec.beliefs, yf, t0, batch, on)

    def _smoothed(self, est, beliefs, yf, t0, batch, on="raise"):
        """The family's backward pass over the forward pass ``est`` (paths flattened). A path the
        backward pass leaves non-finite (where the forward pass did not diverge) is raised or marked
        as a divergence of the smoother (``on``; ``diverged_step``: the last step it left
        non-finite) — never returned silently."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            means, covs, *more = self._smooth(est, beliefs, yf, t0)
        d = est.diverged
        lost = ~d & ~(np.all(np.isfinite(means), axis=-1) & np.all(np.isfinite(covs), axis=(-1, -2))).all(axis=-1)
        if lost.any():
            idx = np.flatnonzero(lost)
            bad_k = ~(np.all(np.isfinite(means[idx]), axis=-1) & np.all(np.isfinite(covs[idx]), axis=(-1, -2)))
            last = bad_k.shape[-1] - 1 - np.argmax(bad_k[:, ::-1], axis=-1)  # the backward pass met it first
            if on == "raise":
                raise DivergenceError(
                    f"{self.name}: the smoother's backward pass became non-finite at step {int(last.max())} on "
                    f"{idx.size} path(s), first {idx[:5].tolist()}; pass on_divergence='mark' to record such paths "
                    "and go on", step=int(last.max()), paths=idx, what="smoother")
            d = d | lost
            step = est.diverged_step.copy()
            step[idx] = last
            est = est._replace(diverged=d, diverged_step=step)
        nan = lambda a: np.where(d.reshape(-1, *(1,) * (a.ndim - 1)), np.nan, a)  # noqa: E731
        out = lambda a: a.reshape(*batch, *a.shape[1:])  # noqa: E731
        extras = {k: out(nan(v)) for k, v in (more[0] if more and more[0] else {}).items()}
        return Estimates(out(nan(means)), out(nan(covs)), d.reshape(batch), est.diverged_step.reshape(batch),
                         MappingProxyType(extras))


class DiscreteFilter(Filter):
    """Base of discrete-time filters on a :class:`~nlfilter.models.DiscreteModel`: subclasses give
    ``predict(state, k)`` and ``update(state, y, k)`` over a :class:`GaussianState`."""

    accepts = ("discrete",)

    def __init__(self, model, *, start: str | None = None):
        if getattr(model, "kind", None) != "discrete":
            raise TypeError(f"model: {type(self).__name__} expects a DiscreteModel, got {type(model).__name__}")
        check_structure(self, model)
        self.model = model
        set_start(self, start)


class ContinuousFilter(Filter):
    """Base of continuous-time filters on an :class:`~nlfilter.models.SDEModel` observed through increments
    ``dy`` on a grid of step ``dt``. Subclasses give ``step(state, dy, t)``: the belief at
    ``t + dt`` after the increment over ``[t, t + dt]``. ``run`` returns estimates at
    ``t_1 .. t_T`` (``t_k = t0 + k dt``), aligned with ``Simulation.xs``."""

    accepts = ("sde",)
    time = "continuous"
    measurement_convention = ITO_EULER

    def __init__(self, model, dt: float, *, scheme: str = "rk4", substeps: int = 1):
        if getattr(model, "kind", None) != "sde":
            raise TypeError(f"model: {type(self).__name__} expects an SDEModel, got {type(model).__name__}")
        self.model = check_structure(self, model)  # angles: refused (increments dy are not angles)
        self.dt = float(V.positive("dt", dt))
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        self.substeps = V.positive("substeps", substeps, integer=True)

    def integrate(self, rhs, state: GaussianState, z, t) -> GaussianState:
        """Integrate ``d(m, P)/dt = rhs(m, P, z, t)`` over one measurement step (``scheme``,
        ``substeps``; :func:`~nlfilter.ode.ode_step`), symmetrizing P after each substep."""
        m, P = ode_step(lambda x, s: rhs(x[0], x[1], z, s), tuple(state), t, self.dt, substeps=self.substeps,
                        scheme=self.scheme, finish=lambda x: (x[0], symmetrize(x[1])))
        return GaussianState(m, P)
