"""Bootstrap particle filter, batched over paths (see :mod:`nlfilter.filters.reference`).

The belief is a :class:`ParticleBelief`: particles ``x (B, Np, n)``, their log-weights
``logw (B, Np)`` and the per-path generators the filter draws from (a
:class:`~nlfilter.streams.PathRNG`: path ``p`` draws its particles from its own stream, so a run
on some paths gives the rows of the run on all paths, bitwise).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ... import _validate as V
from ...angles import angles_of, near, residual, weighted_moments, wrap_components
from ...sde_step import LEFT_POINT, SUBSTEPS, euler_maruyama, increment_loglik
from ...noise import Gaussian, initial_states
from ...streams import FILTER, PathRNG
from ..checks import refuse_infinite
from ..pointmass import cloud_moments, weights
from ..linalg import gaussian_loglik, innovation_info, measurement_loglik, mm, no_information, observed_precision
from ._reference_base import _ReferenceFilter
from .forward_backward import backward_simulation, ffbsm, transition_logpdf


class ParticleBelief(NamedTuple):
    """Particles ``x (B, Np, n)``, log-weights ``logw (B, Np)`` (unnormalized: the weights of the
    last update, kept until the next ``predict``/``step`` resamples), the per-path generators
    ``rng`` (one object for the run: a restarted path keeps drawing from its stream), and ``w``:
    the normalized weights of ``logw`` (:func:`~nlfilter.filters.pointmass.weights`), computed
    once by the update for the step's summary, ESS and resampling, or None (computed when needed)."""

    x: np.ndarray
    logw: np.ndarray
    rng: PathRNG
    w: np.ndarray | None = None

    _shared = ("rng",)


def _dead_paths(logw):
    """``(B,)``: the paths whose log-weights ``(B, N)`` have no finite maximum (zero mass everywhere,
    or a non-finite likelihood): returned as ``bad`` to the run loop, which raises or marks them;
    None when there are none (the loop's fast path)."""
    mx = np.max(logw, axis=-1)
    dead = ~np.isfinite(mx)
    return dead if dead.any() else None


def _weights(belief):
    """The normalized weights of a belief's ``logw``: its ``w``, or computed."""
    return weights(belief.logw) if belief.w is None else belief.w


def _draw(law, rng, shape):
    """``(B, *shape, d)`` draws of the noise law ``law``, path ``i`` from ``rng``'s generator ``i``:
    ``rng.sample(law, shape)``, bitwise. A :class:`~nlfilter.noise.Gaussian`'s standard normals are
    drawn path by path and its ``mean + z Sᵀ`` applied once to all, in place (``Gaussian.sample``'s
    arithmetic: with ``r = 1`` the 1 × 1 matmul's one product, as :func:`~nlfilter.filters.linalg.mm`;
    else the stacked matmul, which makes the per-path matmul's call for each path)."""
    if type(law) is not Gaussian:
        return rng.sample(law, shape)
    z = rng.standard_normal((*shape, law.dim))
    if law.dim == 1:
        z *= law._sqrt[0, 0]
    else:
        z = z @ law._sqrt.T
    z += law.mean
    return z


def systematic_resample(w, rng):
    """Systematic resampling of each row of ``w (B, Np)`` (normalized weights): indices ``(B, Np)``,
    one uniform draw per row, from the row's generator (``rng`` a
    :class:`~nlfilter.streams.PathRNG` over the rows) or from one ``Generator``."""
    B, Np = w.shape
    c = np.cumsum(w, axis=1)
    c[:, -1] = 1.0
    u = ((rng.random((1,)) if isinstance(rng, PathRNG) else rng.random((B, 1))) + np.arange(Np)) / Np
    off = np.arange(B)[:, None]
    idx = np.searchsorted((c + off).ravel(), (u + off).ravel(), side="right")
    return np.minimum(idx.reshape(B, Np) - off * Np, Np - 1)


class ParticleFilter(_ReferenceFilter):
    """Bootstrap particle filter, batched over paths; see :mod:`nlfilter.filters.reference`.
    Discrete models: ``predict``/``update``; SDE models: ``step`` (``time`` is ``"continuous"``).
    ``run(..., rng=)`` seeds the particles (a seed, SeedSequence or Generator: path ``p`` draws
    from the stream ``FILTER`` of path ``p``, :mod:`nlfilter.streams`; or a
    :class:`~nlfilter.streams.PathRNG` over the paths); the prior is N(m0, P0) (one for all paths)
    or the law ``initial``.

    Parameters
    ----------
    model : DiscreteModel or SDEModel
    particles : number of particles per path
    dt, substeps : SDE models: measurement step and Euler–Maruyama steps per measurement step;
        ``substeps`` None (default): the data's when run on a Simulation (``sim.timing.substeps``:
        the simulator's model, :meth:`for_timing`), else :data:`~nlfilter.sde_step.SUBSTEPS` (the
        default of :func:`~nlfilter.simulate.simulate` and ``compare``); one given explicitly is
        kept whatever the data's (a finer one is a legitimate choice: nearer the SDE than the
        simulator's Euler scheme, but not the simulator's model exactly; ``compare`` records the
        difference in its certificate)
    threshold : resample when ESS < threshold · particles
    start : discrete models: step convention

    Notes
    -----
    ``Estimates.extras["ess"] (..., T)``: the effective sample size of each step's weights.
    """

    name = "particle"
    source = "bootstrap particle filter (Gordon, Salmond & Smith 1993), systematic resampling"
    needs = ("noise density",)
    random = True
    structures = ("state-dependent R", "time-varying R", "non-additive noise", "angles")
    measurement_convention = LEFT_POINT
    blas_threads = 1  # small dense products per step (the summary's): one BLAS thread (base.Filter.blas_threads)
    means_only = False  # True: the summary's covariance is not computed (NaN in the output): a run read for its MSE only

    def __init__(self, model, particles: int = 2000, *, dt: float | None = None, substeps: int | None = None,
                 threshold: float = 0.5, start: str | None = None):
        self._options(particles, substeps, threshold)
        self._setup(model, dt, start, "particle filter")
        self._set_smoother()

    def _options(self, particles, substeps, threshold):
        """``particles``, ``substeps`` (and whether stated) and ``threshold``, checked."""
        self.particles = V.positive("particles", particles, integer=True)
        self.threshold = V.real("threshold", threshold)
        if not 0.0 <= self.threshold <= 1.0:
            raise ValueError(f"threshold: expected a number in [0, 1], got {threshold!r}")
        self.substeps_stated = substeps is not None
        self.substeps = SUBSTEPS if substeps is None else V.positive("substeps", substeps, integer=True)

    def _set_smoother(self):
        """No smoother on an SDE with ``substeps > 1``: it needs the transition density of one
        Euler–Maruyama step (the class's FFBSm otherwise)."""
        if self.time == "continuous" and self.substeps != 1:
            self.smoother = None
        else:
            self.__dict__.pop("smoother", None)

    def for_timing(self, timing, *, t0=None):
        """As :meth:`~nlfilter.filters.base.Filter.for_timing`; on an SDE, a filter built without
        ``substeps`` also takes the data's Euler–Maruyama substeps (``timing.substeps``: the
        simulator's model, :mod:`nlfilter.sde_step`); one built with ``substeps`` keeps its own."""
        flt, t0 = super().for_timing(timing, t0=t0)
        sub = getattr(timing, "substeps", None)  # None but for SDE data (increments, continuous-discrete)
        if getattr(self, "substeps_stated", True) or sub is None or sub == flt.substeps:
            return flt, t0
        import copy
        flt = copy.copy(flt)
        flt.substeps = int(sub)
        flt._set_smoother()
        return flt, t0

    # -- the belief functions ----------------------------------------------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None) -> ParticleBelief:
        """``particles`` draws per path from N(m0, P0) (one prior for all paths) or the law
        ``initial``, each path from its own stream; equal weights."""
        md = self.model
        if initial is None and np.ndim(m0) > 1:
            raise ValueError(f"m0: the particle filter takes one prior mean ({md.n},) for all paths, "
                             f"got shape {np.shape(m0)}")
        B, Np = int(np.prod(batch)), self.particles
        rng = PathRNG.of(rng, B, key=FILTER)
        refuse_infinite(P0, type(self).__name__)
        x = initial_states(md.n, B, rng, m0=m0, P0=P0, initial=initial, shape=(Np,))
        return ParticleBelief(x, np.zeros((B, Np)), rng)

    def predict(self, belief: ParticleBelief, k) -> ParticleBelief:
        """Discrete time: resample (systematic) the paths whose ESS is below ``threshold ·
        particles``, then propagate every particle through ``f(x, k) + G(x, k) w``."""
        self._need("discrete", "predict")
        x, logw = self._resample(belief)
        return ParticleBelief(self._propagate(x, k, belief.rng), logw, belief.rng)

    def update(self, belief: ParticleBelief, y, k) -> ParticleBelief:
        """Discrete time: weight by the likelihood of ``y (B, m)`` (NaN components missing); raises
        :class:`~nlfilter.errors.DivergenceError` where ``y`` is impossible for every particle."""
        belief, bad = self._update_unchecked(belief, y, k)
        self._raise_dead(bad, f"step {k}")
        return belief

    def step(self, belief: ParticleBelief, dy, t) -> ParticleBelief:
        """SDE: resample as in ``predict``, Euler–Maruyama over ``[t, t + dt]`` (``substeps``), then
        weight by the exact likelihood of the increment ``dy (B, m)`` given each particle's path,
        ``N(dy; ∫ h ds, R dt)`` with the simulator's left-point ``∫ h ds``
        (:mod:`nlfilter.sde_step`: the same model as :func:`~nlfilter.simulate.simulate` at equal
        ``substeps``)."""
        belief, bad = self._step_unchecked(belief, dy, t)
        self._raise_dead(bad, f"t = {t}")
        return belief

    def summary(self, belief: ParticleBelief):
        """Weighted mean and covariance of the particles (the mean alone, covariance None, when
        ``means_only``: the certificate's refinement run, the yardstick's ``_check``)."""
        ang = angles_of(self.model).states
        if ang:  # circular means of the angular states (nlfilter.angles)
            return weighted_moments(_weights(belief), belief.x, ang, cov=not self.means_only)
        return cloud_moments(_weights(belief), belief.x, cov=not self.means_only)

    def extras(self, belief: ParticleBelief):
        """``ess (B,)`` per step: the effective sample size ``1 / Σ w²`` of the weights after the
        step's update (``particles`` right after a resampling with no measurement)."""
        w = _weights(belief)
        return {"ess": 1.0 / np.sum(w * w, axis=1)}

    def reset(self, belief: ParticleBelief, paths, start):
        """The belief with the paths ``paths`` restarted from ``start`` (field by field), its
        weights ``w`` recomputed when needed."""
        return super().reset(belief._replace(w=None), paths, start._replace(w=None))

    def _update_unchecked(self, belief, y, k):
        self._need("discrete", "update")
        return self._weigh(belief, belief.x, belief.logw, y, k)

    def _step_unchecked(self, belief, dy, t):
        self._need("continuous", "step")
        x, logw = self._resample(belief)
        x, hbar = self._propagate(x, t, belief.rng)
        return self._weigh(belief, x, logw, dy, t + self.dt, hbar=hbar)

    likelihood = "estimate"

    def _update_info(self, belief, y, k):
        """``run(..., loglik=True)``: the update and ``log Σ_i w̄_i p(y | x_i)`` (w̄ the normalized
        predictive weights): the log of the step's factor of the bootstrap filter's unbiased
        estimate of the likelihood (Del Moral 2004, Prop. 7.4.1; its log is biased low by about
        half its variance), with the innovation ``y − Σ w̄_i h(x_i)`` and ``Cov_w̄[h] + R``."""
        self._need("discrete", "update")
        return self._weigh(belief, belief.x, belief.logw, y, k, info=True)

    def _step_info(self, belief, dy, t):
        """``run(..., loglik=True)``: the step and the estimate of the density of ``dy`` (as
        :meth:`_update_info`, with ``N(dy; ∫ h ds, R dt)`` along each particle's path)."""
        self._need("continuous", "step")
        x, logw = self._resample(belief)
        x, hbar = self._propagate(x, t, belief.rng)
        return self._weigh(belief, x, logw, dy, t + self.dt, info=True, hbar=hbar)

    # -- the pieces ----------------------------------------------------------------------------
    def _weigh(self, belief, x, logw, y, k, info: bool = False, hbar=None):
        """The belief after adding the log-likelihood of ``y``; a dead path (no finite log-weight)
        gets equal weights and is returned as bad. With ``info`` also the step's likelihood
        output (:meth:`_update_info`). ``hbar (B, Np, m)``: SDEs, ``∫ h ds / dt`` along each
        particle's path of the interval."""
        out = None
        if not np.all(np.isnan(y)):
            ll = self._loglik(x, y, k, hbar)
            if info:
                out = self._info(x, logw, ll, y, k, hbar)
            logw = logw + ll
        elif info:
            out = no_information(*y.shape)
        bad = _dead_paths(logw)
        if bad is not None:
            logw = np.where(bad[:, None], 0.0, logw)
        return (ParticleBelief(x, logw, belief.rng, weights(logw)), bad) + ((out,) if info else ())

    def _info(self, x, logw, ll, y, k, hbar=None):
        md = self.model
        w = weights(logw)  # the predictive weights
        a = np.log(w) + ll
        with np.errstate(divide="ignore", invalid="ignore"):
            mx = np.max(a, axis=-1)
            lev = mx + np.log(np.sum(np.exp(a - np.where(np.isfinite(mx), mx, 0.0)[:, None]), axis=-1))
        hx = md.h(x, self._at(k)) if hbar is None else hbar
        ang = angles_of(md).measurements
        Eh, Ch = weighted_moments(w, hx, ang) if ang else cloud_moments(w, hx)
        Eh = near(Eh, y, ang)  # angles: the wrapped innovation
        if hbar is None:  # samples y = h(x) + v: Cov[y] = Cov[h] + E[R(x)]
            res = innovation_info(y, Eh, Ch + (md.R if md.R_constant else np.einsum("bp,bpij->bij", w, md.R_of(x, k))))
        else:  # the Kallianpur–Striebel ratio times the density of dy under pure noise N(0, R dt)
            lev = lev + innovation_info(y, np.zeros_like(y), md.R * self.dt)["loglik"]
            res = innovation_info(y / self.dt, Eh, Ch + md.R / self.dt, scale=self.dt)
        res["loglik"] = np.where(np.isnan(y).all(axis=-1), 0.0, lev)  # nothing measured on the path: exactly 0
        return res

    def _resample(self, belief):
        """``(x, logw)`` with the paths whose ESS < threshold · particles resampled (systematic)."""
        x, logw = belief.x, belief.logw
        Np = self.particles
        w = _weights(belief)
        ess = 1.0 / np.sum(w**2, axis=1)
        rs = ess < self.threshold * Np
        if rs.any():
            rows = np.flatnonzero(rs)
            idx = systematic_resample(w[rows], belief.rng.take(rows))
            B, n = x.shape[0], x.shape[-1]
            picked = x.reshape(B * Np, n)[(idx + Np * rows[:, None]).ravel()]  # one gather of the new clouds
            if rows.size == B:
                x, logw = picked.reshape(x.shape), np.zeros_like(logw)
            else:
                x, logw = x.copy(), logw.copy()
                x[rows] = picked.reshape(rows.size, Np, n)
                logw[rows] = 0.0
        return x, logw

    def _propagate(self, x, t, rng):
        """The particles one step on: ``f(x, k) + G(x, k) w`` (discrete, ``t = k``), or
        ``(x, h̄)``: Euler–Maruyama substeps over ``[t, t + dt]`` and ``h̄ = ∫ h ds / dt`` along
        them (SDE, :func:`~nlfilter.sde_step.euler_maruyama`: the simulator's arithmetic)."""
        md = self.model
        if md.kind == "discrete":
            w = _draw(md.process_noise, rng, x.shape[1:-1])
            # f(x) + G(x) w, or f(x, w) for non-additive noise (angular states wrapped)
            return wrap_components(md.transition(x, w, t), angles_of(md).states)
        x, ih = self._euler_maruyama(x, t, self.dt, rng)
        return x, ih / self.dt

    def _euler_maruyama(self, x, t, dt, rng):
        """``(x at t + dt, ∫ h ds)``: the ``substeps`` Euler–Maruyama steps of ``[t, t + dt]``
        (:func:`~nlfilter.sde_step.euler_maruyama`), each particle's increments drawn from its
        path's stream."""
        md = self.model
        sq = np.sqrt(dt / self.substeps)
        L = md.process_noise._sqrt
        return euler_maruyama(md, x, t, dt, self.substeps,
                              lambda j: mm(rng.standard_normal((*x.shape[1:-1], md.r)), L.T) * sq)

    def _at(self, k):
        """The model's time argument of measurement ``k``: ``k`` (the continuous-discrete
        subclass: its time ``t_k``)."""
        return k

    def _loglik(self, x, y, k, hbar=None, md=None):
        md = self.model if md is None else md
        obs = ~np.isnan(y)
        if self.time == "discrete":  # samples y = h(x) + v (also an SDE's, measured at discrete times)
            resid = residual(y[..., None, :], md.h(x, self._at(k)), angles_of(md).measurements)
            if not obs.all():
                resid = np.where(obs[..., None, :], resid, 0.0)
            if not md.R_constant:  # v ~ N(0, R(x)) exactly at each particle
                return gaussian_loglik(resid, md.R_of(x, k), obs[..., None, :])
            return measurement_loglik(md.measurement_noise, resid, obs)
        Rinv = observed_precision(md.R, self._Rinv, obs)  # partly missing: the observed marginal
        return increment_loglik(md.h(x, k) if hbar is None else hbar, np.where(obs, y, 0.0), Rinv, self.dt)

    # -- the smoother ------------------------------------------------------------------------------
    smoother_keeps = True

    # FFBSm; an instance on an SDE model with substeps > 1 has none (no transition density: __init__)
    smoother = "particle"

    def smooth(self, ys, m0=None, P0=None, **kw):
        """The forward-filtering backward-smoothing particle smoother (Doucet, Godsill & Andrieu
        2000; :func:`~nlfilter.filters.reference.forward_backward.ffbsm`): the filter's run, then its
        clouds reweighted backwards by the transition density — ``O(particles²)`` per step and
        path (lower ``particles`` for long records). On an SDE model the transition density is
        that of the filter's own Euler–Maruyama step, so it needs ``substeps=1``. Arguments and
        result as :meth:`~nlfilter.filters.base.Filter.smooth`."""
        from ...simulation import Simulation
        flt = self.for_timing(ys.timing)[0] if isinstance(ys, Simulation) else self  # the data's substeps
        if flt.time == "continuous" and flt.substeps != 1:
            raise TypeError(f"smooth: the particle smoother needs the transition density of the filter's step; on "
                            f"an SDEModel that is the Gaussian Euler–Maruyama step, substeps=1; got "
                            f"substeps={flt.substeps} (build ParticleFilter(model, ..., substeps=1), or smooth with "
                            "the grid filter)")
        return super(ParticleFilter, flt).smooth(ys, m0, P0, **kw)

    def _smooth(self, est, beliefs, ys, t0):
        """FFBSm over the filtered clouds of every step (the belief after each update: the weights
        of that update on the particles before the next resampling)."""
        if not beliefs:  # T = 0: nothing to smooth
            return est.means, est.covs
        logtau, logg, block = self._backward(ys, t0)
        return ffbsm([b.x for b in beliefs], [b.logw for b in beliefs], logtau, block=block, logg=logg,
                     angles=angles_of(self.model).states)

    def _sample(self, beliefs, ys, t0, u):
        """Trajectory draws ``(B, d, T, n)`` by backward simulation through the filtered clouds
        (Godsill, Doucet & West 2004;
        :func:`~nlfilter.filters.reference.forward_backward.backward_simulation`; ``u (B, T, d)``
        uniforms): particles of each step's cloud (:func:`nlfilter.sample_posterior`)."""
        logtau, logg, block = self._backward(ys, t0)
        return backward_simulation([b.x for b in beliefs], [b.logw for b in beliefs], logtau, u, block=block, logg=logg)

    def _backward(self, ys, t0):
        """The backward kernel's pieces for a run from ``t0`` on ``ys (B, T, m)``: ``(logtau, logg,
        block)`` as :func:`~nlfilter.filters.reference.forward_backward.ffbsm` takes them."""
        md = self.model
        logg = None
        if self.time == "continuous":  # step k's cloud is at t0 + (k + 1) dt: one Euler–Maruyama step on
            logtau = lambda x, x1, k: transition_logpdf(md, x, x1, t0 + (k + 1) * self.dt, dt=self.dt)  # noqa: E731

            def logg(x, k, sl):  # the next increment's left-point ∫ h ds = h(x_k) dt (sde_step): it weighs x_k
                y = ys[sl, k + 1]
                return np.where(np.isnan(y).all(axis=-1)[:, None], 0.0, self._loglik(x, y, t0 + (k + 1) * self.dt))
        else:
            offset = 0 if self.start == "update" else 1
            logtau = lambda x, x1, k: transition_logpdf(md, x, x1, k + offset)  # noqa: E731
        per_path = bool(getattr(getattr(md, "_values", None), "per_path", ()))  # parameters per path: no blocks
        return logtau, logg, ys.shape[0] if per_path else None
