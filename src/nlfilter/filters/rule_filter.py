"""A registered filter from a moment rule: the "one registry line" of a new rule.

A rule of :mod:`nlfilter.filters.rules` is a table (a node rule's ``unit_nodes(n) -> (z, wm, wc)``,
a Taylor rule's form); :class:`~nlfilter.filters.gaussian.GaussianFilter` runs any of them. What the
registry (:data:`nlfilter.filters.REGISTRY`) wants is a *class* with the usual constructor
``(model, *, start=None)`` and the registry attributes (``name``, ``family``, ``source``,
``accepts``, ``needs``, ``likelihood``, ``smoother``). :func:`rule_filter` makes it::

    REGISTRY = {..., "ckf5": rule_filter(Cubature5(), name="ckf5", source="Jia, Xin & Cheng 2013, ..."), ...}

and that line is all a new rule needs: the NumPy loop, the compiled loop (which reads ``rule.kind``
and ``rule.unit_nodes``), the RTS smoother and the log-likelihood are the Gaussian skeleton's;
``nlfilter list --filters``, ``compare(model, "all")`` and ``tests/test_contract.py`` read the
registry (the contract builds every :class:`RuleFilter` generically).

The class is a module attribute of this module under its class name (``CKF5`` for ``"ckf5"``), so
it and its instances pickle by reference (Dask workers, the results store): any process that
imports :mod:`nlfilter.filters` makes the registered ones again. A rule filter made elsewhere (a
user's module) pickles in the processes that make it too, as a class defined there would.

>>> import pickle
>>> from nlfilter.filters import REGISTRY
>>> cls = REGISTRY["ckf5"]
>>> cls.__name__, cls.rule, cls.family, cls.accepts, cls.needs, cls.likelihood, cls.smoother
('CKF5', Cubature5(), 'gaussian', ('discrete',), (), 'prediction-error', 'rts')
>>> pickle.loads(pickle.dumps(cls)) is cls, f"{cls.__module__}.{cls.__qualname__}"
(True, 'nlfilter.filters.rule_filter.CKF5')
"""

from __future__ import annotations

from .gaussian import GaussianFilter

__all__ = ["rule_filter", "RuleFilter"]

_MADE: dict = {}  # class name -> (the arguments it was made from, the class)


class RuleFilter(GaussianFilter):
    """Base of the classes :func:`rule_filter` makes: the discrete Gaussian filter over the class's
    ``rule`` (a class attribute), built as ``cls(model, *, start=None)``."""

    rule = None  # the class's rule (the instance's ``rule`` is the same object)
    compiled = True  # its steps are the family's: the compiled loop may run it

    def __init__(self, model, *, start: str | None = None):
        super().__init__(model, type(self).rule, start=start)


def _class_name(name: str) -> str:
    s = "".join(c for c in name.upper() if c.isalnum())
    return s if s[:1].isalpha() else "F" + s


def _rule_needs(rule) -> tuple:
    """What the rule needs of every model, or None when it depends on the model."""
    if getattr(rule, "kind", None) == "nodes":
        return ()
    try:
        return tuple(rule.needs(None))
    except AttributeError:  # the needs depend on the model (Taylor2: on whether G is constant)
        return None


def rule_filter(rule, *, name: str, source: str, cls_name: str | None = None, needs: tuple | None = None):
    """A :class:`~nlfilter.filters.gaussian.GaussianFilter` subclass running ``rule``, for the registry.

    Parameters
    ----------
    rule : a moment rule (a frozen, hashable object with ``moments`` and ``kind``:
        :class:`~nlfilter.filters.rules.NodeRule` subclasses, ``Taylor1()``, ``Taylor2(form)``)
    name : the registry name (the class's ``name``, e.g. ``"ckf5"``)
    source : the paper (the class's ``source``: ``nlfilter list --filters`` shows it)
    cls_name : the class name (default ``name`` upper-cased, alphanumerics only: ``"CKF5"``)
    needs : what the model must offer (default: the rule's, ``()`` for a node rule); give it for a
        rule whose needs depend on the model

    Returns
    -------
    type
        A :class:`RuleFilter` subclass with constructor ``(model, *, start=None)`` and the registry
        attributes (family ``"gaussian"``, accepts ``("discrete",)``, likelihood
        ``"prediction-error"``, smoother ``"rts"``). The same arguments give the same class; another
        rule under a class name already made is a ValueError naming ``cls_name``.
    """
    if not callable(getattr(rule, "moments", None)) or getattr(rule, "kind", None) is None:
        raise TypeError(f"rule: expected a moment rule with moments() and kind (nlfilter.filters.rules), "
                        f"got {type(rule).__name__}")
    try:
        hash(rule)
    except TypeError:
        raise TypeError(f"rule: expected a frozen (hashable) rule, got an unhashable {type(rule).__name__}") from None
    for arg, value in (("name", name), ("source", source)):
        if not isinstance(value, str) or not value.strip():
            raise ValueError(f"{arg}: expected a non-empty string, got {value!r}")
    cls_name = _class_name(name) if cls_name is None else cls_name
    if not (isinstance(cls_name, str) and cls_name.isidentifier()):
        raise ValueError(f"cls_name: expected a Python identifier, got {cls_name!r}")
    needs = _rule_needs(rule) if needs is None else tuple(needs)
    if needs is None:
        raise TypeError(f"needs: the needs of {rule!r} depend on the model; expected needs=(...) "
                        "(e.g. ('f_x', 'h_x', 'f_xx', 'h_xx'))")
    key = (rule, name, source, needs)
    made = _MADE.get(cls_name)
    if made is not None:
        if made[0] == key:
            return made[1]
        raise ValueError(f"cls_name: {cls_name!r} is already the rule filter of {made[0][0]!r} named "
                         f"{made[0][1]!r}; expected another class name for {rule!r}")
    if cls_name in globals():
        raise ValueError(f"cls_name: {cls_name!r} is a name of {__name__}; expected another class name")
    doc = (f"The discrete Gaussian filter over the rule ``{rule!r}`` (registry name ``{name!r}``; made by\n"
           f":func:`~nlfilter.filters.rule_filter.rule_filter`).\n\nSource: {source}.\n")
    cls = type(cls_name, (RuleFilter,), {"__module__": __name__, "__qualname__": cls_name, "__doc__": doc,
                                         "rule": rule, "name": name, "source": source, "needs": needs,
                                         "compiled": True})  # declared by the class itself
    _MADE[cls_name] = (key, cls)
    globals()[cls_name] = cls  # reachable by import: pickles by reference
    return cls
