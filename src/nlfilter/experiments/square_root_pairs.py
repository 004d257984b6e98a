"""Experiment ``square-root``: every square-root filter beside its standard form on ill-conditioned
problems (issue 30, item 2: the evidence that the square-root forms matter).

Pairs (``pairs()``): every registered ``sr-X`` whose standard ``X`` is registered too
(:data:`nlfilter.filters.REGISTRY`), so a square-root form joins the experiment when it is
registered. A pair runs on a problem when both of its filters accept the problem's model (a
discrete-time filter of a ``"discrete"`` model, or a continuous-discrete one of an ``"sde"``
model with discrete measurements) and build on it (``needs``: an EKF needs the Jacobians the
falling body's flow map has not); a pair that cannot run is named in the notes. Problems (row
param ``problem``):

* ``noiseless`` — the classic near-noiseless, nearly collinear measurement (as in Grewal & Andrews,
  *Kalman Filtering: Theory and Practice*, on implementation methods): three static states,
  ``x[k+1] = x + w`` (``Q = q I``, ``q = 0`` by default), ``P0 = I``, measured by
  ``H = [[1, 1, 1], [1, 1, 1 + δ]]`` with ``R = δ² I``; a sweep of ``R/P0 = δ²`` (row param ``r``)
  from 1e-8 down to 1e-18;
* ``long-run`` — a constant-velocity model ``x1' = x1 + τ x2``, ``x2' = x2`` (``τ = long_tau``),
  the position measured with ``R = long_r``, a negligible process noise: the covariance's
  condition number grows like ``τ² k²`` over the run (5e16 after 2·10⁴ steps at τ = 10⁴), the
  run the round-off of the standard forms accumulates over (``long_steps``, 2·10⁵ by default; the issue's 10⁶-step run
  is ``--param long_steps=1000000``, ~20 min of CPU for the kf and ukf pairs);
* ``stiff`` — a stiff continuous-discrete model, ``dx1 = (−λ x1 + λ x2) dt``, ``dx2 = −x2 dt + dβ``
  (``λ = stiff_lambda``), ``y_k = x1(t_k) + v_k``, ``R = stiff_r``, measurements ``stiff_dt``
  apart, RK4 with ``stiff_substeps`` substeps (continuous-discrete pairs only);
* ``quadratic`` and ``falling-body`` — Henriksen's (seed 004) problems of the ``second-order``
  experiment (:mod:`nlfilter.problems`): on the falling body the continuous-discrete pairs run on
  the SDE and the discrete ones on its RK4 flow map (as that experiment's UKF).

Rows per filter (``X`` and ``sr-X``) and problem: ``psd_loss_rate`` (fraction of paths whose
covariance, at some step, is non-finite or has an eigenvalue below ``−n·eps·λ_max``, eigvalsh's
own rounding: ``psd_lost``; a path the run marked diverged counts; binomial s.e.),
``psd_loss_steps`` (the fraction of path-steps), ``log10_cond_max`` (the largest condition
number of a covariance the form kept, log10: how ill-conditioned the run got), ``divergence_rate`` (the paths the run loop
marked diverged, ``on_divergence="mark"``: :mod:`nlfilter.filters.base`), ``mse`` (of the whole
state vector, ``E|x − x̂|²`` over the steps, the paths neither form lost; s.e. across paths),
``cpu_us_per_step`` (CPU time of one step of the whole batch of paths, both on the NumPy loop)
and, for ``X``, ``mse_excess`` (its MSE minus ``sr-X``'s on the same paths, paired s.e.).
Claims, computed from those rows: ``max_psd_loss_rate`` of ``sr-*`` (every square-root form at
once: 0 when none lost PSD anywhere) and, per standard form, ``largest_r_lost``: the largest
``R/P0`` of the sweep at which it lost PSD on some path (NaN: at none). No paper gives numbers:
the paper column is empty.
"""

from __future__ import annotations

import time

import numpy as np
import sympy as sp

from .. import evaluate as ev
from .. import problems as pb
from ..filters import REGISTRY
from ..filters.base import ode_step
from ..models import DiscreteModel, SDEModel
from ..results import Result
from ..simulate import simulate, simulate_continuous_discrete
from . import get
from .henriksen import chosen_problems

PROBLEMS = ("noiseless", "long-run", "stiff", "quadratic", "falling-body")
RUNS = {"noiseless": 200, "long-run": 2, "stiff": 100, "quadratic": 1000, "falling-body": 200}
QUICK = {"runs": {"noiseless": 6, "long-run": 2, "stiff": 3, "quadratic": 16, "falling-body": 3},
         "steps": {"noiseless": 4, "stiff": 2, "quadratic": 10, "falling-body": 6}, "long_steps": 200}
STEPS = {"noiseless": 20, "stiff": 100}  # the others: the problem's own (quadratic 50, falling body 60)


def pairs() -> dict:
    """``{X: (sr-X class, X class)}`` for every registered ``sr-X`` whose ``X`` is registered."""
    return {name[3:]: (cls, REGISTRY[name[3:]]) for name, cls in REGISTRY.items()
            if name.startswith("sr-") and name[3:] in REGISTRY}


def kind(cls) -> str | None:
    """``"discrete"`` (a discrete-time filter of a discrete model), ``"continuous-discrete"`` (a
    discrete-time filter of an SDE with discrete measurements) or None (neither)."""
    accepts, t = getattr(cls, "accepts", ()), getattr(cls, "time", "")
    if t == "discrete" and "sde" in accepts:
        return "continuous-discrete"
    return "discrete" if t == "discrete" and "discrete" in accepts else None


def psd_lost(covs) -> np.ndarray:
    """``(..., T)`` bool: the covariance ``covs (..., T, n, n)`` is non-finite, or its symmetric
    part has an eigenvalue below ``−n·eps·λ_max`` (the backward error of ``eigvalsh``: a smaller
    negative eigenvalue is rounding of a PSD matrix, e.g. of a square-root form's ``S Sᵀ``)."""
    return _spectrum(covs)[0]


def _spectrum(covs):
    """``(lost, log10 of the condition number)`` per path-step (:func:`psd_lost`; NaN where lost or
    singular)."""
    covs = np.asarray(covs, dtype=float)
    n = covs.shape[-1]
    finite = np.isfinite(covs).all(axis=(-1, -2))
    sym = np.where(finite[..., None, None], 0.5 * (covs + np.swapaxes(covs, -1, -2)), 0.0)
    lam = np.linalg.eigvalsh(sym)
    top = np.abs(lam).max(axis=-1)
    lost = ~finite | (lam[..., 0] < -n * np.finfo(float).eps * top)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.where(~lost & (lam[..., 0] > 0), np.log10(top / lam[..., 0]), np.nan)
    return lost, cond


# -- the problems: (model, m0, P0, x0, dt or None, steps, data) -------------------------------------
def collinear(r: float, q: float = 0.0) -> DiscreteModel:
    """The ``noiseless`` problem's model at ``R/P0 = r`` (``δ = √r``; module docstring)."""
    d = float(np.sqrt(r))
    return DiscreteModel.linear(np.eye(3), [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0 + d]], q * np.eye(3), r * np.eye(2),
                                name=f"collinear r={r:g}")


def long_run_model(tau: float, r: float) -> DiscreteModel:
    """The ``long-run`` model (module docstring; process noise 1e-30 · the white-acceleration Q)."""
    Q = 1e-30 * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    return DiscreteModel.linear([[1.0, tau], [0.0, 1.0]], [[1.0, 0.0]], Q, [[r]], name="constant velocity")


def stiff_model(lam: float, r: float) -> SDEModel:
    """The ``stiff`` model (module docstring): eigenvalues −λ and −1 of the drift."""
    x1, x2 = sp.symbols("x1 x2")
    return SDEModel([x1, x2], [-lam * x1 + lam * x2, -x2], [x1], G=[[0], [1]], Q=1.0, R=r, name="stiff")


def _flow_model(md, dt, substeps):
    """The falling body's RK4 flow map over one measurement interval, as a discrete model."""
    flow = lambda x, k=0: ode_step(md.f, x, k * dt, dt, substeps=substeps, scheme="rk4")  # noqa: E731
    return DiscreteModel.from_functions(md.n, 1, flow, md.h, Q=np.zeros((md.n, md.n)), R=md.R,
                                        name="falling-body flow map")


def build(name, cls, model, dt=None, substeps=1, start=None):
    """Filter ``cls`` on ``model`` (continuous-discrete with ``dt``): the instance, or the text of
    its refusal (a ValueError/TypeError naming what the model lacks)."""
    kw = {} if start is None else {"start": start}
    try:
        return cls(model, dt, substeps=substeps, **kw) if kind(cls) == "continuous-discrete" else cls(model, **kw)
    except (ValueError, TypeError) as exc:
        return f"{name}: {exc}"


def _timed(flt, ys, m0, P0):
    t0 = time.process_time()
    est = flt.run(ys, m0, P0, on_divergence="mark", backend="numpy")
    return est, (time.process_time() - t0) / ys.shape[-2]


def compare_pair(res, x, pair, models, sim, m0, P0, **row):
    """Run the pair ``x`` (``(sr class, standard class)``) on ``sim`` and add its rows (module
    docstring) with the row params ``row``; ``models``: ``{kind: (model, dt, substeps, start)}``.
    The text of a refusal, "" when the pair is not of the problem's kind, None when it ran."""
    sr_cls, std_cls = pair
    k = kind(std_cls)
    if k is None or k != kind(sr_cls) or k not in models:
        return ""  # not a filter of this problem's kind of model
    md, dt, sub, start = models[k]
    flts = {f"sr-{x}": build(f"sr-{x}", sr_cls, md, dt, sub, start), x: build(x, std_cls, md, dt, sub, start)}
    for f in flts.values():
        if isinstance(f, str):
            return f
    out, lost = {}, {}
    for name, flt in flts.items():
        with np.errstate(all="ignore"):
            est, cost = _timed(flt, sim.ys, m0, P0)
        bad, cond = _spectrum(est.covs)
        bad |= est.diverged[:, None]
        res.add(name, "log10_cond_max", float(np.nanmax(cond)) if np.isfinite(cond).any() else np.nan, **row)
        lost[name] = bad.any(axis=-1)
        p, n = float(lost[name].mean()), lost[name].size
        res.add(name, "psd_loss_rate", p, np.sqrt(p * (1 - p) / n), **row)
        res.add(name, "psd_loss_steps", float(bad.mean()), **row)
        d = float(est.diverged.mean())
        res.add(name, "divergence_rate", d, np.sqrt(d * (1 - d) / n), **row)
        res.add(name, "cpu_us_per_step", 1e6 * cost, **row)
        out[name] = np.sum((est.means - sim.xs) ** 2, axis=-1).mean(axis=-1)  # per path
    for name, e2 in out.items():  # NaN: fewer than 2 paths kept (s.e.) or none (value)
        s = ev._summary(e2, ~lost[name])
        res.add(name, "mse", s.value, s.stderr, **row)
    d = ev._summary(out[x] - out[f"sr-{x}"], ~lost[x] & ~lost[f"sr-{x}"])
    res.add(x, "mse_excess", d.value, d.stderr, **row)
    return None


def _noiseless(res, p, paths, steps, seed, todo):
    for j, r in enumerate(p["r"]):
        md = collinear(r, p["noiseless_q"])
        m0, P0 = np.zeros(3), np.eye(3)
        sim = simulate(md, steps, paths=paths, rng=ev.stream(seed, 10 + j), m0=m0, P0=P0)
        yield {"discrete": (md, None, 1, None)}, sim, m0, P0, {"r": r}


def _long_run(res, p, paths, steps, seed, todo):
    md = long_run_model(p["long_tau"], p["long_r"])
    m0, P0 = np.zeros(2), np.eye(2)
    sim = simulate(md, steps, paths=paths, rng=ev.stream(seed, 1), m0=m0, P0=P0)
    yield {"discrete": (md, None, 1, None)}, sim, m0, P0, {}


def _stiff(res, p, paths, steps, seed, todo):
    md = stiff_model(p["stiff_lambda"], p["stiff_r"])
    m0, P0, dt, sub = np.zeros(2), np.eye(2), p["stiff_dt"], p["stiff_substeps"]
    if not any(kind(c) == "continuous-discrete" for pr in todo.values() for c in pr):
        return  # nothing to run: no simulation either
    sim = simulate_continuous_discrete(md, steps, paths=paths, rng=ev.stream(seed, 2), m0=m0, P0=P0, dt=dt,
                                       substeps=sub, process="flow")  # RK4 flow + noise per interval
    yield {"continuous-discrete": (md, dt, sub, None)}, sim, m0, P0, {}


def _quadratic(res, p, paths, steps, seed, todo):
    prob = pb.quadratic(r=p["quad_r"])
    sim = simulate(prob.model, steps, paths=paths, rng=ev.stream(seed, 3), m0=prob.m0, P0=prob.P0)
    yield {"discrete": (prob.model, None, 1, None)}, sim, prob.m0, prob.P0, {}


def _falling_body(res, p, paths, steps, seed, todo):
    prob = pb.falling_body(r=p["fb_r"])
    md, dt, sub = prob.model, prob.dt, p["fb_substeps"]
    sim = simulate_continuous_discrete(md, steps, paths=paths, rng=ev.stream(seed, 4), x0=prob.x0, dt=dt,
                                       substeps=sub, process="flow")  # the RK4 flow (no process noise)
    models = {"continuous-discrete": (md, dt, sub, "predict"), "discrete": (_flow_model(md, dt, sub), None, 1,
                                                                             "predict")}
    yield models, sim, prob.m0, prob.P0, {}


CASES = {"noiseless": _noiseless, "long-run": _long_run, "stiff": _stiff, "quadratic": _quadratic,
         "falling-body": _falling_body}


def _chosen(params) -> tuple:
    return chosen_problems(params["problem"], PROBLEMS)


def run(params, *, quick=False, runs=None, seed=0, progress=False):
    """The experiment ``square-root`` (its title, source and parameters: :data:`nlfilter.experiments.EXPERIMENTS`)."""
    p = dict(params)
    chosen = _chosen(p)
    if quick:
        p["long_steps"] = min(p["long_steps"], QUICK["long_steps"])
    exp = get("square-root")
    res = Result("square-root", exp.title, exp.source, p)
    every = pairs()
    res.used("pairs", sorted(every))
    unknown = [x for x in p["long_pairs"] if x not in every]
    if unknown:
        raise ValueError(f"param long_pairs={p['long_pairs']!r}: {unknown} have no registered square-root form; "
                         f"expected names among {sorted(every)}")
    for problem in chosen:
        todo = every if problem != "long-run" else {x: every[x] for x in p["long_pairs"]}
        paths = runs or (QUICK["runs"] if quick else RUNS)[problem]
        steps = p["long_steps"] if problem == "long-run" else (
            QUICK["steps"][problem] if quick else STEPS.get(problem, {"quadratic": 50, "falling-body": 60}.get(problem)))
        skipped = {}
        for models, sim, m0, P0, row in CASES[problem](res, p, paths, steps, seed, todo):
            res.params.setdefault("problem_steps", {})[problem] = steps  # what ran (nothing: not recorded)
            res.params.setdefault("paths", {})[problem] = paths
            for x, pair in todo.items():
                why = compare_pair(res, x, pair, models, sim, m0, P0, problem=problem, **row)
                if why:  # refused by the model (its needs): named in the notes
                    skipped[x] = why
        if problem not in res.params.get("problem_steps", {}):
            res.notes.append(f"{problem}: no pair runs here (no registered square-root form of a filter of this "
                             "model); nothing simulated.")
        elif skipped:
            res.notes.append(f"{problem}: not run: " + "; ".join(sorted(set(skipped.values()))))
    _claims(res, p, chosen, every)
    _figure(res, p, chosen, every)
    return res


def _rows(res, quantity, **params):
    return [r for r in res.rows if r.quantity == quantity and all(r.params.get(k) == v for k, v in params.items())]


def _ran(res, every, problem) -> list:
    """The standard forms of ``every`` pair that ran on ``problem``, in the registry's order."""
    done = {r.filter for r in _rows(res, "psd_loss_rate", problem=problem)}
    return [x for x in every if x in done]


def _claims(res, p, chosen, every):
    """The claims as rows and notes, computed from the rows (module docstring)."""
    sr = [r for r in _rows(res, "psd_loss_rate") if r.filter.startswith("sr-")]
    std = [r for r in _rows(res, "psd_loss_rate") if not r.filter.startswith("sr-")]
    if sr:
        worst = max(sr, key=lambda r: r.value)
        res.add("sr-*", "max_psd_loss_rate", worst.value, worst.stderr)
        res.notes.append("Claim: no square-root form loses positive definiteness: " + (
            f"holds (no path lost in any of the {len(sr)} runs: pair × problem × R/P0)." if worst.value == 0 else
            f"FAILS: {worst.filter} on {worst.params} (rate {worst.value:.3g})."))
    if "noiseless" in chosen:
        parts = []
        for x in _ran(res, every, "noiseless"):
            hit = [r.params["r"] for r in std if r.filter == x and r.params.get("problem") == "noiseless"
                   and r.value > 0]
            res.add(x, "largest_r_lost", max(hit) if hit else np.nan, problem="noiseless")
            parts.append(f"{x} at R/P0 ≤ {max(hit):g}" if hit else f"{x} never (down to {min(p['r']):g})")
        res.notes.append("Claim: the standard forms lose positive definiteness on the near-noiseless "
                         "measurement, from the largest R/P0 of the sweep: " + "; ".join(parts) + ".")
    others = sorted({(r.filter, r.params["problem"]) for r in std if r.value > 0 and r.params["problem"] != "noiseless"})
    res.notes.append("Standard forms that lost positive definiteness on the other problems: " + (
        ", ".join(f"{f} ({q})" for f, q in others) if others else "none") + ".")
    if "long-run" in chosen:
        conds = [r for r in _rows(res, "log10_cond_max", problem="long-run")]
        res.notes.append(f"long-run: {p['long_steps']} steps; the covariances reached a condition number of "
                         + ", ".join(f"1e{r.value:.1f} ({r.filter})" for r in conds) + ".")
    res.notes.append("psd_loss: non-finite, or an eigenvalue < −n·eps·λ_max (eigvalsh's rounding), at some step, "
                     "or marked diverged; mse: E|x − x̂|² of the whole state over the steps, the paths the form "
                     "kept; mse_excess: MSE(X) − MSE(sr-X) on the paths both kept (paired); cpu_us_per_step: CPU "
                     "time of one step of the batch of paths, both forms on the NumPy loop (a shared machine: "
                     "±20%).")


def _figure(res, p, chosen, every):
    """Panels: the sweep's PSD-loss rate and MSE against R/P0; PSD-loss per problem; the cost."""
    rs = list(p["r"])
    names = list(every)
    if "noiseless" in chosen:
        lines = {x: [res.get(x, "psd_loss_rate", problem="noiseless", r=r).value for r in rs]
                 for x in _ran(res, every, "noiseless")}
        sr_max = [max(res.get(f"sr-{x}", "psd_loss_rate", problem="noiseless", r=r).value for x in lines) for r in rs]
        res.series["noiseless: paths whose covariance lost PSD, vs R/P0"] = {
            "x": rs, "lines": {**lines, "every sr- form": sr_max}, "logx": True, "logy": False,
            "xlabel": "R/P0 (δ²)", "ylabel": "PSD-loss rate", "styles": {"every sr- form": "k--"}}
        rel = {x: [abs(res.get(x, "mse_excess", problem="noiseless", r=r).value)
                   / res.get(f"sr-{x}", "mse", problem="noiseless", r=r).value for r in rs] for x in lines}
        res.series["noiseless: |MSE(X) − MSE(sr-X)| / MSE(sr-X), paired (missing: PSD lost; 0: identical)"] = {
            "x": rs, "lines": rel, "logx": True, "xlabel": "R/P0 (δ²)", "ylabel": "relative MSE difference"}
    probs = [q for q in chosen if q != "noiseless" and _ran(res, every, q)]
    ran = [x for x in names if any(x in _ran(res, every, q) for q in probs)]
    if probs:
        def rate(f, q):  # 0: not run there
            return next((r.value for r in _rows(res, "psd_loss_rate", problem=q) if r.filter == f), 0.0)
        res.series["other problems: PSD-loss rate of the standard forms (of the square-root forms: the "
                   "max_psd_loss_rate row)"] = {
            "kind": "bar", "categories": ran, "bars": {q: [rate(f, q) for f in ran] for q in probs},
            "ylabel": "PSD-loss rate", "ylim": (0.0, 1.05)}
    cost_problem = next((q for q in ("quadratic", *chosen) if _rows(res, "cpu_us_per_step", problem=q)), None)
    if cost_problem:
        ran = _ran(res, every, cost_problem)
        at = {"r": rs[0]} if cost_problem == "noiseless" else {}
        pick = lambda f: res.get(f, "cpu_us_per_step", problem=cost_problem, **at).value  # noqa: E731
        res.series[f"cost on {cost_problem} ({res.params['paths'][cost_problem]} paths a batch)"] = {
            "kind": "bar", "categories": ran, "bars": {"standard": [pick(x) for x in ran],
                                                       "square-root": [pick(f"sr-{x}") for x in ran]},
            "ylabel": "CPU µs per step"}
