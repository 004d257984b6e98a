"""The argument checks of :func:`nlfilter.fitting.fit` (issue 26 item 3): bounds, starting
values, SciPy's method and options, and the data (an array or a Simulation) are checked here,
before any likelihood is evaluated, so that nothing malformed reaches SciPy."""

from __future__ import annotations

import math
import numbers
import re

import numpy as np
from scipy import optimize

from . import _validate as V

METHODS = ("L-BFGS-B", "Nelder-Mead", "Powell", "BFGS", "CG", "TNC", "SLSQP", "COBYLA")
# the options fit checks (scipy.optimize.minimize's names); any other key is refused with the method's list
OPTION_KINDS = {"maxiter": "int", "maxfun": "int", "maxfev": "int", "maxcor": "int", "maxls": "int",
                 "ftol": "pos", "gtol": "pos", "eps": "pos", "xtol": "pos", "xatol": "pos", "fatol": "pos",
                 "rhobeg": "pos", "tol": "pos", "catol": "pos", "norm": "real", "disp": "bool", "adaptive": "bool"}


def check_options(method, options) -> dict:
    """``method`` one of :data:`METHODS`, ``options`` None or a dict of options that SciPy's
    ``method`` takes, each of the right type (checked here, before any evaluation)."""
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method: expected one of {list(METHODS)}, got {method!r}")
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError(f"options: expected a dict of scipy.optimize.minimize options, got {options!r}")
    doc = optimize.show_options("minimize", method.lower(), disp=False)
    documented = {name for line in doc.splitlines() for m in [re.match(r"\s*(\w+(?:, \w+)*) :", line)] if m
                  for name in m.group(1).split(", ")}  # the option headers of SciPy's docs ("maxiter, maxfev : int")
    known = [k for k in OPTION_KINDS if k in documented]
    for key, value in options.items():
        if key not in known:
            raise ValueError(f"options: {key!r} is not an option fit passes to method {method!r}; expected some of "
                             f"{known}")
        kind = OPTION_KINDS[key]
        if kind == "bool":
            ok = isinstance(value, (bool, np.bool_))
        elif kind == "int":
            ok = isinstance(value, numbers.Integral) and not isinstance(value, bool) and value > 0
        else:
            ok = (isinstance(value, numbers.Real) and not isinstance(value, bool) and not math.isnan(value)
                  and (kind == "real" or (math.isfinite(value) and value > 0)))
        if not ok:
            want = {"bool": "True or False", "int": "a positive integer", "pos": "a positive finite number",
                    "real": "a number"}[kind]
            raise ValueError(f"options: {key} expected {want}, got {value!r}")
    return dict(options)


def _bound(nm, side, v):
    """One side of ``bounds[nm]``: None (open), or a real number (±inf is open)."""
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise TypeError(f"bounds: the {side} bound of {nm} must be a real number or None, got {v!r}")
    v = float(v)
    if math.isnan(v) or v == (math.inf if side == "lower" else -math.inf):
        raise ValueError(f"bounds: the {side} bound of {nm} must be a number or None (open), got {v!r}")
    return None if math.isinf(v) else v


def parameter_kinds(syms, names, params0, bounds):
    """Per parameter ``(kind, lo, hi)`` of :class:`~nlfilter.fitting._Transform` (``"id"``,
    ``"lo"``, ``"hi"``, ``"logit"``) and the starting values, checked: ``bounds`` a dict of pairs
    of numbers or None (±inf: an open side), ``params0``'s values finite real numbers inside them."""
    if bounds is not None and not isinstance(bounds, dict):
        raise TypeError(f"bounds: expected a dict {{name: (lo, hi)}}, got {bounds!r}")
    bounds = dict(bounds or {})
    for k in bounds:
        if str(k) not in names:
            raise ValueError(f"bounds: {k!r} is not among the fitted parameters {list(names)}")
    bounds = {str(k): v for k, v in bounds.items()}
    kinds, theta0 = [], []
    for s, nm, v in zip(syms, names, params0.values()):
        if isinstance(v, bool) or not (isinstance(v, numbers.Real) or (isinstance(v, np.ndarray) and v.ndim == 0
                                                                        and v.dtype.kind in "iuf")):
            raise TypeError(f"params0: the starting value of {nm} must be a real number, got {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise ValueError(f"params0: the starting value of {nm} must be finite, got {v!r}")
        pair = bounds.get(nm, (0.0 if s.is_positive else None, None))
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise TypeError(f"bounds: expected a pair (lo, hi) for {nm} (None for an open side), got {pair!r}")
        lo, hi = _bound(nm, "lower", pair[0]), _bound(nm, "upper", pair[1])
        if lo is not None and hi is not None and not lo < hi:
            raise ValueError(f"bounds: expected lo < hi for {nm}, got {(lo, hi)}")
        if (lo is not None and not v > lo) or (hi is not None and not v < hi):
            raise ValueError(f"params0: {nm} = {v} is outside its bounds ({lo}, {hi})")
        if lo is not None and hi is not None and not math.isfinite(hi - lo):
            raise ValueError(f"bounds: the interval {(lo, hi)} of {nm} is too wide for a float; expected hi - lo finite")
        kind = "id" if lo is None and hi is None else "lo" if hi is None else "hi" if lo is None else "logit"
        if kind == "logit" and not 0 < (v - lo) / (hi - lo) < 1:  # its logit would be ±inf
            raise ValueError(f"params0: {nm} = {v} is too close to its bounds ({lo}, {hi}) to be optimized")
        kinds.append((kind, lo, hi))
        theta0.append(v)
    return kinds, np.array(theta0)


def fit_data(ys, dt):
    """``(data for run, the checked array, dt)``: a Simulation passes through (its timing is read by
    the filter's run, :meth:`~nlfilter.filters.base.Filter.for_timing`) and gives ``dt``."""
    from .simulation import Simulation

    sim = ys if isinstance(ys, Simulation) else None
    arr = V.finite("ys", V.as_float_array("ys", sim.ys if sim is not None else ys, ndim_min=2), allow_nan=True)
    if np.isnan(arr).all():
        raise ValueError(f"ys: every measurement is missing (NaN, shape {arr.shape}): there is nothing to fit")
    timing = getattr(sim, "timing", None)
    if timing is not None and timing.dt is not None:
        if dt is None:
            dt = timing.dt
        elif not math.isclose(float(V.positive("dt", dt)), timing.dt, rel_tol=1e-12):
            raise ValueError(f"dt: fit was given dt={dt!r}, but the Simulation's measurement step is dt={timing.dt!r}")
    return (arr if sim is None else sim._replace(ys=arr)), arr, dt


def diffuse_check(P0, *, flt=None, label=None, estimate=()) -> None:
    """A ``P0`` with an infinite variance (a diffuse prior): refused for a fit whose filter ``flt``
    has no diffuse form (:func:`~nlfilter.filters.checks.refuse_infinite`, naming ``label``), and
    for an EM that would estimate ``m0`` or ``P0`` (``estimate``; a diffuse prior has neither)."""
    from .filters.checks import is_diffuse, refuse_infinite
    if not is_diffuse(P0):
        return
    if flt is not None and not getattr(flt, "diffuse_prior", False):
        refuse_infinite(P0, f"filter {label!r}")
    if set(estimate) & {"m0", "P0"}:
        raise ValueError(f"P0: a diffuse prior (inf entries, {V.shown(P0)}) has no m0 or P0 to estimate; got "
                         f"estimate={sorted(estimate)} (drop m0 and P0 from it, or give a finite P0)")
