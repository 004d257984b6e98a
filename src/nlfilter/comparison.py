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
Inside a :func:`~nlfilter.montecarlo.session` with a results store (``nlfilter compare`` opens
one), every finished task is kept, and a rerun resumes (:mod:`nlfilter.compare_tasks`).

The reference's cost: ``reference="grid"`` or ``"particle"`` picks the first rung's kind,
``max_particles`` caps the ladder, ``reference_budget`` (seconds) caps it by the cost estimated
from a pilot (:mod:`nlfilter.compare_budget`); with ``progress`` the estimate of a long reference
is printed before it runs. The modules: :mod:`nlfilter.compare_filters` (which filters run, or
why not), :mod:`nlfilter.compare_tasks` (tasks, store), :mod:`nlfilter.compare_rows` (rows, honest
rows for diverging filters, notes, figure), :mod:`nlfilter.compare_budget`.
"""

from __future__ import annotations

import time

import numpy as np

from . import _validate as V
from .compare_filters import _check_filter, _check_filters, _component_names, _resolve, _streams, model_ident
from .compare_rows import (certificate_note, filter_rows, mse_series, smoothed_rows, smoothers,
                           smoothing_note, uninformed_note)
from .compare_switching import mode_rows, switching_filters, switching_setup
from .compare_tasks import Tasks
from .angles import angles_of
from .errors import DivergenceError
from .evaluate import _window
from .filters.registry import model_kind
from .results import Result, provenance
from .switching import SwitchingModel
from .sde_step import SUBSTEPS
from .simulate import simulate, simulate_continuous_discrete
from .simulate_switching import simulate_switching
from .certificate_checks import contradiction_note, contradictions
from .yardstick import MAX_PARTICLES, OPTIMAL, certified_reference, check_given_reference, reference_filter

REFERENCES = ("auto", "grid", "particle")  # the automatic reference's kinds (compare's reference=)


def compare(model, filters, steps, *, paths=200, m0, P0, rng=0, reference="auto", window=0.5, dt=None,
            substeps=SUBSTEPS, start="update", progress=False, on_divergence="mark", rtol=0.02, certify_paths=64,
            max_particles=MAX_PARTICLES, reference_budget=None, chunk=None, full_output=False, smooth=False,
            block=None, executor=None, scheduler=None, workers=None, times=None):
    """Run every filter and a near-optimal reference on one shared simulation; a :class:`Result`.

    Parameters
    ----------
    model : DiscreteModel, SDEModel or BilinearModel (simulated through its SDE/discrete view —
        for a lift, the SDE it lifts; the filters of the bilinear family run on the bilinear model
        from the lifted prior, and are read at the base state's coordinates), or a
        :class:`~nlfilter.switching.SwitchingModel` (jump-Markov: simulated with its modes, judged
        against a certified :class:`~nlfilter.filters.reference.JumpParticleFilter`, ``"all"`` the
        IMMs and the single-mode EKF/UKF, ``mode_error`` rows: :mod:`nlfilter.compare_switching`)
    filters : ``"all"`` — every filter of :data:`nlfilter.filters.REGISTRY` that accepts the model
        and reads its data (increments for an SDE), the reference family aside, each built with
        ``cls.for_model(model, dt=dt, start=start)``; those the model cannot serve (e.g. the KF on
        a nonlinear model) are listed with the reason in ``params["skipped"]`` and a note —, a list
        of registry names (built the same way; one that cannot be built is an error), or a dict
        name -> filter instance (anything with ``run(ys, m0, P0, on_divergence=...)`` returning
        :class:`~nlfilter.filters.estimates.Estimates`), built for ``model`` (and ``dt``)
    steps, paths : measurement steps and Monte Carlo paths (``paths ≥ 2``)
    m0, P0 : the prior: true initial states are drawn from N(m0, P0); every filter starts there
    rng : an integer seed, a ``SeedSequence`` or a ``numpy.random.Generator``: the root of the
        per-path streams; the simulation is ``simulate(model, steps, paths=paths, rng=rng, ...)``'s
        (the same paths for an int seed), and filters that draw random numbers get sub-streams of
        their own per path
    reference : ``"auto"`` (a certified reference, see the module docstring), ``"grid"`` or
        ``"particle"`` (the same, its first rung of that kind; a grid is not followed by
        particles), a filter instance, or ``None`` (no reference, no ``gap_to_optimal`` rows); it
        is named ``"optimal"`` in rows and figure when certified (or not checkable), else
        ``"reference (not converged)"`` — or ``"reference (contradicted: ...)"`` when its NEES
        leaves its band or a filter beats it by more than 2 s.e.
        (:func:`~nlfilter.certificate_checks.contradictions`) —, and its ``gap_*`` rows are then
        ``gap_to_reference``
    rtol, certify_paths, max_particles : the reference's certificate: the largest error bound
        ``|Δ| + 2 se`` of its MSE relative to the MSE, the paths of its refinement run, and the
        most particles the automatic reference may run on all paths (its check runs ``4×`` as
        many on ``certify_paths`` paths; :mod:`nlfilter.yardstick`)
    reference_budget : None, or the seconds the automatic reference may take: its first rung and
        its ladder are chosen by their cost estimated from a pilot (:mod:`nlfilter.compare_budget`),
        the decisions in ``params["reference_budget"]`` and a note; the reference is then only as
        good as the budget allows, which its certificate says
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
    full_output : also return the :class:`~nlfilter.simulation.Simulation` and the dict
        name -> :class:`~nlfilter.filters.estimates.Estimates` the numbers were computed from (with
        ``smooth``, also ``"<name> (smoothed)"`` -> the smoothed estimates)
    smooth : also run the smoother (``Filter.smooth``) of every filter that has one (``smoother``
        not None; the others are listed in ``params["smoothing"]["no_smoother"]``) and of the
        reference (the forward–backward grid smoother or the particle smoother, at the
        reference's own resolution: its certificate is the filter's, no second one is built;
        :mod:`nlfilter.filters.reference.forward_backward`), and report per filter and component
        ``smoothed_mse`` and ``smoothed_gap_to_optimal`` (the paired difference to the reference
        smoother on the same paths, ± its paired s.e. and the reference's certified error in
        quadrature); the filters' rows are the same as without it. A particle reference costs
        ``O(particles²)`` per step and path to smooth, and on an SDE (``substeps > 1``) has no
        smoother: then no smoothed gaps, and a note
    window : what :func:`~nlfilter.evaluate.mse` averages over (``0.5``: the second half)
    dt, substeps : SDE models only: measurement step (required, unless ``times``) and
        Euler–Maruyama substeps per measurement interval of the simulation (default
        :data:`~nlfilter.sde_step.SUBSTEPS`; with ``times`` too, whatever each interval's length),
        of an automatic particle reference and of any particle filter given without ``substeps``
    start : discrete models: step convention (see :mod:`nlfilter.filters.base`)
    times : SDE models measured at discrete times (continuous-discrete, ``y_k = h(x(t_k)) + v_k``):
        the measurement times ``t_1 < ... < t_steps`` after the prior at 0, regular or not, in
        place of ``dt``; simulated by :func:`~nlfilter.simulate.simulate_continuous_discrete`,
        filtered by the continuous-discrete filters at those times (``start="predict"``). The
        simulation takes ``substeps`` Euler–Maruyama steps per interval (the simulator's default
        process), and the reference (``"auto"`` or ``"particle"``; ``"grid"`` is
        refused) is a :class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter`
        through the same steps — the simulator's model exactly —, certified on the particle
        ladder as any other (:func:`~nlfilter.yardstick.certified_reference`); a
        ``ContinuousDiscreteParticleFilter`` given as ``reference`` takes the data's times and
        is checked the same way (one refinement)
    progress : show progress bars naming what runs (the filters, each rung and check of the
        reference, with their paths), and print the reference's estimated cost before a long
        reference (above ``compare_budget.LONG`` seconds) on stderr
    on_divergence : passed to every ``run``; ``"mark"`` leaves diverged paths out of the
        statistics and reports their share as ``divergence_rate``

    Notes
    -----
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
    stop on them. A filter that diverged on so many paths that numbers over its survivors would
    be biased by their selection gets only ``divergence_rate`` and a note (the rule:
    :mod:`nlfilter.compare_rows`). ``series``: one panel per component, MSE per step with ± 2 s.e.
    bands.

    Returns the :class:`Result`, or ``(result, simulation, estimates)`` with ``full_output``.

    Examples
    --------
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
    switching = model if isinstance(model, SwitchingModel) else None
    if switching is not None:  # a jump-Markov model: its simulator, filters and reference (compare_switching)
        model, reference = switching_setup(switching, reference, smooth, times, dt)
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
    if times is not None:
        times, start = _measured_at(times, kind, dt, steps, reference)
    elif kind == "sde" and dt is None:
        raise ValueError("dt: expected the measurement step for an SDEModel, got None")
    if kind == "discrete" and dt is not None:
        raise ValueError(f"dt: a DiscreteModel has no time step; expected None, got {dt!r}")
    if dt is not None:
        dt = float(V.positive("dt", dt))
    if kind == "sde":
        V.positive("substeps", substeps, integer=True)
    V.choice("start", start, {"update", "predict"})
    V.choice("on_divergence", on_divergence, {"raise", "mark"})
    _window(steps, window)  # raises TypeError naming window
    V.positive("rtol", rtol)
    V.positive("certify_paths", certify_paths, integer=True)
    V.positive("max_particles", max_particles, integer=True)
    if reference_budget is not None:
        V.positive("reference_budget", reference_budget)
        if not isinstance(reference, str):
            raise ValueError(f"reference_budget: budgets the automatic reference ('auto', 'grid', 'particle'); "
                             f"expected None with reference={V.shown(reference)}")
    if isinstance(reference, str) and reference not in REFERENCES:
        raise ValueError(f"reference: expected one of {REFERENCES}, None or a filter instance, got {V.shown(reference)}")
    if not (reference is None or isinstance(reference, str)):
        reference = _check_filter("reference", reference, model, dt, start, substeps)
    filters, skipped = (switching_filters(switching, filters, start) if switching is not None else
                        _resolve(filters, given, model, dt, start, None if times is None else "discrete"))
    _check_filters(filters, model, dt, start, reference, substeps)
    m0v = V.mean("m0", m0, model.n, ndim=1)
    P0m = V.covariance("P0", P0, model.n)
    root, seed = _streams(rng)
    if chunk is not None:
        V.positive("chunk", chunk, integer=True)

    if block is not None:
        V.positive("block", block, integer=True)

    from . import montecarlo as mc
    sess = mc.current()
    if executor is None and scheduler is None and workers is None and sess is not None:
        ex = sess.executor  # the open session's
    else:
        ex = mc.make_executor(executor, scheduler=scheduler, workers=workers)
    t_start = time.perf_counter()
    try:
        if switching is not None:
            sim = simulate_switching(switching, steps, paths=paths, rng=root, m0=m0v, P0=P0m, start=start)
        elif times is None:
            sim_kw = {"dt": dt, "substeps": substeps} if kind == "sde" else {"start": start}
            sim = simulate(model, steps, paths=paths, rng=root, m0=m0v, P0=P0m, **sim_kw)
        else:  # continuous-discrete: every filter at the data's times
            sim = simulate_continuous_discrete(model, steps, paths=paths, rng=root, m0=m0v, P0=P0m, times=times,
                                               substeps=substeps)  # its default process: Euler–Maruyama
            filters = {k: f.for_timing(sim.timing)[0] if callable(getattr(f, "for_timing", None)) else f
                       for k, f in filters.items()}
            if callable(getattr(reference, "for_timing", None)):  # a given reference: the data's times, substeps
                reference = reference.for_timing(sim.timing)[0]

        params = {"steps": steps, "paths": paths, "window": window, "seed": seed, "start": start,
                  "on_divergence": on_divergence, "m0": m0v.tolist(),
                  "P0": P0m.tolist()}
        if times is not None:
            params.update(times=times.tolist(), measurements="continuous-discrete", substeps=substeps)
        elif kind == "sde":
            params.update(dt=dt, substeps=substeps)
        if block is not None:  # the blocks' batches: the last bits of the numbers may depend on it
            params["block"] = block
        ident = {"m0": m0v.tolist(), "P0": P0m.tolist(), "on_divergence": on_divergence,
                 "root": [str(root.entropy), list(root.spawn_key)]}  # the stored tasks' keys
        if switching is not None:
            params["switching"] = {"modes": switching.modes, "transition": switching.transition.tolist(),
                                   "mode_probs0": switching.mode_probs0.tolist()}
            ident["switching"] = dict(params["switching"], models=[model_ident(md) for md in switching.models])
        tasks = Tasks(ex, sess, root=root, block=block, chunk=chunk, on_divergence=on_divergence, progress=progress,
                      given=given, model=model, m0=m0v, P0=P0m, ident=ident)
        run = tasks.run

        est, failed = {}, {}
        for (name, flt), e in zip(filters.items(), tasks.execute([(name, flt, sim.ys, None, False, False)
                                                                   for name, flt in filters.items()],
                                                                  f"filters: {len(filters)} × {paths} paths")):
            if isinstance(e, (np.linalg.LinAlgError, FloatingPointError, OverflowError)) and not (
                    on_divergence == "raise" or isinstance(e, DivergenceError)):
                failed[name] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
            elif isinstance(e, BaseException):
                raise e
            else:
                est[name] = e

        cert, budget = None, None
        if reference is not None:
            def ref_run(flt, ys, tag):  # the reference's rungs: the main ones share the stream key "optimal"
                what = f"{tag} × {ys.shape[0]} paths"
                return run(OPTIMAL, flt, ys, key=OPTIMAL if tag.startswith("reference") else tag,
                           bar=what if progress else False, desc=what)

            if isinstance(reference, str):
                if reference_budget is not None or progress:
                    from .compare_budget import ReferenceBudget, stderr_say
                    from .yardstick import _filter_kw
                    kw = _filter_kw(model, dt, start, substeps, times)
                    rungs_of = switching or model
                    budget = ReferenceBudget(reference_budget, ys=sim.ys, certify_paths=certify_paths,
                                             build=lambda r: r.build(rungs_of, kw), say=stderr_say if progress else None,
                                             run=lambda flt, ys, tag: run(OPTIMAL, flt, ys, key=tag, keep=False,
                                                                          desc=f"{tag} × {ys.shape[0]} paths"))
                ref_est, cert = certified_reference(switching or model, sim, m0v, P0m, run=ref_run, judged=est, dt=dt, start=start,
                                                    substeps=substeps, window=window, rtol=rtol,
                                                    certify_paths=certify_paths, max_particles=max_particles,
                                                    first=reference, budget=budget, times=times)
            else:
                ref_est = run(OPTIMAL, reference, sim.ys, bar=progress, desc=f"reference × {paths} paths")
                cert = check_given_reference(reference, ref_est, model, sim, run=ref_run, judged=est, window=window, rtol=rtol,
                                             certify_paths=certify_paths)
            # checks that can fail (NEES band, no filter below −2 s.e.): a failure relabels the reference
            contradictions(cert, ref_est, est, sim.xs, window=window, components=_component_names(model),
                           angles=angles_of(model).states)
            params["reference"] = cert.to_dict()
        else:
            params["reference"] = None
        if reference_budget is not None:
            params["reference_budget"] = budget.to_dict()
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
                ref_flt = (reference_filter(cert, model, dt=dt, start=start, substeps=substeps, times=times)
                           if isinstance(reference, str) else reference)
            sm, smoothing = smoothers(filters, est, failed, ref_name, ref_flt, cert, sim, run, on_divergence)
            params["smoothing"] = smoothing
        what = getattr(switching or model, "name", "") or repr(switching or model)
        res = Result("compare", f"{len(filters)} filter(s) against the optimal reference on {what}",
                     "nlfilter.compare: Monte Carlo on common random numbers", params)
        res.meta = provenance("compare", seed=seed, runs=paths, paths=paths)
        res.meta["execution"] = {"executor": ex.name, "workers": getattr(ex, "workers", 1), "block": block,
                                 "chunk": chunk, "seconds": round(time.perf_counter() - t_start, 3)}
        if tasks.store is not None:
            res.meta["execution"].update(store=str(tasks.store.path), tasks_computed=tasks.computed,
                                         tasks_reused=tasks.reused)
        if budget is not None and budget.log:
            res.meta["execution"]["reference_plan"] = list(budget.log)
        comps = _component_names(model)
        every = dict(filters, **({ref_name: None if isinstance(reference, str) else reference} if cert is not None else {}))
        filter_rows(res, est, every, sim, n=model.n, steps=steps, paths=paths, window=window, cert=cert,
                    ref_name=ref_name, gap=gap, angles=angles_of(model).states)
        for name in failed:
            res.add(name, "divergence_rate", 1.0)
        if switching is not None:
            mode_rows(res, est, sim.modes, window)
        if smooth:
            smoothed_rows(res, sm, ref_name, cert, sim, model.n, window, angles=angles_of(model).states)
        if cert is not None:
            for i, (d, se) in enumerate(cert.error):
                res.add(ref_name, "reference_error", d, se, component=i)
            diag = cert.rungs[-1] if cert.rungs else {}
            if "edge_mass_max" in diag:
                res.add(ref_name, "edge_mass", diag["edge_mass_max"])
            if "ess_min" in diag:
                res.add(ref_name, "ess_min", diag["ess_min"])
        mse_series(res, est, sim, comps, paths=paths, kind=kind, angles=angles_of(model).states)
        blind = uninformed_note(est, filters)
        if blind:
            res.notes.append(blind)
        if skipped:
            res.notes.append("not run: " + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
        if failed:
            res.notes.append("failed (numerical error): " + "; ".join(f"{k}: {v}" for k, v in failed.items()))
        if cert is not None:
            res.notes.append(certificate_note(cert))
            res.notes.append(contradiction_note(cert))
        if reference_budget is not None and budget.log:
            res.notes.append("reference budget: " + "; ".join(budget.log))
        if smooth:
            res.notes.append(smoothing_note(params["smoothing"]))
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


def _measured_at(times, kind, dt, steps, reference):
    """``(times, start)`` of a continuous-discrete comparison (``compare(times=)``): the times
    checked against the model's kind, ``dt`` and ``steps``; start ``"predict"``; a grid reference
    refused (no grid filter reads such data)."""
    if kind != "sde":
        raise ValueError(f"times: measurement times are for an SDEModel measured at discrete times; got a {kind} model")
    if dt is not None:
        raise ValueError(f"dt, times: expected one of them, got dt={dt!r} and times")
    times = V.measurement_times("times", times)
    if len(times) != steps:
        raise ValueError(f"steps: got {steps}; expected the number of measurement times, {len(times)}")
    if isinstance(reference, str) and reference == "grid" or type(reference).__name__ == "GridFilter":
        raise ValueError(f"reference: no grid filter reads an SDE measured at discrete times; expected 'auto', "
                         f"'particle', None or a ContinuousDiscreteParticleFilter, got {V.shown(reference)}")
    return times, "predict"
