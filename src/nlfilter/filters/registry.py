"""The filter registry: every public filter of nlfilter by name, in one plain dict (the way
``scipy.integrate.solve_ivp`` keeps ``METHODS``).

``nlfilter list --filters`` prints it; :func:`nlfilter.compare` runs the registered filters that
accept a model (``compare(model, "all", ...)``); ``tests/test_contract.py`` iterates it, so a new
filter cannot skip the contract. Each class declares what the registry shows: ``family``,
``source`` (seed and equations), ``accepts`` (model kinds: ``"discrete"``, ``"sde"``,
``"bilinear"``, ...), ``needs`` (what the model must offer), ``time``, ``likelihood``,
``smoother`` and, for the filters of continuously measured SDEs, ``measurement_convention``: how
the increment ``dy`` of one interval is read, and to what order in ``dt`` that is the simulator's
convention (:mod:`nlfilter.sde_step`; the particle reference reads it exactly).
"""

from __future__ import annotations

from .. import _validate as V


def get(registry: dict, name: str):
    """The class registered under ``name``; an unknown name (any object) is a ValueError listing
    the choices (``nlfilter._validate.choice``)."""
    return registry[V.choice("filter", name, set(registry))]


def model_kind(model) -> str:
    """The kind of a model as the registry's ``accepts`` names it: a ``BilinearModel`` (whose
    ``kind`` is ``"bilinear"`` in both times) is ``"bilinear"`` in continuous time and
    ``"bilinear-discrete"`` in discrete time."""
    kind = getattr(model, "kind", None)
    if kind in ("bilinear", "model", None) and hasattr(model, "discrete"):  # a BilinearModel: by its time
        return "bilinear-discrete" if model.discrete else "bilinear"
    return kind


def accepting(registry: dict, model) -> dict:
    """The registered filters whose ``accepts`` include the model's kind (their ``needs`` are
    checked when they are built: a model without them is refused there, naming the need)."""
    kind = model_kind(model)
    return {name: cls for name, cls in registry.items() if kind in getattr(cls, "accepts", ())}


def table(registry: dict) -> list[dict]:
    """One row per registered filter: name, class, family, time, accepts, needs, likelihood (what
    ``run(..., loglik=True)`` gives, or ""), smoother (its backward pass, or ""), source,
    measurement_convention (continuous-time filters: how ``dy`` is read and to what order in dt;
    "" for discrete-time ones)."""
    return [{"name": name, "class": cls.__name__, "family": getattr(cls, "family", ""),
             "time": getattr(cls, "time", ""), "accepts": ", ".join(getattr(cls, "accepts", ())),
             "needs": ", ".join(getattr(cls, "needs", ())), "likelihood": getattr(cls, "likelihood", None) or "",
             "smoother": getattr(cls, "smoother", None) or "", "source": getattr(cls, "source", ""),
             "measurement_convention": getattr(cls, "measurement_convention", "") or ""}
            for name, cls in registry.items()]
