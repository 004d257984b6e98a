"""A fair Monte Carlo comparison in one call: every filter against a near-optimal reference on
common random numbers, as a :class:`~nlfilter.results.Result` (table and figure).

One :func:`~nlfilter.simulate.simulate` run is shared by every filter and by the reference, so
the differences between filters are not blurred by different noise: ``gap_to_optimal`` is the
paired difference of squared errors on the same paths, whose standard error is much smaller
than that of either MSE.

The reference (``reference="auto"``)
------------------------------------
:func:`nlfilter.yardstick.certified_reference`: a grid filter for ``n ≤ 2`` whose resolution is
chosen from the model's process-noise and posterior scales, else (or when that grid is too large)
a particle filter; it is rerun at a finer resolution on a subset of paths, and only a reference
whose measured error is within ``rtol`` of its MSE is named ``"optimal"`` — otherwise the finer
one replaces it, up to ``max_particles``, and a reference that never passes is named
``"reference (not converged)"`` with a :class:`~nlfilter.errors.ReferenceWarning`. Its
certificate is ``Result.params["reference"]``, and its error is added (in quadrature) to the
standard error of every ``gap_to_optimal``. A ``GridFilter`` or ``ParticleFilter`` given as
``reference`` is checked the same way (one refinement); any other reference is taken as given.

Randomness: ``compare(rng=seed)`` simulates exactly ``simulate(..., rng=seed)``'s paths (per-path
streams, :mod:`nlfilter.streams`); any filter that draws (``random = True``: a particle filter)
gets per-path sub-streams of its own, keyed by its name: runs are reproducible from ``rng``, do
not depend on the other filters, and are the same for any ``chunk`` of paths.

Execution: every filter, and every rung of the reference, runs as tasks — one per filter and
``block`` of paths — on an executor (:mod:`nlfilter.montecarlo`: this process, or a
``dask.distributed`` cluster with ``executor="dask"``); each block is its own batch with
single-threaded BLAS, so the numbers are bitwise the same for any executor and worker count.
"""

from __future__ import annotations

import math
import numbers
import time
import zlib

import numpy as np

from . import _validate as V
from . import streams
from .evaluate import _window, mse, mse_per_step, nees, paired_difference
from .filters import REGISTRY
from .filters.base import Estimates
from .moments.closures import gaussian_moments
from .filters.registry import accepting, model_kind
from .results import Result, provenance
from .simulate import Timing, simulate
from .errors import DivergenceError

from .yardstick import (MAX_PARTICLES, OPTIMAL, certified_reference, check_given_reference, contradiction_note,
                        contradictions, reference_filter)


def _streams(rng):
    """``(root SeedSequence, seed or None)``: the simulation is ``simulate(..., rng=root)`` — for
    an int seed the same paths as ``simulate(..., rng=seed)`` —, the filters' own streams are
    sub-streams of the same root (:mod:`nlfilter.streams`)."""
    if rng is None or isinstance(rng, bool):  # a comparison is reproducible: no fresh entropy
        raise TypeError(f"rng: expected a non-negative integer seed, a numpy.random.SeedSequence or a "
                        f"numpy.random.Generator, got {rng!r}")
    return streams.root(rng), (int(rng) if isinstance(rng, numbers.Integral) else None)  # root checks the rest


def _run_rng(root, name, paths):
    """The per-path streams of a filter whose ``run`` takes ``rng`` (particle filters), over the
    first ``paths`` paths: path ``p`` draws from the sub-stream ``(p, key)`` of the comparison's
    root, ``key = FILTER`` for the reference's main runs (the stream ``Filter.run(rng=seed)``
    uses) and a key from the name for every other filter (or refinement), so that adding or
    removing other filters, or splitting the paths into chunks, does not change its numbers."""
    key = streams.FILTER if name == OPTIMAL else 1 + zlib.crc32(name.encode())
    return streams.PathRNG(root, paths, key=key)


def _check_filter(label, flt, model, dt, start):
    """``flt`` has ``run`` and the comparison's step convention (discrete) or ``dt`` (SDE); a
    filter built without ``start`` takes the comparison's (``Filter.for_timing``): returns it."""
    if not callable(getattr(flt, "run", None)):
        raise TypeError(f"{label}: expected a filter with a run(ys, m0, P0) method, got {type(flt).__name__}")
    fs = getattr(flt, "start", None)
    if model.kind == "discrete" and isinstance(fs, str) and fs != start:
        if getattr(flt, "start_stated", True) or not callable(getattr(flt, "for_timing", None)):
            raise ValueError(f"{label}: its start={fs!r} differs from start={start!r} of the comparison")
        flt = flt.for_timing(Timing("discrete", start, 0.0, None))[0]
    fdt = getattr(flt, "dt", None)
    if model.kind == "sde" and isinstance(fdt, numbers.Real) and not math.isclose(fdt, dt, rel_tol=1e-12):
        raise ValueError(f"{label}: its dt={fdt!r} differs from dt={dt!r} of the comparison")
    return flt


def _applies(cls, model, kind_of_data) -> bool:
    """A registered filter applies when it accepts the model's kind and reads the comparison's
    data: measurement increments (continuous-time filters) for an SDE, samples for a discrete model."""
    return model_kind(model) in getattr(cls, "accepts", ()) and getattr(cls, "time", None) == kind_of_data


def _resolve(filters, model, sim_model, dt, start):
    """``(dict name -> filter instance, dict name -> reason skipped)`` from a dict of instances,
    ``"all"`` (every registered filter that applies, the reference family aside: the reference is
    the yardstick), or a list of registry names (built with ``cls.for_model``)."""
    if isinstance(filters, dict):
        return dict(filters), {}
    data = "continuous" if sim_model.kind == "sde" else "discrete"
    models = [sim_model] + ([model] if model is not sim_model else [])
    if isinstance(filters, str) and filters == "all":
        names = [name for m in models for name, cls in accepting(REGISTRY, m).items()
                 if getattr(cls, "family", "") != "reference" and _applies(cls, m, data)]
        explicit = False
    elif isinstance(filters, (list, tuple)) and filters and all(isinstance(f, str) for f in filters):
        names = list(filters)
        explicit = True
    else:
        raise TypeError(f"filters: expected 'all', a list of registry names or a non-empty dict of name -> filter "
                        f"instance, got {filters!r}")
    out, skipped = {}, {}
    for name in names:
        if name in out:
            continue
        cls = REGISTRY.get(name)
        if cls is None:
            raise ValueError(f"filters: expected registry names from {sorted(REGISTRY)!r}, got {name!r}")
        target = next((m for m in models if _applies(cls, m, data)), None)
        try:
            if target is None:
                raise ValueError(f"{name} accepts {getattr(cls, 'accepts', ())} models read through "
                                 f"{getattr(cls, 'time', '?')}-time data; this comparison has a "
                                 f"{model_kind(model)} model and {data}-time data")
            out[name] = cls.for_model(target, dt=dt, start=start)
        except (ValueError, TypeError, NotImplementedError) as exc:  # the model lacks what it needs
            if explicit:
                raise ValueError(f"filters: {name}: {exc}") from None
            skipped[name] = str(exc).splitlines()[0]
    if not out:
        raise ValueError(f"filters: no registered filter applies to {model!r}; skipped: {skipped}")
    return out, skipped


def _check_filters(filters, model, dt, start, reference):
    if not isinstance(filters, dict) or not filters:
        raise TypeError(f"filters: expected a non-empty dict of name -> filter instance, got {filters!r}")
    for name, flt in filters.items():
        if not isinstance(name, str) or not name:
            raise TypeError(f"filters: expected non-empty string names, got {name!r}")
        if name == OPTIMAL and reference is not None:
            raise ValueError(f"filters: the name {OPTIMAL!r} is the reference's; rename that filter")
        filters[name] = _check_filter(f"filters[{name!r}]", flt, model, dt, start)


def _lifted_prior(lift, m0, P0):
    """The prior of a bilinear model's state (for a lift, the monomials ``coords`` of the base
    state) under the base prior N(m0, P0): exact Gaussian moments; and the columns of its state
    that are the base state's coordinates (where the comparison reads its estimates)."""
    coords = [tuple(c) for c in lift.coords]
    nb = len(m0)
    mean = gaussian_moments(m0, P0, coords)
    second = gaussian_moments(m0, P0, [tuple(a + b for a, b in zip(ci, cj)) for ci in coords for cj in coords])
    cov = second.reshape(len(coords), len(coords)) - np.outer(mean, mean)
    units = [tuple(int(i == j) for i in range(nb)) for j in range(nb)]
    missing = [u for u in units if u not in coords]
    if missing:
        raise ValueError(f"model: the bilinear model's state does not contain the base state (coords {coords})")
    return mean, 0.5 * (cov + cov.T), [coords.index(u) for u in units]


def _component_names(model):
    states = getattr(model, "states", None)
    return [str(s) for s in states] if states else [f"x{i + 1}" for i in range(model.n)]


def compare(model, filters, steps, *, paths=200, m0, P0, rng=0, reference="auto", window=0.5, dt=None,
            substeps=10, start="update", progress=False, on_divergence="mark", rtol=0.02, certify_paths=64,
            max_particles=MAX_PARTICLES, chunk=None, full_output=False, smooth=False, block=None, executor=None,
            scheduler=None, workers=None):
    """Run every filter and a near-optimal reference on one shared simulation; a :class:`Result`.

    Parameters
    ----------
    model : DiscreteModel, SDEModel or BilinearModel (simulated through its SDE/discrete view —
        for a lift, the SDE it lifts; the filters of the bilinear family run on the bilinear model
        from the lifted prior, and are read at the base state's coordinates)
    filters : ``"all"`` — every filter of :data:`nlfilter.filters.REGISTRY` that accepts the model
        and reads its data (increments for an SDE), the reference family aside, each built with
        ``cls.for_model(model, dt=dt, start=start)``; those the model cannot serve (e.g. the KF on
        a nonlinear model) are listed with the reason in ``params["skipped"]`` and a note —, a list
        of registry names (built the same way; one that cannot be built is an error), or a dict
        name -> filter instance (anything with ``run(ys, m0, P0, on_divergence=...)`` returning
        :class:`~nlfilter.filters.base.Estimates`), built for ``model`` (and ``dt``)
    steps, paths : measurement steps and Monte Carlo paths (``paths ≥ 2``)
    m0, P0 : the prior: true initial states are drawn from N(m0, P0); every filter starts there
    rng : an integer seed, a ``SeedSequence`` or a ``numpy.random.Generator``: the root of the
        per-path streams; the simulation is ``simulate(model, steps, paths=paths, rng=rng, ...)``'s
        (the same paths for an int seed), and filters that draw random numbers get sub-streams of
        their own per path
    reference : ``"auto"`` (a certified reference, see the module docstring), a filter instance,
        or ``None`` (no reference, no ``gap_to_optimal`` rows); it is named ``"optimal"`` in rows
        and figure when certified (or not checkable), else ``"reference (not converged)"`` — or
        ``"reference (contradicted: ...)"`` when its NEES leaves its band or a filter beats it by
        more than 2 s.e. (:func:`~nlfilter.yardstick.contradictions`) —, and its ``gap_*`` rows
        are then ``gap_to_reference``
    rtol, certify_paths, max_particles : the reference's certificate: the largest error bound
        ``|Δ| + 2 se`` of its MSE relative to the MSE, the paths of its refinement run, and the
        most particles the automatic reference may use (:mod:`nlfilter.yardstick`)
    chunk : None, or run every filter on that many paths at a time (memory); the numbers are the
        same for any chunk (per-path streams, :mod:`nlfilter.streams`)
    block : None (every filter runs on all paths as one batch) or the paths per task: each filter
        and each rung of the reference runs on blocks of ``block`` consecutive paths, each block as
        its own batch with single-threaded BLAS (as :func:`nlfilter.montecarlo.montecarlo`'s
        blocks), so that the numbers are identical, bitwise, for any ``executor`` and ``workers``
    executor, scheduler, workers : where the tasks — one per filter and block — run:
        ``None`` (the open :func:`nlfilter.montecarlo.session`'s executor, else this process),
        ``"local"``, ``"dask"`` (a ``dask.distributed`` cluster at ``scheduler``, or a
        ``LocalCluster`` of ``workers`` processes; :class:`~nlfilter.montecarlo.DaskExecutor`)
        or an executor object; the filters run in parallel, and with ``block`` the paths too.
        The simulation and the statistics are computed here; how it ran is
        ``Result.meta["execution"]``
    full_output : also return the :class:`~nlfilter.simulate.Simulation` and the dict
        name -> :class:`~nlfilter.filters.base.Estimates` the numbers were computed from (with
        ``smooth``, also ``"<name> (smoothed)"`` -> the smoothed estimates)
    smooth : also run the smoother (``Filter.smooth``) of every filter that has one (``smoother``
        not None; the others are listed in ``params["smoothing"]["no_smoother"]``) and of the
        reference (the forward–backward grid smoother or the particle smoother, at the
        reference's own resolution: its certificate is the filter's, no second one is built;
        :mod:`nlfilter.filters.reference.smoothing`), and report per filter and component
        ``smoothed_mse`` and ``smoothed_gap_to_optimal`` (the paired difference to the reference
        smoother on the same paths, ± its paired s.e. and the reference's certified error in
        quadrature); the filters' rows are the same as without it. A particle reference costs
        ``O(particles²)`` per step and path to smooth, and on an SDE (``substeps > 1``) has no
        smoother: then no smoothed gaps, and a note
    window : what :func:`~nlfilter.evaluate.mse` averages over (``0.5``: the second half)
    dt, substeps : SDE models only: measurement step (required) and Euler–Maruyama substeps of
        the simulation (and of an automatic particle reference)
    start : discrete models: step convention (see :mod:`nlfilter.filters.base`)
    progress : show a progress bar over the filters, and over the steps of each reference run (the
        certification can take longer than the filters)
    on_divergence : passed to every ``run``; ``"mark"`` leaves diverged paths out of the
        statistics and reports their share as ``divergence_rate``

    Rows (``Result.get(name, quantity, component=i)``): per filter and component ``i``: ``mse``
    (window average ± stderr) and ``gap_to_optimal`` (MSE minus the reference's on the same
    paths; its stderr is the paired one and the reference's own error in quadrature); per
    filter: ``nees`` (only for filters whose ``covs`` are their posterior covariance:
    ``covariance == "posterior"``), ``offline_mse`` per component instead for the off-line-gain
    filters (the mean over the window of the diagonal of their off-line error covariance: the
    MSE they predict), and ``divergence_rate``; for the reference: ``reference_error`` per
    component (``Δ ± se`` of its refinement), ``edge_mass`` (grids) or ``ess_min`` (particles).
    A filter that fails with a numerical error is listed in ``params["failed"]`` (divergence
    rate 1), a NEES that is undefined (a singular covariance) in a note: ``compare`` does not
    stop on them. ``series``: one panel per component, MSE per step with ± 2 s.e. bands.

    Returns the :class:`Result`, or ``(result, simulation, estimates)`` with ``full_output``.

    >>> import sympy as sp; from nlfilter import DiscreteModel; from nlfilter.filters import EKF, UKF
    >>> x = sp.Symbol("x")
    >>> md = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.5)
    >>> res = compare(md, {"ekf": EKF(md), "ukf": UKF(md)}, 20, paths=10, m0=0.0, P0=0.5, rng=1)
    >>> round(res.get("ekf", "mse", component=0).value - res.get("ukf", "mse", component=0).value, 12)
    0.0
    >>> sorted({r.quantity for r in res.rows})
    ['divergence_rate', 'edge_mass', 'gap_to_optimal', 'mse', 'nees', 'reference_error']
    >>> res.params["reference"]["label"], res.params["reference"]["kind"]
    ('optimal', 'grid')
    """
    given = model
    if model_kind(model) in ("bilinear", "bilinear-discrete"):
        # simulated (and the reference run) on its DiscreteModel/SDEModel view: for a lift, the SDE
        # it lifts; the filters that take the bilinear model itself run on it (prior lifted)
        model = model.to_discrete() if model.discrete else model.to_sde()
    kind = getattr(model, "kind", None)
    if kind not in ("discrete", "sde"):
        raise TypeError(f"model: expected a DiscreteModel, SDEModel or BilinearModel, got {type(model).__name__}")
    V.positive("steps", steps, integer=True)
    V.positive("paths", paths, integer=True)
    if paths < 2:
        raise ValueError(f"paths: expected at least 2 paths (for standard errors), got {paths!r}")
    if kind == "sde" and dt is None:
        raise ValueError("dt: expected the measurement step for an SDEModel, got None")
    if kind == "discrete" and dt is not None:
        raise ValueError(f"dt: a DiscreteModel has no time step; expected None, got {dt!r}")
    if dt is not None:
        dt = float(V.positive("dt", dt))
    V.choice("start", start, {"update", "predict"})
    V.choice("on_divergence", on_divergence, {"raise", "mark"})
    _window(steps, window)  # raises TypeError naming window
    V.positive("rtol", rtol)
    V.positive("certify_paths", certify_paths, integer=True)
    V.positive("max_particles", max_particles, integer=True)
    if isinstance(reference, str) and reference != "auto":
        raise ValueError(f"reference: expected 'auto', None or a filter instance, got {reference!r}")
    if not (reference is None or isinstance(reference, str)):
        reference = _check_filter("reference", reference, model, dt, start)
    filters, skipped = _resolve(filters, given, model, dt, start)
    _check_filters(filters, model, dt, start, reference)
    m0v = V.mean("m0", m0, model.n, ndim=1)
    P0m = V.covariance("P0", P0, model.n)
    root, seed = _streams(rng)
    if chunk is not None:
        V.positive("chunk", chunk, integer=True)

    if block is not None:
        V.positive("block", block, integer=True)
    from tqdm.auto import tqdm

    from . import montecarlo as mc
    sess = mc.current()
    if executor is None and scheduler is None and workers is None and sess is not None:
        ex = sess.executor  # the open session's
    else:
        ex = mc.make_executor(executor, scheduler=scheduler, workers=workers)
    t_start = time.perf_counter()
    try:
        sim_kw = {"dt": dt, "substeps": substeps} if kind == "sde" else {"start": start}
        sim = simulate(model, steps, paths=paths, rng=root, m0=m0v, P0=P0m, **sim_kw)

        params = {"steps": steps, "paths": paths, "window": window, "seed": seed, "start": start,
                  "on_divergence": on_divergence, "m0": m0v.tolist(),
                  "P0": P0m.tolist()}
        if kind == "sde":
            params.update(dt=dt, substeps=substeps)
        if block is not None:  # the blocks' batches: the last bits of the numbers may depend on it
            params["block"] = block

        def jobs_of(name, flt, ys, key, smooth, bar):
            """The tasks of one filter on ``ys``: one per block of paths (its own random stream keyed
            by ``key or name``, per path: the same draws for any block), with its prior."""
            go = "smooth" if smooth else "run"
            B = ys.shape[0]
            size = B if block is None else block
            if getattr(flt, "own_prior", False):  # it starts from a prior of its own
                args = ()
            elif given is not model and getattr(flt, "model", None) is given:  # a filter of the bilinear model
                args = _lifted_prior(given, m0v, P0m)[:2]
            else:
                args = (m0v, P0m)
            out = []
            for lo in range(0, B, size):
                hi = min(lo + size, B)
                kw = {"on_divergence": on_divergence}
                if getattr(flt, "random", False):
                    kw["rng"] = _run_rng(root, key or name, range(lo, hi))
                if chunk is not None:
                    kw["chunk"] = chunk
                if bar and size == B and ex.name == "local":  # the steps of a run in this process
                    kw["progress"] = True
                out.append((go, flt, ys[lo:hi], args, kw))
            return out

        def execute(groups, desc):
            """Run the groups ``(name, flt, ys, key, smooth, bar)`` on the executor, all their tasks
            at once; per group its Estimates (blocks concatenated in path order; a bilinear filter's
            read at the base state's coordinates) or the exception of its first failed block, noted
            with the filter's name."""
            jobs, owner = [], []
            for g, group in enumerate(groups):
                js = jobs_of(*group)
                jobs += js
                owner += [g] * len(js)
            done = [None] * len(jobs)
            with tqdm(total=len(jobs), disable=not progress or len(jobs) < 2, desc=desc, unit="task", leave=False) as pbar:
                for i, res_ in ex.map_unordered(_filter_task, jobs):
                    done[i] = res_
                    pbar.update(1)
            if sess is not None:  # an experiment's run: its meta["execution"] counts these blocks too
                sess.computed += len(jobs)
            out = []
            for g, (name, flt, ys, key, smooth, bar) in enumerate(groups):
                parts = [done[i] for i in range(len(jobs)) if owner[i] == g]
                exc = next((p for p in parts if isinstance(p, BaseException)), None)
                if exc is not None:
                    if isinstance(exc, (DivergenceError, np.linalg.LinAlgError, FloatingPointError, OverflowError)):
                        exc.add_note(f"compare: while {'smoothing with' if smooth else 'running'} filter {name!r} "
                                     f"({type(flt).__name__})")
                    out.append(exc)
                    continue
                e = parts[0] if len(parts) == 1 else Estimates.concatenate(parts)
                if given is not model and getattr(flt, "model", None) is given and not getattr(flt, "own_prior", False):
                    cols = _lifted_prior(given, m0v, P0m)[2]
                    if e.means.shape[-1] != len(cols):  # the whole lifted state: read the base coordinates
                        e = Estimates(e.means[..., cols], e.covs[..., cols, :][..., :, cols], e.diverged,
                                      e.diverged_step, e.extras)
                out.append(e)
            return out

        def run(name, flt, ys, key=None, bar=False, smooth=False):
            """One filter's estimates on ``ys`` (:func:`execute`); a failure is raised."""
            (e,) = execute([(name, flt, ys, key, smooth, bar)], name)
            if isinstance(e, BaseException):
                raise e
            return e

        est, failed = {}, {}
        for (name, flt), e in zip(filters.items(), execute([(name, flt, sim.ys, None, False, False)
                                                             for name, flt in filters.items()], "compare")):
            if isinstance(e, (np.linalg.LinAlgError, FloatingPointError, OverflowError)) and not (
                    on_divergence == "raise" or isinstance(e, DivergenceError)):
                failed[name] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
            elif isinstance(e, BaseException):
                raise e
            else:
                est[name] = e

        cert = None
        if reference is not None:
            def ref_run(flt, ys, tag):  # the reference's rungs: the main ones share the stream key "optimal"
                return run(OPTIMAL, flt, ys, key=OPTIMAL if tag.startswith("reference") else tag, bar=progress)

            if reference == "auto":
                ref_est, cert = certified_reference(model, sim, m0v, P0m, run=ref_run, judged=est, dt=dt, start=start,
                                                    substeps=substeps, window=window, rtol=rtol,
                                                    certify_paths=certify_paths, max_particles=max_particles)
            else:
                ref_est = run(OPTIMAL, reference, sim.ys, bar=progress)
                cert = check_given_reference(reference, ref_est, model, sim, run=ref_run, judged=est, window=window, rtol=rtol,
                                             certify_paths=certify_paths)
            # checks that can fail (NEES band, no filter below −2 s.e.): a failure relabels the reference
            contradictions(cert, ref_est, est, sim.xs, window=window, components=_component_names(model))
            params["reference"] = cert.to_dict()
        else:
            params["reference"] = None
        ref_name = cert.label if cert is not None else None
        gap = "gap_to_optimal" if cert is None or cert.label == OPTIMAL else "gap_to_reference"
        if cert is not None:
            est[ref_name] = ref_est

        if skipped:
            params["skipped"] = skipped
        if failed:
            params["failed"] = failed
        if smooth:
            ref_flt = None
            if cert is not None:
                ref_flt = (reference_filter(cert, model, dt=dt, start=start, substeps=substeps)
                           if isinstance(reference, str) else reference)
            sm, smoothing = _smoothers(filters, est, failed, ref_name, ref_flt, cert, sim, run, on_divergence)
            params["smoothing"] = smoothing
        what = getattr(model, "name", "") or repr(model)
        res = Result("compare", f"{len(filters)} filter(s) against the optimal reference on {what}",
                     "nlfilter.compare: Monte Carlo on common random numbers", params)
        res.meta = provenance("compare", seed=seed, runs=paths, paths=paths)
        res.meta["execution"] = {"executor": ex.name, "workers": getattr(ex, "workers", 1), "block": block,
                                 "chunk": chunk, "seconds": round(time.perf_counter() - t_start, 3)}
        comps = _component_names(model)
        every = dict(filters, **({ref_name: None if isinstance(reference, str) else reference} if cert is not None else {}))
        for name, e in est.items():
            if not np.any(~np.asarray(e.diverged, bool)):
                res.add(name, "divergence_rate", 1.0)
                res.notes.append(f"{name}: every path diverged (first at step {int(np.min(e.diverged_step))}): no MSE")
                continue
            for i in range(model.n):
                s_ = mse(e, sim.xs, component=i, window=window)
                res.add(name, "mse", s_.value, s_.stderr, component=i)
                if cert is not None and name != ref_name and np.any(~(np.asarray(e.diverged, bool)
                                                                       | np.asarray(est[ref_name].diverged, bool))):
                    d = paired_difference(e, est[ref_name], sim.xs, component=i, window=window)
                    res.add(name, gap, d.value, math.hypot(d.stderr, cert.reference_error(i)), component=i)
            flt = every.get(name)
            covariance = getattr(flt, "covariance", "posterior") if flt is not None else "posterior"
            ok = ~np.asarray(e.diverged, bool)
            if covariance == "posterior" and ok.any() and np.all(np.isfinite(e.covs[ok])):
                try:
                    s_ = nees(e, sim.xs, window=window, label=name)
                    res.add(name, "nees", s_.value, s_.stderr)
                except ValueError as exc:
                    res.notes.append(f"nees of {name} not computed: {exc}")
            elif covariance == "off-line" and ok.any():
                w = _window(steps, window)
                for i in range(model.n):
                    v = np.diagonal(e.covs[ok][..., w, :, :], axis1=-2, axis2=-1)[..., i]
                    if np.all(np.isfinite(v)):
                        res.add(name, "offline_mse", float(np.mean(v)), component=i)
            res.add(name, "divergence_rate", float(np.mean(e.diverged)))
        for name in failed:
            res.add(name, "divergence_rate", 1.0)
        if smooth:
            _smoothed_rows(res, sm, ref_name, cert, sim, model.n, window)
        if cert is not None:
            for i, (d, se) in enumerate(cert.error):
                res.add(ref_name, "reference_error", d, se, component=i)
            diag = cert.rungs[-1] if cert.rungs else {}
            if "edge_mass_max" in diag:
                res.add(ref_name, "edge_mass", diag["edge_mass_max"])
            if "ess_min" in diag:
                res.add(ref_name, "ess_min", diag["ess_min"])
        for i, c in enumerate(comps):
            lines, bands = {}, {}
            for name, e in est.items():
                if np.sum(~np.asarray(e.diverged, bool)) < 2:
                    continue  # nothing to draw: every path (but one) diverged
                lines[name], se = mse_per_step(e, sim.xs, component=i)
                bands[name] = (lines[name] - 2 * se, lines[name] + 2 * se)
            res.series[f"MSE of {c} per step ({paths} paths)"] = {
                "x": sim.t, "lines": lines, "bands": bands, "ylabel": f"E ({c} − {c}̂)²",
                "xlabel": "t" if kind == "sde" else "step k"}
        if skipped:
            res.notes.append("not run (the model lacks what they need): " + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
        if failed:
            res.notes.append("failed (numerical error): " + "; ".join(f"{k}: {v}" for k, v in failed.items()))
        if cert is not None:
            res.notes.append(_certificate_note(cert))
            res.notes.append(contradiction_note(cert))
        if smooth:
            res.notes.append(_smoothing_note(params["smoothing"]))
            est.update({f"{k} (smoothed)": v for k, v in sm.items()})
        res.notes.append(f"window {window!r} of {steps} steps, {paths} paths; {gap} = MSE − MSE({ref_name}) "
                         f"on the same paths, ± its paired s.e. and the reference's error; NEES ≈ {model.n} for a "
                         f"consistent filter (posterior covariances only; offline_mse: the off-line error "
                         f"variance an off-line-gain filter predicts)" if cert is not None else
                         f"window {window!r} of {steps} steps, {paths} paths; no reference")
        return (res, sim, est) if full_output else res
    finally:
        if ex is not executor and (sess is None or ex is not sess.executor):
            ex.close()


def _filter_task(job):
    """A task of :func:`compare`: ``(method, filter, ys, prior, keywords)`` -> its Estimates, or
    the exception it raised (returned, so that the other tasks run on and the caller decides).
    BLAS runs single-threaded, here as on a Dask worker (:func:`nlfilter.montecarlo._compute`):
    a block's numbers do not depend on where it ran."""
    from threadpoolctl import threadpool_limits

    go, flt, ys, args, kw = job
    with threadpool_limits(limits=1, user_api="blas"):
        try:
            return getattr(flt, go)(ys, *args, **kw)
        except Exception as exc:  # noqa: BLE001 - handed to the caller, which raises or records it
            return exc


def _certificate_note(cert) -> str:
    """One line: what the reference is and how far from converged."""
    size = "×".join(map(str, cert.size)) + " grid" if cert.kind == "grid" else (
        f"{cert.size} particles" if cert.kind == "particle" else cert.kind)
    if cert.certified is None:
        return f"reference: {size}, given by the caller (not checked)"
    err = ", ".join(f"{d:+.2g} ± {se:.2g}" for d, se in cert.error)
    verdict = "certified" if cert.certified else "NOT converged"
    tol = ", ".join(f"{t:.2g}" for t in (cert.rungs[-1].get("tolerance", []) if cert.rungs else []))
    return (f"reference: {size}, {verdict}: a finer reference on {cert.paths} paths changed its MSE by {err} "
            f"(tolerance {tol or '?'}: rtol = {cert.rtol:g} of its MSE or the gaps' smallest s.e.; "
            f"{len(cert.rungs)} rung(s), {cert.seconds:.1f} s)")


def _smoothers(filters, est, failed, ref_name, ref_flt, cert, sim, run, on_divergence):
    """``(name -> smoothed Estimates, params["smoothing"])``: every filter with a smoother (its
    forward pass on its own stream, as its run), then the reference's smoother (the reference's
    stream: its forward pass is the reference's run)."""
    sm, info = {}, {"no_smoother": {}, "failed": {}}
    for name, flt in filters.items():
        if name in failed or name not in est:
            continue
        if getattr(flt, "smoother", None) is None or not callable(getattr(flt, "smooth", None)):
            info["no_smoother"][name] = type(flt).__name__
            continue
        try:
            sm[name] = run(name, flt, sim.ys, smooth=True)
        except (np.linalg.LinAlgError, FloatingPointError, OverflowError, ValueError) as exc:
            if on_divergence == "raise" or isinstance(exc, DivergenceError):
                raise
            info["failed"][name] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    if ref_name is not None:
        kind = getattr(ref_flt, "smoother", None)
        info["reference"] = {"label": ref_name, "smoother": kind,
                             "certificate": "the reference filter's (the smoother reuses its resolution; "
                                            "not certified separately)"}
        if kind is None:
            info["reference"]["reason"] = (f"{type(ref_flt).__name__} has no smoother"
                                           + (" on an SDE with substeps > 1" if getattr(ref_flt, "substeps", 1) != 1
                                              and getattr(ref_flt, "time", "") == "continuous" else ""))
        else:  # the reference's stream (key "optimal"): its forward pass is the reference's run
            try:
                sm[ref_name] = run(OPTIMAL, ref_flt, sim.ys, key=OPTIMAL, smooth=True)
            except (np.linalg.LinAlgError, FloatingPointError, OverflowError, ValueError) as exc:
                if on_divergence == "raise" or isinstance(exc, DivergenceError):
                    raise
                info["reference"]["smoother"] = None
                info["reference"]["reason"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    for k in ("no_smoother", "failed"):
        if not info[k]:
            del info[k]
    return sm, info


def _smoothed_rows(res, sm, ref_name, cert, sim, n, window):
    """``smoothed_mse`` per smoother and component; ``smoothed_gap_to_optimal`` (or ``_to_reference``)
    against the reference smoother on the same paths, ± the paired s.e. and the reference's error."""
    ref = sm.get(ref_name)
    gap = "smoothed_gap_to_optimal" if cert is None or cert.label == OPTIMAL else "smoothed_gap_to_reference"
    for name, e in sm.items():
        ok = ~np.asarray(e.diverged, bool)
        if not ok.any():
            continue
        for i in range(n):
            s_ = mse(e, sim.xs, component=i, window=window)
            res.add(name, "smoothed_mse", s_.value, s_.stderr, component=i)
            if ref is not None and name != ref_name and np.any(ok & ~np.asarray(ref.diverged, bool)):
                d = paired_difference(e, ref, sim.xs, component=i, window=window)
                res.add(name, gap, d.value, math.hypot(d.stderr, cert.reference_error(i)), component=i)


def _smoothing_note(info) -> str:
    """One line: which smoothers ran, and what the reference smoother is."""
    parts = []
    ref = info.get("reference")
    if ref is not None:
        parts.append(f"reference smoother: {ref['smoother']} on the {ref['label']} reference's resolution (its "
                     "certificate is the filter's)" if ref["smoother"] else
                     f"no reference smoother ({ref['reason']}): no smoothed gaps")
    if info.get("no_smoother"):
        parts.append("no smoother: " + ", ".join(info["no_smoother"]))
    if info.get("failed"):
        parts.append("smoother failed: " + "; ".join(f"{k}: {v}" for k, v in info["failed"].items()))
    return "smoothing: " + "; ".join(parts) if parts else "smoothing: every filter smoothed"
