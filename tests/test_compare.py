"""nlfilter.comparison (the function nlfilter.compare): every filter against the reference on common random numbers."""

import pathlib
import re
import textwrap
import warnings

import numpy as np
import pytest
import scipy.linalg as sla
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, compare
from nlfilter.errors import ReferenceWarning
from nlfilter.filters import EKF, UKF, ContinuousEKF, GridFilter, KalmanFilter, ParticleFilter

x = sp.Symbol("x")
A, Q, R = 0.9, 0.1, 0.5
LIN = DiscreteModel([x], f=[A * x], h=[x], Q=Q, R=R)
CUBIC = DiscreteModel([x], f=[0.99 * x], h=[x**3], Q=0.01, R=0.1)

# Grid discretization: the automatic grid has spacing ≤ σ/4 for the narrowest Gaussian it holds
# (σ ≥ 0.31 here: process noise √0.1; the filtered std √0.156 = 0.39), so the trapezoid sums
# behind its moments err by ~exp(-2π²(σ/h)²) < 1e-100, and its bounds lie ≥ 4 σ past every
# simulated state. 1e-6 is a generous allowance for that and for round-off.
GRID_TOL = 1e-6


@pytest.fixture(scope="module")
def linear():
    return compare(LIN, {"kf": KalmanFilter(LIN), "ekf": EKF(LIN)}, 200, paths=400, m0=0.0, P0=0.5, rng=0)


def _row(res, name, q, **kw):
    return res.get(name, q, **kw)


def test_linear_gaussian_kf_ekf_grid_riccati(linear):
    kf, ekf, opt = (_row(linear, k, "mse", component=0) for k in ("kf", "ekf", "optimal"))
    assert abs(kf.value - ekf.value) < 1e-12 and abs(kf.stderr - ekf.stderr) < 1e-12
    assert abs(kf.value - opt.value) < 3 * kf.stderr
    gap = _row(linear, "kf", "gap_to_optimal", component=0)
    assert abs(gap.value) < 3 * gap.stderr + GRID_TOL  # observed: ~3e-17 ± 3e-15
    # steady-state filtered variance from the predicted Riccati solution
    Pp = sla.solve_discrete_are(np.array([[A]]), np.array([[1.0]]), np.array([[Q]]), np.array([[R]]))[0, 0]
    Pf = Pp - Pp**2 / (Pp + R)  # 0.15570
    assert abs(kf.value - Pf) < 3 * kf.stderr  # observed 0.1561 ± 0.0017
    nees = _row(linear, "kf", "nees")
    assert abs(nees.value - 1.0) < 3 * nees.stderr
    assert _row(linear, "kf", "divergence_rate").value == 0.0
    p = linear.params
    assert (p["steps"], p["paths"], p["window"], p["seed"], p["reference"]["kind"]) == (200, 400, 0.5, 0, "grid")
    assert p["reference"]["certified"] is True and p["reference"]["label"] == "optimal"
    assert {"kf", "ekf", "optimal"} <= set(next(iter(linear.series.values()))["lines"])


def test_nonlinear_ekf_gap_positive():
    res = compare(CUBIC, {"ekf": EKF(CUBIC), "ukf": UKF(CUBIC)}, 200, paths=200, m0=0.5, P0=0.1, rng=0)
    gap = _row(res, "ekf", "gap_to_optimal", component=0)
    assert gap.value > 3 * gap.stderr  # observed 0.169 ± 0.023
    ukf = _row(res, "ukf", "gap_to_optimal", component=0)
    assert ukf.value > -3 * ukf.stderr  # no filter beats the reference beyond its noise (0.0016 ± 0.0005)


def test_sde_continuous_ekf():
    md = SDEModel([x], [-x], [x], Q=1.0, R=0.5)
    dt = 0.05
    res = compare(md, {"cekf": ContinuousEKF(md, dt)}, 100, paths=200, m0=0.0, P0=0.5, rng=0, dt=dt)
    assert res.params["reference"]["kind"] == "grid" and res.params["dt"] == dt
    m = _row(res, "cekf", "mse", component=0)
    opt = _row(res, "optimal", "mse", component=0)
    # linear SDE: the Kalman–Bucy filter is optimal; its steady variance solves 2aP + q − P²/r = 0,
    # P = r (a + √(a² + q/r)) = 0.366 for a = −1, q = 1, r = 0.5
    Pinf = 0.5 * (-1 + np.sqrt(1 + 1.0 / 0.5))
    assert abs(m.value - Pinf) < 3 * m.stderr + 0.01  # 0.01: O(dt) time discretization
    gap = _row(res, "cekf", "gap_to_optimal", component=0)
    # the grid (Kushner chain, O(h) and O(dt)) is near-optimal: the gap is a fraction of the MSE
    assert abs(gap.value) < 3 * gap.stderr + 0.02 * opt.value
    np.testing.assert_allclose(res.series[next(iter(res.series))]["x"], dt * np.arange(1, 101))


def test_same_seed_identical_and_common_random_numbers(linear):
    again = compare(LIN, {"kf": KalmanFilter(LIN), "ekf": EKF(LIN)}, 200, paths=400, m0=0.0, P0=0.5, rng=0)
    assert [r.to_dict() for r in again.rows] == [r.to_dict() for r in linear.rows]
    solo = compare(LIN, {"ekf": EKF(LIN)}, 200, paths=400, m0=0.0, P0=0.5, rng=0)
    for q in ("mse", "gap_to_optimal"):
        assert _row(solo, "ekf", q, component=0) == _row(linear, "ekf", q, component=0)
    other = compare(LIN, {"ekf": EKF(LIN)}, 200, paths=400, m0=0.0, P0=0.5, rng=1)
    assert _row(other, "ekf", "mse", component=0).value != _row(solo, "ekf", "mse", component=0).value
    g = compare(LIN, {"ekf": EKF(LIN)}, 50, paths=20, m0=0.0, P0=0.5, rng=np.random.default_rng(5))
    assert g.params["seed"] is None and np.isfinite(_row(g, "ekf", "mse", component=0).value)


def test_particle_reference_for_three_states():
    F = np.diag([0.9, 0.8, 0.7])
    md = DiscreteModel.linear(F, np.eye(3), 0.1 * np.eye(3), 0.5 * np.eye(3))
    run = lambda: compare(md, {"kf": KalmanFilter(md)}, 15, paths=10, m0=np.zeros(3), P0=np.eye(3), rng=3)
    a, b = run(), run()
    assert a.params["reference"]["kind"] == "particle" and len(a.series) == 3
    assert [r.to_dict() for r in a.rows] == [r.to_dict() for r in b.rows]  # the particles are seeded


def test_given_and_no_reference():
    grid = GridFilter(LIN, (-5.0, 5.0), 201)
    res = compare(LIN, {"kf": KalmanFilter(LIN)}, 40, paths=30, m0=0.0, P0=0.5, rng=0, reference=grid)
    ref = res.params["reference"]
    assert (ref["kind"], ref["size"], ref["certified"]) == ("grid", [201], True) and _row(res, "optimal", "mse", component=0)
    again = compare(LIN, {"kf": KalmanFilter(LIN)}, 40, paths=30, m0=0.0, P0=0.5, rng=0, reference=grid,
                    progress=True)
    assert [r.to_dict() for r in again.rows] == [r.to_dict() for r in res.rows]
    none = compare(LIN, {"kf": KalmanFilter(LIN)}, 40, paths=30, m0=0.0, P0=0.5, rng=0, reference=None)
    assert {r.quantity for r in none.rows} == {"mse", "nees", "divergence_rate"}
    assert {r.filter for r in none.rows} == {"kf"}


@pytest.mark.parametrize("kwargs, exc, name", [
    ({"filters": {}}, TypeError, "filters"),
    ({"filters": [EKF(LIN)]}, TypeError, "filters"),
    ({"filters": {"ekf": object()}}, TypeError, "filters"),
    ({"filters": {"optimal": EKF(LIN)}}, ValueError, "filters"),
    ({"filters": {"ekf": EKF(LIN, start="predict")}}, ValueError, "filters"),
    ({"dt": 0.1}, ValueError, "dt"),
    ({"reference": "exact"}, ValueError, "reference"),  # "grid" and "particle" are kinds of the automatic one
    ({"reference": 3}, TypeError, "reference"),
    ({"paths": 1}, ValueError, "paths"),
    ({"paths": 2.5}, TypeError, "paths"),
    ({"rng": "x"}, TypeError, "rng"),
    ({"window": 2}, TypeError, "window"),
    ({"m0": [0.0, 1.0]}, ValueError, "m0"),
    ({"P0": -1.0}, ValueError, "P0"),
    ({"reference": GridFilter(LIN, (-5.0, 5.0), 51, start="predict")}, ValueError, "reference"),
])
def test_bad_input_names_argument(kwargs, exc, name):
    kw = {"filters": {"ekf": EKF(LIN)}, "paths": 5, "m0": 0.0, "P0": 0.5}
    kw.update(kwargs)
    with pytest.raises(exc, match=f"^{name}"):
        compare(LIN, kw.pop("filters"), 10, **kw)


def test_sde_needs_dt():
    md = SDEModel([x], [-x], [x], Q=1.0, R=0.5)
    with pytest.raises(ValueError, match="^dt"):
        compare(md, {"cekf": ContinuousEKF(md, 0.1)}, 10, paths=5, m0=0.0, P0=0.5)
    with pytest.raises(ValueError, match=r"^filters\['cekf'\].*dt"):
        compare(md, {"cekf": ContinuousEKF(md, 0.1)}, 10, paths=5, m0=0.0, P0=0.5, dt=0.05)


def test_plot_result_writes_png(linear, check_figure):
    check_figure(linear, {"MSE of x per step (400 paths)": ["kf", "ekf", "optimal"]})


def test_readme_compare_block_runs(monkeypatch, tmp_path, capsys):
    guide = pathlib.Path(__file__).resolve().parents[1] / "docs" / "guide" / "compare.rst"
    code = textwrap.dedent(re.search(r"\.\. code-block:: python\n\n((?:(?:   .*)?\n)+)", guide.read_text()).group(1))
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README-compare", "exec"), {"model": CUBIC, "EKF": EKF, "UKF": UKF})  # the Quickstart's
    assert "gap_to_optimal" in capsys.readouterr().out
    assert (tmp_path / "compare.png").stat().st_size > 5000


class _MarksFirstPath:
    """A KF whose first path is marked diverged (NaN from step 3), to check the bookkeeping."""

    def __init__(self, model):
        self.kf = KalmanFilter(model)

    def run(self, ys, m0, P0, *, on_divergence="raise"):
        e = self.kf.run(ys, m0, P0, on_divergence=on_divergence)
        means, covs = e.means.copy(), e.covs.copy()
        means[0, 3:], covs[0, 3:] = np.nan, np.nan
        div, step = e.diverged.copy(), e.diverged_step.copy()
        div[0], step[0] = True, 3
        return type(e)(means, covs, div, step)


def test_diverged_paths_left_out_and_counted():
    res = compare(LIN, {"kf": KalmanFilter(LIN), "bad": _MarksFirstPath(LIN)}, 40, paths=20, m0=0.0, P0=0.5, rng=0)
    assert _row(res, "bad", "divergence_rate").value == 1 / 20
    gap = _row(res, "bad", "gap_to_optimal", component=0)
    assert abs(gap.value) < GRID_TOL  # the KF on the 19 other paths, where it equals the grid
    assert "bad: diverged on 1 of 20 paths (first at step 3): its MSE, gap and NEES are over its 19 surviving " \
           "paths only" in res.notes
    lines = next(iter(res.series.values()))["lines"]
    assert np.all(np.isfinite(lines["bad"]))


def test_particle_filter_in_filters_seeded_by_name():
    run = lambda fs: compare(LIN, fs, 30, paths=10, m0=0.0, P0=0.5, rng=4)
    a = run({"pf": ParticleFilter(LIN, 200), "kf": KalmanFilter(LIN)})
    b = run({"pf": ParticleFilter(LIN, 200)})
    assert _row(a, "pf", "mse", component=0) == _row(b, "pf", "mse", component=0)
    c = run({"pf2": ParticleFilter(LIN, 200)})  # another name, another stream
    assert _row(c, "pf2", "mse", component=0).value != _row(b, "pf", "mse", component=0).value


def test_module_and_function_both_reachable():
    """issue 10 item 8.5: the module is nlfilter.comparison, the function nlfilter.compare (the
    package's `from .compare import compare` used to shadow the module of the same name)."""
    import importlib
    import types
    import nlfilter
    mod = importlib.import_module("nlfilter.comparison")
    assert isinstance(mod, types.ModuleType) and mod.__name__ == "nlfilter.comparison"
    assert callable(nlfilter.compare) and isinstance(nlfilter.compare, types.FunctionType)
    assert nlfilter.compare is mod.compare and nlfilter.compare.__module__ == "nlfilter.comparison"
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("nlfilter.compare")


# -- compare(model, "all") over the filter registry ----------------------------------------------------
x1, x2 = sp.symbols("x1 x2")
D2 = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2 - 0.05 * x1**3], [x1 + 0.1 * x2**2, x2],
                   Q=np.diag([0.1, 0.05]), R=np.diag([0.2, 0.1]))
CUBIC_SDE = SDEModel([x], [-x], [x**3], Q=1.0, R=1.0)


def _families(res):
    from nlfilter.filters import REGISTRY
    return {REGISTRY[r.filter].family for r in res.rows if r.filter in REGISTRY}


def test_all_on_a_two_state_discrete_model_runs_every_family_that_accepts_it():
    from nlfilter.filters import REGISTRY
    res = compare(D2, "all", 12, paths=4, m0=[0.3, -0.2], P0=np.diag([0.5, 0.4]), rng=0)
    ran = {r.filter for r in res.rows} - {"optimal"}
    want = {name for name, cls in REGISTRY.items() if "discrete" in getattr(cls, "accepts", ())}
    assert ran | set(res.params.get("skipped", {})) == want  # each one ran, or is skipped with a reason
    assert "yardstick" in res.params["skipped"]["grid"]  # the reference family: named, not silently left out
    assert {"gaussian", "second-order", "conditional moments"} <= _families(res)
    assert "kf" in res.params["skipped"] and "linear" in res.params["skipped"]["kf"]  # D2 is nonlinear
    for name in ran:  # one shared simulation: every filter's MSE is finite, the paired gap has a stderr
        assert np.isfinite(res.get(name, "mse", component=1).value)
        assert res.get(name, "gap_to_optimal", component=0).stderr >= 0


def test_all_on_a_scalar_polynomial_sde_and_on_its_bilinear_lift():
    from nlfilter.bilinear import BilinearModel
    kw = dict(paths=6, m0=0.0, P0=0.5, dt=0.05, rng=1)
    sde = compare(CUBIC_SDE, "all", 20, **kw)
    assert {"continuous-ekf", "continuous-second-order", "conditional-moment", "quasilinear"} <= {r.filter for r in sde.rows}
    assert not any(r.filter.startswith("continuous-discrete") for r in sde.rows)  # they read samples, not increments
    lift = compare(BilinearModel.from_polynomial(CUBIC_SDE), "all", 20, **kw)
    names = {r.filter for r in lift.rows}
    assert {"tensor", "updated-innovations"} <= names  # the bilinear family, on the lift
    assert {"continuous-ekf", "quasilinear"} <= names  # and every SDE filter, on the SDE it lifts
    # same simulation (the lift's SDE view is the SDE itself): the SDE filters' numbers do not move
    for name in ("continuous-ekf", "quasilinear", "optimal"):
        assert lift.get(name, "mse", component=0).value == sde.get(name, "mse", component=0).value
    assert "pseudo-observables" in lift.params["skipped"]  # needs the user's x_moment


def test_named_filters_and_unknown_names():
    res = compare(LIN, ["kf", "ekf"], 20, paths=4, m0=0.0, P0=0.5, rng=0)
    assert {r.filter for r in res.rows} == {"kf", "ekf", "optimal"}
    assert res.get("kf", "mse", component=0).value == pytest.approx(res.get("ekf", "mse", component=0).value, abs=1e-12)
    with pytest.raises(ValueError, match=r"^filters: expected registry names from .*'ekf'.*, got 'bogus'"):
        compare(LIN, ["ekf", "bogus"], 20, paths=4, m0=0.0, P0=0.5, rng=0)
    with pytest.raises(ValueError, match=r"^filters: kf: model: KalmanFilter needs a linear model"):
        compare(CUBIC, ["kf"], 20, paths=4, m0=0.0, P0=0.5, rng=0)
    with pytest.raises(TypeError, match=r"^filters: expected 'all'"):
        compare(LIN, "some", 20, paths=4, m0=0.0, P0=0.5, rng=0)


# -- smooth=True: every smoother against the optimal (grid) smoother ---------------------------------
SMOOTH_FILTERS = ("ekf", "ukf", "discrete-conditional-moment")


@pytest.fixture(scope="module")
def smoothed():
    return compare(CUBIC, list(SMOOTH_FILTERS), 60, paths=40, m0=0.5, P0=0.1, rng=0, smooth=True, full_output=True)


def test_smooth_reports_smoothed_mse_and_gaps_beside_the_filters(smoothed):
    """``smooth=True`` (cubic sensor, 40 paths, 60 steps): ``smoothed_mse`` and
    ``smoothed_gap_to_optimal`` for every filter with a smoother, against the grid's
    forward–backward smoother at the certified grid's resolution; the optimal smoother beats the
    optimal filter (measured 0.0357 against 0.0433, a 358-point grid) and no smoother beats it
    beyond 3 s.e. (measured: EKF 0.059 ± 0.038, UKF 0.0058 ± 0.0020; each below its filter's MSE,
    0.094 < 0.102, 0.041 < 0.045); the filter without a smoother gets no
    smoothed rows and a note; the filters' own rows are those of ``smooth=False``."""
    res, sim, est = smoothed
    opt, opt_s = (res.get("optimal", q, component=0) for q in ("mse", "smoothed_mse"))
    assert opt_s.value < opt.value
    d = np.mean((est["optimal"].means[..., 30:, 0] - sim.xs[..., 30:, 0]) ** 2
                - (est["optimal (smoothed)"].means[..., 30:, 0] - sim.xs[..., 30:, 0]) ** 2, axis=1)
    # the paired gain over the window: measured 0.0076 ± 0.0043 (1.8 s.e. at 40 paths)
    assert d.mean() > 0 and np.isclose(d.mean(), opt.value - opt_s.value, rtol=1e-10)
    for name in ("ekf", "ukf"):
        gap = res.get(name, "smoothed_gap_to_optimal", component=0)
        s_ = res.get(name, "smoothed_mse", component=0)
        assert gap.value > -3 * gap.stderr and s_.value >= opt_s.value - 3 * gap.stderr
        np.testing.assert_allclose(gap.value, s_.value - opt_s.value, rtol=1e-10, atol=1e-15)
    assert not [r for r in res.rows if r.filter == "discrete-conditional-moment" and r.quantity.startswith("smoothed")]
    sm = res.params["smoothing"]
    assert sm["no_smoother"] == {"discrete-conditional-moment": "DiscreteConditionalMomentFilter"}
    assert sm["reference"]["smoother"] == "forward-backward" and "resolution" in sm["reference"]["certificate"]
    assert any(n.startswith("smoothing:") for n in res.notes)
    # the smoothers end at their filters
    for name in ("ekf", "ukf", "optimal"):
        np.testing.assert_allclose(est[f"{name} (smoothed)"].means[:, -1], est[name].means[:, -1], rtol=0, atol=1e-12)
    plain = compare(CUBIC, list(SMOOTH_FILTERS), 60, paths=40, m0=0.5, P0=0.1, rng=0)
    assert [r.to_dict() for r in plain.rows] == [r.to_dict() for r in res.rows
                                                 if not r.quantity.startswith("smoothed")]


def test_smooth_with_a_particle_reference_and_a_reference_without_smoother():
    """A particle reference smooths by FFBSm on the reference's streams (its forward pass is the
    reference's run: the last step agrees); on an SDE the particle reference (substeps > 1) has no
    smoother: no smoothed gaps, a reason."""
    ref = ParticleFilter(LIN, 300)
    with warnings.catch_warnings():  # 300 particles on 8 paths: not certified (labelled so)
        warnings.simplefilter("ignore", ReferenceWarning)
        res, sim, est = compare(LIN, {"kf": KalmanFilter(LIN)}, 20, paths=8, m0=0.0, P0=0.5, rng=2, reference=ref,
                                smooth=True, full_output=True, certify_paths=4)
    label = res.params["reference"]["label"]
    assert res.params["smoothing"]["reference"] == {**res.params["smoothing"]["reference"], "label": label,
                                                    "smoother": "particle"}
    np.testing.assert_allclose(est[f"{label} (smoothed)"].means[:, -1], est[label].means[:, -1], rtol=0, atol=1e-12)
    gap = res.get("kf", "smoothed_gap_to_reference" if label != "optimal" else "smoothed_gap_to_optimal", component=0)
    assert np.isfinite(gap.value) and gap.stderr > 0
    md = SDEModel([x], [-x], [x], Q=1.0, R=0.5)
    res = compare(md, {"cekf": ContinuousEKF(md, 0.05)}, 20, paths=6, m0=0.0, P0=0.5, rng=0, dt=0.05, smooth=True,
                  reference=ParticleFilter(md, 100, dt=0.05), certify_paths=3)
    assert res.params["smoothing"]["reference"]["smoother"] is None
    assert "substeps" in res.params["smoothing"]["reference"]["reason"]
    assert res.get("cekf", "smoothed_mse", component=0).value > 0
    assert not [r for r in res.rows if r.quantity.startswith("smoothed_gap")]
