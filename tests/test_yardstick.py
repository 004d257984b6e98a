"""nlfilter.yardstick: the reference of a comparison certifies itself (issue 11, item 1), and
compare's evaluation is honest about it (item 2)."""

import warnings

import numpy as np
import pytest
import sympy as sp

from nlfilter import DiscreteModel, SDEModel, compare
from nlfilter.errors import ReferenceWarning
from nlfilter.evaluate import paired_difference
from nlfilter.filters import EKF, GridFilter, KalmanFilter, ParticleFilter, UKF
from nlfilter.yardstick import NOT_CONVERGED, OPTIMAL

th, om, x = sp.symbols("theta omega x")
DT = 0.1
_om = om - 9.81 * DT * sp.sin(th)
# the pendulum of issue 11: symplectic Euler, small process noise, y = sin θ + v
PENDULUM = DiscreteModel([th, om], f=[th + DT * _om, _om], h=[sp.sin(th)], Q=np.diag([2e-3, 0.05]), R=0.02,
                         name="pendulum")
PKW = dict(m0=[1.2, 0.0], P0=np.diag([0.5, 1.0]), rng=0)


@pytest.fixture(scope="module")
def pendulum():
    with warnings.catch_warnings():
        warnings.simplefilter("error", ReferenceWarning)  # the automatic reference must certify itself
        return compare(PENDULUM, {"ekf": EKF(PENDULUM), "ukf": UKF(PENDULUM)}, 30, paths=60, certify_paths=30,
                       full_output=True, **PKW)


def test_pendulum_reference_is_certified_and_no_filter_beats_it(pendulum):
    res, sim, est = pendulum
    cert = res.params["reference"]
    # a grid resolving the process noise (s.d. 0.045 in θ) at 1/4 of it would need > 1700 points:
    # the automatic reference falls back to particles, and certifies them by refinement
    assert cert["kind"] == "particle" and cert["certified"] is True and cert["label"] == OPTIMAL
    assert "exceeds" in cert["reason"]
    last = cert["rungs"][-1]
    assert last["verdict"] == "certified" and last["refined_to"] == 4 * cert["size"]
    for name in ("ekf", "ukf"):
        for i in range(2):
            gap = res.get(name, "gap_to_optimal", component=i)
            assert gap.value > -2 * gap.stderr, (name, i, gap)
    # the reference's own error enters every gap's standard error
    d = paired_difference(est["ukf"], est[OPTIMAL], sim.xs, component=0, window=0.5)
    gap = res.get("ukf", "gap_to_optimal", component=0)
    err = res.get(OPTIMAL, "reference_error", component=0)
    assert gap.value == d.value and gap.stderr == pytest.approx(np.hypot(d.stderr, np.hypot(err.value, err.stderr)))
    assert res.get(OPTIMAL, "ess_min").value > 1


def test_pendulum_reference_agrees_with_four_times_its_resolution(pendulum):
    res, sim, est = pendulum
    cert = res.params["reference"]
    fine = ParticleFilter(PENDULUM, 4 * cert["size"]).run(sim.ys, PKW["m0"], PKW["P0"], rng=123)
    for i in range(2):
        d = paired_difference(fine, est[OPTIMAL], sim.xs, component=i, window=0.5)
        # within 2 s.e. of the paired difference, or within the certificate's tolerance (rtol of the MSE)
        assert abs(d.value) <= max(2 * d.stderr, cert["rungs"][-1]["tolerance"][i]), (i, d)


def test_coarse_user_grid_is_labelled_not_converged_with_a_warning():
    # the cap of the old automatic grid (61 × 61) on the pendulum: spacing 0.19 against a
    # process-noise s.d. of 0.045 — its refinement moves its MSE, so it is not called optimal
    grid = GridFilter(PENDULUM, [(-2.5, 4.0), (-6.0, 6.0)], 31)
    with pytest.warns(ReferenceWarning, match="not converged"):
        res = compare(PENDULUM, {"ukf": UKF(PENDULUM)}, 20, paths=20, certify_paths=10, reference=grid, **PKW)
    assert res.params["reference"]["certified"] is False
    assert {r.filter for r in res.rows} == {"ukf", NOT_CONVERGED}
    assert res.get("ukf", "gap_to_reference", component=0)
    assert not [r for r in res.rows if r.quantity == "gap_to_optimal"]
    assert any("NOT converged" in n for n in res.notes)


def test_reference_out_of_budget_is_labelled_with_a_warning_naming_what_to_raise():
    md = DiscreteModel.linear(np.diag([0.9, 0.8, 0.7]), np.eye(3), 0.1 * np.eye(3), 0.5 * np.eye(3))
    with pytest.warns(ReferenceWarning, match=r"Raise max_particles \(now 2000\)"):
        res = compare(md, {"kf": KalmanFilter(md)}, 10, paths=8, m0=np.zeros(3), P0=np.eye(3), rng=3,
                      max_particles=2000, rtol=1e-9)
    cert = res.params["reference"]
    assert (cert["kind"], cert["size"], cert["certified"], cert["label"]) == ("particle", 2000, False, NOT_CONVERGED)
    assert res.get("kf", "gap_to_reference", component=0)


def test_grid_edge_mass_is_reported_and_a_cut_density_is_not_certified():
    LIN = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.5)
    narrow = GridFilter(LIN, (-0.5, 0.5), 101)  # the state (s.d. 0.7) leaves these bounds
    with pytest.warns(ReferenceWarning, match="edge mass"):
        res = compare(LIN, {"kf": KalmanFilter(LIN)}, 30, paths=10, m0=0.0, P0=0.5, rng=0, reference=narrow)
    assert res.get(NOT_CONVERGED, "edge_mass").value > 1e-3
    wide = compare(LIN, {"kf": KalmanFilter(LIN)}, 30, paths=10, m0=0.0, P0=0.5, rng=0)
    assert wide.params["reference"]["certified"] is True and wide.get(OPTIMAL, "edge_mass").value < 1e-3


def test_nees_only_for_posterior_covariances_offline_mse_for_offline_gains():
    from nlfilter.bilinear import BilinearModel
    md = BilinearModel.from_polynomial(SDEModel([x], [-x], [x**3], Q=1.0, R=1.0))
    res = compare(md, ["continuous-ekf", "quasilinear", "optimal-linear"], 20, paths=6, m0=0.0, P0=0.5, dt=0.05,
                  rng=1)
    quantities = lambda f: {r.quantity for r in res.rows if r.filter == f}  # noqa: E731
    assert "nees" in quantities("continuous-ekf") and "nees" in quantities(OPTIMAL)
    assert "nees" not in quantities("quasilinear") and "offline_mse" not in quantities("quasilinear")  # P(t): a model covariance
    assert "nees" not in quantities("optimal-linear") and "offline_mse" in quantities("optimal-linear")


class _Broken(EKF):
    """An EKF whose covariance turns singular / whose linear algebra fails at step 3."""

    def __init__(self, model, how):
        super().__init__(model)
        self.how = how

    def update(self, belief, y, k):
        if k == 3 and self.how == "linalg":
            raise np.linalg.LinAlgError("Singular matrix")
        return super().update(belief, y, k)

    def summary(self, belief):
        m, P = super().summary(belief)
        return m, (np.zeros_like(P) if self.how == "singular" else P)


def test_numerical_failures_are_named_not_tracebacks():
    LIN = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.5)
    kw = dict(paths=4, m0=0.0, P0=0.5, rng=0)
    res = compare(LIN, {"kf": KalmanFilter(LIN), "bad": _Broken(LIN, "linalg")}, 10, **kw)
    assert res.params["failed"] == {"bad": "LinAlgError: Singular matrix"}
    assert res.get("bad", "divergence_rate").value == 1.0 and res.get("kf", "mse", component=0)
    with pytest.raises(np.linalg.LinAlgError) as info:
        compare(LIN, {"bad": _Broken(LIN, "linalg")}, 10, on_divergence="raise", **kw)
    assert "compare: while running filter 'bad'" in "".join(getattr(info.value, "__notes__", []))
    # a covariance that is singular (but not a divergence: zero is a PSD matrix) leaves NEES undefined
    res = compare(LIN, {"zero": _Broken(LIN, "singular")}, 10, **kw)
    assert not [r for r in res.rows if r.filter == "zero" and r.quantity == "nees"]
    assert any(n.startswith("nees of zero not computed: zero: NEES undefined: the covariance at path 0, step 5")
               for n in res.notes)


def test_certificate_is_in_params_and_json_ready():
    import json
    LIN = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.5)
    res = compare(LIN, {"kf": KalmanFilter(LIN)}, 20, paths=8, m0=0.0, P0=0.5, rng=0)
    cert = json.loads(json.dumps(res.to_dict()))["params"]["reference"]
    assert {"kind", "certified", "label", "size", "error", "bound", "rungs", "seconds", "reason"} <= set(cert)
    assert cert["rungs"][-1]["verdict"] == "certified" and len(cert["error"]) == 1


def test_compare_result_round_trips_through_json(tmp_path):
    from nlfilter.results import Result
    LIN = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.5)
    res = compare(LIN, {"kf": KalmanFilter(LIN)}, 20, paths=8, m0=0.0, P0=0.5, rng=0)
    res.to_json(tmp_path / "c.json")
    back = Result.from_json(tmp_path / "c.json")
    assert back == res and back.params["reference"] == res.params["reference"]


def test_compare_simulates_what_simulate_does_and_any_chunk_gives_the_same_numbers():
    from nlfilter.simulate import simulate
    LIN = DiscreteModel([x], f=[0.9 * x], h=[x], Q=0.1, R=0.5)
    filters = {"kf": KalmanFilter(LIN), "pf": ParticleFilter(LIN, 300)}
    kw = dict(paths=9, m0=0.0, P0=0.5, rng=4, reference=ParticleFilter(LIN, 500), certify_paths=5)
    with pytest.warns(ReferenceWarning):  # 500 particles on 5 paths: not certified (not what this test checks)
        res, sim, est = compare(LIN, filters, 15, full_output=True, **kw)
    same = simulate(LIN, 15, paths=9, rng=4, m0=0.0, P0=0.5)
    assert np.array_equal(sim.xs, same.xs) and np.array_equal(sim.ys, same.ys)  # the same streams
    with pytest.warns(ReferenceWarning):
        chunked = compare(LIN, filters, 15, chunk=2, **kw)
    # the particle filters' per-path streams make chunks bitwise equal; the Kalman filter's
    # batched linear algebra may round the last bit differently with the batch size
    for a, b in zip(res.rows, chunked.rows):
        assert (a.filter, a.quantity, a.params) == (b.filter, b.quantity, b.params)
        assert a.value == pytest.approx(b.value, rel=1e-12, abs=1e-15), (a, b)
    pf = [r for r in res.rows if r.filter == "pf" and r.quantity == "mse"][0]
    assert pf == [r for r in chunked.rows if r.filter == "pf" and r.quantity == "mse"][0]
    assert est["pf"].extras["ess"].shape == (9, 15)


def test_a_given_grid_too_large_to_refine_is_checked_against_particles():
    md = DiscreteModel.linear(np.diag([0.9, 0.8]), np.eye(2), 0.1 * np.eye(2), 0.5 * np.eye(2))
    # its 2× refinement, 89² = 7921 points, exceeds REFINE_POINTS (6800); 45², not 61² (its kernel,
    # N² pairs, is the cost of the test)
    grid = GridFilter(md, [(-6.0, 6.0), (-6.0, 6.0)], 45)
    res = compare(md, {"kf": KalmanFilter(md)}, 20, paths=12, certify_paths=12, m0=np.zeros(2), P0=np.eye(2),
                  rng=0, reference=grid)
    cert = res.params["reference"]
    assert "checked against 8000 particles" in cert["reason"] and cert["certified"] is True, cert
    assert res.get(OPTIMAL, "edge_mass").value < 1e-3 and res.get("kf", "gap_to_optimal", component=0)
    # the old automatic rule's 61 × 61 grid on the pendulum: too coarse, and now said so
    with pytest.warns(ReferenceWarning, match="not converged"):
        bad = compare(PENDULUM, {"ukf": UKF(PENDULUM)}, 20, paths=12, certify_paths=6,
                      reference=GridFilter(PENDULUM, [(-2.5, 4.0), (-6.0, 6.0)], 61), **PKW)
    assert bad.params["reference"]["certified"] is False
