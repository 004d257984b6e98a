"""``linear-gaussian``: the evaluation machinery on a model whose answer is known.

A stable 2-state linear Gaussian model, ``x[k+1] = F x[k] + w``, ``y = H x + v``; KF, EKF, UKF,
the grid filter and the particle filter run on the same paths (common random numbers). Each
row is the error variance of the first state component averaged over the second half of the
run, beside the Riccati prediction (steady-state filtered covariance from
``scipy.linalg.solve_discrete_are``). All five filters are optimal here, so every MSE should
agree with the Riccati value within its Monte Carlo standard error (the grid and particle
filters up to their discretization error). ``gap_to_optimal`` rows: each filter's MSE minus the
Kalman filter's (the optimum here) on the same paths, with its paired standard error.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from tqdm.auto import tqdm

from ..evaluate import chunk, in_chunks, mse, mse_per_step, nees, paired_difference, stream
from ..filters.ekf import EKF
from ..filters.kalman import KalmanFilter, steady_state
from ..filters.reference import GridFilter, ParticleFilter
from ..filters.ukf import UKF
from ..models import DiscreteModel
from ..results import Result
from ..simulate import simulate
from . import experiment

TITLE = "Linear Gaussian 2-state model: every filter against the Riccati steady state"


def model(q1=0.1, q2=0.2, r=0.5):
    """The experiment's model: F = [[0.95, 0.1], [0, 0.9]], H = [1, 0], Q = diag(q1, q2), R = r."""
    F = np.array([[0.95, 0.1], [0.0, 0.9]])
    return DiscreteModel.linear(F, [[1.0, 0.0]], np.diag([q1, q2]), [[r]], name="linear-gaussian")


@experiment("linear-gaussian", title=TITLE, source="nlfilter check (no paper): Riccati equation",
            params={"q1": 0.1, "q2": 0.2, "r": 0.5, "steps": 200, "grid": 61, "particles": 1000})
def run(params, *, quick=False, runs=None, seed=0, progress=False):
    p = dict(params)
    if quick:
        p["steps"], p["grid"], p["particles"] = min(p["steps"], 80), min(p["grid"], 41), min(p["particles"], 400)
    runs = runs or (100 if quick else 1000)
    md = model(p["q1"], p["q2"], p["r"])
    F = md.f_x(np.zeros(2), 0)
    P_stat = sla.solve_discrete_lyapunov(F, md.Q)  # stationary state covariance: the prior
    m0 = np.zeros(2)
    sim = in_chunks(lambda rows: simulate(md, p["steps"], paths=rows, rng=stream(seed, 0), m0=m0, P0=P_stat), runs)
    c = chunk()
    half = 0.5
    _, Pf = steady_state(md)
    res = Result("linear-gaussian", TITLE, "nlfilter check (no paper): Riccati equation", p)
    res.used("paths", runs)
    res.add("riccati", "mse", Pf[0, 0])
    width = 6.0 * np.sqrt(np.diag(P_stat))
    filters = {
        "kf": lambda: KalmanFilter(md).run(sim.ys, m0, P_stat, chunk=c),
        "ekf": lambda: EKF(md).run(sim.ys, m0, P_stat, chunk=c),
        "ukf": lambda: UKF(md).run(sim.ys, m0, P_stat, chunk=c),
        "grid": lambda: GridFilter(md, list(zip(-width, width)), p["grid"]).run(sim.ys, m0, P_stat, chunk=c),
        "particle": lambda: ParticleFilter(md, p["particles"]).run(sim.ys, m0, P_stat, rng=stream(seed, 1), chunk=c),
    }
    curves, bands = {}, {}
    for name, go in tqdm(filters.items(), disable=not progress, desc="filters"):
        est = go()
        s = mse(est, sim.xs, window=half)
        res.add(name, "mse", s.value, s.stderr)
        res.add(name, "nees", nees(est, sim.xs, window=half).value, nees(est, sim.xs, window=half).stderr)
        if name == "kf":
            optimal = est  # the Kalman filter is the optimal filter of this model
        else:  # paired on the same paths: its standard error is far below the MSE's
            d = paired_difference(est, optimal, sim.xs, window=half)
            res.add(name, "gap_to_optimal", d.value, d.stderr)
        curves[name], se = mse_per_step(est, sim.xs)
        if name == "kf":  # all five are optimal here: one band shows the Monte Carlo noise
            bands[name] = (curves[name] - 2 * se, curves[name] + 2 * se)
    curves["riccati"] = np.full(p["steps"], Pf[0, 0])
    res.series[f"MSE of x1 per step ({runs} paths): all filters optimal, on the Riccati value"] = {
        "x": np.arange(p["steps"]), "lines": curves, "bands": bands, "xlabel": "step k",
        "ylabel": "E (x1 − x̂1)²", "styles": {"riccati": "k--", "particle": ":"}}
    res.notes.append(f"window: second half of {p['steps']} steps, {runs} paths; NEES ≈ 2 for a consistent filter")
    return res
