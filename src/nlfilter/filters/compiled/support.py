"""What the compiled loop takes: numba, the filter's declaration (``compiled = True`` on the class
whose steps are the family's, overridden by no subclass) and the model's structure.

:func:`steps_refusal` is the declaration rule alone (the rule a backend that chooses by itself
reuses); :func:`unsupported` adds numba, the rule and the model.
"""

from __future__ import annotations

import functools
import weakref


@functools.lru_cache(maxsize=1)
def numba():
    """``(numba module or None, the import's error or None)``: numba imported on first need (it
    costs a second; the automatic backend decides most small runs without it). numba is a core
    dependency; a broken install leaves the NumPy loop."""
    try:
        import numba as nb
    except Exception as exc:  # pragma: no cover - exercised only without numba
        return None, exc
    return nb, None

#: the rule kinds (``rule.kind``) the compiled loop has a step kernel for; ``"kalman"``: the linear
#: Kalman filter (its class's ``compiled_kind``; the model's matrices as data, :mod:`.kalman_loop`);
#: ``"sqrt-taylor1"``, ``"sqrt-nodes"``: the square-root filters' (:mod:`.sqrt_kernels`); ``"ito"``: the
#: continuous-time (Itô) filters over a Taylor rule (:mod:`.ito_kernels`); :data:`CD_KINDS`: the
#: continuous-discrete filters over the Taylor and node rules (:mod:`.cd_kernels`)
CD_KINDS = ("cd-taylor1", "cd-taylor2", "cd-nodes")
KINDS = ("taylor1", "nodes", "taylor2", "kalman", "sqrt-taylor1", "sqrt-nodes", "ito", *CD_KINDS)

#: what a subclass of a class declaring ``compiled = True`` may redefine and still run compiled:
#: its constructor and representation. Any other method of the family it redefines (``predict``,
#: ``update``, ``_condition``, ``_predict``, ``init``, ``summary``, ``output``, ... — the NumPy loop's
#: steps, whatever their names become) would run as the declaring class's on the compiled loop,
#: silently, so the filter is refused there (and runs on the NumPy loop)
ALLOWED_OVERRIDES = ("__init__", "__repr__", "__str__", "__init_subclass__", "__getstate__", "__setstate__",
                     "__reduce__", "__reduce_ex__")


def _methods(cls) -> set:
    """The names of the methods (functions, static/class methods, properties) ``cls`` defines itself."""
    return {k for k, v in vars(cls).items() if callable(v) or isinstance(v, (staticmethod, classmethod, property))}


def available() -> bool:
    """Whether numba imports (the ``"numba"`` backend can run)."""
    return numba()[0] is not None


class _Jit:
    """``fn`` compiled by numba at its first call, numba imported then (not at the import of the
    module that defines it); ``fn`` itself without numba."""

    def __init__(self, fn, kw):
        self.py_func, self._kw, self._compiled = fn, kw, None

    def dispatcher(self):
        """The numba dispatcher (made once); the kernels it calls, globals of its module that are
        still :class:`_Jit`, are replaced there by theirs (numba types a dispatcher, not this)."""
        if self._compiled is None:
            nb = numba()[0]
            # error_model="numpy": a division by zero gives inf/NaN (caught by the divergence
            # test), as in NumPy, instead of raising ZeroDivisionError
            self._compiled = self.py_func if nb is None else nb.njit(error_model="numpy", nogil=True, **self._kw)(self.py_func)
            names = self.py_func.__globals__
            for name, value in list(names.items()):
                if isinstance(value, _Jit):
                    names[name] = value.dispatcher()
        return self._compiled

    def __call__(self, *args):
        return self.dispatcher()(*args)


def jit(fn, **kw):
    """``fn`` compiled by numba at its first call from Python (the kernels' own versions, for direct
    use and tests; the loops compile the kernels' sources in their generated modules, :mod:`.build`)."""
    return _Jit(fn, kw)


def steps_refusal(flt) -> str | None:
    """Why ``flt``'s steps are not those of a class declaring ``compiled = True``, or None.

    The class nearest ``type(flt)`` in its MRO that sets ``compiled`` in its own body must set it
    True, and no class before it (a user's subclass) nor the instance may redefine a method of the
    family but those of :data:`ALLOWED_OVERRIDES`: a subclass that changes a step never runs as its parent.
    """
    cls = type(flt)
    decided = _DECIDED.get(cls)
    if decided is None:
        decided = _DECIDED[cls] = _class_refusal(cls)
    why, family, base = decided
    if why is not None:
        return why
    for meth in sorted(family & set(vars(flt))):
        return f"the filter's own attribute {meth} replaces the step of {base}"
    return None


#: :func:`_class_refusal` of every filter class seen: decided once per class (a fit builds a filter
#: per evaluation); held weakly (a class made in a loop goes when unused); a method set on a class
#: after its first run is not seen (a subclass defined later is a new class, decided anew)
_DECIDED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _class_refusal(cls) -> tuple:
    """``(why the class's steps are not a compiled family's or None, the family's method names, the
    declaring class's name)``: :func:`steps_refusal`'s rule on the class."""
    mro = cls.__mro__
    at = next((i for i, c in enumerate(mro) if "compiled" in vars(c)), None)
    if at is None or not vars(mro[at])["compiled"]:
        why = getattr(cls, "compiled_refusal", None)  # the family's own reason (e.g. the square-root filters)
        if why:
            return f"{cls.__name__} has no compiled loop: {why}", frozenset(), None
        by = "" if at is None else f" ({mro[at].__name__} sets compiled = False)"
        return (f"{cls.__name__} has no compiled loop{by}; it runs the discrete Gaussian filters (kf, ekf, ukf, ckf, "
                "ghkf, slf, the discrete second-order forms; sr-kf, sr-ekf, sr-ukf, sr-ckf, sr-ghkf, sr-slf; the "
                "continuous Itô EKF and second-order filters; the continuous-discrete filters but the iterated "
                "EKF)"), frozenset(), None
    family = frozenset(set().union(*(_methods(c) for c in mro[at:])) - set(ALLOWED_OVERRIDES))
    for c in mro[:at]:
        for meth in sorted(_methods(c) & family):
            return (f"{c.__name__} overrides {meth} of {mro[at].__name__}, whose steps the compiled loop runs "
                    f"(a subclass that changes a step runs on the NumPy loop; set compiled = True in "
                    f"{c.__name__} only if its steps are still {mro[at].__name__}'s)"), family, mro[at].__name__
    return None, family, mro[at].__name__


def rule_kind(flt):
    """The rule's step kernel (``rule.kind``: ``"taylor1"``, ``"nodes"``, ``"taylor2"``; the
    filter's ``compiled_kind``: ``"kalman"``, the square-root filters' ``"sqrt-taylor1"``,
    ``"sqrt-nodes"``), or None."""
    kind = getattr(flt, "compiled_kind", None) or getattr(getattr(flt, "rule", None), "kind", None)
    return kind if kind in KINDS else None


def unsupported(flt) -> str | None:
    """Why ``flt`` cannot run on the compiled loop, or None when it can."""
    reason = static_refusal(flt)
    if reason is None and not available():
        reason = f"numba does not import here ({numba()[1]!r})"
    return reason


def static_refusal(flt) -> str | None:
    """:func:`unsupported` but for numba itself (nothing imported: the automatic backend's first test)."""
    name = type(flt).__name__
    reason = steps_refusal(flt)
    if reason is not None:
        return reason
    if getattr(flt, "fading", 1.0) != 1.0:
        return f"{name} with fading memory (alpha = {flt.fading:g}, nlfilter.filters.fading) has no compiled form"
    kind = rule_kind(flt)
    if kind is None:
        return f"{name}'s rule {type(getattr(flt, 'rule', None)).__name__} has no compiled form"
    if getattr(flt, "augmented", False):
        return f"{name} with augmented sigma points has no compiled form"
    md = flt.model
    if getattr(md, "angles", None):
        return "the model declares angular components (angles=): wrapped residuals and circular means run on NumPy"
    if kind == "kalman":
        return _kalman_refusal(md)
    if kind == "ito" or kind in CD_KINDS:
        why = _ito_refusal(flt) if kind == "ito" else _cd_refusal(flt)
        if why is not None:
            return why
    elif getattr(md, "kind", None) != "discrete" or md.expressions is None:
        return "the model must be a DiscreteModel stated in SymPy (not from_functions)"
    if not (md.additive and md.additive_measurement):
        return "the model's noise enters f or h non-additively (noise=, meas_noise=)"
    if md.piecewise:
        return (f"the model uses {', '.join(sorted(md.piecewise))}, which the compiled code does not take (NumPy evaluates them, "
                "with the derivative convention of nlfilter.models)")
    if md.cross_noise is not None:
        return "the model has correlated process and measurement noise (cross_noise)"
    if not md.R_constant:
        return _R_refusal(md)
    vals = md._values
    if vals.arrays or vals.unset or md._fold:
        return "the model has parameters, inputs or a Q that vary over time (arrays, Q given per step) or are not given"
    if kind in ("taylor2", "cd-taylor2") and not md._G_fixed:
        return "the second-order filters' compiled loop needs a G that depends on neither the state nor the time"
    return None


def _ito_refusal(flt) -> str | None:
    """Why the continuous Itô loop (:mod:`.ito_kernels`) cannot take ``flt``, or None: the Itô
    innovation, an SDEModel in SymPy whose f, h, G do not depend on the time (the loop times step
    ``k`` as ``k dt``, without the run's t0) and, for a second-order rule, a G free of the state."""
    md = flt.model
    name = type(flt).__name__
    if getattr(flt, "innovation", "ito") != "ito":
        return f"{name} with innovation={flt.innovation!r} has no compiled form (the Itô step, innovation='ito', has)"
    if getattr(md, "kind", None) != "sde" or md.expressions is None:
        return "the model must be an SDEModel stated in SymPy"
    if not md.time_invariant:
        return "the model's f, h, G or noise depend on the time; the compiled continuous loop takes time-invariant models"
    if flt.rule.second and not md.G_constant:
        return "the continuous second-order filters' compiled loop needs a G that does not depend on the state"
    return None


def _cd_refusal(flt) -> str | None:
    """Why the continuous-discrete loop (:mod:`.cd_kernels`) cannot take ``flt``, or None: an
    SDEModel in SymPy whose f, h, G do not depend on the time (the loop does not read the stages'
    times), measured on a regular grid of a given ``dt`` (not :meth:`at_times`)."""
    md = flt.model
    if getattr(md, "kind", None) != "sde" or md.expressions is None:
        return "the model must be an SDEModel stated in SymPy"
    if not md.time_invariant:
        return "the model's f, h, G or noise depend on the time; the compiled continuous-discrete loop takes time-invariant models"
    if getattr(flt, "times", None) is not None or getattr(flt, "dt", None) is None:
        return "the compiled continuous-discrete loop takes a regular grid of a given dt (not at_times, not dt=None)"
    return None


def _kalman_refusal(md) -> str | None:
    """Why the Kalman filter's compiled loop cannot take the linear model ``md``, or None: its
    matrices are data (:mod:`.kalman_loop`), so any linear DiscreteModel, from SymPy or from
    callables, time-varying or not, with one set of parameter values for all paths."""
    if md.cross_noise is not None:
        return "the model has correlated process and measurement noise (cross_noise)"
    if not md.R_constant:
        return _R_refusal(md)
    vals = md._values
    if vals.per_path or vals.unset or getattr(md, "_per_path_G", False):
        return "the model has parameters, inputs or a Q given per step per path, or inputs not given"
    return None


def _R_refusal(md) -> str:
    """Why a compiled loop cannot take a model without one constant R: the loops read one matrix."""
    if getattr(md, "_R_kind", None) == "time":
        return "the model's R varies over the steps (R_k given per step, or in parameters given per step); the compiled loops read one R"
    return "the model's R depends on the state"
