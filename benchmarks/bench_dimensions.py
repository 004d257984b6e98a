"""The Gaussian filters' cost per path-step at every state dimension, side by side with peers
(issue 13, goals 1 and 6: the dimension sweep; issue 28, item 7: every side pinned alike).

Model (n states, m = ⌈n/2⌉ measurements; a nonlinear coupled chain, :func:`_models.chain`)::

    x_i[k+1] = 0.9 x_i[k] + 0.1 sin(x_{i+1}[k]) + w_i      (x_{n+1} := x_1; n = 1: 0.9 x + 0.1 sin x)
    y_j[k]   = x_j[k] + 0.1 x_{j+m}[k]² + v_j             (x_{j+m} := x_j past n)

with Q = 0.01 I, R = 0.1 I, m0 = 0, P0 = I, 1000 paths × 200 steps (``--paths``, ``--steps``).
Sides, in one run, one core and one thread each (:mod:`_pin`, imported first):

* nlfilter EKF, UKF, CKF, SecondOrderFilter (default form) and, with ``--filters``, GHKF-2,
  batched over paths, in the columns of ``--columns``: ``default`` (``run`` with no ``backend=``:
  what it resolves to is recorded), ``numpy``, ``numba`` (:func:`_peers.nlfilter_sides`: the first
  call on the whole job apart, i.e. the compile, and included);
* dynamax ``extended_kalman_filter`` / ``unscented_kalman_filter`` (and the CKF as its unscented
  filter with alpha = 1, beta = 0, kappa = 0) in float64 under ``jit`` + ``vmap``: compile apart
  and included;
* the second-order filter's peer (dynamax has none): a second-order EKF in dynamax's style
  (float64, ``jit`` + ``vmap``, ``lax.scan``, ``jax.jacfwd`` / ``jax.hessian`` of f and h;
  :func:`_peers.second_order_filter`), the equations of nlfilter's ``SecondOrderFilter`` in its
  default form: compile apart and included;
* filterpy ``ExtendedKalmanFilter`` and ``UnscentedKalmanFilter`` (a Python loop per path and
  step) on ``--filterpy-paths`` paths, per path-step.

``--cache warm`` (default ``cold``): the default column as a rerun meets it, the job's compiled
loop already on disk — for each filter and n another process runs the job once with
``backend="numba"`` into the run's ``NLFILTER_CACHE`` folder, then a fresh process (nothing compiled
in it) times the default call, its load counted as its compile (:mod:`_warm`); the other nlfilter
columns then find the cache warm too. ``--cache shape``: the same, but the filling process runs
*another* model of the job's shape (the chain with decay 0.85) with ``backend="numba-shared"``: the
model-free loop of the shape is on disk, not the job's model (a new model in an installation that
has run its shape before). Rows name the cache state (``cache``).

Every best is of ``--repeat`` (3) calls, the first apart. With ``--default-repeat N`` the default
column is the call repeated as a process repeating the job makes it, up to N times
(:func:`_pin.default_calls`): the NumPy loop until the time spent repays the cached loop's load or
the compile, then the compiled loop; it stops two calls into that steady state. Its best is the
steady state's (the backend of its best call: ``best_call_backend``), its ``to_steady`` the wall
and CPU seconds of the calls before it (the NumPy calls and the compile or load: what the process
paid to get there), each call's backend in ``calls``. Each row of the JSON names both sides
(``ours``, ``peer``) and gives ``peer_over_ours`` (> 1: nlfilter faster), with the compile apart
(µs per path-step) and included (seconds to the first result). The largest relative difference of
filtered means is reported between the columns and against each peer (same start: filterpy
predicts first, so nlfilter runs with ``start="predict"`` against it; dynamax updates first, as
nlfilter's default). ``--label`` names the run in the JSON (other runs kept). No timing is asserted
anywhere.

Run: ``taskset -c 1 python benchmarks/bench_dimensions.py [--label pinned] [--dims 1 2 4 8 16]
[--columns default numpy numba] [--cache cold|warm] [--quick]``
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread for every side)

import argparse  # noqa: E402
import pathlib  # noqa: E402

import numpy as np  # noqa: E402
from _models import Q, R, chain, chain_jax, chain_np  # noqa: E402
from _peers import (dynamax_filters, filterpy_pair, jax_second_order, nlfilter_sides, per_step,  # noqa: E402
                    relmaxdiff, rows_against)

from nlfilter.filters import CKF, EKF, GHKF, UKF, SecondOrderFilter  # noqa: E402
from nlfilter.simulate import simulate  # noqa: E402

SO_PEER = "jax jit+vmap float64, dynamax's form (benchmarks/_peers.py)"  # rows add the kind: second-order
OUT = pathlib.Path(__file__).parent / "results" / "bench_dimensions.json"
FILTERS = {"ekf": EKF, "ukf": UKF, "ckf": CKF, "second-order": SecondOrderFilter,
           "ghkf-2": lambda md: GHKF(md, order=2)}


def make_filter(kind, n, a=0.9):
    """The filter ``kind`` on :func:`_models.chain` ``(n, a)`` (the warm cache's processes make it so;
    ``--cache shape`` fills the cache with another ``a``: another model of the same shape)."""
    return FILTERS[kind](chain(n, a))


def measure(n, a):
    """One dimension's row: nlfilter's columns, dynamax, filterpy, the rows side by side."""
    md = chain(n)
    m0, P0 = np.zeros(n), np.eye(n)
    ys = np.ascontiguousarray(simulate(md, a.steps, paths=a.paths, rng=n, m0=m0, P0=P0).ys)
    ps = a.paths * a.steps
    row = {"n": n, "m": ys.shape[-1], "paths": a.paths, "steps": a.steps, "nlfilter": {}, "notes": [],
           "max_rel_difference_of_means": {}}
    ours, est = {}, {}
    for kind in a.filters:
        if kind == "ghkf-2" and n > 8:
            continue  # 2^n nodes
        warm = None if a.cache == "cold" else ("bench_dimensions:make_filter", [kind, n],
                                                ("numba", [kind, n]) if a.cache == "warm" else ("numba-shared", [kind, n, 0.85]))
        t, e, notes = nlfilter_sides(lambda: FILTERS[kind](md), ys, m0, P0, a.repeat, a.columns, warm=warm,
                                     default_repeat=a.default_repeat)
        ours[kind], est[kind] = t, e
        row["nlfilter"][kind] = {col: per_step(v, ps) for col, v in t.items()}
        row["notes"] += [f"{kind}: {x}" for x in notes if x not in row["notes"]]
        base = e.get("numpy", e.get("default"))
        for col in e:
            if base is not None and col != "numpy" and e[col] is not base:
                row["max_rel_difference_of_means"][f"{kind}: {col} vs numpy"] = relmaxdiff(e[col].means, base.means)
    row["rows"] = []
    cache = None if a.cache == "cold" else a.cache
    if a.no_peers:
        return row
    try:
        dm, dm_means = dynamax_filters(lambda jnp: chain_jax(n, jnp), ys, a.repeat,
                                       kinds=[k for k in ("ekf", "ukf", "ckf") if k in ours])
        row["dynamax"] = {k: per_step(v, ps) for k, v in dm.items()}
        row["rows"] += rows_against(ours, "dynamax jit+vmap float64", dm, ps, cache)
        for k in dm:
            col = next(iter(est[k]))
            row["max_rel_difference_of_means"][f"{k}: nlfilter {col} vs dynamax"] = relmaxdiff(
                est[k][col].means, dm_means[k])
    except ImportError as exc:
        row["notes"].append(f"dynamax/jax not installed: {exc}")
    if "second-order" in ours:
        try:
            so, so_means = jax_second_order(lambda jnp: chain_jax(n, jnp), ys, a.repeat)
            row["jax_second_order"] = {k: per_step(v, ps) for k, v in so.items()}
            row["rows"] += rows_against(ours, SO_PEER, so, ps, cache)
            col = next(iter(est["second-order"]))
            row["max_rel_difference_of_means"][f"second-order: nlfilter {col} vs jax second-order"] = relmaxdiff(
                est["second-order"][col].means, so_means["second-order"])
        except ImportError as exc:
            row["notes"].append(f"jax not installed: {exc}")
    try:
        npth = min(a.filterpy_paths, a.paths)
        per, means = filterpy_pair(chain_np(n), ys[:npth], m0, P0, Q * np.eye(n), R * np.eye(ys.shape[-1]),
                                   a.repeat)
        row["filterpy"] = {k: {"us_per_step": v * 1e6, "paths_timed": npth} for k, v in per.items()}
        row["rows"] += rows_against(ours, f"filterpy (a Python loop, {npth} paths timed)",
                                    {k: {"best": v * ps} for k, v in per.items() if k in ours}, ps, cache)
        for k in per:  # filterpy predicts first
            pred = (EKF if k == "ekf" else UKF)(md, start="predict")
            row["max_rel_difference_of_means"][f"{k}: nlfilter vs filterpy"] = relmaxdiff(
                pred.run(ys[:npth], m0, P0).means, means[k])
    except ImportError as exc:
        row["notes"].append(f"filterpy not installed: {exc}")
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dims", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    ap.add_argument("--paths", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3, help="calls per column, the first (compile) apart")
    ap.add_argument("--default-repeat", type=int, default=None,
                    help="calls of the default column (default --repeat): the automatic rule's steady state")
    ap.add_argument("--filterpy-paths", type=int, default=5)
    ap.add_argument("--filters", nargs="+", choices=list(FILTERS), default=["ekf", "ukf", "ckf", "second-order"])
    ap.add_argument("--columns", nargs="+",
                    choices=["default", "numpy", "numba", "numba-shared", "numba-fresh", "numba-shared-fresh"],
                    default=["default", "numpy", "numba"],
                    help="nlfilter's calls: default (no backend=), numpy, numba, numba-shared; with --cache warm "
                         "or shape also numba-fresh, numba-shared-fresh (that backend in a fresh process)")
    ap.add_argument("--cache", choices=["cold", "warm", "shape"], default="cold",
                    help="the disk cache at the default call: cold (empty), warm (the job's loop written by "
                         "another process; the default call timed in a fresh one) or shape (the model-free loop "
                         "of the job's shape written by another process running another model of that shape)")
    ap.add_argument("--no-peers", action="store_true", help="nlfilter only")
    ap.add_argument("--quick", action="store_true", help="smoke size: n = 1, 2; 20 paths x 10 steps; 2 calls")
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    if a.quick:
        a.dims, a.paths, a.steps, a.repeat, a.filterpy_paths = [1, 2], 20, 10, 2, 2
    rows = []
    for n in a.dims:
        rows.append(measure(n, a))
        print(_summary(rows[-1]), flush=True)
    _pin.write(a.out, a.label, {
        "problem": "x_i' = 0.9 x_i + 0.1 sin(x_{i+1}) + w, y_j = x_j + 0.1 x_{j+m}^2 + v, Q = 0.01 I, "
                   "R = 0.1 I, m0 = 0, P0 = I, m = ceil(n/2)",
        "repeat": a.repeat, "default_repeat": a.default_repeat or a.repeat, "quick": a.quick, "columns": a.columns, "cache": a.cache, "rows": rows}, benchmark="dimensions")


def _summary(row):
    out = [f"n = {row['n']}:"]
    for r in row["rows"]:
        cpu = r.get("cpu_peer_over_ours", {}).get(r["compile"])
        cpu = f" (CPU {cpu:.2f}x)" if cpu is not None else ""
        out.append(f"  {r['ours']} vs {r['peer']} ({r['compile']}): {r['peer_over_ours']:.2f}x{cpu}")
    for kind, cols in row["nlfilter"].items():
        if "backend" in cols.get("default", {}):
            calls = "/".join(c["backend"] for c in cols["default"].get("calls", []))
            out.append(f"  {kind} default call: {cols['default']['backend']} ({cols['default']['why']}); calls: {calls}")
    return "\n".join(out)


if __name__ == "__main__":
    main()
