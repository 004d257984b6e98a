"""``smoothing``: every Gaussian smoother beside its own filter and the optimal smoother.

Two discrete models with a cubic sensor (issue 12's benchmark; no paper):

* ``cubic`` — the quickstart's ``x[k+1] = 0.99 x + w``, ``y = x³ + v``, ``Q = 0.01``, ``R = 0.1``,
  ``x0 ~ N(0.5, 0.1)``;
* ``rotating-cubic`` — 2-D, ``x[k+1] = [[0.8, 0.3], [−0.3, 0.8]] x + w``, ``Q = 0.2 I``, measured
  by ``y = x1³/3 + v``, ``R = 0.1``, ``x0 ~ N((0.5, 0), 0.5 I)``: the second component is seen only
  through the dynamics, so smoothing matters most there.

For each, :func:`~nlfilter.compare` with ``smooth=True`` runs the EKF, iterated EKF, UKF, CKF, SLF,
GHKF and the Gaussian second-order filter and their RTS smoothers
(:mod:`nlfilter.filters.smoothing`: one backward pass through each filter's moment rule) on one
simulation, beside the certified reference and its smoother (the forward–backward grid smoother
in 1-D, the FFBSm particle smoother in 2-D: :mod:`nlfilter.filters.reference.forward_backward`). Rows
per filter and component, the MSE over the whole record: ``mse`` (filter), ``smoothed_mse``,
``smoothing_gain`` (filter MSE − smoothed MSE on the same paths, paired s.e.) and
``smoothed_gap_to_optimal`` (smoothed MSE − the optimal smoother's, paired s.e. and the
reference's error). A smoother whose gain is negative is worse than its own filter: the RTS
pass trusts the filter's covariances, and an inconsistent filter (NEES far above n) misleads it.

The Monte Carlo runs in blocks of ``block`` paths (0: one block of all the run's paths, the
default): ``compare(block=...)`` runs every filter, smoother and reference rung on each block as
its own batch with single-threaded BLAS (:func:`nlfilter.comparison.compare`), so the rows are
bitwise the same for any executor, worker count and chunk (the chunk does not split a block).
The simulation, the reference's resolution and the statistics use every path, as before.
"""

from __future__ import annotations

import numpy as np
import sympy as sp
from tqdm.auto import tqdm

from ..comparison import compare
from ..evaluate import paired_difference, stream
from ..filters.reference import ParticleFilter
from ..models import DiscreteModel
from ..results import Result
from . import get
from ._blocks import block_size

FILTERS = ("ekf", "iekf", "ukf", "ckf", "ghkf", "slf", "second-order")


def cases():
    """``{name: (model, m0, P0)}`` of the experiment (see the module docstring)."""
    x, x1, x2 = sp.symbols("x x1 x2")
    cubic = DiscreteModel([x], [0.99 * x], [x**3], Q=0.01, R=0.1, name="cubic")
    rot = DiscreteModel([x1, x2], [0.8 * x1 + 0.3 * x2, -0.3 * x1 + 0.8 * x2], [x1**3 / 3], Q=0.2 * np.eye(2),
                        R=0.1, name="rotating-cubic")
    return {"cubic": (cubic, np.array([0.5]), np.array([[0.1]])),
            "rotating-cubic": (rot, np.array([0.5, 0.0]), 0.5 * np.eye(2))}




def run(params, *, quick=False, runs=None, seed=0, progress=False):
    """The experiment ``smoothing`` (its title, source and parameters: :data:`nlfilter.experiments.EXPERIMENTS`)."""
    p = dict(params)
    if quick:
        p["steps"], p["particles"] = min(p["steps"], 20), min(p["particles"], 300)
    runs = runs or (16 if quick else 200)
    exp = get("smoothing")
    res = Result("smoothing", exp.title, exp.source, p)
    res.used("paths", runs)
    block = block_size(res, p, runs)
    refs = {}
    for k, (name, (md, m0, P0)) in enumerate(tqdm(cases().items(), disable=not progress, desc="models")):
        # 1-D: the automatic (certified grid) reference; 2-D: a particle filter, refined once to
        # 4x its particles by the certificate (the FFBSm smoother costs particles² per step and path)
        ref = "auto" if md.n == 1 else ParticleFilter(md, p["particles"])
        out, sim, est = compare(md, list(FILTERS), p["steps"], paths=runs, m0=m0, P0=P0, rng=stream(seed, k),
                                reference=ref, window=None, smooth=True, block=block, full_output=True)
        refs[name] = out.params["reference"]
        for row in out.rows:
            if row.quantity in ("mse", "smoothed_mse", "gap_to_optimal", "smoothed_gap_to_optimal",
                                "gap_to_reference", "smoothed_gap_to_reference", "nees"):
                res.add(row.filter, row.quantity, row.value, row.stderr, model=name, **row.params)
        for flt in [*FILTERS, next(iter(r.filter for r in out.rows if r.quantity == "smoothed_mse"
                                        and r.filter not in FILTERS), None)]:
            if flt is None or f"{flt} (smoothed)" not in est:
                continue
            for i in range(md.n):  # filter − its smoother, paired on the same paths
                d = paired_difference(est[flt], est[f"{flt} (smoothed)"], sim.xs, component=i)
                res.add(flt, "smoothing_gain", d.value, d.stderr, model=name, component=i)
        res.notes.extend(f"{name}: {n}" for n in out.notes[:-1])
        ref_label = next(r.filter for r in out.rows if r.quantity == "smoothed_mse" and r.filter not in FILTERS)
        names = [*FILTERS, ref_label]
        for i in range(md.n):
            rows = {"filter": [res.get(f, "mse", model=name, component=i) for f in names],
                    "RTS smoother": [res.get(f, "smoothed_mse", model=name, component=i) for f in names]}
            res.series[f"{name}, x{i + 1}: MSE of each filter and its smoother ({runs} paths)"] = {
                "kind": "bar", "categories": names, "bars": {k: [r.value for r in v] for k, v in rows.items()},
                "errors": {k: [2 * r.stderr for r in v] for k, v in rows.items()}, "ylabel": "mean square error"}
    res.params["references"] = refs
    res.notes.append("MSE over the whole record; smoothing_gain = MSE(filter) − MSE(its smoother) on the same "
                     "paths; smoothed_gap_to_optimal = MSE(smoother) − MSE(optimal smoother), paired")
    return res
