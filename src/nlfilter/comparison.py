"""A fair Monte Carlo comparison in one call: every filter against a near-optimal reference on
common random numbers, as a :class:`~nlfilter.results.Result` (table and figure).

One :func:`~nlfilter.simulate.simulate` run is shared by every filter and by the reference, so
the differences between filters are not blurred by different noise: ``gap_to_optimal`` is the
paired difference of squared errors on the same paths, whose standard error is much smaller
than that of either MSE.

Automatic reference (``reference="auto"``)
------------------------------------------
* ``n ≤ 2``: a :class:`~nlfilter.filters.reference.GridFilter`. Per axis ``i`` let ``s_i`` be
  the smaller of the prior standard deviation ``√P0_ii`` and the root-mean-square standard
  deviation of the noise over one measurement step (``G Q Gᵀ``, times ``dt`` for an SDE, over
  the simulated states), and ``S_i`` the larger. The bounds are the range of the simulated
  states and of ``m0`` widened by ``4 S_i`` on each side; the spacing is at most ``s_i / 4``
  (a quarter of the narrowest noise the kernel must resolve), with at least 101 points (1-D)
  or 21 per axis (2-D) and at most :data:`GRID_MAX` points per axis (the cap bounds time and
  memory; pass your own ``GridFilter`` for a finer grid).
* ``n > 2``: a :class:`~nlfilter.filters.reference.ParticleFilter` with :data:`PARTICLES`
  particles, seeded from its own spawned stream (the simulation's numbers do not move).

Any filter that draws (``random = True``: a particle filter in ``filters``) gets a stream of its
own, keyed by its name: runs are reproducible from ``rng`` and do not depend on the other filters.
"""

from __future__ import annotations

import math
import numbers
import zlib

import numpy as np

from . import _validate as V
from .evaluate import _window, mse, mse_per_step, nees, paired_difference, stream
from .filters import REGISTRY
from .filters.base import Estimates
from .moments.closures import gaussian_moments
from .filters.reference import GridFilter, ParticleFilter
from .filters.registry import accepting, model_kind
from .results import Result, provenance
from .simulate import simulate

PARTICLES = 2000
GRID_MAX = {1: 801, 2: 61}
GRID_MIN = {1: 101, 2: 21}
OPTIMAL = "optimal"


def _streams(rng):
    """``(simulation generator, root SeedSequence of the filters' own streams, seed or None)``.

    An int seed simulates with ``stream(seed, 0)``; a Generator simulates itself and roots the
    filters' streams in a spawned child, so neither shifts the simulation's numbers."""
    if isinstance(rng, np.random.Generator):
        return rng, rng.spawn(1)[0].bit_generator.seed_seq, None
    if isinstance(rng, bool) or not isinstance(rng, numbers.Integral) or rng < 0:
        raise TypeError(f"rng: expected a non-negative integer seed or a numpy.random.Generator, got {rng!r}")
    return stream(int(rng), 0), np.random.SeedSequence(int(rng)), int(rng)


def _run_rng(root, name):
    """The generator of a filter whose ``run`` takes ``rng`` (particle filters): the reference gets
    spawn key 1 (``stream(seed, 1)`` for an int seed), a filter a key from its name, so that
    adding or removing other filters does not change its numbers."""
    key = (1,) if name == OPTIMAL else (2, zlib.crc32(name.encode()))
    return np.random.default_rng(np.random.SeedSequence(root.entropy, spawn_key=(*root.spawn_key, *key)))


def _check_filter(label, flt, model, dt, start):
    """``flt`` has ``run`` and the comparison's step convention (discrete) or ``dt`` (SDE)."""
    if not callable(getattr(flt, "run", None)):
        raise TypeError(f"{label}: expected a filter with a run(ys, m0, P0) method, got {type(flt).__name__}")
    fs = getattr(flt, "start", None)
    if model.kind == "discrete" and isinstance(fs, str) and fs != start:
        raise ValueError(f"{label}: its start={fs!r} differs from start={start!r} of the comparison")
    fdt = getattr(flt, "dt", None)
    if model.kind == "sde" and isinstance(fdt, numbers.Real) and not math.isclose(fdt, dt, rel_tol=1e-12):
        raise ValueError(f"{label}: its dt={fdt!r} differs from dt={dt!r} of the comparison")


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
        _check_filter(f"filters[{name!r}]", flt, model, dt, start)


def _grid(model, sim, m0, P0, dt, start):
    """The automatic grid reference (rule in the module docstring) and its bounds and sizes."""
    n = model.n
    xs = sim.xs.reshape(-1, n)
    g = model.GQGT(xs)
    var = np.diagonal(g, axis1=-2, axis2=-1)  # (states, n)
    noise = np.sqrt(np.mean(var, axis=0) * (dt if model.kind == "sde" else 1.0))
    prior = np.sqrt(np.diag(P0))
    small = np.minimum(noise, prior)
    small = np.where(small > 0, small, np.maximum(noise, prior))
    big = np.maximum(noise, prior)
    if not np.all(small > 0):
        raise ValueError("reference: the automatic grid needs a positive prior or noise variance per state; "
                         "pass a GridFilter or ParticleFilter as reference")
    lo = np.minimum(xs.min(axis=0), m0) - 4 * big
    hi = np.maximum(xs.max(axis=0), m0) + 4 * big
    sizes = np.clip(np.ceil((hi - lo) / (small / 4)).astype(int) + 1, GRID_MIN[n], GRID_MAX[n])
    bounds = [(float(a), float(b)) for a, b in zip(lo, hi)]
    if n == 2 and model.kind == "sde" and np.any(np.abs(g[..., 0, 1]) > 1e-12 * (np.sum(var, axis=-1) + 1e-300)):
        return None, bounds, sizes  # the 2-D SDE grid needs a diagonal diffusion: particles instead
    kw = {"dt": dt} if model.kind == "sde" else {"start": start}
    flt = GridFilter(model, bounds[0] if n == 1 else bounds, [int(s) for s in sizes] if n > 1 else int(sizes[0]), **kw)
    return flt, bounds, sizes


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
            substeps=10, start="update", progress=False, on_divergence="mark") -> Result:
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
    rng : an integer seed or a ``numpy.random.Generator`` (the simulation's; filters that draw
        random numbers get spawned streams of their own)
    reference : ``"auto"`` (see the module docstring), a filter instance, or ``None`` (no
        reference, no ``gap_to_optimal`` rows); it is named ``"optimal"`` in rows and figure
    window : what :func:`~nlfilter.evaluate.mse` averages over (``0.5``: the second half)
    dt, substeps : SDE models only: measurement step (required) and Euler–Maruyama substeps of
        the simulation (and of an automatic particle reference)
    start : discrete models: step convention (see :mod:`nlfilter.filters.base`)
    progress : show a progress bar over the filters
    on_divergence : passed to every ``run``; ``"mark"`` leaves diverged paths out of the
        statistics and reports their share as ``divergence_rate``

    Rows (``Result.get(name, quantity, component=i)``): per filter and component ``i``: ``mse``
    (window average ± stderr) and ``gap_to_optimal`` (MSE minus the reference's on the same
    paths ± stderr); per filter: ``nees`` (when its covariances are finite) and
    ``divergence_rate``. ``series``: one panel per component, MSE per step with ± 2 s.e. bands.

    >>> import sympy as sp; from nlfilter import DiscreteModel; from nlfilter.filters import EKF, UKF
    >>> x = sp.Symbol("x")
    >>> md = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.5)
    >>> res = compare(md, {"ekf": EKF(md), "ukf": UKF(md)}, 20, paths=10, m0=0.0, P0=0.5, rng=1)
    >>> round(res.get("ekf", "mse", component=0).value - res.get("ukf", "mse", component=0).value, 12)
    0.0
    >>> sorted({r.quantity for r in res.rows})
    ['divergence_rate', 'gap_to_optimal', 'mse', 'nees']
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
    if isinstance(reference, str) and reference != "auto":
        raise ValueError(f"reference: expected 'auto', None or a filter instance, got {reference!r}")
    if not (reference is None or isinstance(reference, str)):
        _check_filter("reference", reference, model, dt, start)
    filters, skipped = _resolve(filters, given, model, dt, start)
    _check_filters(filters, model, dt, start, reference)
    m0v = (V.as_float_array("m0", m0, ndim=1, shape_tail=(model.n,)) if np.ndim(m0)
           else np.full(model.n, float(m0)))
    V.finite("m0", m0v)
    P0m = V.covariance("P0", P0, model.n)
    sim_rng, root, seed = _streams(rng)

    sim_kw = {"dt": dt, "substeps": substeps} if kind == "sde" else {"start": start}
    sim = simulate(model, steps, paths=paths, rng=sim_rng, m0=m0v, P0=P0m, **sim_kw)

    params = {"steps": steps, "paths": paths, "window": window, "seed": seed, "start": start,
              "on_divergence": on_divergence, "m0": m0v.tolist(),
              "P0": P0m.tolist()}
    if kind == "sde":
        params.update(dt=dt, substeps=substeps)
    runs = dict(filters)
    ref = reference
    if reference == "auto":
        ref = None
        if model.n <= 2:
            ref, bounds, sizes = _grid(model, sim, m0v, P0m, dt, start)
            if ref is not None:
                params.update(reference="grid", grid_bounds=bounds, grid_size=[int(s) for s in sizes])
        if ref is None:
            ref = ParticleFilter(model, PARTICLES, **({"dt": dt, "substeps": substeps} if kind == "sde"
                                                      else {"start": start}))
            params.update(reference="particle", particles=PARTICLES)
    elif reference is not None:
        params["reference"] = type(reference).__name__
    else:
        params["reference"] = None
    if ref is not None:
        runs[OPTIMAL] = ref

    from tqdm.auto import tqdm
    est = {}
    for name, flt in tqdm(runs.items(), disable=not progress, desc="compare"):
        kw = {"rng": _run_rng(root, name)} if getattr(flt, "random", False) else {}
        if getattr(flt, "own_prior", False):  # it starts from a prior of its own
            est[name] = flt.run(sim.ys, on_divergence=on_divergence, **kw)
        elif given is not model and getattr(flt, "model", None) is given:  # a filter of the bilinear model
            lm0, lP0, cols = _lifted_prior(given, m0v, P0m)
            e = flt.run(sim.ys, lm0, lP0, on_divergence=on_divergence, **kw)
            if e.means.shape[-1] != len(cols):  # the whole lifted state: read the base coordinates
                e = Estimates(e.means[..., cols], e.covs[..., cols, :][..., :, cols], e.diverged,
                              e.diverged_step, e.extras)
            est[name] = e
        else:
            est[name] = flt.run(sim.ys, m0v, P0m, on_divergence=on_divergence, **kw)

    if skipped:
        params["skipped"] = skipped
    what = getattr(model, "name", "") or repr(model)
    res = Result("compare", f"{len(filters)} filter(s) against the optimal reference on {what}",
                 "nlfilter.compare: Monte Carlo on common random numbers", params)
    res.meta = provenance("compare", seed=seed, runs=paths, paths=paths)
    comps = _component_names(model)
    for name, e in est.items():
        for i in range(model.n):
            s = mse(e, sim.xs, component=i, window=window)
            res.add(name, "mse", s.value, s.stderr, component=i)
            if ref is not None and name != OPTIMAL:
                d = paired_difference(e, est[OPTIMAL], sim.xs, component=i, window=window)
                res.add(name, "gap_to_optimal", d.value, d.stderr, component=i)
        ok = ~np.asarray(e.diverged, bool)
        if ok.any() and np.all(np.isfinite(e.covs[ok])):
            s = nees(e, sim.xs, window=window)
            res.add(name, "nees", s.value, s.stderr)
        res.add(name, "divergence_rate", float(np.mean(e.diverged)))
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
    res.notes.append(f"window {window!r} of {steps} steps, {paths} paths; gap_to_optimal = MSE − MSE(optimal) "
                     f"on the same paths; NEES ≈ {model.n} for a consistent filter")
    return res
