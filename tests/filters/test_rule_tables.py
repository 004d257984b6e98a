"""The rules as tables (issue 27, item 1), tested against their defining conditions as scipy's
``test_rk.py`` tests a Runge–Kutta tableau: every node rule's ``unit_nodes(n) -> (z, wm, wc)`` for
n = 1..5 (Gauss–Hermite: orders 1..5, n = 1..3), and, driven by the registry, every registered
filter over a node or Taylor rule equal to the Kalman filter on a linear-Gaussian model.

Tolerances. A table's moment ``Σ_i w_i Π_j z_ij^a_j`` is a sum of at most 125 terms: its rounding is
at most ``N·eps·Σ|w_i z_i^a|`` (≈ 3e-14 of that scale), so the tests allow 1e-12 of it; a moment that
is *not* exact is off by O(1) (the smallest miss here is 0.5), so "not exact" means off by more than
1e-6. The filters on the linear model: see :func:`test_every_rule_filter_is_the_kalman_filter`.
"""

from __future__ import annotations

import functools
import inspect
import itertools
import math
import pickle

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel
from nlfilter.errors import DivergenceError
from nlfilter.filters import REGISTRY, GaussianFilter, GaussianState, KalmanBucy, KalmanFilter
from nlfilter.filters import rules
from nlfilter.filters.rule_filter import RuleFilter, rule_filter
from nlfilter.filters.rules import FORM_TABLE, Cubature, Cubature5, GaussHermite, NodeRule, Taylor2, Unscented
from nlfilter.filters.square_root import SquareRootFilter
from nlfilter.simulate import simulate
from tests.filters.test_rules import _exact_discretization  # Van Loan's exact discretization, one copy

NS = (1, 2, 3, 4, 5)
#: (rule, exact degree, per_axis): a total-degree rule integrates every monomial of total degree ≤ d
#: exactly; a tensor (per-axis) rule every monomial with each exponent ≤ d
TABLES = [(Unscented(), 3, False, NS), (Unscented(0.5, 2.0, 1.0), 3, False, NS),
          (Unscented(1.0, 0.0, 1.0), 3, False, NS), (Cubature(), 3, False, NS), (Cubature5(), 5, False, NS),
          *[(GaussHermite(k), 2 * k - 1, True, (1, 2, 3)) for k in range(1, 6)]]
IDS = [f"{r!r}" for r, *_ in TABLES]


def _normal_moment(a: int) -> float:
    """``E[z^a]`` for z ~ N(0, 1): 0 for odd a, (a − 1)!! for even a."""
    return 0.0 if a % 2 else float(math.prod(range(a - 1, 0, -2)))


def _moment(z, w, alpha):
    """``(Σ_i w_i Π_j z_ij^α_j, its rounding scale Σ_i |w_i Π_j z_ij^α_j|)``."""
    terms = w * np.prod(z ** np.asarray(alpha), axis=1)
    return terms.sum(), np.abs(terms).sum()


def _exact(z, w, alpha) -> bool:
    got, scale = _moment(z, w, alpha)
    want = math.prod(_normal_moment(a) for a in alpha)
    return abs(got - want) <= 1e-12 * max(1.0, scale)


def _monomials(n, degree, per_axis):
    """Exponent tuples: each ≤ degree (per_axis) or total ≤ degree."""
    for alpha in itertools.product(range(degree + 1), repeat=n):
        if per_axis or sum(alpha) <= degree:
            yield alpha


def test_every_node_rule_of_the_module_has_its_table_tested():
    """A new node rule of :mod:`nlfilter.filters.rules` cannot skip these conditions."""
    defined = {c for c in vars(rules).values() if isinstance(c, type) and issubclass(c, NodeRule) and c is not NodeRule}
    assert defined == {type(r) for r, *_ in TABLES}


@pytest.mark.parametrize("rule,degree,per_axis,ns", TABLES, ids=IDS)
def test_table_meets_its_defining_conditions(rule, degree, per_axis, ns):
    for n in ns:
        z, wm, wc = rule.unit_nodes(n)
        N = z.shape[0]
        assert z.shape == (N, n) and wm.shape == wc.shape == (N,)
        # read-only and cached: the compiled loop and every filter share one table
        assert not (z.flags.writeable or wm.flags.writeable or wc.flags.writeable)
        with pytest.raises(ValueError):
            wm[0] = 0.0
        assert rule.unit_nodes(n)[0] is z
        assert abs(wm.sum() - 1.0) <= 1e-14 * np.abs(wm).sum(), n  # weights sum to 1
        # odd moments vanish (a centrally symmetric table), to two degrees past the exact degree
        for alpha in _monomials(n, degree + 2, False):
            if sum(alpha) % 2:
                got, scale = _moment(z, wm, alpha)
                assert abs(got) <= 1e-12 * max(1.0, scale), (n, alpha)
        if degree >= 2:  # E[z zᵀ] = I with the covariance weights (the nodes' centre is z = 0)
            np.testing.assert_allclose(np.einsum("i,ia,ib->ab", wc, z, z), np.eye(n), rtol=0, atol=1e-13)
        # exact to its degree: every monomial against the standard normal moments ...
        bad = [a for a in _monomials(n, degree, per_axis) if not _exact(z, wm, a)]
        assert not bad, (n, bad[:5])
        # ... and not beyond: a monomial of the next degree is off by more than rounding
        nxt = ([(degree + 1,) + (0,) * (n - 1)] if per_axis
               else [a for a in _monomials(n, degree + 1, False) if sum(a) == degree + 1])
        misses = [abs(_moment(z, wm, a)[0] - math.prod(map(_normal_moment, a))) for a in nxt]
        assert max(misses) > 1e-6, (n, "exact beyond its stated degree")


@pytest.mark.parametrize("n", NS)
def test_covariance_weights(n):
    """``wc = wm`` for every table but the unscented centre: ``wc_0 = wm_0 + 1 − α² + β``
    (van der Merwe 2004), ``wm_0 = λ/(n + λ)``, ``λ = α²(n + κ) − n``."""
    for rule, *_ in TABLES:
        z, wm, wc = rule.unit_nodes(n) if not isinstance(rule, GaussHermite) or n <= 3 else (None,) * 3
        if z is None:
            continue
        if isinstance(rule, Unscented):
            a, b, k = rule.alpha, rule.beta, rule.kappa
            lam = a**2 * (n + k) - n
            assert not z[0].any() and wm[0] == pytest.approx(lam / (n + lam), abs=1e-15)
            assert wc[0] == pytest.approx(wm[0] + 1 - a**2 + b, abs=1e-15)
            np.testing.assert_array_equal(wc[1:], wm[1:])
        else:
            np.testing.assert_array_equal(wc, wm)


def test_cubature5_weights_and_dimensions():
    """Stroud's weights: positive up to n = 3, the axis weights 0 at n = 4 and negative from
    n = 5 (documented); n = 1 is Gauss–Hermite of order 3; n > 215 is refused, naming the rule."""
    for n in range(1, 8):
        z, w, _ = Cubature5().unit_nodes(n)
        axis = w[1:2 * n + 1]
        assert z.shape == (2 * n * n + 1, n) and w[0] == pytest.approx(2 / (n + 2), abs=1e-15)
        assert np.all(axis == axis[0]) and np.sign(axis[0]) == np.sign(4 - n)
    zg, wg, _ = GaussHermite(3).unit_nodes(1)
    z1, w1, _ = Cubature5().unit_nodes(1)
    order = np.argsort(z1[:, 0])
    np.testing.assert_allclose(z1[order], zg, atol=1e-14)
    np.testing.assert_allclose(w1[order], wg, atol=1e-14)
    Cubature5().check(215)
    with pytest.raises(ValueError, match=r"^rule: Cubature5 in n = 216"):
        Cubature5().check(216)


def test_cubature5_negative_weights_are_never_silent():
    """n = 6: under N(0, I) the rule gives g = x₁⁴ the variance −57 (the true one is 96); a filter
    measuring h = x₁⁴ fails that update (S screened) instead of going on with a wrong gain."""
    s = GaussianState(np.zeros(6), np.eye(6))
    mo = Cubature5().moments(s, lambda X, t: X[..., :1] ** 4, 0)
    np.testing.assert_allclose(mo.mean, [3.0], atol=1e-12)  # degree 4: exact
    np.testing.assert_allclose(mo.cov, [[-57.0]], atol=1e-11)  # Σ w x⁸ − 9 = −48 − 9
    lin = Cubature5().moments(s, lambda X, t: X[..., :2] @ np.array([[1.0, 2.0], [0.5, -1.0]]), 0)
    np.testing.assert_allclose(lin.cov, [[1.25, 1.5], [1.5, 5.0]], atol=1e-12)  # affine g: exact, PSD
    xs = sp.symbols("x1:7")
    md = DiscreteModel(list(xs), [0.9 * v for v in xs], [xs[0] ** 4], Q=0.1 * np.eye(6), R=1.0)
    with pytest.raises(DivergenceError):
        REGISTRY["ckf5"](md).run(np.ones((2, 3, 1)), np.zeros(6), np.eye(6))


# -- the registry: every filter over a node or Taylor rule is the Kalman filter on a linear model ---------
RC = np.array([[0.2, 0.08], [0.08, 0.1]])
LIN = DiscreteModel.linear([[0.95, 0.1], [-0.05, 0.9]], [[1.0, 0.5], [0.0, 1.0]], np.diag([0.1, 0.2]), RC)
x1, x2 = sp.symbols("x1 x2")
SLIN = SDEModel([x1, x2], [x2, -x1 - 0.5 * x2], [x1, x1 + x2], G=[[0.3, 0.0], [0.2, 0.7]], Q=np.eye(2), R=RC)
DT = 0.01  # continuous-discrete: RK4's error per step ≈ (‖A‖ dt)⁵/5! ≈ 2e-12, far below the tolerance
KINDS = ("taylor1", "nodes", "taylor2")
M0, P0 = np.array([0.3, -0.2]), np.array([[0.5, 0.1], [0.1, 0.4]])


def _model_alone(cls) -> bool:
    """Whether ``cls`` is built from a model (and dt) alone: its other parameters have defaults."""
    params = list(inspect.signature(cls).parameters.values())[1:]
    return all(p.default is not p.empty or (p.name == "dt" and p.kind == p.POSITIONAL_OR_KEYWORD) for p in params)


def _rule_filters():
    """``(name, build(**options), model, kind)`` of every registered filter over a rule whose
    ``kind`` is a node or Taylor rule, discovered by building each filter that accepts a
    discrete or SDE model from the model alone and reading its ``rule``."""
    out = []
    for name, cls in REGISTRY.items():
        model = LIN if "discrete" in cls.accepts else SLIN if "sde" in cls.accepts else None
        if model is None or not _model_alone(cls) or cls in (KalmanFilter, KalmanBucy):  # the references
            continue
        build = (lambda cls=cls, model=model, **kw: cls(model, **kw)) if model is LIN else (
            lambda cls=cls, model=model, **kw: cls(model, DT, **kw))
        kind = getattr(getattr(build(), "rule", None), "kind", None)
        if kind in KINDS:
            out.append((name, build, model, kind))
    return out


RULE_FILTERS = _rule_filters()


def test_discovery_finds_every_kind_and_every_rule_filter():
    """The discovery cannot pass by finding nothing: each kind is there, and every rule_filter line."""
    assert {k for *_, k in RULE_FILTERS} == set(KINDS)
    made = {n for n, c in REGISTRY.items() if issubclass(c, RuleFilter)}
    assert made and made <= {n for n, *_ in RULE_FILTERS}


def _data(model, continuous=False, T=25, paths=3):
    """Measurements of ``model``: samples (discrete, continuous-discrete) or increments (continuous)."""
    if continuous:
        ys = simulate(SLIN, T, paths=paths, rng=9, m0=M0, P0=P0, dt=DT).ys
    elif model is LIN:
        ys = simulate(LIN, T, paths=paths, rng=9, m0=M0, P0=P0).ys
    else:
        ys = simulate(_exact_discretization(SLIN, DT), T, paths=paths, rng=9, m0=M0, P0=P0, start="predict").ys
    ys[0, 4, 1] = np.nan  # partly missing (correlated R)
    ys[1, 6] = np.nan  # missing
    return ys


def _forms(name, build, kind):
    """The filter, and for a Taylor-2 filter that takes ``form`` one per form of FORM_TABLE."""
    if kind == "taylor2" and "form" in inspect.signature(REGISTRY[name]).parameters:
        return [(f"{name}[{form}]", lambda form=form: build(form=form)) for form in FORM_TABLE]
    return [(name, build)]


@pytest.mark.parametrize("name,build,model,kind", RULE_FILTERS, ids=[r[0] for r in RULE_FILTERS])
def test_every_rule_filter_is_the_kalman_filter(name, build, model, kind):
    """Means, covariances and log-likelihood equal the Kalman filter's: discrete filters the
    KalmanFilter of the model, continuous-discrete ones the KalmanFilter of the exact discretization
    (Van Loan), continuous-time ones the Kalman–Bucy filter. Outputs are O(0.1-10); a formula error
    (a Taylor-2 term that does not vanish, a weight off) moves them by 1e-3 or more. Tolerance
    1e-10 absolute where the filters differ from the reference by rounding only (the Joseph form,
    node sums: ~1e-15 per step over 25 steps); 1e-8 for the continuous-discrete filters, whose
    moment ODE is integrated by RK4 at dt = 0.01: measured 1.2e-10 (means), 1.5e-9 (log-likelihood),
    16 times less at two substeps (RK4's fourth order: integration error, not a formula's). The
    square-root continuous-discrete filters integrate the factor ODE, whose rate
    ``‖S⁻¹ G Q Gᵀ S⁻ᵀ‖ ≈ ‖G Q Gᵀ‖ / λ_min(P)`` is ~40 here (P's smallest eigenvalue 0.013 after the
    updates) where the covariance ODE's is ‖F‖ ≈ 1: at one substep they are within 1.2e-6 of the
    reference, falling 16x per doubling (7e-8, 4.2e-9); they run at 8 substeps (measured 2.6e-10
    on the means, 2.7e-9 on the log-likelihood)."""
    continuous = REGISTRY[name].time == "continuous"
    ys = _data(model, continuous)
    tol = 1e-10
    if continuous:
        ref = KalmanBucy(model, DT).run(ys, M0, P0, loglik=True)
    elif model is LIN:
        ref = KalmanFilter(LIN).run(ys, M0, P0, loglik=True)
    else:
        ref = KalmanFilter(_exact_discretization(SLIN, DT), start="predict").run(ys, M0, P0, loglik=True)
        tol = 1e-8
    if issubclass(REGISTRY[name], SquareRootFilter) and "sde" in REGISTRY[name].accepts:
        build = functools.partial(build, substeps=8)
    for label, make in _forms(name, build, kind):
        est = make().run(ys, M0, P0, loglik=True)
        for what in ("means", "covs"):
            np.testing.assert_allclose(getattr(est, what), getattr(ref, what), rtol=0, atol=tol, err_msg=label)
        np.testing.assert_allclose(est.loglik, ref.loglik, rtol=0, atol=tol, err_msg=label)


@pytest.mark.parametrize("form", list(FORM_TABLE))
def test_every_taylor2_form_through_the_skeleton_is_the_kalman_filter(form):
    """Every row of FORM_TABLE, as ``GaussianFilter(model, Taylor2(form))``: the second-order terms
    vanish on a linear model (exact, to the tolerance above)."""
    ys = _data(LIN)
    ref = KalmanFilter(LIN).run(ys, M0, P0, loglik=True)
    est = GaussianFilter(LIN, Taylor2(form)).run(ys, M0, P0, loglik=True)
    np.testing.assert_allclose(est.means, ref.means, rtol=0, atol=1e-10)
    np.testing.assert_allclose(est.covs, ref.covs, rtol=0, atol=1e-10)
    np.testing.assert_allclose(est.loglik, ref.loglik, rtol=0, atol=1e-10)


# -- rule_filter: the one registry line ---------------------------------------------------------------------
def test_rule_filter_class_is_a_registry_entry():
    cls = REGISTRY["ckf5"]
    assert issubclass(cls, RuleFilter) and cls.rule == Cubature5() and cls.name == "ckf5"
    assert (cls.family, cls.time, cls.accepts, cls.needs, cls.likelihood, cls.smoother) == (
        "gaussian", "discrete", ("discrete",), (), "prediction-error", "rts")
    assert "Jia" in cls.source and cls.__module__ == "nlfilter.filters.rule_filter"
    assert rule_filter(Cubature5(), name="ckf5", source=cls.source) is cls  # the same arguments: the same class
    flt = cls.for_model(LIN, start="predict")
    assert flt.rule == Cubature5() and flt.start == "predict"
    # pickles by reference (importing nlfilter.filters makes the class in any process), the instance
    # with its model's generated functions as the other filters do (cloudpickle: Dask, the store)
    import cloudpickle
    assert pickle.loads(pickle.dumps(cls)) is cls
    again = cloudpickle.loads(cloudpickle.dumps(flt))
    assert type(again) is cls and again.rule == flt.rule
    with pytest.raises(ValueError, match="^cls_name"):
        rule_filter(Cubature(), name="ckf5", source="x")  # CKF5 is another rule's class
    with pytest.raises(TypeError, match="^rule"):
        rule_filter("cubature", name="c", source="x")
    with pytest.raises(ValueError, match="^source"):
        rule_filter(Cubature5(), name="c5", source="")
    with pytest.raises(TypeError, match="^needs"):
        rule_filter(Taylor2(), name="t2", source="x")  # its needs depend on the model


def test_rule_filter_smoother_on_a_nonlinear_model_is_finite_and_improves_on_the_filter():
    """The RTS smoother through the rule: finite, and on simulated data its MSE below the filter's."""
    md = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2 - 0.05 * x1**3], [x1 + 0.1 * x2**2, x2],
                       Q=np.diag([0.1, 0.05]), R=RC)
    sim = simulate(md, 40, paths=20, rng=4, m0=M0, P0=P0)
    flt = REGISTRY["ckf5"](md)
    est, sm = flt.run(sim.ys, M0, P0), flt.smooth(sim.ys, M0, P0)
    assert np.isfinite(sm.means).all() and np.isfinite(sm.covs).all()
    assert ((sm.means - sim.xs) ** 2).mean() < ((est.means - sim.xs) ** 2).mean()
