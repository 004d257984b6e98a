"""Filters for bilinear systems (seed 001, Vallot 1981) that post-process the optimal linear filter
(:mod:`.linear_bilinear`, 001 eqs. 2.31-2.47): the "tensor filter" ``x̂ = Σ_k α_k φ_k(ẑ)``, odd
monomials of the linear estimate with gains from the exact joint (x, ẑ) moments (001 §3.3,
eqs. 3.29-3.35; fits and multi-stage in :mod:`.post_processors`), and the updated-innovations
filter (001 §3.4). Both run on the off-line-gain runner's steady schedule (:mod:`.offline`). The
pseudo-observables filter is in :mod:`.pseudo_observables`; all are re-exported here.
"""

from __future__ import annotations

import numbers
from typing import Callable

import numpy as np

from .. import _validate as V
from ..bilinear import BilinearModel
from ..moments.solve import stationary_moments
from ..sde_step import HELD
from .base import gaussian_prior, ode_step
# the joint analysis and post-processor fits, and the pseudo-observables filter, have modules of their own
from .post_processors import (JointProcess, PostProcessorFit, fit_post_processor, joint_process,  # noqa: F401
                              multistage, odd_features)
from .pseudo_observables import PseudoObservablesFilter  # noqa: F401


# the model analysis lives beside BilinearModel (nlfilter.bilinear_analysis); re-exported here
from ..bilinear_analysis import (WonhamReport, augmented_second_moment,  # noqa: E402,F401
                                 state_second_moments, wonham_condition)


# ================================================ the optimal linear filters (moved: linear_bilinear)
from .linear_bilinear import (DiscreteOptimalLinearFilter, LinearSteadyState, OptimalLinearFilter,  # noqa: E402,F401
                              _LinearSchedule)
from .offline import OfflineGainFilter, OfflineState  # noqa: E402


class _SteadyLinearRecursion(OfflineGainFilter):
    """The optimal linear filter's steady-gain recursion ``dẑ = F ẑ dt + K (dy − H ẑ dt)``
    (001 eqs. 2.31-2.32, gains of eq. 2.54) on the off-line-gain runner of :mod:`.offline`: its
    schedule is the steady one of :class:`OptimalLinearFilter` (convention ``"held"``: one RK4 or
    Euler step with ``dy/dt`` held constant is the affine map ``ẑ ↦ Φ ẑ + Γ dy/dt``, computed once
    per run and missing pattern).

    Missing data: a NaN component of ``dy`` contributes no innovation (its gain column is
    dropped for that step; the off-line gains are not re-optimised), and the path's covariance is
    that of the recursion actually run (:mod:`.offline`). Prior: ``ẑ0 = (m0, 1)``, per path
    allowed; the gains are the steady state's from t = 0 and do not depend on the prior, so
    ``P0`` is checked but does not enter."""

    accepts = ("bilinear", "phase")
    needs = ("time-invariant model", "finite steady state (Wonham condition)")
    time = "continuous"
    measurement_convention = HELD

    def _linear(self, model, dt, scheme, X0):
        self.linear = OptimalLinearFilter(model, dt, gains="steady", X0=X0, scheme=scheme)
        self.model, self.dt = model, self.linear.dt

    def schedule(self, m0, P0, batch, steps, t0):
        """The steady schedule (from ``t0``), ``ẑ0 = (m0, 1)`` on every path (``m0`` common or per
        path; ``P0`` checked only) and the steady error covariance."""
        g = gaussian_prior(m0, P0, self.model.n, batch, who=type(self).__name__)
        z = g.mean if self.model.N == self.model.n else np.concatenate([g.mean, np.ones((len(g.mean), 1))], axis=1)
        ss = self.linear.steady_state()
        return _LinearSchedule(self.linear, t0, steady=ss), z, ss.P


def _targets(targets, N: int) -> list:
    """The ``targets`` of a tensor filter checked: a non-empty sequence of distinct coordinate
    indices of the augmented state, each in ``[0, N)``."""
    tg = list(targets) if isinstance(targets, (list, tuple, range, np.ndarray)) else None
    if not tg or not all(isinstance(k, numbers.Integral) and not isinstance(k, (bool, np.bool_)) and 0 <= k < N
                         for k in tg) or len(set(int(k) for k in tg)) != len(tg):
        raise ValueError(f"targets: expected a non-empty list of distinct coordinate indices in [0, {N}), "
                         f"got {V.shown(targets)}")
    return [int(k) for k in tg]


class TensorFilter(_SteadyLinearRecursion):
    """Optimal linear filter followed by memoryless polynomial post-processors (001 Fig. 3.3,
    §3.3; "tensor filter", 001 §4.3 and ch. 5). All gains are computed off-line from the steady
    state.

    Parameters
    ----------
    model : BilinearModel
    dt : measurement step
    targets : augmented coordinates to estimate (default: all of x)
    degree : odd degree of the post-processor (3 = ``α x̂ + β x̂³``; 5, 7 ... also)
    inputs : "own" (each target from powers of its own linear estimate, as 001 eqs. 4.20, 5.11-5.12)
        or "cross" (odd monomials of all random estimates, with cross terms)
    initial : callable ``base monomial -> E[.]`` at t = 0 (needed on conservative state spaces)

    Notes
    -----
    ``run(ys, m0, P0)`` (``ys`` the increments ``dy``): the linear filter's augmented estimate
    ``ẑ`` follows the affine runner of :mod:`.offline` (``_SteadyLinearRecursion``: prior
    ``ẑ0 = (m0, 1)``, missing components give no innovation); the post-processor is the runner's
    output map from ``ẑ`` to the reported estimate, applied at every step (``summary``) so that the
    run loop screens its overflow too (``x̂³`` of a huge but finite ``ẑ``). ``means`` are the targets' estimates ``(..., T, len(targets))``;
    ``covs`` the off-line steady-state error covariance of the post-processed estimates
    (:meth:`error_covariance`), the same at every step.
    """

    name = "tensor"
    source = "seed 001 §3.3, Fig. 3.3, eqs. 3.29-3.35 (ch. 4-5)"

    def __init__(self, model: BilinearModel, dt: float, *, targets=None, degree: int = 3, inputs: str = "own",
                 initial: Callable | None = None, X0=None, scheme: str = "rk4"):
        if V.positive("degree", degree, integer=True) % 2 == 0:
            raise ValueError(f"degree: expected an odd positive integer, got {degree!r}")
        self._linear(model, dt, scheme, X0)
        self.degree = degree
        self.inputs = V.choice("inputs", inputs, {"own", "cross"})
        self.targets = list(range(model.n)) if targets is None else _targets(targets, model.N)
        self.initial = initial
        self._fits = None
        self._cov = None

    @classmethod
    def for_model(cls, model, *, dt=None, start=None):
        """Default instance: the targets are the coordinates of the base state (for a lift, the
        degree-1 monomials), the estimates a comparison reads."""
        nb = len(model.coords[0])
        units = [tuple(int(i == j) for i in range(nb)) for j in range(nb)]
        return cls(model, dt, targets=[model.coords.index(u) for u in units if u in model.coords])

    @property
    def state_dim(self) -> int:
        return len(self.targets)

    def fit(self) -> list:
        """Off-line: steady gains, the joint process, and one post-processor per target."""
        if self._fits is not None:
            return self._fits
        ss = self.linear.steady_state()
        jp = joint_process(self.model, ss.K)
        self.joint = jp
        z0 = np.zeros(self.model.N)
        if self.model.constant_index is not None:
            z0[self.model.constant_index] = 1.0
        init = None if self.initial is None else jp.initial(self.initial, z0)
        self._joint_initial = init
        nv = jp.sde.n
        fits, mom = [], {}
        for k in self.targets:
            if k not in jp.estimate_vars:
                raise ValueError(f"targets: coordinate {k} has a deterministic linear estimate; nothing to post-process")
            v = jp.nb + jp.estimate_vars.index(k)
            if self.inputs == "own":
                feats = odd_features([v], self.degree, nv)
            else:
                feats = odd_features(list(range(jp.nb, nv)), self.degree, nv, cross=True)
            fit = fit_post_processor(jp, jp.coord_poly(k), feats, jp.estimate_poly(k), initial=init, moments=mom)
            mom = fit.moments
            fits.append(fit)
        self._fits = fits
        self._outputs = [f.output_poly() for f in fits]
        return fits

    def error_covariance(self) -> np.ndarray:
        """Off-line steady-state ``E[(t − ψ)(t − ψ)ᵀ]`` of the targets ``t`` and their
        post-processed estimates ``ψ``: the diagonal is each fit's ``mse``; the cross terms come
        from the same exact joint moments (a few more monomials)."""
        if self._cov is None:
            fits = self.fit()
            nt = len(fits)
            errs = [f.target - f.output_poly() for f in fits]
            cov = np.diag([f.mse for f in fits])
            pairs = [(i, j) for i in range(nt) for j in range(i + 1, nt)]
            if pairs:
                mom = dict(fits[-1].moments)
                prods = {(i, j): errs[i] * errs[j] for i, j in pairs}
                missing = sorted({e for p in prods.values() for e in p.terms if e not in mom})
                if missing:
                    mom.update(stationary_moments(self.joint.sde, missing, initial=self._joint_initial))
                for (i, j), p in prods.items():
                    cov[i, j] = cov[j, i] = float(p.expect(mom))
            self._cov = cov
        return self._cov

    def with_dt(self, dt: float) -> "TensorFilter":
        """The same filter (same off-line gains, computed once) for increments of step ``dt``."""
        other = type(self).__new__(type(self))
        other.__dict__.update(self.__dict__)
        other.linear = OptimalLinearFilter(self.model, dt, gains="steady", X0=self.linear.X0, scheme=self.linear.scheme)
        other.linear._steady = self.linear._steady
        other.dt = float(dt)
        return other

    def post_process(self, zhat: np.ndarray) -> np.ndarray:
        """Apply the post-processors to linear estimates ``(..., N)`` (augmented) -> ``(..., len(targets))``."""
        self.fit()
        jp = self.joint
        vals = np.zeros((*zhat.shape[:-1], jp.sde.n))
        for i, k in enumerate(jp.estimate_vars):
            vals[..., jp.nb + i] = zhat[..., k]
        return np.stack([out(vals) for out in self._outputs], axis=-1)

    def init(self, m0, P0, batch, *, initial=None, rng=None, **kw):
        self.fit()
        return super().init(m0, P0, batch, initial=initial, rng=rng, **kw)

    def summary(self, belief):
        """The post-processor as the runner's output map: ``(ψ(ẑ) (B, len(targets)), the off-line
        steady error covariance of ψ)`` (the same on every path, missing data or not)."""
        cov = self.error_covariance()
        return self.post_process(belief.mean), np.broadcast_to(cov, (len(belief.mean), *cov.shape))


# ====================================================================== updated innovations
class UpdatedInnovationsFilter(TensorFilter):
    """The linear filter's recursion driven by innovations formed with the post-processed
    estimate (001 Fig. 3.4; "not evaluated in this research": evaluated here by Monte Carlo)::

        dẑ = F ẑ dt + K (dy − H ẑ' dt),   ẑ' = ẑ with its post-processed coordinates replaced

    Gains ``K`` and post-processor gains are those of :class:`TensorFilter` (off-line). The
    recursion is nonlinear, so its error has no closed moment system: it is evaluated by
    simulation, and ``covs`` are NaN on every path (no error covariance; a path whose estimate
    overflows is raised or marked in ``diverged``). The belief and gains are the off-line-gain
    runner's (:mod:`.offline`); the step is its own. Integration: explicit RK4 (or Euler) with
    ``dy/dt`` held constant over a step; a missing component of ``dy`` gives no innovation
    (skipped in the recursion). Prior as :class:`TensorFilter`: ``ẑ0 = (m0, 1)``.
    """

    covariance = "none"

    name = "updated-innovations"
    source = "seed 001 §3.4, Fig. 3.4"

    @classmethod
    def from_tensor(cls, tf: TensorFilter, dt: float | None = None) -> "UpdatedInnovationsFilter":
        """Reuse a fitted :class:`TensorFilter`'s off-line gains (and optionally a new step)."""
        other = cls.__new__(cls)
        other.__dict__.update((tf if dt is None else tf.with_dt(dt)).__dict__)
        return other

    def step(self, belief, dy, t):
        """``ẑ`` at ``t + dt`` after ``dy (B, m)``: RK4 (or Euler) of the updated-innovations SDE
        (nonlinear in ẑ: not the runner's affine step; its gains are the runner's schedule)."""
        sch = belief.schedule
        aug = self.model.augmented(0)
        F, H, K = aug.F, aug.H, sch.steady.K
        tg = self.targets
        miss = np.isnan(dy)
        y = (np.where(miss, 0.0, dy) if miss.any() else dy) / self.dt

        def rhs(z):
            zp = z.copy()
            zp[..., tg] = self.post_process(z)
            innov = y - zp @ H.T
            if miss.any():
                innov = np.where(miss, 0.0, innov)  # a missing component: no innovation
            return z @ F.T + innov @ K.T

        z = ode_step(lambda z, s: rhs(z), belief.mean, t, self.dt, scheme=self.linear.scheme)
        return OfflineState(z, belief.cov, belief.own, (belief.pos[0] + 1, "predicted"), sch)

    def summary(self, belief):
        """``(ψ(ẑ), None)``: no error covariance for this nonlinear recursion (``covs`` NaN)."""
        return self.post_process(belief.mean), None

__all__ = ["PseudoObservablesFilter", "OptimalLinearFilter", "DiscreteOptimalLinearFilter", "LinearSteadyState", "WonhamReport",
           "wonham_condition", "state_second_moments", "augmented_second_moment", "JointProcess",
           "joint_process", "odd_features", "fit_post_processor", "PostProcessorFit", "TensorFilter",
           "multistage", "UpdatedInnovationsFilter"]
