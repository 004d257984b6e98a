"""Off-line gains: one affine runner for every filter whose gains are computed before the data.

The quasilinear filters (seed 003), the optimal linear filters of bilinear systems (seed 001,
time-varying or steady, continuous or discrete), the tensor (post-processor) filters, the
pseudo-observables filter (001 §3.2) and the linear quadrature and phase tensor filters (001
ch. 4) share one structure: everything but the estimate — the linearized (or exact) affine model,
the gains, the covariance — depends on the prior only (or on nothing: the steady gains), so it is
computed once, off-line, as a *gain schedule*; on-line the estimate follows one affine recursion
for the whole batch. What a filter reports is its output map of that estimate (``summary``: the
post-processor of the tensor filters; ``output``: ``atan2`` of the phase filters). A steady
schedule does not depend on the prior, so its filters take a prior mean per path. The updated-
innovations filter (001 Fig. 3.4) uses the schedule with its own, nonlinear, step; the PLL (001
eq. 4.8) is not here: its innovation ``cos θ̂ dz₁ − sin θ̂ dz₂`` is nonlinear in the estimate.

Belief (:class:`OfflineState`): the mean ``(B, N)`` of the recursion (augmented coordinates for
the bilinear filters; :meth:`Filter.summary` reports the first ``state_dim``), the covariance
``(B, N, N)``, the flag ``own (B,)`` and the shared position ``pos = (k, "predicted" | "filtered")``
with the schedule itself (``_shared``: not per path).

Discrete time (:class:`DiscreteSchedule`): the schedule is the Kalman recursion of the affine model
``x[k+1] = F_k x + b_k + (noise Q_k)``, ``y[k] = H_k x + d_k + (noise S_k)`` assuming every
component observed at every step (gains ``K_k``, covariances ``P⁻_k``, ``P⁺_k``); it is extended
lazily along k (the same numbers for any horizon)::

    predict:  m ← F_k m + b_k
    update:   m ← m + K_k (y − H_k m − d_k),   a missing component of y contributes no innovation

Continuous time (:class:`ContinuousSchedule`): ``dm = (A m + b) dt + K (dy − (H m + d) dt)`` with the
schedule's coefficients on the stage grid of the scheme (``t_k + i h/2``, ``h = dt/substeps``),
integrated by :func:`~nlfilter.ode.ode_step`; a missing increment component contributes
nothing (its column of K is dropped, in the drift term too). Two conventions, as the filters were
published and validated: ``"ito"`` (the quasilinear filters: the dt terms by the scheme, the
innovation ``K(t_k) dy`` added as an Itô increment with the gain at the step's start) and
``"held"`` (the bilinear linear filter: ``dy/dt`` held constant over the step inside the scheme,
applied as the exact affine map ``m ↦ Φ m + Γ dy/dt`` of that scheme step). Under ``"held"`` the
schedule may drive the recursion by an input map ``u = drive(carried, dy)`` instead of ``dy``
(the pseudo-observables' increments ``d(y_i^p)``, 001 eq. 3.16, from the running ``y`` the belief
carries); the missing components of ``u`` then drop their gain columns.

Covariance reported (missing data). The schedule's covariance is that of the recursion *with
every component observed*. A path whose measurement misses a component (or a whole step) gets
the gain with those columns dropped; from then on (``own``) the filter reports the covariance of
the affine recursion actually run on that path, under the same (linearized) model:

* discrete: ``P⁺ = (I − K_u H) P⁻ (I − K_u H)ᵀ + K_u S K_uᵀ`` (Joseph form, any gain ``K_u``; the
  schedule's gain at every later step), ``P⁻ = F P⁺ Fᵀ + Q``;
* continuous: ``dP/dt = A_u P + P A_uᵀ + Q + K_u S K_uᵀ``, ``A_u = A − K_u H``, integrated over the
  step with the same scheme and substeps.

For a path with every component observed these are the schedule's own equations, so its
covariance stays the schedule's (reported bit for bit). A schedule with ``own_cov = False`` (the
pseudo-observables') reports its own covariance on every path. For the quasilinear filters P is the
covariance of the statistically linearized model, not the true error covariance (seed 003,
below eq. 8), with or without missing data; the true error comes from ``error_analysis``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _validate as V
from .base import Filter, ode_step
from .linalg import symmetrize

__all__ = ["OfflineState", "DiscreteSchedule", "ContinuousSchedule", "OfflineGainFilter"]


class OfflineState(NamedTuple):
    """Belief of an off-line-gain filter: ``mean (B, N)``, ``cov (B, N, N)`` (the schedule's, or
    the path's own after a missing component), ``own (B,)``, the shared step position ``pos``, the
    shared ``schedule``, and ``carried (B, ...)`` per path what the schedule's input map carries
    from step to step (the pseudo-observables' running observation ``y``; None for the others)."""

    mean: np.ndarray
    cov: np.ndarray
    own: np.ndarray
    pos: tuple
    schedule: object
    carried: object = None
    _shared = ("pos", "schedule")


def _joseph(P, K, H, S, obs):
    """``(I − K_u H) P (I − K_u H)ᵀ + K_u S K_uᵀ`` per path, ``K_u = K`` with the columns of the
    missing components (``obs (B, m)`` False) dropped; ``P (B, N, N)``."""
    Ku = K[None] * obs[:, None, :]
    IKH = np.eye(P.shape[-1]) - Ku @ H
    return symmetrize(IKH @ P @ np.swapaxes(IKH, -1, -2) + Ku @ S @ np.swapaxes(Ku, -1, -2))


class DiscreteSchedule:
    """Off-line gains of a discrete filter: the Kalman recursion of an affine model, extended
    lazily along k. Subclasses give ``model(k) -> (F, b, H, d, Q, S)`` (called in order
    k = 0, 1, ...), ``gain(P⁻, H, S) -> (K, P⁺)`` and ``predicted(F, P⁺, Q) -> P⁻``.
    ``start="predict"``: the prior is the filtered belief of step 0 (no update there)."""

    def __init__(self, P0, start: str = "update"):
        self.start = start
        self.pred = [np.asarray(P0, dtype=float)]  # P⁻[k]
        self.filt, self.gains, self.models = [], [], []  # P⁺[k], K[k], (F, b, H, d, Q, S)[k]

    def ensure(self, k: int):
        """Rows up to step ``k`` (and ``P⁻[k + 1]``)."""
        while len(self.filt) <= k:
            j = len(self.filt)
            F, b, H, d, Q, S = mdl = self.model(j)
            self.models.append(mdl)
            if j == 0 and self.start == "predict":
                K, Pf = None, self.pred[0]
            else:
                K, Pf = self.gain(self.pred[j], H, S)
            self.gains.append(K)
            self.filt.append(Pf)
            self.pred.append(self.predicted(F, Pf, Q))

    def model(self, k):  # pragma: no cover - abstract
        raise NotImplementedError

    def gain(self, P, H, S):
        Ssum = H @ P @ H.T + S
        K = P @ H.T @ np.linalg.inv(Ssum)
        return K, symmetrize(P - K @ Ssum @ K.T)

    def predicted(self, F, Pf, Q):
        return symmetrize(F @ Pf @ F.T + Q)


class ContinuousSchedule:
    """Off-line gains of a continuous filter on the stage grid ``t_k + i h/2`` (``h = dt/substeps``,
    index ``2 k substeps + i``). Subclasses give ``coeffs(i) -> (A, b, H, d, K, Q, S)``,
    ``cov(k)`` (the schedule's covariance at ``t_k``) and, by convention:
    ``"ito"``: ``drift(i) -> (A − K H, b − K d)`` with every component observed;
    ``"held"``: ``step_map(k, obs) -> (Φ, Γ)`` (``obs`` bool over the components of the input, or
    None for all observed).

    Input map (``"held"``): the recursion is driven by ``u = drive(carried, dy)`` (NaN: an
    unobserved component of u; default ``u = dy``), and the belief's ``carried`` goes on as
    ``carry(carried, dy, mean)`` with the new mean (default: unchanged) — the pseudo-observables'
    increments ``d(y_i^p)`` formed from the running ``y``. ``own_cov = False``: every path reports
    the schedule's covariance, missing components or not (``coeffs`` then need not exist)."""

    convention = "ito"
    substeps = 1
    scheme = "rk4"
    dt = 1.0
    own_cov = True

    def drive(self, carried, dy):
        return dy

    def carry(self, carried, dy, mean):
        return carried

    def cov(self, k):  # pragma: no cover - abstract
        raise NotImplementedError

    def coeffs(self, i):  # pragma: no cover - abstract
        raise NotImplementedError

    def drift(self, i):
        A, b, H, d, K, _, _ = self.coeffs(i)
        return A - K @ H, b - K @ d

    def step_map(self, k, obs):  # pragma: no cover - abstract
        raise NotImplementedError


def _patterns(obs):
    """The distinct rows of ``obs (B, m)`` with the paths of each (all paths: ``slice(None)``)."""
    if obs.all():
        return [(obs[0], slice(None))]
    pats, inv = np.unique(obs, axis=0, return_inverse=True)
    return [(p, np.flatnonzero(inv.reshape(-1) == j)) for j, p in enumerate(pats)]


class OfflineGainFilter(Filter):
    covariance = "off-line"
    """Base of the filters with precomputed gains: the one affine runner (module docstring).

    Subclasses give ``schedule(m0, P0, batch, steps, t0) -> (schedule, mean0, cov0 (N, N)[, carried0])``
    (the prior checked, in the recursion's coordinates; ``mean0 (N,)``, or ``(B, N)`` per path
    where the gains do not depend on the prior — the steady-gain filters; ``carried0 (B, ...)``
    the start of the schedule's input map), and set ``time``. ``family`` is ``"off-line gains"``."""

    family = "off-line gains"

    def _run_init(self, m0, P0, batch, initial, rng, steps, t0):
        """The run's horizon (``steps`` from ``t0``) reaches :meth:`init`: the continuous schedules
        are solved for it."""
        return self.init(m0, P0, batch, initial=initial, rng=rng, steps=steps, t0=t0)

    def init(self, m0, P0, batch, *, initial=None, rng=None, steps=None, t0=None):
        if initial is not None:
            raise ValueError(f"initial: {type(self).__name__} starts from a Gaussian prior (m0, P0); "
                             f"expected None, got {type(initial).__name__}")
        out = self.schedule(m0, P0, batch, steps, V.real("t0", 0.0 if t0 is None else t0))
        sch, z0, C0 = out[:3]
        B = int(np.prod(batch))
        N = z0.shape[-1]
        stage = "filtered" if self.time == "discrete" and self.start == "predict" else "predicted"
        return OfflineState(np.broadcast_to(z0, (B, N)).copy(), np.broadcast_to(C0, (B, N, N)),
                            np.zeros(B, bool), (0, stage), sch, out[3] if len(out) > 3 else None)

    def summary(self, belief):
        r = self.state_dim
        return belief.mean[:, :r], belief.cov[:, :r, :r]

    @staticmethod
    def _mix(own, own_cov, sched):
        """The schedule's covariance on the paths not ``own``, ``own_cov()`` on the others."""
        B = own.shape[0]
        shared = np.broadcast_to(sched, (B, *sched.shape))
        if not own.any():
            return shared
        return np.where(own[:, None, None], own_cov(), shared)

    # -- discrete ------------------------------------------------------------------------------
    def _at(self, belief, k, stage, what):
        if belief.pos != (k, stage):
            if belief.pos[0] != k or stage == "predicted":
                raise ValueError(f"k: {what} of step {k}, but the belief is the {belief.pos[1]} one of "
                                 f"step {belief.pos[0]}")

    def predict(self, belief, k):
        self._at(belief, k, "filtered", "predict")
        sch = belief.schedule
        sch.ensure(k)
        F, b, _, _, Q, _ = sch.models[k]
        own = belief.own
        if belief.pos[1] != "filtered":  # step k had no update (all missing): its gain was 0
            own = np.ones_like(own)
        mean = belief.mean @ F.T + b
        cov = self._mix(own, lambda: symmetrize(F @ belief.cov @ F.T + Q), sch.pred[k + 1])
        return OfflineState(mean, cov, own, (k + 1, "predicted"), sch)

    def update(self, belief, y, k):
        self._at(belief, k, "predicted", "update")
        sch = belief.schedule
        sch.ensure(k)
        _, _, H, d, _, S = sch.models[k]
        K = sch.gains[k]
        if K is None:
            raise ValueError(f"k: step {k} is the prior of start='predict'; it has no update")
        y = np.asarray(y, dtype=float)
        obs = ~np.isnan(y)
        innov = np.where(obs, y - (belief.mean @ H.T + d), 0.0)  # a missing component: no innovation
        mean = belief.mean + innov @ K.T
        own = belief.own | ~obs.all(axis=-1)
        cov = self._mix(own, lambda: _joseph(belief.cov, K, H, S, obs), sch.filt[k])
        return OfflineState(mean, cov, own, (k, "filtered"), sch)

    # -- continuous ----------------------------------------------------------------------------
    def step(self, belief, dy, t):
        sch = belief.schedule
        k = belief.pos[0]
        h = sch.dt / sch.substeps
        dy = np.asarray(dy, dtype=float)
        carried = belief.carried
        held = sch.convention == "held"
        if held:  # the input map: u from dy (and what the belief carries)
            u = sch.drive(carried, dy)
            obs = ~np.isnan(u)
        else:
            u, obs = dy, ~np.isnan(dy)
        full = obs.all(axis=-1)
        dyz = np.where(obs, u, 0.0)
        x = belief.mean
        base = 2 * k * sch.substeps

        def idx(s):
            return base + int(round((s - t) / (0.5 * h)))
        if held:  # dy/dt held constant: the scheme's step is the affine map m ↦ Φ m + Γ u/dt
            new = np.empty_like(x)
            for o, paths in _patterns(obs):
                Phi, Gam = sch.step_map(k, None if o.all() else o)
                new[paths] = x[paths] @ Phi.T + (dyz[paths] / sch.dt) @ Gam.T
            carried = sch.carry(carried, dy, new)
        else:
            ein = lambda A, v: np.einsum("ij,...j->...i", A, v)  # noqa: E731
            Kdy = ein(sch.coeffs(base)[4], dyz)  # Itô: the innovation with the gain at t_k
            new = np.empty_like(x)
            for o, paths in _patterns(obs):
                if o.all():
                    def rhs(v, s):
                        F, u = sch.drift(idx(s))
                        return ein(F, v) + u
                else:
                    def rhs(v, s, o=o):
                        A, b, H, d, K, _, _ = sch.coeffs(idx(s))
                        Ko = K * o
                        return ein(A - Ko @ H, v) + (b - Ko @ d)
                new[paths] = ode_step(rhs, x[paths], t, sch.dt, substeps=sch.substeps, scheme=sch.scheme)
            new = new + Kdy
        own = belief.own | ~full if sch.own_cov else belief.own

        def own_cov():
            P = belief.cov
            Ob = obs[:, None, :]

            def rhs(P, s):
                A, _, H, _, K, Q, S = sch.coeffs(idx(s))
                Ku = K[None] * Ob
                Au = A - Ku @ H
                return Au @ P + P @ np.swapaxes(Au, -1, -2) + Q + Ku @ S @ np.swapaxes(Ku, -1, -2)
            return ode_step(rhs, np.array(P), t, sch.dt, substeps=sch.substeps, scheme=sch.scheme,
                            finish=symmetrize)
        cov = self._mix(own, own_cov, sch.cov(k + 1))
        return OfflineState(new, cov, own, (k + 1, "predicted"), sch, carried)
