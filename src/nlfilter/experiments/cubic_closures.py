"""Experiment ``cubic-sensor-closures``: conditional-moment filters with closures on the cubic
sensor of seed 001, ch. 5 (Vallot 1981).

Model (001 eqs. 5.1-5.4): ``dx = −x dt + dw``, ``dy = x³ dt + dv``, ``E dw² = q dt``,
``E dv² = r dt``, stationary start ``x(0) ~ N(0, q/2)``. Cases: the lists ``q`` and ``r`` (zipped);
by default (q, r) = (2, 1) and (1, 1), the cases of the thesis' Tables 5.1-5.2.

Filters (row ``filter``): ``ekf`` (continuous EKF: started at the stationary mean 0 its gain
3x̂²P/r is 0 and it never moves), ``gaussian-closure`` (Kushner-Stratonovich moments with the
Gaussian closure: the Gaussian assumed-density filter with exact polynomial moments),
``edgeworth4-closure`` (moments up to order 4, Edgeworth / quasi-moment closure),
``optimal`` (grid filter). Quantities: ``mse_x`` — the steady-state time average of (x − x̂)² over
t ≥ ``burn_in`` with its standard error across paths; ``mse_x_gap`` — the paired difference to the
optimal filter on the same paths. Each row's ``params`` holds q and r.

The thesis gives no number for these filters (its Tables 5.1-5.2 list the optimal *linear* filter,
its tensor filter and the Bobrovsky-Zakai bound; they are quoted in the notes for context).
The Monte Carlo is computed in blocks of ``block`` paths (``_closures_block``,
:func:`nlfilter.montecarlo.montecarlo`).
"""

from __future__ import annotations

from functools import partial

import numpy as np

from .. import _validate as V
from .. import evaluate as ev
from .. import problems as pb
from ..filters.ekf import ContinuousEKF
from ..filters.moment_filters import ConditionalMomentFilter
from ..filters.reference import GridFilter
from ..models import SDEModel
from ..montecarlo import montecarlo
from ..moments.closures import EdgeworthClosure, GaussianClosure
from ..results import Result
from ..simulate import simulate

# 001 Tables 5.1-5.2: steady-state E(x − x̂)² of the optimal linear filter, the tensor filter, and the
# Bobrovsky-Zakai lower bound (for context only: not the filters of this experiment)
THESIS = {(2.0, 1.0): {"linear": 0.540, "tensor": 0.522, "bz_bound": 0.238},
          (1.0, 1.0): {"linear": 0.378, "tensor": 0.371, "bz_bound": 0.264}}


def model(q: float, r: float) -> SDEModel:
    """001 eqs. 5.1-5.4 (:func:`nlfilter.problems.cubic_sensor`)."""
    return pb.cubic_sensor(q, r).model


FILTERS = ("ekf", "gaussian-closure", "edgeworth4-closure", "optimal")


def _filters(md, dt, q, grid):
    """The filters of the experiment, by name (:data:`FILTERS`)."""
    sd = np.sqrt(q / 2)
    return {
        "ekf": ContinuousEKF(md, dt, substeps=2),
        "gaussian-closure": ConditionalMomentFilter(md, dt, closure=GaussianClosure(), name="gaussian-closure"),
        "edgeworth4-closure": ConditionalMomentFilter(md, dt, closure=EdgeworthClosure(4), name="edgeworth4-closure"),
        "optimal": GridFilter(md, (-7 * sd, 7 * sd), size=grid, dt=dt),
    }


def _closures_block(rows, *, q, r, dt, steps, nb, substeps, grid, seed, case):
    """One Monte Carlo block (:func:`nlfilter.montecarlo.montecarlo`): simulate the paths ``rows`` of
    001 eqs. 5.1-5.4 from the stationary start (per-path streams of case ``case`` of ``seed``;
    Euler-Maruyama with ``substeps`` per step), run the filters (:func:`_filters`) on the common
    noise and reduce each path to ``mse_<f>`` (mean (x − x̂)² after the first ``nb`` steps),
    ``gap_<f>`` (the same, paired, minus the optimal filter's), ``ok_<f>`` (not diverged) and
    ``e2_<f>`` (the squared error at every step, for the MSE over t)."""
    md = model(q, r)
    m0, P0 = np.zeros(1), np.array([[q / 2]])
    sim = simulate(md, steps, paths=rows, rng=ev.stream(seed, case), m0=m0, P0=P0, dt=dt, substeps=substeps)
    x = sim.xs[..., 0]
    out, e2 = {}, {}
    for name, f in _filters(md, dt, q, grid).items():
        est = f.run(sim.ys, m0, P0, on_divergence="mark")
        e2[name] = (est.means[..., 0] - x) ** 2
        out[f"mse_{name}"] = np.mean(e2[name][:, nb:], axis=-1)
        out[f"ok_{name}"] = ~np.asarray(est.diverged)
        out[f"e2_{name}"] = e2[name]
    for name in FILTERS[:-1]:
        out[f"gap_{name}"] = np.mean((e2[name] - e2["optimal"])[:, nb:], axis=-1)
    return out


def run(params, *, quick, runs, seed, progress):
    """The experiment ``cubic-sensor-closures`` (its title, source and parameters: :data:`nlfilter.experiments.EXPERIMENTS`)."""
    p = params
    qs, rs = list(p["q"]), list(p["r"])
    if len(qs) != len(rs) or not qs:
        raise ValueError(f"param q={qs!r}, r={rs!r}: expected two lists of the same positive length (zipped cases)")
    for q, r in zip(qs, rs):
        V.positive("param q", q)
        V.positive("param r", r)
    for nm in ("dt", "t_end"):
        V.positive(f"param {nm}", p[nm])
    if not 0 <= p["burn_in"] < p["t_end"]:
        raise ValueError(f"param burn_in={p['burn_in']}: expected 0 ≤ burn_in < t_end = {p['t_end']}")
    res = Result("cubic-sensor-closures", "closures on the cubic sensor", "seed 001, ch. 5", p)
    dt = p["dt"]
    t_end = res.used("t_end", 3.0 if quick else p["t_end"])
    burn = res.used("burn_in", min(p["burn_in"], 1.0) if quick else p["burn_in"])
    steps = res.used("steps", int(round(t_end / dt)))
    npaths = res.used("paths", runs or (16 if quick else 300))
    gsize = res.used("grid_size", 121 if quick else p["grid_size"])
    substeps = res.used("substeps", 5 if quick else 10)
    block = res.used("block", int(p["block"]))
    for case, (q, r) in enumerate(zip(qs, rs)):
        q, r = float(q), float(r)
        var = q / 2  # stationary variance of dx = −x dt + dw
        ident = {"q": q, "r": r, "dt": dt, "steps": steps, "nb": int(round(burn / dt)), "substeps": substeps,
                 "grid": gsize, "seed": seed, "case": case}
        pp = montecarlo(f"cubic q={q:g} r={r:g}", partial(_closures_block, **ident), npaths, block=block,
                        ident=ident)
        opt = ev._summary(pp["mse_optimal"], pp["ok_optimal"])
        for name in FILTERS:
            s = ev._summary(pp[f"mse_{name}"], pp[f"ok_{name}"])
            res.add(name, "mse_x", s.value, s.stderr, q=q, r=r, diverged=s.diverged)
            if name != "optimal":
                d = ev._summary(pp[f"gap_{name}"], pp[f"ok_{name}"] & pp["ok_optimal"])
                res.add(name, "mse_x_gap", d.value, d.stderr, q=q, r=r)
        lines = {}
        for name in FILTERS:
            e2 = pp[f"e2_{name}"][pp[f"ok_{name}"]]  # ev.mse_per_step: the paths that did not diverge
            if e2.shape[0] < 2:
                raise ValueError(f"estimates: need at least 2 non-diverged paths, got {e2.shape[0]}")
            mse_t = e2.mean(axis=0)
            k = max(1, int(round(0.5 / dt)))  # half-unit running mean, for legibility
            norm = np.convolve(np.ones_like(mse_t), np.ones(k), mode="same")  # shorter windows at the ends
            lines[name] = np.convolve(mse_t, np.ones(k), mode="same") / norm
        th = THESIS.get((q, r), {})  # context: the thesis' steady-state best linear filter and its bound
        paper = {f"{k}, 001 Tables 5.1-5.2": (None, th[v]) for k, v in
                 (("best linear filter", "linear"), ("Bobrovsky-Zakai bound", "bz_bound")) if v in th}
        res.series[f"q={q:g}, r={r:g}: MSE over t (running mean over 0.5, {npaths} paths)"] = {
            "x": dt * np.arange(1, steps + 1), "lines": lines, "paper": paper, "xlabel": "t", "ylabel": "E (x − x̂)²",
            "styles": {"ekf": "--"}}
        gc = res.get("gaussian-closure", "mse_x", q=q, r=r).value
        e4 = res.get("edgeworth4-closure", "mse_x", q=q, r=r).value
        res.notes.append(
            f"q={q:g}, r={r:g}: optimal {opt.value:.4f} ± {opt.stderr:.2g}; Gaussian closure "
            f"{100 * (gc / opt.value - 1):+.2f} %, Edgeworth-4 {100 * (e4 / opt.value - 1):+.2f} % relative to it; "
            f"EKF {res.get('ekf', 'mse_x', q=q, r=r).value:.4f} (stationary variance {var:g}: it does not move).")
        th = THESIS.get((q, r))
        if th:
            res.notes.append(f"  thesis (001 Table 5.{1 if q == 2.0 else 2}, other filters): optimal linear "
                             f"{th['linear']}, tensor filter {th['tensor']}, Bobrovsky-Zakai bound {th['bz_bound']}.")
    return res
