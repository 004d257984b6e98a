"""The yardstick of a comparison: a near-optimal reference filter that chooses its own resolution
and measures its own error (:func:`certified_reference`).

A Monte Carlo comparison judges each filter by ``gap_to_optimal``, its MSE minus the optimal
filter's on the same paths. The "optimal" filter is in practice a grid or particle filter, optimal
only in the limit of a fine grid or many particles; a reference that is too coarse makes filters
look better than optimal. So the reference used by :func:`~nlfilter.comparison.compare` certifies
itself:

1. **Resolution from the model.** For ``n ≤ 2`` a :class:`~nlfilter.filters.reference.GridFilter`
   whose spacing per axis is at most ``1 / RESOLUTION`` of the smaller of two scales: the
   process-noise standard deviation over one measurement step (``√(G Q Gᵀ)_ii``, times ``dt`` for
   an SDE, averaged over the simulated states) and the posterior standard deviation (the
   ``POSTERIOR_QUANTILE`` quantile over paths and steps of a pilot particle filter's, on a few
   paths). Its bounds hold the simulated states and ``m0`` widened by ``4`` times the larger
   scale. When that grid needs more than :data:`GRID_POINTS` points (or, for a 2-D SDE, the
   diffusion is not diagonal) it falls back to a
   :class:`~nlfilter.filters.reference.ParticleFilter` with :data:`PARTICLES` particles.
2. **Edge mass.** A grid reports the posterior mass on its outermost points at every step
   (``extras["edge_mass"]``); above :data:`EDGE_MASS`, or when paths left the grid (the grid
   filter marks them diverged: its ``edge_limit``), the bounds are widened by half and the grid
   rerun (twice at most), then flagged.
3. **Its own error.** The reference is rerun at the next resolution (``2×`` the points per axis,
   or ``4×`` the particles) on the first ``certify_paths`` paths, and the change of its MSE per
   component is measured on those paths as a paired difference ``Δ ± se``. The tolerance per
   component is ``rtol`` times its MSE or the smallest standard error of the gaps it judges (an
   error below the comparison's resolution changes no verdict), whichever is larger; when in
   every component ``se`` is within it and the decrease ``−Δ`` is within it or within ``2 se``
   (no gain beyond the noise), the reference is *certified* and named ``"optimal"``. Otherwise the next rung replaces it (run on all paths:
   particles after a grid, ``4×`` the particles after particles, up to ``max_particles``) and is
   checked the same way (on a :class:`~nlfilter.switching.SwitchingModel` the rungs are
   :class:`~nlfilter.filters.reference.JumpParticleFilter` s, particles over (mode, state),
   from the first); a reference that never
   passes is named ``"reference (not converged)"`` and a :class:`~nlfilter.errors.ReferenceWarning`
   says what to raise.

4. **Checks that can fail** (:mod:`nlfilter.certificate_checks`): refinement alone cannot see a
   reference of the wrong *model*, so ``compare`` and the experiments also check its NEES per
   component against the exact posterior's band and that no filter beats it by more than 2 s.e.;
   either failing relabels it ``"reference (contradicted: ...)"``.

The certificate (:class:`Certificate`) records every rung tried, with sizes, error bounds, edge
mass, effective sample size and seconds; ``compare`` writes it into ``Result.params["reference"]``
and adds the reference's error (``√(Δ² + se²)``) to the standard error of every
``gap_to_optimal``.

On a continuously measured SDE the grid reads each increment with ``h`` at the interval's end
point (:class:`~nlfilter.filters.reference.GridFilter`, first order in ``dt``), the particle
filter exactly as the simulator does (:mod:`nlfilter.sde_step`, at the simulator's ``substeps``);
the automatic reference takes particles where the end-point reading is not accurate
(:func:`endpoint_error` above :data:`ENDPOINT_TOL`). An SDE measured at discrete times
(``compare(times=)``) has no grid rung: its reference is
:class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter` through the simulator's
Euler–Maruyama steps (its ``substeps`` per interval: the simulator's model exactly), on the same
particle ladder (``certified_reference(..., times=)``).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .angles import angles_of
from .errors import ReferenceWarning
from .evaluate import mse, paired_difference
from .filters.reference import ContinuousDiscreteParticleFilter, GridFilter, JumpParticleFilter, ParticleFilter
from .sde_step import SUBSTEPS
from .switching import SwitchingModel

RESOLUTION = 4          # grid points per (smallest) scale
POSTERIOR_QUANTILE = 0.1
GRID_POINTS = {1: 4001, 2: 1700}   #: the largest automatic grid on all paths (its 2× refinement runs on a few)
GRID_MIN = {1: 101, 2: 21}
REFINE_POINTS = {1: 4 * GRID_POINTS[1], 2: 4 * GRID_POINTS[2]}  #: the largest refinement run (a few paths)
PARTICLES = 2000  #: the particles of an automatic particle reference
MAX_PARTICLES = 32000
EDGE_MASS = 1e-3  #: the largest posterior mass on a grid's outermost points that certifies it
ENDPOINT_TOL = 0.1      #: the grid's end-point reading of dy: rms error per interval / measurement noise
OPTIMAL = "optimal"
NOT_CONVERGED = "reference (not converged)"


@dataclass
class Certificate:
    """How a reference was chosen and how far it is from converged.

    ``kind`` (``"grid"``, ``"particle"`` or the class name of a given reference), ``certified``
    (True: its refinement moved its MSE by no more than the tolerance; None: a reference of
    a kind that cannot be refined, not checked), ``label`` (the name in the table), ``size`` (grid
    points per axis or particles), ``error`` (per component ``Δ`` and ``se``: the change of MSE
    from this reference to the next finer one on ``paths`` paths), ``bound`` (``|Δ| + 2 se``,
    the error it may have),
    ``rungs`` (every resolution tried, with its numbers), ``seconds``, ``reason``;
    ``contradicted``: the failures of :func:`~nlfilter.certificate_checks.contradictions` (empty: none, or not checked)."""

    kind: str
    certified: bool | None
    label: str
    size: object = None
    bounds: object = None
    rtol: float = 0.02
    paths: int = 0
    error: list = field(default_factory=list)   # [(Δ, se)] per component
    bound: list = field(default_factory=list)
    rungs: list = field(default_factory=list)
    seconds: float = 0.0
    reason: str = ""
    contradicted: list = field(default_factory=list)

    def reference_error(self, i: int) -> float:
        """The reference's error in component ``i`` as a standard deviation: ``√(Δ² + se²)`` (0
        when not measured)."""
        if not self.error:
            return 0.0
        d, se = self.error[i]
        return math.hypot(d, se)

    def to_dict(self) -> dict:
        """Plain JSON types (lists, floats): what ``Result.params["reference"]`` keeps."""
        import json
        return json.loads(json.dumps({
            "kind": self.kind, "certified": self.certified, "label": self.label, "size": self.size,
            "bounds": self.bounds, "rtol": self.rtol, "paths": self.paths, "error": [list(e) for e in self.error],
            "bound": list(self.bound), "rungs": self.rungs, "seconds": round(self.seconds, 3),
            "reason": self.reason, "contradicted": self.contradicted}, default=float))


# -- the rungs of the ladder ----------------------------------------------------------------------
@dataclass
class _Rung:
    kind: str          # "grid" or "particle"
    size: object       # list of points per axis, or particles
    bounds: object = None

    def build(self, model, kw):
        if "cd" in kw:  # an SDE measured at discrete times: particles through the simulator's scheme
            return ContinuousDiscreteParticleFilter(model, None, int(self.size), **kw["cd"]).at_times(kw["times"])
        if self.kind == "grid":
            n = model.n
            return GridFilter(model, self.bounds[0] if n == 1 else self.bounds,
                              int(self.size[0]) if n == 1 else [int(s) for s in self.size], **kw["grid"])
        if isinstance(model, SwitchingModel):  # particles over (mode, state): the optimal filter of a switching model
            return JumpParticleFilter(model, int(self.size), **kw["particle"])
        return ParticleFilter(model, int(self.size), **kw["particle"])

    def refined(self):
        """The next resolution, run on the certification paths only: ``2×`` the points per axis
        (every other point of it is one of this grid's), or ``4×`` the particles."""
        if self.kind == "grid":
            return _Rung("grid", [2 * s - 1 for s in self.size], self.bounds)
        return _Rung("particle", 4 * self.size)

    def next(self, max_particles):
        """The rung that replaces this one when it is not certified (run on all paths): particles
        after a grid (a finer grid on all paths would cost ``4×``–``16×``), ``4×`` the particles
        after particles, None past ``max_particles``."""
        if self.kind == "grid":
            return _Rung("particle", PARTICLES)
        return _Rung("particle", 4 * self.size) if 4 * self.size <= max_particles else None

    def describe(self):
        return f"a {'×'.join(map(str, self.size))} grid" if self.kind == "grid" else f"{self.size} particles"


def _scales(model, sim, P0, dt, post_sd):
    """Per axis ``(small, big)``: the smaller of the process-noise and posterior standard
    deviations (the prior's where neither is positive), and the largest of those and the prior's."""
    xs = sim.xs.reshape(-1, model.n)
    g = model.GQGT(xs[:: max(1, xs.shape[0] // 20000)])
    noise = np.sqrt(np.mean(np.diagonal(g, axis1=-2, axis2=-1), axis=0) * (dt if model.kind == "sde" else 1.0))
    prior = np.sqrt(np.diag(P0))
    post = np.where(np.isfinite(post_sd) & (post_sd > 0), post_sd, prior)
    cand = np.stack([noise, post])
    small = np.min(np.where(cand > 0, cand, np.inf), axis=0)
    small = np.where(np.isfinite(small), small, prior)
    big = np.max(np.stack([noise, post, prior]), axis=0)
    return small, big


def endpoint_error(model, sim, dt, *, steps: int = 200, paths: int = 100) -> float:
    """How far the grid's end-point reading of an SDE's increments is from the simulator's
    left-point ``∫ h ds`` (:mod:`nlfilter.sde_step`), against the measurement noise: the root mean
    square over the simulated intervals of ``|R^{-1/2} (h(x(t_{k+1})) − h(x(t_k)))| · √dt / 2``
    (half the movement of ``h`` within an interval, as a mean error of ``h̄``, over the noise
    ``√(R/dt)`` of ``dy/dt``), on at most ``paths`` paths and ``steps`` intervals of ``sim``.
    The automatic reference takes particles above :data:`ENDPOINT_TOL`."""
    from .filters.base import continuous_precision
    x = np.concatenate([sim.x0[:, None, :], sim.xs], axis=1)
    x = x[np.isfinite(x).all(axis=(-2, -1))][:paths]
    T = sim.xs.shape[1]
    if x.shape[0] == 0 or T == 0:
        return 0.0
    t = np.concatenate([[sim.t[0] - dt], sim.t])
    ks = np.unique(np.linspace(0, T - 1, min(steps, T)).astype(int))
    Rinv = continuous_precision(model)
    q = []
    for k in ks:
        d = model.h(x[:, k + 1], t[k + 1]) - model.h(x[:, k], t[k])
        q.append(np.einsum("pa,ab,pb->p", d, Rinv, d))
    return float(np.sqrt(np.mean(q) * dt / 4.0))


def _first_rung(model, sim, m0, P0, dt, post_sd, widen=1.0):
    n = model.n
    if n > 2:
        return _Rung("particle", PARTICLES), "n > 2: particles"
    if model.kind == "sde":
        rho = endpoint_error(model, sim, dt)
        if rho > ENDPOINT_TOL:
            return _Rung("particle", PARTICLES), (
                f"h moves within a measurement interval by {rho:.2g} of the measurement noise (rms, > {ENDPOINT_TOL}): "
                "the grid's end-point reading of dy would be inexact; particles read it as the simulator does")
    beyond = sorted(set(getattr(model, "structure", ())) - set(GridFilter.structures))
    if beyond:  # e.g. non-additive noise: the grid has no transition density for it
        return _Rung("particle", PARTICLES), f"the grid filter does not take {', '.join(beyond)}: particles"
    if n == 2 and model.kind == "sde":
        g = model.GQGT(sim.xs.reshape(-1, n)[:1000])
        if np.any(np.abs(g[..., 0, 1]) > 1e-12 * (np.abs(g[..., 0, 0]) + np.abs(g[..., 1, 1]) + 1e-300)):
            return _Rung("particle", PARTICLES), "the 2-D SDE grid needs a diagonal diffusion: particles"
    small, big = _scales(model, sim, P0, dt, post_sd)
    if not np.all(small > 0):
        return _Rung("particle", PARTICLES), "no positive noise or posterior scale on an axis: particles"
    xs = sim.xs.reshape(-1, n)
    lo = np.minimum(xs.min(axis=0), m0) - 4 * big
    hi = np.maximum(xs.max(axis=0), m0) + 4 * big
    mid, half = (lo + hi) / 2, widen * (hi - lo) / 2
    lo, hi = mid - half, mid + half
    for d in angles_of(model).states:  # an angular axis is the whole circle (a periodic grid)
        lo[d], hi[d] = -math.pi, math.pi
    size = np.maximum(np.ceil((hi - lo) / (small / RESOLUTION)).astype(int) + 1, GRID_MIN[n])
    size = [int(s) for s in size]
    bounds = [(float(a), float(b)) for a, b in zip(lo, hi)]
    if math.prod(size) > GRID_POINTS[n]:
        return _Rung("particle", PARTICLES), (f"the grid the model needs ({'×'.join(map(str, size))} points: spacing "
                                            f"{', '.join(f'{s / RESOLUTION:.3g}' for s in small)}) exceeds "
                                            f"{GRID_POINTS[n]} points: particles")
    return _Rung("grid", size, bounds), "grid: spacing ≤ 1/%d of the smallest scale per axis" % RESOLUTION


def _pilot_posterior_sd(model, sim, m0, P0, kw, run, paths=16, particles=500):
    """``(n,)`` the ``POSTERIOR_QUANTILE`` quantile of a pilot particle filter's posterior standard
    deviations over a few paths and all steps."""
    sub = slice(0, min(paths, sim.ys.shape[0]))
    est = run(ParticleFilter(model, particles, **kw["particle"]), sim.ys[sub], "pilot")
    ok = ~np.asarray(est.diverged, bool)
    sd = np.sqrt(np.diagonal(est.covs[ok], axis1=-2, axis2=-1)).reshape(-1, model.n)
    sd = sd[np.all(np.isfinite(sd), axis=1)]
    return np.quantile(sd, POSTERIOR_QUANTILE, axis=0) if sd.size else np.full(model.n, np.nan)


def _diagnostics(est):
    """Edge mass (grids: over every step of every path, a diverged one's up to its divergence —
    a path that left the grid is marked diverged, and the mass it had on the edge before counts)
    and effective sample size (particles, over the paths that did not diverge), and the number of
    paths that diverged."""
    out = {}
    ok = ~np.asarray(est.diverged, bool)
    if "edge_mass" in est.extras:
        em = np.asarray(est.extras["edge_mass"], float)
        em = em[np.isfinite(em)]
        out["edge_mass_max"] = float(np.max(em)) if em.size else 0.0
    if "ess" in est.extras:
        ess = np.asarray(est.extras["ess"])[ok]
        out["ess_min"] = float(np.min(ess)) if ess.size else float("nan")
        out["ess_median"] = float(np.median(ess)) if ess.size else float("nan")
    out["diverged"] = int(np.sum(~ok))
    return out


def _refinement_error(fine, coarse, xs, window, angles=()):
    """Per component ``(Δ, se)``: MSE(fine) − MSE(coarse) on the same paths."""
    out = []
    for i in range(xs.shape[-1]):
        d = paired_difference(fine, coarse, xs, component=i, window=window, angles=angles)
        out.append((d.value, d.stderr))
    return out


def _tolerance(est, judged, xs, window, rtol, angles=()):
    """Per component, the largest error bound a certified reference may have: ``rtol`` times its
    MSE, or the smallest standard error of the gaps it judges (``judged``: name -> Estimates),
    whichever is larger — an error below the comparison's own resolution changes no verdict."""
    out = []
    for i in range(xs.shape[-1]):
        tol = rtol * abs(mse(est, xs, component=i, window=window, angles=angles).value)
        ses = [paired_difference(e, est, xs, component=i, window=window, angles=angles).stderr for e in judged.values()]
        ses = [s for s in ses if np.isfinite(s)]
        out.append(max(tol, min(ses)) if ses else tol)
    return out


def _verdict(error, tol):
    """``(bound |Δ| + 2 se per component, certified)``: certified when in every component the
    refinement's noise is within the tolerance (``se ≤ tol``) and the decrease of the MSE it
    brings is within the tolerance or not distinguishable from that noise
    (``max(−Δ, 0) ≤ max(tol, 2 se)``). One-sided: a finer reference that does *worse*
    (``Δ > 0``) shows its own error (a particle filter's noise), not this reference's."""
    bound = [abs(d) + 2 * se for d, se in error]
    ok = all(np.isfinite(d) and np.isfinite(se) and se <= t and max(-d, 0.0) <= max(t, 2 * se)
             for (d, se), t in zip(error, tol))
    return bound, ok


def _check(est, diag, fine, sim, sub, judged, window, rtol, run, tag):
    """The refinement check of a reference's estimates ``est`` (all paths) against the filter
    ``fine`` run on the paths ``sub``: ``(record fields, certified)`` — the change ``error``
    ``[(Δ, se)]``, its ``bound``, the ``tolerance``, the reference's ``mse``; certified when
    :func:`_verdict` passes, the edge mass is within :data:`EDGE_MASS` and no path diverged.
    A particle ``fine`` runs ``means_only`` (the check reads its MSE alone: no covariances)."""
    if isinstance(fine, ParticleFilter):
        fine.means_only = True
    ang = angles_of(fine.model).states  # angular states: wrapped errors (nlfilter.angles)
    error = _refinement_error(run(fine, sim.ys[sub], tag), est.take(sub), sim.xs[sub], window, ang)
    ref_mse = [mse(est, sim.xs, component=i, window=window, angles=ang).value for i in range(sim.xs.shape[-1])]
    tol = _tolerance(est, judged, sim.xs, window, rtol, ang)
    bound, ok = _verdict(error, tol)
    ok = ok and diag.get("edge_mass_max", 0.0) <= EDGE_MASS and diag["diverged"] == 0
    return {"error": [list(e) for e in error], "bound": bound, "tolerance": tol, "mse": ref_mse}, ok


def _filter_kw(model, dt, start, substeps, times=None):
    """The constructor options of the reference filters on ``model``; ``times``: an SDE measured
    at those discrete times (:class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter`,
    its prior at 0, with ``substeps`` Euler–Maruyama steps per interval)."""
    if times is not None:
        return {"cd": {"substeps": substeps, "start": start}, "times": times}
    return {"grid": {"dt": dt} if model.kind == "sde" else {"start": start},
            "particle": ({"dt": dt, "substeps": substeps} if model.kind == "sde" else {"start": start})}


def certified_reference(model, sim, m0, P0, *, run, judged=None, dt=None, start="update", substeps=SUBSTEPS,
                        window=0.5, rtol=0.02, certify_paths=64, max_particles=MAX_PARTICLES, first="auto",
                        budget=None, times=None):
    """``(estimates on all paths, Certificate)`` of the automatic reference (module docstring).

    ``run(flt, ys, tag) -> Estimates`` runs a filter on (some of) the simulation's measurements
    (the comparison supplies it, with the filter's own random stream keyed by ``tag``);
    ``sim`` the shared :class:`~nlfilter.simulation.Simulation`; ``judged`` the filters' estimates
    (name -> Estimates) whose gaps the reference will judge; the tolerance of the certificate is
    ``rtol`` times the reference's MSE or the smallest standard error of those gaps, whichever is
    larger (rule in the module docstring); ``certify_paths`` the paths of the refinement runs;
    ``max_particles`` the last rung of the ladder (and the most particles of the first);
    ``first``: ``"auto"`` (module docstring), ``"grid"`` (the automatic grid, a ValueError naming
    ``reference`` when the model cannot have one; no particle rung after it) or ``"particle"``
    (particles from the first rung); ``budget``: None or a
    :class:`~nlfilter.compare_budget.ReferenceBudget`, which may replace the first rung and stop
    the ladder by the estimated cost of each rung. ``times``: an SDE measured at those discrete
    times (``dt`` None): particles from the first rung,
    :class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter` with the simulation's
    ``substeps`` (its Euler–Maruyama scheme: the simulator's model); ``first="grid"`` is refused."""
    judged = judged or {}
    t_start = time.perf_counter()
    kw = _filter_kw(model, dt, start, substeps, times)
    sub = slice(0, min(certify_paths, sim.ys.shape[0]))
    if times is not None and first == "grid":
        raise ValueError("reference: 'grid' cannot serve an SDE measured at discrete times (no grid filter reads "
                         "such data); expected 'auto' or 'particle'")
    if first == "particle" or times is not None:
        post_sd = np.full(model.n, np.nan)
        rung, reason = _Rung("particle", PARTICLES), ("reference='particle': particles" if times is None else
                                                      "measured at discrete times: particles through the "
                                                      "simulator's Euler–Maruyama steps")
    else:
        post_sd = _pilot_posterior_sd(model, sim, m0, P0, kw, run) if model.n <= 2 else np.full(model.n, np.nan)
        rung, reason = _first_rung(model, sim, m0, P0, dt, post_sd)
        if first == "grid" and rung.kind != "grid":
            raise ValueError(f"reference: 'grid' cannot serve this model ({reason}); expected 'auto' or 'particle'")
    if rung.kind == "particle" and rung.size > max_particles:
        rung = _Rung("particle", max_particles)
    if budget is not None:
        rung, reason = budget.first(rung, reason, switch=first == "auto" and times is None)
    rungs, widen = [], 1.0
    est = run(rung.build(model, kw), sim.ys, f"reference {rung.kind} {rung.size}")
    while True:
        diag = _diagnostics(est)
        record = {"kind": rung.kind, "size": rung.size, "bounds": rung.bounds, **diag}
        cut = diag.get("edge_mass_max", 0.0) > EDGE_MASS
        if rung.kind == "grid" and (cut or diag["diverged"]) and widen < 2.0:
            widen *= 1.5  # the bounds cut the density, or paths left the grid: widen by half and rerun
            record["verdict"] = (f"edge mass {diag['edge_mass_max']:.2g} > {EDGE_MASS}" if cut else
                                 f"{diag['diverged']} path(s) left the grid or diverged") + ": bounds widened"
            rungs.append(record)
            rung, reason = _first_rung(model, sim, m0, P0, dt, post_sd, widen=widen)
            est = run(rung.build(model, kw), sim.ys, f"reference {rung.kind} {rung.size}")
            continue
        fine = rung.refined()
        fields, ok = _check(est, diag, fine.build(model, kw), sim, sub, judged, window, rtol, run,
                            f"refine {fine.kind} {fine.size}")
        record.update(refined_to=fine.size, **fields, verdict="certified" if ok else "not converged")
        rungs.append(record)
        if ok:
            cert = Certificate(rung.kind, True, OPTIMAL, rung.size, rung.bounds, rtol, sub.stop,
                               [tuple(e) for e in fields["error"]], fields["bound"], rungs,
                               time.perf_counter() - t_start, reason)
            return est, cert
        nxt = rung.next(max_particles) if first != "grid" else None
        if nxt is None or (budget is not None and not budget.allows(nxt)):
            break
        rung = nxt
        est = run(rung.build(model, kw), sim.ys, f"reference {rung.kind} {rung.size}")
    last = rungs[-1]
    error = [tuple(e) for e in last.get("error", [])]
    bound = last.get("bound", [])
    if budget is not None and budget.capped:
        reason = f"{reason}; stopped by the reference budget ({budget.seconds:g} s)"
    cert = Certificate(rung.kind, False, NOT_CONVERGED, rung.size, rung.bounds, rtol, sub.stop, error, bound,
                       rungs, time.perf_counter() - t_start, reason)
    warnings.warn(
        f"compare: the automatic reference did not converge within its budget: refining {rung.describe()} "
        f"to {rung.refined().describe()} changed the MSE by "
        f"{', '.join(f'{d:+.3g} ± {se:.2g}' for d, se in error) or '?'} (error bound "
        f"{', '.join(f'{b:.3g}' for b in bound) or '?'}; the tolerance is "
        f"{', '.join(f'{t:.3g}' for t in last.get('tolerance', [])) or '?'}: rtol = {rtol} of the MSE or the "
        f"gaps' smallest s.e.); its rows "
        f"are labelled {NOT_CONVERGED!r}. Raise max_particles (now {max_particles})"
        f"{' or the reference budget' if budget is not None and budget.capped else ''} or pass "
        f"reference=ParticleFilter(model, {4 * int(rung.size) if rung.kind == 'particle' else PARTICLES}, ...)",
        ReferenceWarning, stacklevel=3)
    return est, cert


def reference_filter(cert, model, *, dt=None, start="update", substeps=SUBSTEPS, times=None):
    """The filter of the rung a :class:`Certificate` of :func:`certified_reference` names (kind,
    size, bounds), built again on ``model`` with the comparison's options: what a smoother of the
    reference runs (the same grid, or the same particles on the same streams)."""
    if cert.kind not in ("grid", "particle"):
        raise ValueError(f"cert: expected the certificate of an automatic grid or particle reference, got kind "
                         f"{cert.kind!r}")
    return _Rung(cert.kind, cert.size, cert.bounds).build(model, _filter_kw(model, dt, start, substeps, times))


def check_given_reference(flt, est, model, sim, *, run, judged=None, window=0.5, rtol=0.02, certify_paths=64):
    """The certificate of a reference the user passed: a ``GridFilter`` or ``ParticleFilter`` is
    refined once (``2×`` points per axis, ``4×`` particles) on ``certify_paths`` paths and
    labelled as the automatic one (a grid whose 2× refinement would exceed :data:`REFINE_POINTS`
    points is checked against ``4 × PARTICLES`` particles instead); other kinds are taken as
    given (``certified = None``, named ``"optimal"``). Edge mass and effective sample size are reported either way; a grid whose
    edge mass exceeds :data:`EDGE_MASS` or a refinement that moves the MSE beyond ``rtol``
    warns. A particle reference on an SDE whose ``substeps`` differ from the simulation's
    (``sim.timing.substeps``) has another model than the simulator's: the certificate's
    ``reason`` says so."""
    t_start = time.perf_counter()
    diag = _diagnostics(est)
    sub = slice(0, min(certify_paths, sim.ys.shape[0]))
    reason = "given by the caller"
    data_substeps = getattr(getattr(sim, "timing", None), "substeps", None)
    if isinstance(flt, GridFilter):
        md = flt.model
        kw = _filter_kw(md, getattr(flt, "dt", None), flt.start, data_substeps or SUBSTEPS)
        kind, size = "grid", [len(a) for a in flt.axes]
        rung = _Rung("grid", size, [(float(a[0]), float(a[-1])) for a in flt.axes]).refined()
        finer = rung.build(md, kw)
        if math.prod(rung.size) > REFINE_POINTS[md.n]:  # too large to run: 4 × PARTICLES particles instead
            finer = _Rung("particle", 4 * PARTICLES).build(md, kw)
            reason = (f"given by the caller; its 2× refinement ({math.prod(rung.size)} points) exceeds "
                      f"{REFINE_POINTS[md.n]}: checked against {4 * PARTICLES} particles")
    elif isinstance(flt, ContinuousDiscreteParticleFilter):  # the same filter (times, substeps), 4× the particles
        import copy
        finer, kind, size = copy.copy(flt), "particle", flt.particles
        finer.particles = 4 * flt.particles
    elif isinstance(flt, JumpParticleFilter):
        finer = JumpParticleFilter(flt.switching, 4 * flt.particles, threshold=flt.threshold, start=flt.start)
        kind, size = "particle", flt.particles
    elif isinstance(flt, ParticleFilter):
        kw = {"dt": flt.dt, "substeps": flt.substeps} if flt.model.kind == "sde" else {"start": flt.start}
        finer = ParticleFilter(flt.model, 4 * flt.particles, threshold=flt.threshold, **kw)
        kind, size = "particle", flt.particles
    else:
        return Certificate(type(flt).__name__, None, OPTIMAL, rungs=[diag], reason="given by the caller: not checked",
                           seconds=time.perf_counter() - t_start)
    if kind == "particle" and flt.model.kind == "sde" and data_substeps is not None and flt.substeps != data_substeps:
        reason = (f"given by the caller, with substeps={flt.substeps} where the simulation has {data_substeps}: "
                  f"the posterior of a {'finer' if flt.substeps > data_substeps else 'coarser'} Euler–Maruyama "
                  "model than the simulator's (equal substeps: its model exactly; sde_step)")
    fields, ok = _check(est, diag, finer, sim, sub, judged or {}, window, rtol, run, "refine given")
    error, tol = [tuple(e) for e in fields["error"]], fields["tolerance"]
    cert = Certificate(kind, ok, OPTIMAL if ok else NOT_CONVERGED, size, None, rtol, sub.stop, error,
                       fields["bound"], [{**diag, **fields}], time.perf_counter() - t_start, reason)
    if not ok:
        what = [f"refining it changed the MSE by {', '.join(f'{d:+.3g} ± {se:.2g}' for d, se in error)} "
                f"(tolerance {', '.join(f'{t:.3g}' for t in tol)})"]
        if kind == "grid":
            what.append(f"edge mass {diag.get('edge_mass_max', 0.0):.2g} (at most {EDGE_MASS:g})")
        if diag["diverged"]:
            what.append(f"{diag['diverged']} diverged path(s)")
        warnings.warn(f"compare: the given reference ({kind} {size}) is not converged: {'; '.join(what)}; its numbers "
                      f"are labelled {NOT_CONVERGED!r}: raise its "
                      f"{'points per axis or widen its bounds' if kind == 'grid' else 'particles'}",
                      ReferenceWarning, stacklevel=3)
    return cert
