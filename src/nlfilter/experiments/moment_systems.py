"""Seed 000, Chapters IV-V (outlined in its abstract): the moment Bayesian filter on first- and
second-order systems with bounded, non-Gaussian inputs, against the Kalman filter (which knows the
input's true mean and variance) and the grid optimum.

The paper's claim checked here (000 abstract): the moment filter "yields a much lower mean-square
estimation error than the Kalman filter" when the input is far from Gaussian, and compares
favourably (about equal) when it is near.  Input laws (all on ``[-w_b, w_b]``, Beta laws rescaled):

* ``uniform``        U(-w_b, w_b)
* ``bimodal``        Beta(0.3, 0.3): U-shaped, mass near both bounds
* ``skewed``         Beta(0.5, 5): most mass near -w_b, long right tail
* ``near-gaussian``  Beta(4, 4): bell-shaped, close to a Gaussian

Filters: ``kalman`` (000 eqs. 1.33-1.36), ``moment{N}`` (input moments known), ``adaptive{N}``
(input moments learned from the data, initial guess uniform, weight n0, refresh every ``window``
samples), ``optimal`` (grid on the reachable set, exact for the bounded laws up to the cell width).
MSE is averaged over the Monte Carlo paths and the steps ``skip <= k < T`` (steady state, 000
assumption 6), with the standard error over paths; the gap to the optimum is a paired difference.

Each input law's Monte Carlo is computed in blocks of ``block`` paths (0: one block of all the
run's paths, the default; :func:`nlfilter.montecarlo.montecarlo`): a block simulates its paths
(per-path streams of the law's case) and runs every filter on them (``_first_order_block``,
``_second_order_block``; the particle optimum draws from each path's ``streams.FILTER``
sub-stream, the same in any block).
"""

from __future__ import annotations

from functools import partial

import numpy as np
import scipy.stats as st

from .. import evaluate as ev
from .. import streams
from ..filters.kalman import KalmanFilter
from ..bounded import BoundedNoiseModel
from ..filters.moment_bayes import FirstOrderMomentFilter
from ._blocks import block_arrays, block_estimates, block_size
from .zero_order_problem import failure_rate_row
from ..filters.reference.bounded import BoundedGridFilter1D
from ..models import DiscreteModel
from ..montecarlo import montecarlo
from ..results import Result

LAWS = {"uniform": (1.0, 1.0), "bimodal": (0.3, 0.3), "skewed": (0.5, 5.0), "near-gaussian": (4.0, 4.0)}


def input_law(name: str, w_bound: float):
    """The frozen ``scipy.stats`` law of the input on ``[-w_bound, w_bound]``."""
    if name not in LAWS:
        raise ValueError(f"law: expected one of {sorted(LAWS)}, got {name!r}")
    a, b = LAWS[name]
    return st.beta(a, b, loc=-w_bound, scale=2.0 * w_bound)


def raw_moments(law, N: int) -> np.ndarray:
    return np.array([law.moment(i) for i in range(1, N + 1)])


BURN = 300  # burn-in of the simulations (BoundedNoiseModel.simulate): steps from 0 to stationarity


def kalman_first_order(zs, h, law, noise_halfwidth=1.0):
    """Kalman filter knowing the input's true mean and variance (on centred variables)."""
    mu, var = float(law.mean()), float(law.var())
    mux = mu / (1.0 - h)
    model = DiscreteModel.linear([[h]], [[1.0]], [[var]], [[noise_halfwidth ** 2 / 3.0]])
    est = KalmanFilter(model).run((zs - mux)[..., None], np.zeros(1), np.array([[var / (1.0 - h * h)]]))
    return est.means[..., 0] + mux


def _mse_rows(res, errs, skip, law_name, extra=None):
    """Add rows ``mse`` (mean over paths and steps >= skip, se over paths) and paired gaps."""
    per_path = {k: np.mean(e[:, skip:] ** 2, axis=1) for k, e in errs.items()}
    R = next(iter(per_path.values())).shape[0]
    for k, v in per_path.items():
        res.add(k, "mse", v.mean(), stderr=v.std(ddof=1) / np.sqrt(R), law=law_name, **(extra or {}))
    if "optimal" in per_path:
        for k, v in per_path.items():
            if k != "optimal":
                d = v - per_path["optimal"]
                res.add(k, "gap_to_optimal", d.mean(), stderr=d.std(ddof=1) / np.sqrt(R), law=law_name,
                        **(extra or {}))
    return per_path


def _claims(res, per_path, law_name, Ns, prefix):
    """The abstract's claim: moment filter vs Kalman, paired difference (kalman - moment)."""
    R = per_path["kalman"].shape[0]
    for N in Ns:
        for kind in ("moment", "adaptive"):
            key = f"{kind}{N}"
            if key not in per_path:
                continue
            d = per_path["kalman"] - per_path[key]
            m, s = d.mean(), d.std(ddof=1) / np.sqrt(R)
            rel = per_path[key].mean() / per_path["kalman"].mean() - 1.0
            res.add(f"kalman-{key}", "paired_diff", m, stderr=s, law=law_name)
            verdict = "lower than Kalman" if m > 2 * s else ("higher than Kalman" if m < -2 * s else "equal within 2 se")
            res.notes.append(f"{prefix} law={law_name}: {key} MSE {100 * rel:+.1f}% vs Kalman "
                             f"(kalman - {key} = {m:.4f} +- {s:.4f}) -> {verdict}")


def _horizon(params, quick, T_quick, skip_quick):
    """Steps ``T`` and the burn-in ``skip`` left out of the MSE (capped in quick runs)."""
    T = int(params["T"]) if not quick else min(int(params["T"]), T_quick)
    skip = int(params["skip"]) if not quick else min(int(params["skip"]), skip_quick)
    if not 0 <= skip < T:
        raise ValueError(f"skip: expected 0 <= skip < T = {T}, got {skip}")
    return T, skip


def _per_law(res, params, R, skip, Ns, kind, block_fn, ident, errors):
    """The Monte Carlo of every input law of ``params["laws"]`` (``R`` paths of ``block_fn`` with
    ``ident(law, i)``) and its rows in ``res``: the adaptive filters' refresh failures, the MSE
    after ``skip`` of the errors ``errors(estimates, xs)``, the claims, the fallback note. Returns
    the laws."""
    laws = list(params["laws"])
    block = block_size(res, params, R)
    for i, law_name in enumerate(laws):
        idt = ident(law_name, i)
        mc = montecarlo(law_name, partial(block_fn, **idt), R, block=block, ident=idt)
        for N in Ns:
            failure_rate_row(res, f"adaptive{N}", mc[f"refresh:adaptive{N}"], law=law_name)
        per_path = _mse_rows(res, errors(block_estimates(mc), mc["xs"]), skip, law_name)
        _claims(res, per_path, law_name, Ns, kind)
        res.notes.append(f"{kind} law={law_name}: uniform fallback used in " + _fallbacks(mc) + " of steps")
    return laws


def run_first_order(params, *, quick, runs, seed, progress):
    """The experiment ``moment-first-order`` (its title, source and parameters: :data:`nlfilter.experiments.EXPERIMENTS`)."""
    h, wb = float(params["h"]), float(params["w_bound"])
    Ns = [int(N) for N in params["N"]]
    T, skip = _horizon(params, quick, 120, 30)
    G = int(params["grid"]) if not quick else min(int(params["grid"]), 200)
    R = runs or (20 if quick else 200)
    res = Result("moment-first-order", "First-order system x+ = h x + w, z = x + v",
                 "seed 000, eqs. 2.4-2.5", params)
    res.params.update(T=T, skip=skip, grid=G, paths=R)  # the values that ran (quick caps included)
    laws = _per_law(res, params, R, skip, Ns, "first-order", _first_order_block,
                    lambda law, i: {"h": h, "wb": wb, "law": law, "Ns": Ns, "T": T, "G": G, "n0": params["n0"],
                                    "window": params["window"], "seed": seed, "case": i},
                    lambda est, xs: {k: v[..., 0] - xs for k, v in est.items()})
    _figure(res, laws, Ns, f"{R} paths × steps {skip}..{T - 1}", "grid filter")
    return res


def _first_order_block(rows, *, h, wb, law, Ns, T, G, n0, window, seed, case):
    """One Monte Carlo block of the first-order system with input law ``law``: the paths ``rows``
    (per-path streams of case ``case`` of ``seed``; stationary: :data:`BURN` steps of burn-in from
    0), the grid optimum, the Kalman filter knowing the input's mean and variance, the moment
    filter with the input's moments ``moment{N}`` and 000's adaptive algorithm as is
    ``adaptive{N}``; per path ``xs`` and every filter's :func:`~nlfilter.experiments._blocks.block_arrays`
    (the moment filters' fallback flags per step)."""
    w_law = input_law(law, wb)
    truth = BoundedNoiseModel.first_order(h, wb, w_law=w_law)
    xs, zs = truth.simulate(T, rows, ev.stream(seed, case), burn=BURN)
    xs, zs = xs[..., 0], zs[..., 0]
    out = {"xs": xs, "est:optimal": BoundedGridFilter1D(truth, G=G).run(zs[..., None]).means,
           "est:kalman": kalman_first_order(zs, h, w_law)[..., None]}
    model = BoundedNoiseModel.first_order(h, wb)
    for N in Ns:
        out.update(block_arrays(f"moment{N}", FirstOrderMomentFilter(model, N, w_moments=raw_moments(w_law, N)).run(
            zs[..., None]), "fallback"))
        out.update(block_arrays(f"adaptive{N}", FirstOrderMomentFilter(
            model, N, adaptive=True, n0=n0, window=window, invalid_moments="ignore").run(zs[..., None]), "fallback"))
    return out


def _fallbacks(mc) -> str:
    """``"moment2 1.23%, adaptive2 4.56%, ..."``: the share of steps in which each moment filter
    fell back to the uniform law, over every path of the Monte Carlo ``mc``."""
    return ", ".join(f"{k.partition(':')[2]} {100 * v.mean():.2f}%" for k, v in mc.items() if k.startswith("fallback:"))


def _figure(res, laws, Ns, what, optimal):
    """Two bar panels from the rows: MSE per input law (known input moments) and the paired excess
    over the optimum of every filter (adaptive ones included), ± 2 s.e."""
    def bars(names, qty):
        rows = {nm: [res.get(nm, qty, law=law) for law in laws] for nm in names}
        return {"bars": {nm: [r.value for r in v] for nm, v in rows.items()},
                "errors": {nm: [2 * r.stderr for r in v] for nm, v in rows.items()}}
    known = ["optimal", "kalman"] + [f"moment{N}" for N in Ns]
    res.series[f"MSE by input law ({what}; optimal: {optimal})"] = {
        "kind": "bar", "categories": laws, **bars(known, "mse"), "ylabel": "mean square error"}
    gaps = ["kalman"] + [f"moment{N}" for N in Ns] + [f"adaptive{N}" for N in Ns]
    res.series["Excess MSE over the optimum (paired on the same paths)"] = {
        "kind": "bar", "categories": laws, **bars(gaps, "gap_to_optimal"), "ylabel": "MSE − MSE of optimal"}


# ------------------------------------------------------------------ second-order system

def kalman_second_order(zs, A, b, c, law, noise_halfwidth=1.0):
    """Kalman filter knowing the input's true mean and variance (centred variables)."""
    import scipy.linalg as sla
    mu, var = float(law.mean()), float(law.var())
    mux = np.linalg.solve(np.eye(2) - A, b * mu)
    model = DiscreteModel.linear(A, c[None, :], [[var]], [[noise_halfwidth ** 2 / 3.0]], G=b[:, None])
    P0 = sla.solve_discrete_lyapunov(A, var * np.outer(b, b))
    est = KalmanFilter(model).run((zs - c @ mux)[..., None], np.zeros(2), P0)
    return est.means + mux


def run_second_order(params, *, quick, runs, seed, progress):
    """The experiment ``moment-second-order`` (its title, source and parameters: :data:`nlfilter.experiments.EXPERIMENTS`)."""
    A = np.diag([float(params["h1"]), float(params["h2"])])
    b = np.array([float(params["d1"]), float(params["d2"])])
    c = b.copy()  # 000 eqs. 2.6-2.7 as the OCR reads them: the same d1, d2 in the input and the output
    wb = float(params["w_bound"])
    Ns = [int(N) for N in params["N"]]
    T, skip = _horizon(params, quick, 50, 10)  # quick: 50 steps (the MSE over 40), ~12 s of CPU
    P = int(params["particles"]) if not quick else min(int(params["particles"]), 1000)
    R = runs or (8 if quick else 80)
    bkw = dict(bounding=params["bounding"], directions=int(params["directions"]))
    res = Result("moment-second-order", "Second-order system x+ = A x + b w, z = c.x + v",
                 "seed 000, eqs. 2.6-2.8", params)
    res.params.update(T=T, skip=skip, particles=P, paths=R)  # the values that ran (quick caps included)
    laws = _per_law(res, params, R, skip, Ns, "second-order", _second_order_block,
                    lambda law, i: {"A": A.tolist(), "b": b.tolist(), "c": c.tolist(), "wb": wb, "law": law, "Ns": Ns,
                                    "T": T, "P": P, "n0": params["n0"], "window": params["window"], **bkw,
                                    "seed": seed, "case": i},
                    lambda est, xs: {k: np.sqrt(np.sum((v - xs) ** 2, axis=-1)) for k, v in est.items()})  # |x - x_hat|
    _figure(res, laws, Ns, f"{R} paths × steps {skip}..{T - 1}; E|x − x̂|² over both states",
            f"particle filter, {P} particles")
    res.notes.append(f"reachable-set bound: {params['bounding']} ({params['directions']} template directions + "
                     "the measurement's) ; mse = E|x - x_hat|^2 summed over both states; 'optimal' = bootstrap particle filter "
                     f"({P} particles): near-optimal, its own Monte Carlo error is part of its row's noise.")
    return res


def _second_order_block(rows, *, A, b, c, wb, law, Ns, T, P, n0, window, bounding, directions, seed, case):
    """One Monte Carlo block of the second-order system with input law ``law``: the paths ``rows``
    (per-path streams of case ``case`` of ``seed``; stationary: :data:`BURN` steps of burn-in from
    0), the bootstrap particle optimum (``P`` particles, x0 from 200 steps of the input from 0;
    each path's ``streams.FILTER`` sub-stream), the Kalman filter knowing the input's mean and
    variance, and the moment filters ``moment{N}`` (input moments known) and ``adaptive{N}``
    (000's algorithm) on the ``bounding`` reachable set; per path ``xs`` and every filter's
    :func:`~nlfilter.experiments._blocks.block_arrays` (the moment filters' fallback flags)."""
    from ..filters.moment_bayes import SecondOrderMomentFilter
    from ..filters.reference.bounded import BoundedParticleFilter
    A, b, c = np.asarray(A), np.asarray(b), np.asarray(c)
    w_law = input_law(law, wb)
    rng = ev.stream(seed, case)  # simulation: the paths' streams; the particle filter: their FILTER sub-streams
    truth = BoundedNoiseModel(A, b, c, wb, w_law=w_law)
    xs, zs = truth.simulate(T, rows, rng, burn=BURN)
    zs = zs[..., 0]
    bkw = dict(bounding=bounding, directions=directions)
    out = {"xs": xs,
           "est:optimal": BoundedParticleFilter(truth, particles=P).run(
               zs[..., None], initial=partial(_stationary_x0, A=A, b=b, law=w_law),
               rng=streams.PathRNG(rng, rows, key=streams.FILTER)).means,
           "est:kalman": kalman_second_order(zs, A, b, c, w_law)}
    model = BoundedNoiseModel(A, b, c, wb)
    for N in Ns:
        out.update(block_arrays(f"moment{N}", SecondOrderMomentFilter(
            model, N, w_moments=raw_moments(w_law, N), **bkw).run(zs[..., None]), "fallback"))
        out.update(block_arrays(f"adaptive{N}", SecondOrderMomentFilter(
            model, N, adaptive=True, n0=n0, window=window, invalid_moments="ignore", **bkw).run(zs[..., None]),
            "fallback"))
    return out


def _stationary_x0(r, shape, *, A, b, law):
    """The particle optimum's initial sampler: x0 after 200 steps of ``x+ = A x + b w`` from 0."""
    x = np.zeros((*shape, 2))
    for _ in range(200):
        x = x @ A.T + law.rvs(size=shape, random_state=r)[..., None] * b
    return x
