"""One trajectory, many steps: the cost per step of filtering a single path, side by side with
peers (issue 13, goal 3; issue 28, item 7: every side on one core with one thread, :mod:`_pin`).

Two models, one path each (``--steps``, default 20000):

* (a) the scalar cubic sensor of ``bench_ekf.py``: ``x[k+1] = 0.99 x[k] + w``, ``y = x³ + v``,
  Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1;
* (b) the n = 4 sin-coupled chain of ``bench_dimensions.py`` (``chain(4)``, m = 2 measurements,
  m0 = 0, P0 = I).

Sides, in one run, µs per step (best of ``--repeat``, 3, calls; the first apart):

* nlfilter ``EKF``, ``UKF`` and ``SecondOrderFilter`` (form ``"truncated"``) in the columns
  ``default`` (``run`` with no ``backend=``; what it resolves to is recorded), ``numpy`` and
  ``numba`` (compile apart and included). A column that runs the NumPy loop runs the first
  ``--numpy-steps`` steps (2000: its cost per step does not depend on the length); its
  "compile included" time is its first call with the run part scaled to all the steps;
* filterpy ``ExtendedKalmanFilter`` / ``UnscentedKalmanFilter`` (a Python loop over steps);
* dynamax ``extended_kalman_filter`` / ``unscented_kalman_filter`` in float64 under ``jit``, no
  ``vmap`` (one trajectory; compile apart and included);
* the second-order filter has no peer: nlfilter only;
* (a) only: a hand-written **Python-float EKF loop** (plain floats, the ``math`` module; no NumPy in
  the loop), the baseline issue 28 names ("one scalar trajectory by the default call ≤ 3× the
  Python-float loop"); its means agree with ``backend="numpy"`` to 1e-12 (asserted).

**The default call in a fresh process** (``default_call``: ``EKF(model).run(ys, m0, P0)`` and the
same for ``UKF``, no ``backend=``; both problems, ``--default-steps`` 2000 and 20000): for each
size a new Python (pinned alike: it inherits the core and thread variables) on an empty
``NLFILTER_CACHE`` (**cold**: whatever ``backend="auto"`` chooses there, a compile included), which
then fills the cache (``backend="numba"``, timed apart) if its calls did not, and a second new
Python on that cache (**warm**). Each records ``flt.backend_for(1, T)`` and its reason before its
first call, the first call's wall and CPU seconds (numba's import, a cache load or a compile
included: the model is built before), whether numba was imported, then ``--child-calls`` − 1 more
calls (each with the backend it took: the tally of ``auto`` may move a later call to the compiled
loop) whose best is the steady state. Rows name both sides: the default call against the
Python-float loop (n = 1, EKF) and against dynamax ``jit`` with its compile apart (n = 4), with the
criterion and whether it is met.

The largest |difference| of filtered means is reported between the columns and for each peer,
with the same start: filterpy predicts first (nlfilter ``start="predict"``), dynamax updates first
(nlfilter's default). Writes the run ``--label`` of ``benchmarks/results/bench_single_path.json``:
the sides, and the rows naming both (``peer_over_ours`` > 1: nlfilter faster). No timing is
asserted anywhere.

Run: ``taskset -c 1 python benchmarks/bench_single_path.py [--steps 20000] [--repeat 3] [--quick]
[--default-steps 2000 20000] [--label NAME]``
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread for every side)

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import pathlib  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from _peers import (dynamax_filters, filterpy_pair, maxdiff, nlfilter_sides, per_step, rows_against,  # noqa: E402
                    scaled)
from _models import (A, CUBIC_M0, CUBIC_P0, CUBIC_Q, CUBIC_R, Q, R, chain, chain_jax, chain_np, cubic,  # noqa: E402
                     cubic_jax, cubic_np)

from nlfilter.filters import EKF, UKF, SecondOrderFilter  # noqa: E402
from nlfilter.simulate import simulate  # noqa: E402

OUT = pathlib.Path(__file__).parent / "results" / "bench_single_path.json"
FILTERS = {"ekf": EKF, "ukf": UKF, "second-order": lambda md: SecondOrderFilter(md, form="truncated")}


def problems():
    """name -> (model, m0, P0, filterpy functions, dynamax spec, Q, R)."""
    return {"cubic sensor (n=1)": (cubic(), np.array([0.5]), np.array([[0.1]]), cubic_np(), cubic_jax,
                                   np.array([[CUBIC_Q]]), np.array([[CUBIC_R]])),
            "chain (n=4)": (chain(4), np.zeros(4), np.eye(4), chain_np(4), lambda jnp: chain_jax(4, jnp),
                            Q * np.eye(4), R * np.eye(2))}


def python_float_ekf(ys, m=CUBIC_M0, P=CUBIC_P0, a=A, q=CUBIC_Q, r=CUBIC_R):
    """The scalar cubic sensor's EKF as a plain Python loop over floats (update first, as
    nlfilter's default): the filtered means, a list. ``ys``: a list of floats."""
    out = []
    for y in ys:
        hx = m * m * m  # update: y = x³ + v
        H = 3.0 * m * m
        S = H * P * H + r
        K = P * H / S
        m = m + K * (y - hx)
        P = (1.0 - K * H) * P
        out.append(m)
        m = a * m  # predict: x' = a x + w
        P = a * P * a + q
    return out


def python_float_side(ys, means_numpy, repeat):
    """Time :func:`python_float_ekf` on the trajectory ``ys (1, T, 1)``: wall and CPU µs per step
    (best of ``repeat``) and its largest |difference| from nlfilter's NumPy loop (≤ 1e-12 asserted)."""
    yl = [float(v) for v in ys[0, :, 0]]
    wall = cpu = float("inf")
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = python_float_ekf(yl)
        wall, cpu = min(wall, time.perf_counter() - w), min(cpu, time.process_time() - c)
    k = means_numpy.shape[0]
    d = maxdiff(out[:k], means_numpy[:, 0])
    assert d <= 1e-12, f"the Python-float loop differs from nlfilter's NumPy loop by {d}"
    T = len(yl)
    return {"side": "Python-float EKF loop (plain floats, math module)", "steps": T, "repeat": repeat,
            "us_per_step": wall / T * 1e6, "cpu_us_per_step": cpu / T * 1e6,
            "max_abs_difference_vs_nlfilter_numpy": d, "compared_steps": k}


CHILD_MODELS = {"cubic sensor (n=1)": (cubic, [CUBIC_M0], [[CUBIC_P0]]), "chain (n=4)": (lambda: chain(4), None, None)}


def child(spec: dict) -> dict:
    """In a fresh process: the default call ``FILTER(model).run(ys, m0, P0)`` as :data:`CHILD`
    describes (the first call, then more), and filling the cache if asked and still empty."""
    make, m0, P0 = CHILD_MODELS[spec["problem"]]
    md = make()
    n = md.n
    m0 = np.zeros(n) if m0 is None else np.array(m0, float)
    P0 = np.eye(n) if P0 is None else np.array(P0, float)
    ys = np.load(spec["ys"])
    T = ys.shape[1]
    flt = FILTERS[spec["filter"]](md)
    chose, why = flt.backend_for(1, T)
    out = {"chose": chose, "why": why, "numba_imported_before": "numba" in sys.modules,
           "load_at_start": list(os.getloadavg())}
    w, c = time.perf_counter(), time.process_time()
    est = flt.run(ys, m0, P0)
    out.update(first_wall_s=time.perf_counter() - w, first_cpu_s=time.process_time() - c,
               numba_imported_after_first="numba" in sys.modules)
    np.save(spec["means"], est.means[0])
    calls = []
    for _ in range(spec["calls"] - 1):
        b, y = flt.backend_for(1, T)
        w, c = time.perf_counter(), time.process_time()
        flt.run(ys, m0, P0)
        calls.append({"backend": b, "why": y, "wall_s": time.perf_counter() - w, "cpu_s": time.process_time() - c})
    out["later_calls"] = calls
    if spec.get("fill"):
        b, y = flt.backend_for(1, T)
        out["after_calls"] = {"backend": b, "why": y}
        if "loaded in this process" not in y:  # the cache is not filled yet: compile it now (timed apart)
            w, c = time.perf_counter(), time.process_time()
            flt.run(ys[:, :5], m0, P0, backend="numba")
            out["fill"] = {"wall_s": time.perf_counter() - w, "cpu_s": time.process_time() - c}
    out["process_cpu_s"] = time.process_time()
    out["load_at_end"] = list(os.getloadavg())
    return out


def run_child(spec: dict, cache: str) -> dict:
    env = {**os.environ, "NLFILTER_CACHE": cache, "NLFILTER_BENCH_CACHE": "keep"}
    w = time.perf_counter()
    res = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], env=env, capture_output=True,
                         text=True, timeout=3600, check=False)
    if res.returncode:
        raise RuntimeError(f"child {spec} failed:\n{res.stderr[-3000:]}")
    return {**json.loads(res.stdout.strip().splitlines()[-1]), "process_wall_s": time.perf_counter() - w}


def default_call(name, ys, est_numpy, a, pyfloat, t_dm):
    """The default call in fresh processes, cold then warm, for the EKF and UKF at each of
    ``--default-steps``: the table ``default_call`` and the rows ``default_call_rows``."""
    table, rows = [], []
    with tempfile.TemporaryDirectory(prefix="nlfilter-bench-default-") as tmp:
        for T in [t for t in a.default_steps if t <= ys.shape[1]]:
            yfile = os.path.join(tmp, f"ys{T}.npy")
            np.save(yfile, np.ascontiguousarray(ys[:, :T]))
            for k in ("ekf", "ukf"):
                cache = tempfile.mkdtemp(prefix=f"cache-{k}-{T}-", dir=tmp)
                for state in ("cold", "warm"):
                    spec = {"problem": name, "filter": k, "ys": yfile, "calls": a.child_calls,
                            "means": os.path.join(tmp, f"means-{k}-{T}-{state}.npy"), "fill": state == "cold"}
                    r = run_child(spec, cache)
                    later = r["later_calls"]
                    best = min(later, key=lambda x: x["wall_s"]) if later else None
                    means = np.load(spec["means"])
                    ref = est_numpy[k].means[0]
                    kk = min(len(ref), T)
                    row = {"problem": name, "filter": k, "steps": T, "cache": state, "chose": r["chose"], "why": r["why"],
                           "first_call_wall_s": r["first_wall_s"], "first_call_cpu_s": r["first_cpu_s"],
                           "first_us_per_step_wall": r["first_wall_s"] / T * 1e6,
                           "first_us_per_step_cpu": r["first_cpu_s"] / T * 1e6,
                           "numba_imported": r["numba_imported_after_first"],
                           "steady_backend": best and best["backend"],
                           "steady_us_per_step_wall": best and best["wall_s"] / T * 1e6,
                           "steady_us_per_step_cpu": best and best["cpu_s"] / T * 1e6,
                           "later_calls_backends": [x["backend"] for x in later],
                           "fill_cpu_s": r.get("fill", {}).get("cpu_s"), "process_cpu_s": r["process_cpu_s"],
                           "process_wall_s": r["process_wall_s"], "load_1min_at_start": r["load_at_start"][0],
                           "max_abs_difference_vs_numpy": maxdiff(means[:kk], ref[:kk])}
                    table.append(row)
                    print(f"{name} {k} T={T} {state}: {r['chose']} ({r['why']}); first {row['first_us_per_step_wall']:.3g} "
                          f"µs/step wall ({row['first_us_per_step_cpu']:.3g} CPU), steady {row['steady_us_per_step_wall']:.3g} "
                          f"({row['steady_backend']})", flush=True)
                    rows += _default_rows(row, k, pyfloat, t_dm)
    return table, rows


def _default_rows(row, k, pyfloat, t_dm):
    """The default call against its baseline: the Python-float loop (scalar EKF: ours ≤ 3× its time)
    or dynamax jit with its compile apart (n = 4: ours ≥ 5× faster)."""
    from _pin import side_by_side

    if pyfloat is not None and k == "ekf":
        peer, pv, crit = pyfloat["side"], pyfloat["cpu_us_per_step"], ("ours ≤ 3× the peer's time", lambda r: r >= 1 / 3)
        unit, cols = "CPU µs per step (both sides: the core is shared)", ("first_us_per_step_cpu", "steady_us_per_step_cpu")
    elif t_dm is not None and row["problem"] == "chain (n=4)" and k in t_dm:
        peer, pv = f"dynamax jit float64 {k} (compile apart)", t_dm[k]["best_cpu"] / t_dm[k]["steps"] * 1e6
        crit = ("ours ≥ 5× faster than the peer", lambda r: r >= 5)
        unit, cols = "CPU µs per step (both sides: the core is shared)", ("first_us_per_step_cpu", "steady_us_per_step_cpu")
    else:
        return []
    out = []
    for what, col in zip(("first call in a fresh process", "steady state"), cols):
        if row[col] is None:
            continue
        ours = f"nlfilter {k}, default call, {row['cache']} cache, T = {row['steps']}, {what}"
        r = side_by_side(ours, peer, row[col], pv, unit, kind=k, cache=row["cache"],
                         steps=row["steps"], chose=row["chose"] if col.startswith("first") else row["steady_backend"],
                         criterion=crit[0])
        r["met"] = bool(crit[1](r["peer_over_ours"]))
        out.append(r)
    return out


def measure(name, md, m0, P0, fns, spec, Qm, Rm, a):
    sim = simulate(md, a.steps, paths=1, rng=13, m0=m0, P0=P0)
    ys = np.ascontiguousarray(sim.ys)  # (1, T, m)
    T, Tn = a.steps, min(a.numpy_steps, a.steps)
    n = len(m0)
    row = {"problem": name, "n": int(n), "m": int(ys.shape[-1]), "steps": T, "numpy_steps": Tn,
           "nlfilter": {}, "notes": [], "max_abs_difference_of_means": {}}
    diff = row["max_abs_difference_of_means"]
    on_numpy = [c for c in a.columns if c == "numpy" or (c == "default" and _pin.default_backend() == "numpy")]
    ours, est = {}, {}
    for k in FILTERS:
        ours[k], est[k] = {}, {}
        for cols, steps in ((on_numpy, Tn), ([c for c in a.columns if c not in on_numpy], T)):
            if not cols:
                continue
            t, e, notes = nlfilter_sides(lambda: FILTERS[k](md), ys[:, :steps], m0, P0, a.repeat, cols)
            row["notes"] += [f"{k}: {x}" for x in notes if f"{k}: {x}" not in row["notes"]]
            done = {}  # the numpy column may be the default call's own measurement: one object, kept one
            for col in t:
                ours[k][col] = done.setdefault(id(t[col]), scaled(t[col], T / steps))
                row["nlfilter"].setdefault(k, {})[col] = {**per_step(t[col], steps), "steps": steps}
            est[k].update(e)
        base = est[k].get("numpy")
        for col, e in est[k].items():
            if base is not None and e is not base:  # not the default call's own (same) measurement
                diff[f"{k}: {col} vs numpy"] = maxdiff(e.means[0, :Tn], base.means[0, :Tn])
    full = {k: next((e for c, e in est[k].items() if e.means.shape[1] == T), None) for k in est}
    rows = []
    try:
        t_fp, fp_means = filterpy_pair(fns, ys, m0, P0, Qm, Rm, a.repeat)
        row["filterpy"] = {k: {"us_per_step": v * 1e6} for k, v in t_fp.items()}
        rows += rows_against(ours, "filterpy (a Python loop)", {k: {"best": v * T} for k, v in t_fp.items()}, T)
        for k in t_fp:  # filterpy predicts first
            pred = (EKF if k == "ekf" else UKF)(md, start="predict").run(ys[:, :Tn], m0, P0, backend="numpy").means
            diff[f"{k}: filterpy vs numpy"] = maxdiff(fp_means[k][0, :Tn], pred[0])
    except ImportError as exc:
        row["notes"].append(f"filterpy not installed: {exc}")
    t_dm = pyfloat = None
    if n == 1:
        pyfloat = python_float_side(ys, est["ekf"]["numpy"].means[0], a.repeat)
        row["python_float_loop"] = pyfloat
        print(f"{name}: Python-float EKF loop {pyfloat['us_per_step']:.3g} µs/step "
              f"(|diff| {pyfloat['max_abs_difference_vs_nlfilter_numpy']:.2g})", flush=True)
    try:
        t_dm, dm_means = dynamax_filters(spec, ys[0], a.repeat, vmap=False, kinds=("ekf", "ukf"))
        t_dm = {k: {**v, "steps": T} for k, v in t_dm.items()}
        row["dynamax"] = {k: per_step(v, T) for k, v in t_dm.items()}
        rows += rows_against(ours, "dynamax jit float64", t_dm, T)
        for k in t_dm:
            if full.get(k) is not None:
                diff[f"{k}: dynamax vs nlfilter (all steps)"] = maxdiff(dm_means[k], full[k].means[0])
    except ImportError as exc:
        row["notes"].append(f"dynamax/jax not installed: {exc}")
    row["rows"] = rows
    if a.default_steps:
        row["default_call"], row["default_call_rows"] = default_call(name, ys, {k: est[k]["numpy"] for k in ("ekf", "ukf")},
                                                                     a, pyfloat, t_dm)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--numpy-steps", type=int, default=2000, help="steps of the NumPy loop (per step reported)")
    ap.add_argument("--repeat", type=int, default=3, help="calls per side, the first (compile) apart")
    ap.add_argument("--columns", nargs="+", choices=["default", "numpy", "numba"],
                    default=["default", "numpy", "numba"], help="nlfilter's calls: default (no backend=), numpy, numba")
    ap.add_argument("--quick", action="store_true", help="smoke size: 300 steps, 100 NumPy steps, 2 calls")
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--default-steps", type=int, nargs="*", default=[2000, 20000],
                    help="steps of the default call in fresh processes, cold and warm (none: skip)")
    ap.add_argument("--child-calls", type=int, default=4, help="default calls in each fresh process (the first apart)")
    ap.add_argument("--child", help=argparse.SUPPRESS)  # internal: one fresh process of default_call
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(child(json.loads(a.child)), default=float))
        return
    if a.quick:
        a.steps, a.numpy_steps, a.repeat, a.default_steps, a.child_calls = 300, 100, 2, [300], 2
    rows, extra = [], {"python_float_loop": [], "default_call": [], "default_call_rows": []}
    for name, problem in problems().items():
        rows.append(measure(name, *problem, a))
        for r in rows[-1]["rows"]:
            print(f"{name}: {r['ours']} vs {r['peer']} ({r['compile']}): {r['peer_over_ours']:.2f}x", flush=True)
        if "python_float_loop" in rows[-1]:
            extra["python_float_loop"].append({"problem": name, **rows[-1].pop("python_float_loop")})
        for key in ("default_call", "default_call_rows"):
            extra[key] += rows[-1].pop(key, [])
    _pin.write(a.out, a.label, {
        "quick": a.quick, "repeat": a.repeat, "columns": a.columns,
        "problems": {"cubic sensor (n=1)": "x' = 0.99 x + w, y = x^3 + v, Q = 0.01, R = 0.1, m0 = 0.5, P0 = 0.1",
                     "chain (n=4)": "_models.chain(4): x_i' = 0.9 x_i + 0.1 sin(x_{i+1}) + w, "
                                    "y_j = x_j + 0.1 x_{j+2}^2 + v, Q = 0.01 I, R = 0.1 I, m0 = 0, P0 = I"},
        "units": "µs per step of one trajectory; compile apart and included", "second_order_form": "truncated (no peer)",
        "default_steps": a.default_steps, "child_calls": a.child_calls,
        "issue_28_criteria": ["one scalar trajectory by the default call ≤ 3× the Python-float loop",
                              "at n = 4 ≥ 5× dynamax jit (compile apart)"],
        **{k: v for k, v in extra.items() if v}, "rows": rows}, benchmark="single path")


if __name__ == "__main__":
    main()
