"""Which filters a comparison runs, and on what: the filters of :func:`nlfilter.comparison.compare`
resolved from the registry by the model's kind (every registered filter that accepts the kind
either runs or is listed in ``skipped`` with the reason), their checks against the comparison's
conventions, the lifted prior of a bilinear model's filters, and the random streams.

The contract (``tests/test_compare.py``): for ``filters="all"``, every filter of
:data:`nlfilter.filters.REGISTRY` whose ``accepts`` holds the kind of the model (or, for a
:class:`~nlfilter.bilinear.BilinearModel`, of the model it is simulated through) runs, or is in
``skipped`` with one of the reasons: the reference family (the yardstick, not judged: pass one as
``reference=``), data of the other time (a filter of samples on a continuously measured SDE, or
the reverse), or what its ``for_model`` refused (a need the model lacks).
"""

from __future__ import annotations

import hashlib
import math
import numbers
import zlib

import numpy as np

from . import _validate as V
from . import streams
from .filters import REGISTRY
from .filters.registry import accepting, model_kind
from .moments.closures import gaussian_moments
from .simulation import Timing
from .yardstick import OPTIMAL

REFERENCE_FAMILY = ("the reference family: the yardstick of the comparison, not judged by it (pass one as "
                    "reference=...)")


def _streams(rng):
    """``(root SeedSequence, seed or None)``: the simulation is ``simulate(..., rng=root)`` — for
    an int seed the same paths as ``simulate(..., rng=seed)`` —, the filters' own streams are
    sub-streams of the same root (:mod:`nlfilter.streams`)."""
    if rng is None or isinstance(rng, bool):  # a comparison is reproducible: no fresh entropy
        raise TypeError(f"rng: expected a non-negative integer seed, a numpy.random.SeedSequence or a "
                        f"numpy.random.Generator, got {V.shown(rng)}")
    return streams.root(rng), (int(rng) if isinstance(rng, numbers.Integral) else None)  # root checks the rest


def _run_rng(root, name, paths):
    """The per-path streams of a filter whose ``run`` takes ``rng`` (particle filters), over the
    first ``paths`` paths: path ``p`` draws from the sub-stream ``(p, key)`` of the comparison's
    root, ``key = FILTER`` for the reference's main runs (the stream ``Filter.run(rng=seed)``
    uses) and a key from the name for every other filter (or refinement), so that adding or
    removing other filters, or splitting the paths into chunks, does not change its numbers."""
    key = streams.FILTER if name == OPTIMAL else 1 + zlib.crc32(name.encode())
    return streams.PathRNG(root, paths, key=key)


def _check_filter(label, flt, model, dt, start, substeps=None):
    """``flt`` has ``run`` and the comparison's step convention (discrete) or ``dt`` (SDE); a
    filter built without ``start`` takes the comparison's, a particle filter on an SDE built
    without ``substeps`` the simulation's ``substeps`` (``Filter.for_timing``): returns it."""
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
    if (model.kind == "sde" and substeps is not None and getattr(flt, "substeps_stated", True) is False
            and getattr(flt, "time", None) == "continuous"):  # (continuous-discrete: the data's, at for_timing)
        flt = flt.for_timing(Timing("increments", None, 0.0, dt, substeps))[0]
    return flt


def _applies(cls, model, kind_of_data) -> bool:
    """A registered filter applies when it accepts the model's kind and reads the comparison's
    data: measurement increments (continuous-time filters) for an SDE, samples for a discrete model."""
    return model_kind(model) in getattr(cls, "accepts", ()) and getattr(cls, "time", None) == kind_of_data


def check_names(names) -> None:
    """A ValueError naming ``filters`` for the first of ``names`` not in the registry."""
    bad = next((n for n in names if n not in REGISTRY), None)
    if bad is not None:
        raise ValueError(f"filters: expected registry names from {sorted(REGISTRY)!r}, got {V.shown(bad)}")


def _resolve(filters, model, sim_model, dt, start, measured=None):
    """``(dict name -> filter instance, dict name -> reason skipped)`` from a dict of instances,
    ``"all"`` (every registered filter that accepts the kind of ``model`` or of ``sim_model``: it
    runs, or is skipped with the reason — the reference family, the other time's data, or what
    ``cls.for_model`` refused; module docstring), or a list of registry names (built with
    ``cls.for_model``; one that cannot be built is an error). ``measured="discrete"``: an SDE
    measured at discrete times (the continuous-discrete filters run)."""
    if isinstance(filters, dict):
        return dict(filters), {}
    data = measured or ("continuous" if sim_model.kind == "sde" else "discrete")
    models = [sim_model] + ([model] if model is not sim_model else [])
    skipped = {}
    if isinstance(filters, str) and filters == "all":
        names = []
        for m in models:
            for name, cls in accepting(REGISTRY, m).items():
                if getattr(cls, "family", "") == "reference":
                    skipped.setdefault(name, REFERENCE_FAMILY)
                elif name not in names:
                    names.append(name)
        explicit = False
    elif isinstance(filters, (list, tuple)) and filters and all(isinstance(f, str) for f in filters):
        names = list(filters)
        explicit = True
    else:
        raise TypeError(f"filters: expected 'all', a list of registry names or a non-empty dict of name -> filter "
                        f"instance, got {V.shown(filters)}")
    check_names(names)
    ref = next((n for n in names if explicit and getattr(REGISTRY[n], "family", "") == "reference"), None)
    if ref is not None:  # the yardstick is chosen as the reference, not judged as a filter
        raise ValueError(f"filters: {ref}: the grid and particle filters are the reference: pass reference= or a "
                         "dict of name -> filter instance (command line: --reference grid|particle)")
    out = {}
    for name in names:
        if name in out:
            continue
        cls = REGISTRY[name]
        target = next((m for m in models if _applies(cls, m, data)), None)
        try:
            if target is None:
                raise ValueError(f"{name} reads {getattr(cls, 'time', '?')}-time data (accepts "
                                 f"{', '.join(getattr(cls, 'accepts', ()))} models); this comparison has a "
                                 f"{model_kind(model)!r} model and {data}-time data"
                                 + (" (measurement increments)" if data == "continuous" else
                                    " (samples at the measurement times)" if measured else " (samples)"))
            out[name] = cls.for_model(target, dt=dt, start=start)
        except (ValueError, TypeError, NotImplementedError) as exc:  # the model lacks what it needs
            if explicit:
                raise ValueError(f"filters: {name}: {exc}") from None
            skipped[name] = str(exc).splitlines()[0]
    if not out:
        raise ValueError(f"filters: no registered filter applies to {model!r}; skipped: {skipped}")
    return out, skipped


def _check_filters(filters, model, dt, start, reference, substeps=None):
    if not isinstance(filters, dict) or not filters:
        raise TypeError(f"filters: expected a non-empty dict of name -> filter instance, got {V.shown(filters)}")
    for name, flt in filters.items():
        if not isinstance(name, str) or not name:
            raise TypeError(f"filters: expected non-empty string names, got {V.shown(name)}")
        if name == OPTIMAL and reference is not None:
            raise ValueError(f"filters: the name {OPTIMAL!r} is the reference's; rename that filter")
        filters[name] = _check_filter(f"filters[{name!r}]", flt, model, dt, start, substeps)


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


def model_ident(model) -> str:
    """A fingerprint of a model (SHA-256, 16 hex digits) for the keys of a comparison's stored
    blocks: its class, ``repr``, symbolic functions and noise matrices — the same model stated
    again gives the same key."""
    h = hashlib.sha256(type(model).__qualname__.encode())
    h.update(repr(model).encode())
    for k, v in sorted((getattr(model, "sym", None) or {}).items()):
        h.update(f"{k}={v}".encode())
    for name in ("Q", "R", "S", "G", "n", "m", "structure", "discrete"):
        v = getattr(model, name, None)
        if isinstance(v, np.ndarray):
            h.update(np.ascontiguousarray(v, float).tobytes())
        elif v is not None and not callable(v):
            h.update(f"{name}={v!r}".encode())
    return h.hexdigest()[:16]


def filter_ident(flt, _depth: int = 0) -> dict:
    """The settings of a filter instance that fix its numbers, JSON-able (for the keys of stored
    blocks): its class and every scalar, string or array attribute (arrays by SHA-256), its model
    by :func:`model_ident`, and the same of the objects it holds (a rule, a closure), two levels
    deep."""
    out = {"class": f"{type(flt).__module__}.{type(flt).__qualname__}"}
    for k, v in sorted(vars(flt).items()):
        if isinstance(v, (bool, str, numbers.Number)) or v is None:
            out[k] = v if not isinstance(v, float) or math.isfinite(v) else repr(v)
        elif isinstance(v, np.ndarray) and v.dtype.kind in "biuf":
            out[k] = hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest()[:16]
        elif isinstance(v, (list, tuple)) and all(isinstance(a, (str, numbers.Number)) for a in v):
            out[k] = [a if not isinstance(a, numbers.Number) else float(a) for a in v]
        elif k != "model" and _depth < 2 and hasattr(v, "__dict__") and not callable(v):
            out[k] = filter_ident(v, _depth + 1)
    model = getattr(flt, "model", None)
    if model is not None and _depth == 0:
        out["model"] = model_ident(model)
    return out
