"""Angular components (``angles=``, :mod:`nlfilter.angles`): a range–bearing track whose bearing
crosses ±π several times, filtered by every Gaussian rule, the square-root forms, the IMM, the
smoothers and the reference filters, each compared with its own run on the same track rotated
by a constant angle so that it never crosses.

Why 1e-10: the rotated problem is the same problem with every angle shifted by α, so each filter
computes the same numbers up to rounding (the node rules' points shift by α exactly, a circular
mean is rotation-equivariant, every residual is wrapped): the differences measured are at most
1.2e-14 in the means and covariances and 6e-14 in the log-likelihood (a sum of 30 terms). The grid filter is rotated by a whole
number of cells (its points on the circle are then permuted exactly); the particle filter draws the
same noises (common random numbers) for the rotated clouds, and its resampling reads only the
weights, which agree to rounding.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel
from nlfilter.angles import (NO_ANGLES, Angles, circular_mean, declare, mixture, near, residual, weighted_moments,
                             wrap)
from nlfilter.evaluate import mse, nees
from nlfilter.filters import EKF, REGISTRY, GridFilter, ParticleFilter
from nlfilter.filters.fixed_lag import fixed_lag
from nlfilter.modelfile import ModelFileError, load_model
from nlfilter.simulate import simulate

TOL = 1e-10
ALPHA = -3.0  # the rotation: the bearings π ± 0.8 become −0.66..0.94, far from ±π
th, r, v = sp.symbols("th r v")


def _model(angles=True):
    """Bearing ``th`` (an angle), range ``r``, tangential speed ``v``; range and a bearing with a
    speed-dependent offset measured (polynomial, so that the SLF applies too)."""
    k = 0.2 - 0.01 * r  # ≈ 1/r near r = 10
    return DiscreteModel([th, r, v], [th + v * k, r, v], [r, th + 0.3 * v * k], Q=np.diag([0.02, 0.01, 1.0]),
                         R=np.diag([0.02, 0.02]), angles={"states": [th], "measurements": [1]} if angles else None)


def _track(alpha=0.0, T=30, B=2):
    """The bearing π + 0.8 sin(k/2) (crossing ±π five times in 30 steps) at range 10, measured with
    the model's noise; everything rotated by ``alpha``."""
    k = np.arange(T + 1)
    bearing = np.pi + 0.8 * np.sin(0.5 * k)
    speed = 10.0 * np.diff(bearing)
    e = np.random.default_rng(1).normal(0.0, np.sqrt(0.02), (B, T, 2))
    ys = np.stack([10.0 + e[..., 0], wrap(bearing[:-1] + 0.03 * speed + alpha + e[..., 1])], axis=-1)
    truth = np.stack([wrap(bearing[:-1] + alpha), np.full(T, 10.0), speed], axis=-1)
    return ys, np.array([wrap(np.pi + alpha), 10.0, 0.0]), np.diag([0.05, 0.1, 2.0]), truth


def _crossings(a):
    return int(np.sum(np.abs(np.diff(a)) > np.pi))


def _same(e0, e1, alpha, what):
    """``e1`` is ``e0`` rotated by ``alpha`` (angle component 0): means, covariances to TOL."""
    d = np.abs(wrap(e1.means[..., 0] - alpha - e0.means[..., 0])).max()
    rest = np.abs(e1.means[..., 1:] - e0.means[..., 1:]).max()
    dc = np.abs(e1.covs - e0.covs).max()
    assert d <= TOL and rest <= TOL and dc <= TOL, (what, d, rest, dc)


def test_track_crosses():
    assert _crossings(_track()[3][:, 0]) == 5 and _crossings(_track(ALPHA)[3][:, 0]) == 0


GAUSSIAN = ["ekf", "iekf", "ukf", "ckf", "ghkf", "slf", "ckf5", "second-order", "sr-ekf", "sr-ukf", "sr-ckf",
            "sr-ghkf", "sr-slf", "sr-iekf", "imm"]


@pytest.mark.parametrize("name", GAUSSIAN)
def test_gaussian_filters_rotation(name):
    """Filter (with log-likelihood) and RTS smoother: no jump at the crossings (the wrapped error
    stays below 0.35 rad, the bearing's noise 0.14), every mean in (−π, π], and the rotated run
    equal to TOL."""
    flt = REGISTRY[name](_model())
    y0, m0, P0, x0 = _track()
    y1, m1, P1, _ = _track(ALPHA)
    e0, e1 = flt.run(y0, m0, P0, loglik=True), flt.run(y1, m1, P1, loglik=True)
    _same(e0, e1, ALPHA, name)
    assert np.abs(e0.loglik - e1.loglik).max() <= TOL * np.abs(e0.loglik).max()
    s0, s1 = flt.smooth(y0, m0, P0), flt.smooth(y1, m1, P1)
    _same(s0, s1, ALPHA, name + " smoothed")
    for e in (e0, s0):
        assert np.abs(wrap(e.means[..., 0] - x0[:, 0])).max() < 0.35
        assert np.all((e.means[..., 0] > -np.pi) & (e.means[..., 0] <= np.pi))


def test_undeclared_angle_jumps():
    """The same EKF without the declaration loses the track at the first crossing (the innovation
    of a bearing across ±π is ~2π): what the declaration prevents."""
    y0, m0, P0, x0 = _track()
    e = EKF(_model(angles=False)).run(y0, m0, P0)
    assert np.abs(wrap(e.means[..., 0] - x0[:, 0])).max() > 1.0


def test_fixed_lag_and_sampler_rotation():
    from nlfilter import sample_posterior
    flt = REGISTRY["ukf"](_model())
    y0, m0, P0, _ = _track(T=12)
    y1, m1, P1, _ = _track(ALPHA, T=12)
    _same(fixed_lag(flt, y0, m0, P0, lag=3), fixed_lag(flt, y1, m1, P1, lag=3), ALPHA, "fixed-lag")
    d0, d1 = sample_posterior(flt, y0, m0, P0, n=3, rng=5), sample_posterior(flt, y1, m1, P1, n=3, rng=5)
    assert np.abs(wrap(d1[..., 0] - ALPHA - d0[..., 0])).max() <= TOL
    assert np.all(np.abs(d0[..., 0]) <= np.pi)


# -- the reference filters: a 2-D model (the grid's limit) ------------------------------------------
om = sp.Symbol("om")
MODEL2 = DiscreteModel([th, om], [th + om, 0.9 * om], [th + 0.2 * om * om], Q=np.diag([0.01, 0.05]), R=[[0.02]],
                       angles={"states": [th], "measurements": [0]})
CELLS = 60  # grid points on the circle; the rotation is 29 cells (−2.9 rad)


def _track2(alpha, T=20, B=2):
    k = np.arange(T + 1)
    bearing = np.pi + 0.8 * np.sin(0.5 * k)
    rate = np.diff(bearing)
    e = np.random.default_rng(3).normal(0.0, np.sqrt(0.02), (B, T, 1))
    ys = wrap(bearing[:-1, None] + 0.2 * rate[:, None] ** 2 + alpha + e)
    return ys, np.array([wrap(np.pi + alpha), 0.0]), np.diag([0.1, 0.2]), np.stack([wrap(bearing[:-1] + alpha), rate], -1)


@pytest.mark.parametrize("kind", ["grid", "particle"])
def test_reference_filters_rotation(kind):
    alpha = -2 * np.pi * 29 / CELLS
    flt, kw = ((GridFilter(MODEL2, [(-np.pi, np.pi), (-2.5, 2.5)], size=(CELLS, 31)), {}) if kind == "grid"
               else (ParticleFilter(MODEL2, 200), {"rng": 0}))
    y0, m0, P0, x0 = _track2(0.0)
    y1, m1, P1, x1 = _track2(alpha)
    assert _crossings(x0[:, 0]) == 4 and _crossings(x1[:, 0]) == 0
    e0, e1 = flt.run(y0, m0, P0, loglik=True, **kw), flt.run(y1, m1, P1, loglik=True, **kw)
    _same(e0, e1, alpha, kind)
    assert np.abs(e0.loglik - e1.loglik).max() <= TOL * np.abs(e0.loglik).max()
    s0, s1 = flt.smooth(y0, m0, P0, **kw), flt.smooth(y1, m1, P1, **kw)
    _same(s0, s1, alpha, kind + " smoothed")
    for e in (e0, s0):  # no jump: the error stays at the grid's spacing and the noise's scale
        assert np.abs(wrap(e.means[..., 0] - x0[:, 0])).max() < 0.45
    # MSE and NEES on wrapped errors: the crossing run equals the rotated one
    x0, x1 = np.broadcast_to(x0, e0.means.shape), np.broadcast_to(x1, e1.means.shape)
    assert abs(mse(e0, x0, angles=(0,)).value - mse(e1, x1, angles=(0,)).value) <= TOL
    assert mse(e0, x0, angles=(0,)).value < 0.05 < mse(e0, x0).value
    assert abs(nees(e0, x0, angles=(0,)).value - nees(e1, x1, angles=(0,)).value) <= 1e-8


def test_grid_axis_must_be_the_circle():
    with pytest.raises(ValueError, match=r"bounds: state 0 is an angle.*\(-pi, pi\).*\(-3\.0, 3\.0\)"):
        GridFilter(MODEL2, [(-3.0, 3.0), (-2.5, 2.5)], size=11)


def test_simulation_wraps():
    sim = simulate(MODEL2, 40, paths=3, rng=2, m0=[3.0, 0.5], P0=np.diag([0.01, 0.01]))
    for a in (sim.xs[..., 0], sim.ys[..., 0]):
        assert np.all((a > -np.pi) & (a <= np.pi))
    assert _crossings(sim.xs[0, :, 0]) >= 1  # a rate near 0.5 rad/step turns the bearing over ±π


def test_compiled_backend_refuses_angles_auto_falls_back():
    from nlfilter.filters.compiled.support import static_refusal
    flt = EKF(MODEL2)
    assert "angles" in static_refusal(flt)
    y0, m0, P0, _ = _track2(0.0)
    a, b = flt.run(y0, m0, P0, backend="auto"), flt.run(y0, m0, P0, backend="numpy")
    assert np.array_equal(a.means, b.means)


# -- the module's functions -------------------------------------------------------------------------
def test_wrap_mean_residual():
    assert wrap(np.pi) == np.pi and wrap(-np.pi) == np.pi and abs(wrap(7.0) - (7.0 - 2 * np.pi)) < 1e-15
    X = np.array([[3.0, 1.0], [-3.0, 3.0]])
    m = circular_mean(X, np.array([0.5, 0.5]), (0,))
    assert abs(m[0] - np.pi) < 1e-15 and m[1] == 2.0  # the mean of ±3 rad is π, not 0
    assert abs(residual(np.array([-3.0]), np.array([3.0]), (0,))[0] - (2 * np.pi - 6.0)) < 1e-15
    assert abs(near(np.array([3.0]), np.array([-3.0]), (0,))[0] - (3.0 - 2 * np.pi)) < 1e-15
    mean, cov = weighted_moments(np.array([0.5, 0.5]), X, (0,))
    assert abs(cov[0, 0] - (np.pi - 3.0) ** 2) < 1e-14  # deviations ±(π − 3), wrapped
    mm, mc = mixture(np.array([0.5, 0.5]), X, np.zeros((2, 2, 2)), (0,))
    assert np.allclose(mm, mean, rtol=0, atol=1e-15) and np.allclose(mc, cov, rtol=0, atol=1e-15)


def test_declaration():
    assert declare(None, 3, 2) is NO_ANGLES and not NO_ANGLES
    assert declare({"states": [th, "v"], "measurements": [1]}, 3, 2, [th, r, v]) == Angles((0, 2), (1,))
    assert declare([2], 3, 2) == Angles((2,), ())
    assert _model().angles == Angles((0,), (1,))
    bad = [({"states": ["psi"]}, ValueError, "got the states component 'psi', which does not exist"),
           ({"measurements": [2]}, ValueError, "measurements component 2, which does not exist.*0 to 1"),
           ({"states": [3]}, ValueError, "states component 3"),
           ({"state": [0]}, ValueError, "unknown key"),
           ({"states": [0, "th"]}, ValueError, "repeats"),
           ({"states": [True]}, TypeError, "bool"),
           ("th", TypeError, "expected a dict")]
    for given, exc, msg in bad:
        with pytest.raises(exc, match="^angles: .*" + msg):
            DiscreteModel([th, r, v], [th, r, v], [r, th], Q=np.eye(3), R=np.eye(2), angles=given)


TOML = """
[model]
kind = "discrete"
states = ["th", "om"]
angles = {ANGLES}
[dynamics]
f = ["th + om", "0.9*om"]
Q = [[0.01, 0], [0, 0.05]]
[measurement]
h = ["th + 0.2*om**2"]
R = [[0.02]]
[prior]
mean = [3.0, 0.0]
cov = [0.1, 0.2]
"""


def test_model_file(tmp_path):
    p = pathlib.Path(tmp_path, "bearing.toml")
    p.write_text(TOML.replace("{ANGLES}", '{ states = ["th"], measurements = [0] }'))
    spec = load_model(p)
    assert spec.model.angles == MODEL2.angles
    y0, _, _, _ = _track2(0.0, T=5)
    a = EKF(spec.model).run(y0, spec.m0, spec.P0)
    b = EKF(MODEL2).run(y0, spec.m0, spec.P0)
    assert np.array_equal(a.means, b.means)
    p.write_text(TOML.replace("{ANGLES}", '{ states = ["psi"] }'))
    with pytest.raises(ModelFileError, match=r"bearing\.toml:5: model\.angles: got the states component 'psi'"):
        load_model(p)


def test_compare_on_angles():
    """``compare`` on a bearing that turns over ±π many times (rate ≈ 0.5 rad/step over 30 steps):
    MSE and NEES from wrapped errors — the EKF's bearing MSE is its noise level, its NEES ≈ n = 2
    (an unwrapped error of 2π at each crossing would make both ~10-100× larger)."""
    from nlfilter import compare
    res = compare(MODEL2, ["ekf"], 30, paths=16, m0=[3.0, 0.5], P0=np.diag([0.05, 0.05]), rng=1)
    got = {(r.quantity, r.params.get("component")): r.value for r in res.rows if r.filter == "ekf"}
    assert got[("mse", 0)] < 0.05 and 1.0 < got[("nees", None)] < 3.5


@pytest.mark.parametrize("name", ["kf", "sr-kf"])
def test_kalman_filters_rotation(name):
    """The Kalman filters on a linear bearing-and-rate model: filter, log-likelihood and RTS smoother
    equal to their rotated runs to TOL (measured ≤ 1e-14)."""
    linear = DiscreteModel([th, om], [th + om, 0.9 * om], [th], Q=np.diag([0.01, 0.05]), R=[[0.02]],
                           angles={"states": [th], "measurements": [0]})
    flt = REGISTRY[name](linear)
    y0, m0, P0, x0 = _track2(0.0)
    y1, m1, P1, _ = _track2(ALPHA)
    e0, e1 = flt.run(y0, m0, P0, loglik=True), flt.run(y1, m1, P1, loglik=True)
    _same(e0, e1, ALPHA, name)
    assert np.abs(e0.loglik - e1.loglik).max() <= TOL * np.abs(e0.loglik).max()
    _same(flt.smooth(y0, m0, P0), flt.smooth(y1, m1, P1), ALPHA, name + " smoothed")
    assert np.abs(wrap(e0.means[..., 0] - x0[:, 0])).max() < 0.45
    if name == "kf":  # the prediction wraps too: 3.1 + 0.2 -> 3.3 - 2π
        from nlfilter.filters.base import GaussianState
        pred = flt.predict(GaussianState(np.array([3.1, 0.2]), 0.1 * np.eye(2)), 0)
        assert pred.mean[0] == pytest.approx(3.3 - 2 * np.pi, abs=1e-12)


def test_filters_without_angles_refuse_them():
    """A filter that does not treat angles refuses the model at construction, naming ``angles``
    (its ``structures``): never a silent jump at ±π."""
    from nlfilter import SDEModel
    with pytest.raises(ValueError, match=r"^angles: the model declares angular components.*DiscreteConditionalMomentFilter"):
        REGISTRY["discrete-conditional-moment"](MODEL2)
    sde = SDEModel([th], [-0.1 * th], [th], Q=0.1, R=0.1, angles={"states": [th]})
    with pytest.raises(ValueError, match=r"^angles: .*ContinuousEKF"):
        REGISTRY["continuous-ekf"](sde, 0.1)


@pytest.mark.parametrize("name", ["particle", "grid"])
def test_reference_refuses_angular_increments(name):
    """On an SDEModel the grid and particle references read increments dy = h dt + dη, which are not
    angles: a bearing declared angular is refused naming ``angles`` (angular states are taken)."""
    from nlfilter import SDEModel
    sde = SDEModel([th], [-0.1 * th], [th], Q=0.1, R=0.1, angles={"states": [th], "measurements": [0]})
    args = (sde,) if name == "particle" else (sde, [(-np.pi, np.pi)])
    with pytest.raises(ValueError, match=r"^angles: .*increments.*\[0\]"):
        REGISTRY[name](*args, dt=0.1)
    states_only = SDEModel([th], [-0.1 * th], [th], Q=0.1, R=0.1, angles={"states": [th]})
    assert REGISTRY[name](*((states_only,) + args[1:]), dt=0.1).time == "continuous"


def test_augmented_ukf_rotation():
    """The UKF's augmented sigma points (noise entering f non-additively) average circularly too."""
    w = sp.Symbol("w")
    md = DiscreteModel([th, om], [th + om + w, 0.9 * om], [th + 0.2 * om * om], noise=[w], Q=[[0.01]], R=[[0.02]],
                       angles={"states": [th], "measurements": [0]})
    flt = REGISTRY["ukf"](md)
    assert flt.augmented
    y0, m0, P0, x0 = _track2(0.0)
    y1, m1, P1, _ = _track2(ALPHA)
    e0, e1 = flt.run(y0, m0, P0, loglik=True), flt.run(y1, m1, P1, loglik=True)
    _same(e0, e1, ALPHA, "augmented ukf")
    assert np.abs(e0.loglik - e1.loglik).max() <= TOL * np.abs(e0.loglik).max()
    assert np.abs(wrap(e0.means[..., 0] - x0[:, 0])).max() < 0.5


@pytest.mark.parametrize("form", ["gaussian", "modified"])
def test_second_order_forms_rotation(form):
    """Seed 004's forms with a forcing tensor (gaussian) and the −¼ innovation term (modified):
    their Taylor terms at the wrapped innovation. (truncated-jazwinski loses definiteness on this
    model at step 1 with or without angles, on the rotated track as well: that form's own limit.)"""
    from nlfilter.filters.second_order import SecondOrderFilter
    flt = SecondOrderFilter(MODEL2, form=form)
    y0, m0, P0, x0 = _track2(0.0)
    y1, m1, P1, _ = _track2(ALPHA)
    e0, e1 = flt.run(y0, m0, P0, loglik=True), flt.run(y1, m1, P1, loglik=True)
    _same(e0, e1, ALPHA, form)
    assert np.abs(e0.loglik - e1.loglik).max() <= TOL * np.abs(e0.loglik).max()
    assert np.abs(wrap(e0.means[..., 0] - x0[:, 0])).max() < 0.5


@pytest.mark.parametrize("name", ["continuous-discrete-ekf", "continuous-discrete-ukf"])
def test_continuous_discrete_rotation(name):
    """An SDE's bearing measured every 0.5: the moment ODE's mean wrapped at each measurement."""
    from nlfilter import SDEModel
    sde = SDEModel([th, om], [om, -0.2 * om], [th + 0.2 * om * om], Q=np.diag([0.02, 0.1]), R=[[0.02]],
                   angles={"states": [th], "measurements": [0]})
    flt = REGISTRY[name](sde, 0.5, substeps=2)
    y0, m0, P0, x0 = _track2(0.0)
    y1, m1, P1, _ = _track2(ALPHA)
    e0, e1 = flt.run(y0, m0, P0, loglik=True), flt.run(y1, m1, P1, loglik=True)
    _same(e0, e1, ALPHA, name)
    _same(flt.smooth(y0, m0, P0), flt.smooth(y1, m1, P1), ALPHA, name + " smoothed")
    assert np.abs(e0.loglik - e1.loglik).max() <= TOL * np.abs(e0.loglik).max()
