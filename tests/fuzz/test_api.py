"""Fuzz of the model constructors, ``simulate``, the evaluation functions and the moment engine
(issue 15, item 7): table-driven bad and extreme inputs, and hypothesis over model expressions.
Each call is classified by the harness (conftest.py)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hst

from nlfilter import BilinearModel, DiscreteModel, SDEModel, mse, nees, paired_difference
from nlfilter.filters import EKF, QLF, UKF, ContinuousEKF, GridFilter, KalmanBucy, ParticleFilter, TensorFilter
from nlfilter.moments import (PolynomialSDE, gauss_hermite_rule, gaussian_moments, monomials, moment_equations,
                              propagate, steady_state)
from nlfilter.filters.quasilinear import DiscreteQuasilinearFilter

S = importlib.import_module("nlfilter.simulate")  # the module (the package attribute is the function)
x, y, t, a = sp.symbols("x y t a")
nan, inf = float("nan"), float("inf")
D1 = DiscreteModel([x], [0.9 * x - 0.05 * x**3], [x + 0.1 * x**2], Q=0.1, R=0.2)
SDE1 = SDEModel([x], [-x], [x], Q=0.5, R=0.1)


def _disc(f=(0.9 * x,), h=(x,), **kw):
    kw = {"Q": 0.1, "R": 0.2, **kw}
    return lambda: DiscreteModel([x], list(f), list(h), **kw)


def _sde(f=(-x,), h=(x,), **kw):
    kw = {"Q": 0.5, "R": 0.1, **kw}
    return lambda: SDEModel([x], list(f), list(h), **kw)


MODELS = [  # (label, constructor, names an error must carry)
    ("f imaginary", _disc(f=(sp.I * x,)), "f"),
    ("f zoo", _disc(f=(sp.zoo,)), "f"),
    ("f oo*x", _disc(f=(sp.oo * x,)), "f"),
    ("f nan*x", _disc(f=(sp.nan * x,)), "f"),
    ("h imaginary", _disc(h=(sp.I * x,)), "h"),
    ("f undefined function", _disc(f=(sp.Function("g")(x),)), "f"),
    ("f DiracDelta", _disc(f=(sp.DiracDelta(x),)), "f"),
    ("f string", _disc(f=("x +",)), "f"),
    ("f None", lambda: DiscreteModel([x], None, [x], Q=0.1, R=0.2), "f"),
    ("f length", _disc(f=(x, x)), "f"),
    ("h empty", _disc(h=()), "h"),
    ("states empty", lambda: DiscreteModel([], [], [x], Q=0.1, R=0.2), "states"),
    ("states repeated", lambda: DiscreteModel([x, x], [x, x], [x], Q=np.eye(2), R=0.2), "states"),
    ("states number", lambda: DiscreteModel([1], [x], [x], Q=0.1, R=0.2), "states"),
    ("param None", _disc(f=(a * x,), params={a: None}), "a"),
    ("param nan", _disc(f=(a * x,), params={a: nan}), "a"),
    ("param inf", _disc(f=(a * x,), params={a: inf}), "a"),
    ("param complex", _disc(f=(a * x,), params={a: 1j}), "a"),
    ("param string", _disc(f=(a * x,), params={a: "abc"}), "a"),
    ("state as parameter", _disc(f=(a * x,), params={a: 0.5, x: 1.0}), "x"),
    ("time is a state", _disc(f=(x,), time=x), "time"),
    ("Q nan", _disc(Q=nan), "Q"),
    ("Q negative", _disc(Q=-1.0), "Q"),
    ("Q complex", _disc(Q=1j), "Q"),
    ("Q string", _disc(Q="abc"), "Q"),
    ("R inf", _disc(R=inf), "R"),
    ("R negative", _disc(R=-0.2), "R"),
    ("R not symmetric", lambda: DiscreteModel([x], [x], [x, x], Q=0.1, R=[[1, 2], [0, 1]]), "R"),
    ("R wrong size", _disc(R=np.eye(3)), "R"),
    ("G wrong shape", _disc(G=[[1], [1]]), "G"),
    ("sde f imaginary", _sde(f=(sp.I * x,)), "f"),
    ("sde Q negative", _sde(Q=-0.5), "Q"),
    ("bilinear c wrong length", lambda: BilinearModel([[-1.0]], [[1.0]], B=[[1.0]], Q=1.0, R=1.0,
                                                                   c=[1.0, 2.0]), "c"),
    ("bilinear degree 3.5", lambda: BilinearModel.from_polynomial(SDE1, degree=3.5), "degree"),
    ("polynomial sde negative diffusion", lambda: PolynomialSDE.from_sympy([x], [-x], [[-1.0]]), ("sigma", "G", "Q")),
]


@pytest.mark.parametrize("label,make,names", MODELS, ids=[m[0] for m in MODELS])
def test_bad_model_is_refused_naming_the_field(fuzz, label, make, names):
    fuzz.check("models", make, names, label=label)


def _runs_through(make):
    """Build a model and run it end to end: simulate 3 paths, EKF and UKF (marking)."""
    def go():
        md = make()
        sim = S.simulate(md, 6, paths=3, rng=1, m0=[0.5], P0=[[0.2]])
        return [f(md).run(sim.ys, [0.5], [[0.2]], on_divergence="mark") for f in (EKF, UKF)], sim
    return go


NONSMOOTH = [  # supported with a stated derivative convention, or refused naming f
    ("Abs", sp.Abs(x)), ("sign", sp.sign(x)), ("floor", sp.floor(x)), ("Max", sp.Max(x, 0)),
    ("Min", sp.Min(x, 1)), ("Heaviside", sp.Heaviside(x)), ("ceiling", sp.ceiling(x)),
    ("Piecewise", sp.Piecewise((x, x > 0), (0, True))),
]


@pytest.mark.parametrize("label,expr", NONSMOOTH, ids=[n[0] for n in NONSMOOTH])
def test_nonsmooth_functions_run_or_are_refused(fuzz, label, expr):
    fuzz.check("models: nonsmooth f", _runs_through(_disc(f=(0.5 * x + 0.1 * expr,))), "f", bad=False, label=label)


def test_time_varying_model_singular_at_zero(fuzz):
    """f = x/t at t = 0: inf, so the simulation raises naming on_divergence (or marks) — never a
    ZeroDivisionError."""
    make = lambda: DiscreteModel([x], [x / t], [x], Q=0.1, R=0.2, time=t)  # noqa: E731
    fuzz.check("models: nonsmooth f", _runs_through(make), ("f", "t", "time", "on_divergence"), bad=False,
               label="x/t")


# -- hypothesis: random expressions with bad atoms -------------------------------------------------
_ATOMS = [x, x**2, sp.sin(x), sp.exp(-x**2), sp.Float(0.3)]
_BAD_ATOMS = [sp.I, sp.zoo, sp.oo, sp.nan, sp.Function("u")(x), sp.DiracDelta(x)]


@settings(max_examples=30, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(good=hst.lists(hst.sampled_from(_ATOMS), min_size=1, max_size=3), bad=hst.sampled_from(_BAD_ATOMS),
       where=hst.sampled_from(["f", "h"]))
def test_random_expressions_with_a_bad_atom(fuzz, good, bad, where):
    expr = sp.Add(*good) * sp.Float(0.1) + bad * x
    make = _disc(**{where: (expr,)})
    fuzz.check("models: random expressions", _runs_through(make), where, label=f"{where} = {expr}")


# -- filters built on bad models/options -------------------------------------------------------------
OPTIONS = [
    ("ContinuousEKF R = 0", lambda: ContinuousEKF(SDEModel([x], [-x], [x], Q=0.5, R=0.0), 0.05), "R"),
    ("KalmanBucy R = 0", lambda: KalmanBucy(SDEModel([x], [-x], [x], Q=0.5, R=0.0), 0.05), "R"),
    ("QLF R = 0", lambda: QLF(SDEModel([x], [-x], [x], Q=0.5, R=0.0), 0.05), "R"),
    ("grid SDE R = 0", lambda: GridFilter(SDEModel([x], [-x], [x], Q=0.5, R=0.0), (-3, 3), 41, dt=0.05), "R"),
    ("particle SDE R = 0", lambda: ParticleFilter(SDEModel([x], [-x], [x], Q=0.5, R=0.0), 50, dt=0.05), "R"),
    ("grid G = x singular at 0", lambda: GridFilter(DiscreteModel([x], [0.9 * x], [x], G=[[x]], Q=0.5, R=0.1),
                                                    (-3, 3), 41).run(np.zeros((1, 3, 1)), 0.5, 0.2), "G"),
    ("GridFilter size 30.7", lambda: GridFilter(D1, (-3, 3), 30.7), "size"),
    ("GridFilter size 0", lambda: GridFilter(D1, (-3, 3), 0), "size"),
    ("GridFilter bounds reversed", lambda: GridFilter(D1, (3, -3), 41), "bounds"),
    ("GridFilter bounds nan", lambda: GridFilter(D1, (nan, 3), 41), "bounds"),
    ("TensorFilter degree 3.0", lambda: TensorFilter(BilinearModel.from_polynomial(SDE1), 0.05, degree=3.0), "degree"),
    ("QLF rtol -1", lambda: QLF(SDE1, 0.05, rtol=-1.0), "rtol"),
    ("QLF dt 0", lambda: QLF(SDE1, 0.0), "dt"),
    ("QLF dt nan", lambda: QLF(SDE1, nan), "dt"),
    ("QLF substeps 2.5", lambda: QLF(SDE1, 0.05, substeps=2.5), "substeps"),
    ("ParticleFilter particles 0", lambda: ParticleFilter(D1, 0), "particles"),
    ("ParticleFilter particles 10.5", lambda: ParticleFilter(D1, 10.5), "particles"),
    ("EKF model None", lambda: EKF(None), "model"),
    ("EKF model string", lambda: EKF("model"), "model"),
    ("dqlf error_analysis order 30", lambda: DiscreteQuasilinearFilter(D1).error_analysis(0.5, 0.2, 3, order=30),
     "order"),
    ("dqlf error_analysis steps -1", lambda: DiscreteQuasilinearFilter(D1).error_analysis(0.5, 0.2, -1), "steps"),
]


@pytest.mark.parametrize("label,make,names", OPTIONS, ids=[o[0] for o in OPTIONS])
def test_bad_filter_construction_is_refused_naming_it(fuzz, label, make, names):
    fuzz.check("filters: construction", make, names, label=label)


# -- simulate ------------------------------------------------------------------------------------------
def _sim(**kw):
    kw = {"paths": 2, "rng": 1, "m0": [0.5], "P0": [[0.2]], **kw}
    steps = kw.pop("steps", 5)
    model = kw.pop("model", D1)
    return lambda: S.simulate(model, steps, **kw)


SIMULATE = [
    ("m0 nan", _sim(m0=[nan]), "m0"), ("m0 complex", _sim(m0=[1j]), "m0"), ("P0 complex", _sim(P0=[[1j]]), "P0"),
    ("P0 negative", _sim(P0=[[-1.0]]), "P0"), ("x0 inf", _sim(m0=None, P0=None, x0=[inf]), "x0"),
    ("x0 complex", _sim(m0=None, P0=None, x0=[1j]), "x0"), ("t0 nan", _sim(t0=nan), "t0"),
    ("t0 'abc'", _sim(t0="abc"), "t0"), ("steps 2.5", _sim(steps=2.5), "steps"), ("steps -1", _sim(steps=-1), "steps"),
    ("paths 0", _sim(paths=0), "paths"), ("paths 2.5", _sim(paths=2.5), "paths"), ("paths 'a'", _sim(paths="a"), "paths"),
    ("rng 'abc'", _sim(rng="abc"), "rng"), ("huge allocation", _sim(steps=10**9, paths=1000), ("steps", "paths")),
    ("no prior", _sim(m0=None, P0=None), ("m0", "x0")), ("dt 0 on an SDE", _sim(model=SDE1, dt=0.0), "dt"),
    ("dt nan on an SDE", _sim(model=SDE1, dt=nan), "dt"), ("substeps 0", _sim(model=SDE1, dt=0.1, substeps=0), "substeps"),
    ("continuous-discrete t0 nan", lambda: S.simulate_continuous_discrete(SDE1, 5, paths=2, rng=1, m0=[0.5], P0=[[0.2]],
                                                                          dt=0.1, t0=nan), "t0"),
]


@pytest.mark.parametrize("label,make,names", SIMULATE, ids=[s[0] for s in SIMULATE])
def test_bad_simulate_input_is_refused_naming_it(fuzz, label, make, names):
    fuzz.check("simulate", make, names, label=label)


DIVERGING = [  # the paths blow up: DivergenceError naming the step (on_divergence), or marked
    ("cubic map from 1e200", _sim(model=DiscreteModel([x], [x**3], [x], Q=0.1, R=0.1), m0=None, P0=None, x0=[1e200])),
    ("unstable x+ = 2x + w", _sim(model=DiscreteModel([x], [2 * x], [x], Q=1.0, R=1.0), steps=1100)),
    ("explicit Euler too coarse for -x^3", _sim(model=SDEModel([x], [-x**3], [x], Q=1.0, R=1.0), m0=None, P0=None,
                                                x0=[10.0], dt=1.0, substeps=1, steps=50)),
]


@pytest.mark.parametrize("label,make", DIVERGING, ids=[d[0] for d in DIVERGING])
def test_diverging_simulation_is_named_or_marked(fuzz, label, make):
    fuzz.check("simulate: diverging", make, ("on_divergence", "x0", "m0"), bad=False, label=label)


# -- evaluate ------------------------------------------------------------------------------------------
_SIM = S.simulate(D1, 6, paths=3, rng=2, m0=[0.5], P0=[[0.2]])
_EST = EKF(D1).run(_SIM.ys, [0.5], [[0.2]])
EVALUATE = [
    ("mse truth nan", lambda: mse(_EST, _SIM.xs * nan), "xs"), ("mse truth inf", lambda: mse(_EST, _SIM.xs * inf), "xs"),
    ("mse truth complex", lambda: mse(_EST, _SIM.xs * 1j), "xs"), ("mse truth shape", lambda: mse(_EST, _SIM.xs[:1]), "xs"),
    ("mse component 5", lambda: mse(_EST, _SIM.xs, component=5), "component"),
    ("mse component 0.5", lambda: mse(_EST, _SIM.xs, component=0.5), "component"),
    ("mse window reversed", lambda: mse(_EST, _SIM.xs, window=(4, 1)), "window"),
    ("nees truth nan", lambda: nees(_EST, _SIM.xs * nan), "xs"),
    ("paired truth nan", lambda: paired_difference(_EST, _EST, _SIM.xs * nan), "xs"),
    ("mse estimates None", lambda: mse(None, _SIM.xs), ("est", "estimates")),
]


@pytest.mark.parametrize("label,make,names", EVALUATE, ids=[e[0] for e in EVALUATE])
def test_bad_evaluate_input_is_refused_naming_it(fuzz, label, make, names):
    fuzz.check("evaluate", make, names, label=label)


# -- the moment engine ----------------------------------------------------------------------------------
_EQ = moment_equations(PolynomialSDE.from_sympy([x], [-x], [[1.0]]), monomials(1, 2, min_degree=1))
MOMENTS = [
    ("gauss_hermite 400 points", lambda: gauss_hermite_rule(1, 400), "points"),
    ("gauss_hermite 0 points", lambda: gauss_hermite_rule(1, 0), "points"),
    ("gauss_hermite 2.5 points", lambda: gauss_hermite_rule(1, 2.5), "points"),
    ("gauss_hermite n 0", lambda: gauss_hermite_rule(0, 3), "n"),
    ("gauss_hermite 10^8 nodes", lambda: gauss_hermite_rule(8, 10), ("points", "n", "nodes")),
    ("gaussian_moments negative variance", lambda: gaussian_moments([0.0], [[-1.0]], [(2,)]), "cov"),
    ("gaussian_moments mean nan", lambda: gaussian_moments([nan], [[1.0]], [(2,)]), "mean"),
    ("steady_state unstable", lambda: steady_state(moment_equations(PolynomialSDE.from_sympy([x], [x], [[1.0]]),
                                                                    monomials(1, 2, min_degree=1))), "eqs"),
    ("propagate t0 nan", lambda: propagate(_EQ, [0.5, 0.5], [1.0], t0=nan), "t0"),
    ("propagate t_eval nan", lambda: propagate(_EQ, [0.5, 0.5], [nan]), "t_eval"),
    ("propagate mu0 nan", lambda: propagate(_EQ, [nan, 0.5], [1.0]), "mu0"),
    ("propagate mu0 length", lambda: propagate(_EQ, [0.5], [1.0]), "mu0"),
    ("propagate mu0 complex", lambda: propagate(_EQ, [0.5j, 0.5], [1.0]), "mu0"),
    ("propagate rtol -1", lambda: propagate(_EQ, [0.5, 0.5], [1.0], rtol=-1.0), "rtol"),
    ("monomials n 0", lambda: monomials(0, 2), "n"),
    ("monomials max_degree -1", lambda: monomials(1, -1), "max_degree"),
    ("monomials max_degree 2.5", lambda: monomials(1, 2.5), "max_degree"),
    ("moment_equations bad index", lambda: moment_equations(PolynomialSDE.from_sympy([x], [-x], [[1.0]]), [(1, 2)]),
     ("indices", "wanted")),
    ("moment_equations negative power", lambda: moment_equations(PolynomialSDE.from_sympy([x], [-x], [[1.0]]), [(-1,)]),
     ("indices", "wanted")),
    ("stationary_moments bad wanted", lambda: __import__("nlfilter").moments.stationary_moments(
        PolynomialSDE.from_sympy([x], [-x], [[1.0]]), [(1, 1)]), "wanted"),
    ("closure_by_name bogus", lambda: __import__("nlfilter").moments.closure_by_name("bogus"), "closure"),
    ("expect_gaussian cov negative", lambda: __import__("nlfilter").moments.expect_gaussian(
        lambda z: z, [0.0], [[-1.0]]), "cov"),
    ("expect_gaussian rule bogus", lambda: __import__("nlfilter").moments.expect_gaussian(
        lambda z: z, [0.0], [[1.0]], rule="bogus"), "rule"),
    ("iterate steps -1", lambda: __import__("nlfilter").moments.iterate(
        __import__("nlfilter").moments.discrete_moment_equations(DiscreteModel([x], [0.5 * x], [x], Q=1.0, R=1.0),
                                                                  monomials(1, 2, min_degree=1)), [0.5, 0.5], -1),
     "steps"),
]


@pytest.mark.parametrize("label,make,names", MOMENTS, ids=[m[0] for m in MOMENTS])
def test_bad_moment_engine_input_is_refused_naming_it(fuzz, label, make, names):
    fuzz.check("moment engine", make, names, label=label)


# -- the user-facing compositions: compare, fit, parameters, inputs, smoothing, likelihood ------------
xa = sp.Symbol("xa")
DA = DiscreteModel([x], [a * x], [x], Q=0.1, R=0.2, params={a: 0.8})
DU = DiscreteModel([x], [0.9 * x + sp.Symbol("u")], [x], Q=0.1, R=0.2, inputs=[sp.Symbol("u")])
_YS = _SIM.ys
_P = {"m0": [0.5], "P0": [[0.2]]}
COMPOSE = [
    ("compare model None", lambda: __import__("nlfilter").compare(None, ["ekf"], 5, paths=4, **_P), "model"),
    ("compare unknown filter", lambda: __import__("nlfilter").compare(D1, ["no-such"], 5, paths=4, **_P), "filters"),
    ("compare steps 0", lambda: __import__("nlfilter").compare(D1, ["ekf"], 0, paths=4, **_P), "steps"),
    ("compare paths 1", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=1, **_P), "paths"),
    ("compare paths 2.5", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=2.5, **_P), "paths"),
    ("compare m0 nan", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=4, m0=[nan], P0=[[0.2]]), "m0"),
    ("compare P0 complex", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=4, m0=[0.5], P0=[[1j]]), "P0"),
    ("compare window 2", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=4, window=2.0, **_P), "window"),
    ("compare rtol -1", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=4, rtol=-1.0, **_P), "rtol"),
    ("compare reference bogus", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=4, reference="bogus", **_P),
     "reference"),
    ("compare block 0", lambda: __import__("nlfilter").compare(D1, ["ekf"], 5, paths=4, block=0, **_P), "block"),
    ("fit params0 nan", lambda: __import__("nlfilter").fit(DA, _YS, {a: nan}, **_P), ("params0", "a")),
    ("fit unknown parameter", lambda: __import__("nlfilter").fit(DA, _YS, {xa: 0.5}, **_P), ("params0", "xa")),
    ("fit ys complex", lambda: __import__("nlfilter").fit(DA, _YS * 1j, {a: 0.5}, **_P), "ys"),
    ("fit filter bogus", lambda: __import__("nlfilter").fit(DA, _YS, {a: 0.5}, filter="bogus", **_P), "filter"),
    ("fit bounds reversed", lambda: __import__("nlfilter").fit(DA, _YS, {a: 0.5}, bounds={a: (1.0, 0.0)}, **_P),
     ("bounds", "a")),
    ("fit_em iterations 0", lambda: __import__("nlfilter").fit_em(_YS, [[0.9]], [[1.0]], [[0.1]], [[0.2]], [0.5],
                                                                  [[0.2]], iterations=0), "iterations"),
    ("fit_em Q negative", lambda: __import__("nlfilter").fit_em(_YS, [[0.9]], [[1.0]], [[-0.1]], [[0.2]], [0.5],
                                                                [[0.2]]), "Q"),
    ("with_params nan", lambda: DA.with_params({a: nan}), "a"),
    ("with_params complex", lambda: DA.with_params({a: 1j}), "a"),
    ("with_params unknown", lambda: DA.with_params({xa: 1.0}), "xa"),
    ("with_params per-path wrong shape", lambda: EKF(DA.with_params({a: np.ones((2, 3, 4))})).run(_YS, **_P),
     ("a", "params")),
    ("with_inputs nan", lambda: DU.with_inputs(np.full((6, 1), nan)), ("u", "inputs")),
    ("with_inputs wrong width", lambda: DU.with_inputs(np.zeros((6, 3))), ("u", "inputs")),
    ("with_inputs too short", lambda: EKF(DU.with_inputs(np.zeros((2, 1)))).run(_YS, **_P), ("u", "inputs")),
    ("smooth ys complex", lambda: EKF(D1).smooth(_YS * 1j, **_P), "ys"),
    ("smooth P0 negative", lambda: EKF(D1).smooth(_YS, m0=[0.5], P0=[[-1.0]]), "P0"),
    ("loglik replicates 0", lambda: __import__("nlfilter").evaluate.loglik(EKF(D1), _YS, replicates=0, **_P),
     "replicates"),
    ("load_model missing file", lambda: __import__("nlfilter").load_model("/nonexistent/model.toml"), "model.toml"),
    ("load_model None", lambda: __import__("nlfilter").load_model(None), "path"),
]


@pytest.mark.parametrize("label,make,names", COMPOSE, ids=[c[0] for c in COMPOSE])
def test_bad_composition_input_is_refused_naming_it(fuzz, label, make, names):
    fuzz.check("compare, fit, params, inputs", make, names, label=label)


# -- fit on bad input and bad likelihoods (issue 26 item 3) --------------------------------------------
def _fit(**kw):
    """``fit`` of DA's ``a`` on the shared records, the Kalman likelihood; ``kw`` overrides."""
    args = dict(model=DA, ys=_YS, params0={a: 0.5}, filter="kf", se=False, **_P)
    args.update(kw)
    return __import__("nlfilter").fit(args.pop("model"), args.pop("ys"), args.pop("params0"), **args)


def _finite_fit(res):
    """What of a FitResult must be finite (its standard errors only where it says they exist)."""
    return res.loglik, res.params, (res.se if res.se_ok else None)


def _not_converged(res, why):
    """A fit that must not claim convergence, and must say ``why``: else an AssertionError (raw)."""
    if res.converged or why not in res.message:
        raise AssertionError(f"fit claimed {res.converged=} with message {res.message!r}; expected {why!r}")
    return _finite_fit(res)


_q = sp.Symbol("q", positive=True)
DEG = DiscreteModel([x], [0.9 * x], [x], Q=[[_q]], R=0.0, params={_q: 0.3})
FIT = [
    *[(f"fit bounds {b!r}", lambda b=b: _fit(bounds={a: b}), ("bounds", "a"))
      for b in ((nan, 1.0), (inf, None), (None, -inf), (1.0, 1.0), ("x", None), (0.0, [1]), 3, (0.0,), None,
                (-1e308, 1e308), (0.5, 1.0), (True, None))],
    ("fit bounds list", lambda: _fit(bounds=[(0, 1)]), "bounds"),
    ("fit bounds unknown name", lambda: _fit(bounds={"zz": (0, 1)}), "bounds"),
    *[(f"fit params0 {v!r}", lambda v=v: _fit(params0={a: v}), ("params0", "a"))
      for v in ("x", None, [1, 2], 1j, inf, -inf, True, np.array([0.5, 0.6]))],
    ("fit params0 empty", lambda: _fit(params0={}), "params0"),
    ("fit params0 list", lambda: _fit(params0=[0.5]), "params0"),
    *[(f"fit options {o!r}", lambda o=o: _fit(options=o), "options")
      for o in ({"maxiter": "a"}, {"maxiter": 0}, {"maxiter": 2.5}, {"bogus": 1}, {"xatol": 1e-3}, [1],
                {"ftol": -1.0}, {"ftol": nan}, {"disp": "yes"}, {"gtol": inf})],
    ("fit options Nelder-Mead maxfun", lambda: _fit(method="Nelder-Mead", options={"maxfun": 10}), "options"),
    *[(f"fit method {m!r}", lambda m=m: _fit(method=m), "method") for m in ("bogus", 3, None, "trust-exact")],
    ("fit filter_options list", lambda: _fit(filter_options=[1]), "filter_options"),
    ("fit filter_options with a callable", lambda: _fit(filter=lambda md: EKF(md), filter_options={"x": 1}),
     "filter_options"),
    ("fit filter_options start conflict", lambda: _fit(filter="ekf", start="predict", filter_options={"start": "update"}),
     "filter_options"),
    ("fit start bogus", lambda: _fit(start="bogus"), "start"),
    ("fit se string", lambda: _fit(se="yes"), "se"),
    ("fit progress 1", lambda: _fit(progress=1), "progress"),
    ("fit backend bogus", lambda: _fit(backend="bogus"), "backend"),
    ("fit options Nelder-Mead maxfev 0", lambda: _fit(method="Nelder-Mead", options={"maxfev": 0}), "options"),
    ("fit start conflicts with the Simulation", lambda: _fit(ys=_SIM, start="predict"), "start"),
    ("fit dt on a discrete Simulation", lambda: _fit(ys=_SIM, dt=0.1), "dt"),
    ("fit ys all missing", lambda: _fit(ys=np.full((3, 6, 1), nan)), "ys"),
    ("fit ys Simulation all missing", lambda: _fit(ys=_SIM._replace(ys=np.full((3, 6, 1), nan))), "ys"),
    ("fit ys inf", lambda: _fit(ys=np.full((3, 6, 1), inf)), "ys"),
    ("fit ys 1-D", lambda: _fit(ys=np.zeros(6)), "ys"),
    ("fit_em one step", lambda: __import__("nlfilter").fit_em(_YS[:, :1], [[0.9]], [[1.0]], [[0.1]], [[0.2]], [0.5],
                                                              [[0.2]]), "ys"),
    ("fit_em F unidentified", lambda: __import__("nlfilter").fit_em(np.zeros((1, 2, 1)), [[0.9]], [[1.0]], [[0.1]],
                                                                    [[0.2]], [0.0], [[0.0]], iterations=3), ("ys", "F")),
]
FIT_EXTREME = [
    ("fit degenerate likelihood (variance to 0)",
     lambda: _not_converged(_fit(model=DEG, ys=(2.0 * 0.9 ** np.arange(30))[None, :, None], params0={"q": 0.5},
                                 m0=[2.0], P0=[[1.0]]), "degenerate"), "q"),
    ("fit from a start far out", lambda: _finite_fit(_fit(params0={a: 50.0})), "a"),
    ("fit infinite bounds", lambda: _finite_fit(_fit(bounds={a: (-inf, inf)})), "a"),
    ("fit half-open infinite bound", lambda: _finite_fit(_fit(bounds={a: (0.0, inf)})), "a"),
    ("fit huge data", lambda: _finite_fit(_fit(ys=_YS * 1e150)), ("ys", "params0")),
    ("fit mostly missing", lambda: _finite_fit(_fit(ys=np.where(np.arange(6)[None, :, None] == 2, _YS, nan))), "ys"),
]


@pytest.mark.parametrize("label,make,names", FIT, ids=[c[0] for c in FIT])
def test_bad_fit_input_is_refused_naming_it(fuzz, label, make, names):
    fuzz.check("fit", make, names, label=label)


@pytest.mark.parametrize("label,make,names", FIT_EXTREME, ids=[c[0] for c in FIT_EXTREME])
def test_extreme_fit_is_handled_honestly(fuzz, label, make, names):
    fuzz.check("fit", make, names, bad=False, label=label)


_BOUND = hst.one_of(hst.none(), hst.floats(allow_nan=True, allow_infinity=True), hst.integers(-3, 3), hst.text(max_size=2),
                    hst.booleans())


@settings(max_examples=15, deadline=None, suppress_health_check=list(HealthCheck))
@given(lo=_BOUND, hi=_BOUND, start=hst.one_of(hst.floats(-2, 2), hst.floats(allow_nan=True, allow_infinity=True)))
def test_fit_bounds_and_starts_fuzzed(fuzz, lo, hi, start):
    """Any bounds pair and starting value: a named refusal, or a fit whose numbers are finite."""
    fuzz.check("fit", lambda: _finite_fit(_fit(bounds={a: (lo, hi)}, params0={a: start})), ("bounds", "params0", "a"),
                 bad=False, label=f"bounds ({lo!r}, {hi!r}), start {start!r}")


# -- the data's timing convention against the filter's (issue 25 item 3) -------------------------------
def _timing_cases():
    from nlfilter.evaluate import loglik
    from nlfilter.filters.ekf import ContinuousDiscreteEKF
    sde_sim = S.simulate(SDE1, 5, paths=2, rng=1, m0=[0.5], P0=[[0.2]], dt=0.1, t0=1.0)
    cd_sim = S.simulate_continuous_discrete(SDE1, 5, paths=2, rng=1, m0=[0.5], P0=[[0.2]], dt=0.1)
    return [
        ("run start conflicts", lambda: EKF(D1, start="predict").run(_SIM, **_P), "start"),
        ("smooth start conflicts", lambda: EKF(D1, start="predict").smooth(_SIM, **_P), "start"),
        ("loglik start conflicts", lambda: loglik(EKF(D1, start="predict"), _SIM, **_P), "start"),
        ("run CD filter on discrete data", lambda: ContinuousDiscreteEKF(SDE1, 0.1).run(_SIM, **_P), "ys"),
        ("run CD filter on increments", lambda: ContinuousDiscreteEKF(SDE1, 0.1).run(sde_sim, **_P), "ys"),
        ("run CD filter dt conflicts", lambda: ContinuousDiscreteEKF(SDE1, 0.2).run(cd_sim, **_P), "dt"),
        ("run CD filter t0 conflicts", lambda: ContinuousDiscreteEKF(SDE1, 0.1, t0=2.0).run(cd_sim, **_P), "t0"),
        ("run CD filter start conflicts", lambda: ContinuousDiscreteEKF(SDE1, 0.1, start="update").run(cd_sim, **_P),
         "start"),
        ("run continuous filter on CD data", lambda: KalmanBucy(SDE1, 0.1).run(cd_sim, **_P), "ys"),
        ("run continuous filter t0 conflicts", lambda: KalmanBucy(SDE1, 0.1).run(sde_sim, t0=0.0, **_P), "t0"),
        ("run continuous filter dt conflicts", lambda: KalmanBucy(SDE1, 0.05).run(sde_sim, **_P), "dt"),
        ("run discrete filter on increments", lambda: EKF(D1).run(sde_sim, **_P), "ys"),
        ("Simulation timing not a Timing", lambda: S.Simulation(*_SIM, timing="predict"), "timing"),
    ]


TIMING = _timing_cases()


@pytest.mark.parametrize("label,make,names", TIMING, ids=[c[0] for c in TIMING])
def test_conflicting_timing_is_refused_naming_it(fuzz, label, make, names):
    fuzz.check("timing convention", make, names, label=label)
