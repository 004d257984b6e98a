"""Fuzz of every smoother and every log-likelihood (issue 26): the bad and extreme inputs that
``run`` gets (test_filters.py), fed to ``smooth`` of every filter with a smoother, to
``run(..., loglik=True)`` and ``evaluate.loglik`` of every filter with a likelihood (the contract's
cases: every registered filter), plus degenerate but legal priors and noises (P0 = 0; Q = 0 and
P0 = 0 in one state; R = 0) and data of 1e200; and option objects no validator expected (a list,
a dict, an array, an object whose hash, equality and repr raise) for every option of every
filter and of ``run``. Each call is classified by the harness (conftest.py; a per-step
log-likelihood term that is non-finite outside the marked paths is a silent NaN)."""

from __future__ import annotations

import importlib.util
import inspect
import sys
from pathlib import Path

import numpy as np
import pytest

from nlfilter.evaluate import loglik


def _module(name, path):
    """The module of ``path`` as pytest (or another test file) loaded it, else loaded now."""
    for mod in list(sys.modules.values()):
        if getattr(mod, "__file__", None) == str(path):
            return mod
    spec = importlib.util.spec_from_file_location(name, path)
    mod = sys.modules[name] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


F = _module("_fuzz_filters", Path(__file__).parent / "test_filters.py")  # its _bad_runs, _extreme_runs, _data
CASES = F.CASES
SMOOTHING = [c for c in CASES if c.filter().smoother is not None]
LIKELIHOOD = [c for c in CASES if c.filter().likelihood is not None]
FAR = 1e200
_DATA: dict = {}


def _data(case):
    """The case's valid data (test_filters.py's), simulated once per case."""
    if case.name not in _DATA:
        _DATA[case.name] = F._data(case)
    return _DATA[case.name].copy()


def _twin(case, kind):
    """The case's filter on a degenerate twin of its model (None where the case takes no model or
    its model is not a plain DiscreteModel/SDEModel): ``"Q0 one"`` no process noise in the last
    state, ``"Q0"`` none at all, ``"R0"`` an exact measurement."""
    if "model" not in inspect.signature(case.make).parameters:
        return None
    md = case.filter().model
    if getattr(md, "kind", None) not in ("discrete", "sde"):
        return None
    Q, R = np.array(md.Q, float), np.array(md.R, float)
    if kind == "Q0 one":
        Q[-1, :] = Q[:, -1] = 0.0
    elif kind == "Q0":
        Q[:] = 0.0
    else:
        R[:] = 0.0

    def make():  # each twin model built once (its code generation is the cost), each filter once
        if (id(md), kind) not in _TWINS:
            _TWINS[id(md), kind] = type(md)(md.states, md.sym["f"], md.sym["h"], G=md.sym["G"], Q=Q, R=R)
        if (case.name, kind) not in _TWINS:
            _TWINS[case.name, kind] = case.make(model=_TWINS[id(md), kind])
        return _TWINS[case.name, kind]
    return make


_TWINS: dict = {}


def _extremes(case):
    """``run``'s extreme inputs, data of 1e200, and the degenerate priors and noises: (label,
    argument an error must name, run keywords, filter factory or None for the case's own)."""
    out = [(label, name, kw, None) for label, name, kw in F._extreme_runs(case)]
    d = _data(case)
    out.append(("ys × 1e200", "ys", {"ys": d * FAR}, None))
    if case.prior:
        P0 = np.array(case.prior["P0"], float)
        P0_one = P0.copy()
        P0_one[-1, :] = P0_one[:, -1] = 0.0
        out.append(("P0 = 0", "P0", {"P0": np.zeros_like(P0)}, None))
        for kind, prior in (("Q0 one", P0_one), ("Q0", np.zeros_like(P0)), ("R0", P0)):
            make = _twin(case, kind)
            if make is not None:
                out.append((f"{kind}, P0 {'= 0' if not prior.any() else 'singular' if kind == 'Q0 one' else 'as given'}",
                            ("Q", "R", "P0", "G", "process_noise", "measurement_noise"), {"P0": prior}, make))
    return out


def _bad(case, smooth):
    """``run``'s bad inputs (``smooth`` takes no ``loglik``)."""
    return [(label, name, kw) for label, name, kw in F._bad_runs(case) if not (smooth and name == "loglik")]


def _call(case, kw, *, smooth, make=None, mark=False, plain=False):
    kw = dict(kw)
    d = kw.pop("ys") if "ys" in kw else _data(case)
    run_kw = {**case.prior, **case.run_kw, **kw}
    if mark:
        run_kw.setdefault("on_divergence", "mark")
    if not (smooth or plain):
        run_kw["loglik"] = run_kw.get("loglik", True)

    def go():
        flt = (make or case.filter)()
        return flt.smooth(d, **run_kw) if smooth else flt.run(d, **run_kw)
    return go


def _check_all(fuzz, area, calls):
    """``fuzz.check`` each ``(label, fn, names, bad)`` of one case (counted one by one in the
    table), then fail listing every call that did not pass: one test item per case keeps pytest's
    per-item cost out of the fuzz suite's time."""
    failed = []
    for label, fn, names, bad in calls:
        try:
            fuzz.check(area, fn, names, bad=bad, label=label)
        except AssertionError as exc:
            failed.append(str(exc).splitlines()[0])
    assert not failed, "\n".join(failed)


ROWS = [(c, True) for c in SMOOTHING] + [(c, False) for c in LIKELIHOOD]  # (case, smooth: else loglik)
ROW_IDS = [f"{'smooth' if smooth else 'loglik'}-{c.name}" for c, smooth in ROWS]


@pytest.mark.parametrize("case,smooth", ROWS, ids=ROW_IDS)
def test_bad_input_is_refused_naming_it(fuzz, case, smooth):
    _check_all(fuzz, f"{'smoothers' if smooth else 'loglik'}: bad input",
               [(f"{case.name}: {lab}", _call(case, kw, smooth=smooth), n, True) for lab, n, kw in _bad(case, smooth)])


@pytest.mark.parametrize("case,smooth", ROWS, ids=ROW_IDS)
def test_extreme_or_degenerate_input_is_finite_marked_or_refused(fuzz, case, smooth):
    _check_all(fuzz, f"{'smoothers' if smooth else 'loglik'}: extreme/degenerate",
               [(f"{case.name}: {lab}", _call(case, kw, smooth=smooth, make=mk, mark=True), n, False)
                for lab, n, kw, mk in _extremes(case)])


def _evaluate(case, ys, **kw):
    flt = case.filter()
    reps = 2 if flt.random else 1
    run_kw = {k: v for k, v in case.run_kw.items() if k != "rng"}
    return lambda: loglik(flt, ys, replicates=reps, **case.prior, **run_kw, **kw)


@pytest.mark.parametrize("case", LIKELIHOOD, ids=[c.name for c in LIKELIHOOD])
def test_evaluate_loglik_is_named_finite_or_marked(fuzz, case):
    d = _data(case)
    calls = [(f"{case.name}: {lab}", _evaluate(case, ys, **({} if bad else {"on_divergence": "mark"})), "ys", bad)
             for lab, ys, bad in (("ys complex", F._complex(d), True), ("ys strings", np.full(d.shape, "a"), True),
                                  ("ys None", None, True), ("ys inf", d * np.inf, True),
                                  ("ys × 1e200", d * FAR, False), ("ys one huge outlier", F._outlier(d), False))]
    for label, fn, names, bad in calls:
        fuzz.check(f"evaluate.loglik: {'bad' if bad else 'extreme'}", fn, names, bad=bad, label=label)


# -- option objects no validator expected ------------------------------------------------------------
class Hostile:
    """An option whose ``__hash__``, ``__eq__``, ``__bool__`` and ``__repr__`` all raise."""

    def __hash__(self):
        raise RuntimeError("hash")

    def __eq__(self, other):
        raise RuntimeError("eq")

    def __bool__(self):
        raise RuntimeError("bool")

    def __repr__(self):
        raise RuntimeError("repr")


OBJECTS = [("list", lambda v: [v]), ("dict", lambda v: {"k": v}), ("array", lambda v: np.array([v, v])),
           ("hostile", lambda v: Hostile())]
RUN_OPTIONS = ("on_divergence", "backend", "chunk", "loglik", "t0")
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_option_objects_are_refused_naming_the_option(fuzz, case):
    """Every constructor option of the case, and ``run``'s options, given each object."""
    calls = [(f"{case.name}({kw}={lab})", lambda kw=kw, v=wrap(bogus): case.make(**{kw: v}), kw, True)
             for kw, bogus in dict(case.options).items() for lab, wrap in OBJECTS]
    calls += [(f"{case.name}.run({kw}={lab})", _call(case, {kw: wrap("mark")}, smooth=False, plain=True), kw, True)
              for kw in RUN_OPTIONS for lab, wrap in OBJECTS]
    _check_all(fuzz, "options: any object", calls)


# -- issue 26, item 6: the objects and sizes that reached raw errors ------------------------------------
def _item6():
    import sympy as sp

    from nlfilter import DiscreteModel, SDEModel, simulate
    from nlfilter.bilinear import BilinearModel
    from nlfilter.filters import EKF, QLF, REGISTRY, UKF, GridFilter, ParticleFilter, TensorFilter
    from nlfilter.filters.registry import get
    from nlfilter.moments import closure_by_name
    x = sp.Symbol("x")
    D1 = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x + 0.1 * x**2], Q=0.1, R=0.2)
    S1 = SDEModel([x], [-x**3], [x], Q=0.5, R=0.1)
    BIL = BilinearModel([[-1.0]], [[1.0]], G=[[[0.3]]], B=[[1.0]], R=[[1.0]])
    ys = 0.3 * np.random.default_rng(0).standard_normal((2, 5, 1))
    p = {"m0": [0.5], "P0": [[0.2]]}
    return [
        ("UKF kappa 'a'", lambda: UKF(D1, kappa="a"), "kappa"),
        ("UKF alpha 1e-300", lambda: UKF(D1, alpha=1e-300), "alpha"),
        ("UKF alpha 1e200", lambda: UKF(D1, alpha=1e200), "alpha"),
        ("ParticleFilter threshold None", lambda: ParticleFilter(D1, 50, threshold=None), "threshold"),
        ("GridFilter size [10, 10] on 1-D", lambda: GridFilter(D1, (-4.0, 4.0), [10, 10]), "size"),
        ("GridFilter bounds 'abc'", lambda: GridFilter(D1, "abc", 41), "bounds"),
        ("TensorFilter targets []", lambda: TensorFilter(BIL, 0.05, targets=[]), "targets"),
        ("TensorFilter targets [7]", lambda: TensorFilter(BIL, 0.05, targets=[7]), "targets"),
        ("simulate model 'x'", lambda: simulate("x", 5, paths=2, rng=1, **p), "model"),
        ("simulate per-path m0 (3, 1) for 2 paths", lambda: simulate(D1, 5, paths=2, rng=1, m0=np.zeros((3, 1)),
                                                                     P0=[[0.2]]), "m0"),
        ("simulate per-path x0 (2, 3, 1)", lambda: simulate(D1, 5, paths=2, rng=1, x0=np.zeros((2, 3, 1))), "x0"),
        ("EKF per-path m0 (3, 1) for 2 paths", lambda: EKF(D1).run(ys, np.zeros((3, 1)), [[0.2]]), "m0"),
        ("QLF t0 1e300", lambda: QLF(S1, 0.05).run(ys, **p, t0=1e300), "t0"),
        ("simulate SDE t0 1e300", lambda: simulate(S1, 5, paths=2, rng=1, dt=0.05, t0=1e300, **p), "t0"),
        ("evaluate.loglik complex ys", lambda: loglik(EKF(D1), ys * (1 + 1j), **p), "ys"),
        ("registry name hostile", lambda: get(REGISTRY, Hostile()), "filter"),
        ("registry name list", lambda: get(REGISTRY, ["ekf"]), "filter"),
        ("closure_by_name hostile", lambda: closure_by_name(Hostile()), "closure"),
        ("closure_by_name gaussian order hostile", lambda: closure_by_name("gaussian", Hostile()), "order"),
    ]


def test_item_6_objects_are_refused_naming_them(fuzz):
    _check_all(fuzz, "options: item 6", [(label, fn, name, True) for label, fn, name in _item6()])


def test_item_6_empty_records(fuzz):
    """T = 0: ``run(..., loglik=True).loglik`` is 0 on every path, the smoothers return empty
    estimates (every smoother of the contract)."""
    for case in LIKELIHOOD:
        d = _data(case)[:, :0]
        est = case.filter().run(d, **case.prior, **case.run_kw, loglik=True)
        fuzz.count("T = 0", "handled", ok=bool(np.all(est.loglik == 0.0)), label=f"{case.name}: loglik")
        assert np.all(est.loglik == 0.0), case.name
    for case in SMOOTHING:
        sm = case.filter().smooth(_data(case)[:, :0], **case.prior, **case.run_kw)
        fuzz.count("T = 0", "handled", ok=sm.means.shape[-2] == 0, label=f"{case.name}: smooth")
        assert sm.means.shape[-2] == 0, case.name
