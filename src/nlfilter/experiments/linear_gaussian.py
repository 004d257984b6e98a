"""``linear-gaussian``: the evaluation machinery on a model whose answer is known.

A stable 2-state linear Gaussian model, ``x[k+1] = F x[k] + w``, ``y = H x + v``; KF, EKF, UKF,
the grid filter and the particle filter run on the same paths (common random numbers). Each
row is the error variance of the first state component averaged over the second half of the
run, beside the Riccati prediction (steady-state filtered covariance from
``scipy.linalg.solve_discrete_are``). All five filters are optimal here, so every MSE should
agree with the Riccati value within its Monte Carlo standard error (the grid and particle
filters up to their discretization error). ``gap_to_optimal`` rows: each filter's MSE minus the
Kalman filter's (the optimum here) on the same paths, with its paired standard error. The Monte Carlo is computed in blocks of ``block`` paths
(``_linear_block``, :func:`nlfilter.montecarlo.montecarlo`).
"""

from __future__ import annotations

from functools import partial

import numpy as np
import scipy.linalg as sla

from ..evaluate import _per_step, _summary, nees_per_path, stream
from ..filters.ekf import EKF
from ..filters.kalman import KalmanFilter, steady_state
from ..filters.reference import GridFilter, ParticleFilter
from ..filters.ukf import UKF
from ..models import DiscreteModel
from ..montecarlo import montecarlo
from ..results import Result
from ..simulate import simulate
from ..streams import FILTER, PathRNG
from . import get



def model(q1=0.1, q2=0.2, r=0.5):
    """The experiment's model: F = [[0.95, 0.1], [0, 0.9]], H = [1, 0], Q = diag(q1, q2), R = r."""
    F = np.array([[0.95, 0.1], [0.0, 0.9]])
    return DiscreteModel.linear(F, [[1.0, 0.0]], np.diag([q1, q2]), [[r]], name="linear-gaussian")


FILTERS = ("kf", "ekf", "ukf", "grid", "particle")


def _linear_block(rows, *, q1, q2, r, steps, grid, particles, seed):
    """One Monte Carlo block (:func:`nlfilter.montecarlo.montecarlo`): simulate the paths ``rows``
    from the stationary prior (per-path streams of case 0 of ``seed``), run the filters on them (the
    particle filter draws from the paths' streams of case 1) and reduce each path to its means over
    the second half of the run: ``mse_<f>`` (of (x1 − x̂1)²), ``nees_<f>``, ``gap_<f>`` (the paired
    difference to the Kalman filter's), with ``ok_<f>`` (not diverged) and ``e2_<f>`` (the squared
    error at every step, for the MSE per step)."""
    md = model(q1, q2, r)
    F = md.f_x(np.zeros(2), 0)
    P_stat = sla.solve_discrete_lyapunov(F, md.Q)  # stationary state covariance: the prior
    m0 = np.zeros(2)
    sim = simulate(md, steps, paths=rows, rng=stream(seed, 0), m0=m0, P0=P_stat)
    width = 6.0 * np.sqrt(np.diag(P_stat))
    filters = {
        "kf": lambda: KalmanFilter(md).run(sim.ys, m0, P_stat),
        "ekf": lambda: EKF(md).run(sim.ys, m0, P_stat),
        "ukf": lambda: UKF(md).run(sim.ys, m0, P_stat),
        "grid": lambda: GridFilter(md, list(zip(-width, width)), grid).run(sim.ys, m0, P_stat),
        "particle": lambda: ParticleFilter(md, particles).run(sim.ys, m0, P_stat,
                                                              rng=PathRNG(stream(seed, 1), rows, key=FILTER)),
    }
    half = slice(int(round(0.5 * steps)), None)  # the window 0.5 of nlfilter.evaluate.mse
    out, e2 = {}, {}
    for name, go in filters.items():
        est = go()
        e2[name] = (est.means[..., 0] - sim.xs[..., 0]) ** 2
        out[f"mse_{name}"] = np.mean(e2[name][:, half], axis=-1)
        out[f"nees_{name}"], out[f"ok_{name}"] = nees_per_path(est, sim.xs, window=half, label=name)
        if name != "kf":
            out[f"gap_{name}"] = np.mean((e2[name] - e2["kf"])[:, half], axis=-1)
        out[f"e2_{name}"] = e2[name]
    return out


def run(params, *, quick=False, runs=None, seed=0, progress=False):
    """The experiment ``linear-gaussian`` (its title, source and parameters: :data:`nlfilter.experiments.EXPERIMENTS`)."""
    p = dict(params)
    if quick:
        p["steps"], p["grid"], p["particles"] = min(p["steps"], 80), min(p["grid"], 41), min(p["particles"], 400)
    runs = runs or (100 if quick else 1000)
    md = model(p["q1"], p["q2"], p["r"])
    _, Pf = steady_state(md)
    exp = get("linear-gaussian")
    res = Result("linear-gaussian", exp.title, exp.source, p)
    res.used("paths", runs)
    block = res.used("block", int(p["block"]))
    res.add("riccati", "mse", Pf[0, 0])
    ident = {"q1": p["q1"], "q2": p["q2"], "r": p["r"], "steps": p["steps"], "grid": p["grid"],
             "particles": p["particles"], "seed": seed}
    pp = montecarlo("filters", partial(_linear_block, **ident), runs, block=block, ident=ident)
    curves, bands = {}, {}
    for name in FILTERS:
        ok = pp[f"ok_{name}"]
        s = _summary(pp[f"mse_{name}"], ok)
        res.add(name, "mse", s.value, s.stderr)
        n = _summary(pp[f"nees_{name}"], ok)
        res.add(name, "nees", n.value, n.stderr)
        if name != "kf":  # paired on the same paths (the Kalman filter is the optimal filter of this model)
            d = _summary(pp[f"gap_{name}"], ok & pp["ok_kf"])
            res.add(name, "gap_to_optimal", d.value, d.stderr)
        curves[name], se = _per_step(pp[f"e2_{name}"], ok)
        if name == "kf":  # all five are optimal here: one band shows the Monte Carlo noise
            bands[name] = (curves[name] - 2 * se, curves[name] + 2 * se)
    curves["riccati"] = np.full(p["steps"], Pf[0, 0])
    res.series[f"MSE of x1 per step ({runs} paths): all filters optimal, on the Riccati value"] = {
        "x": np.arange(p["steps"]), "lines": curves, "bands": bands, "xlabel": "step k",
        "ylabel": "E (x1 − x̂1)²", "styles": {"riccati": "k--", "particle": ":"}}
    res.notes.append(f"window: second half of {p['steps']} steps, {runs} paths; NEES ≈ 2 for a consistent filter")
    return res
