"""Model files that carry everything (issue 31, item 3): parameters kept as symbols
(``ModelSpec.with_params``, ``nlfilter fit MODEL.toml DATA.csv --params``), ``kind =
"continuous-discrete"`` with irregular measurement times (in Python: ``at_times``,
``simulate_continuous_discrete(times=)``), ``nlfilter simulate`` into a CSV checked against the
model, ``nlfilter compare`` on a continuous-discrete file, and the coverage of the fit's
intervals over seeds."""

from __future__ import annotations

import json

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel, cli
from nlfilter.data_csv import DataFileError, read_csv
from nlfilter.filters import ContinuousDiscreteEKF, ContinuousDiscreteUKF
from nlfilter.modelfile import ModelFileError, load_model
from nlfilter.simulate import simulate_continuous_discrete

OU = """\
[model]
name = "ou-cd"
kind = "continuous-discrete"
states = ["x"]

[parameters]
a = 1.0
q = 0.5
r = 0.1

[dynamics]
drift = ["-a*x"]
Q = [["q"]]

[measurement]
h = ["x"]
R = [["r"]]
names = ["y"]
times = [0.1, 0.3, 0.35, 0.9, 1.0, 1.6, 2.2, 2.25, 2.3, 3.0, 3.1, 3.5, 4.2, 4.3, 5.0, 5.2, 5.9, 6.0, 6.5, 7.0]

[prior]
mean = [0.0]
cov = ["q/(2*a)"]
"""
TIMES = [0.1, 0.3, 0.35, 0.9, 1.0, 1.6, 2.2, 2.25, 2.3, 3.0, 3.1, 3.5, 4.2, 4.3, 5.0, 5.2, 5.9, 6.0, 6.5, 7.0]


@pytest.fixture
def ou(tmp_path):
    path = tmp_path / "ou.toml"
    path.write_text(OU)
    return path


def _one_error(capsys, *words):
    out, err = capsys.readouterr()
    assert err.startswith("nlfilter: error: ") and err.count("\n") == 1, err
    assert all(w in err for w in words), err
    return err


def test_parameters_stay_symbols(ou):
    """The file's parameters are the model's (``params``), covariances in them are evaluated at
    any value (``with_params``), and the prior's covariance follows them."""
    spec = load_model(ou)
    assert spec.kind == "continuous-discrete" and spec.names == ("y",) and spec.times == tuple(TIMES)
    assert dict(spec.model.params) == {"a": 1.0, "q": 0.5, "r": 0.1} and spec.dt is None
    assert spec.model.Q.tolist() == [[0.5]] and spec.model.R.tolist() == [[0.1]] and spec.P0.tolist() == [[0.25]]
    other = spec.with_params(q=2.0, a=0.5)
    assert other.model.Q.tolist() == [[2.0]] and other.P0.tolist() == [[2.0]]  # q / (2a)
    assert other.model.f(np.array([[2.0]]), 0.0).tolist() == [[-1.0]]  # -a x, a = 0.5
    assert spec.model.Q.tolist() == [[0.5]] and spec.P0.tolist() == [[0.25]]  # the original is unchanged
    with pytest.raises(ValueError, match="P0: the prior covariance"):
        spec.with_params(a=-1.0)  # q / (2a) < 0
    x = sp.Symbol("x")
    assert spec.model.sym["f"] == sp.Matrix([-1.0 * x])  # values substituted for the symbolic methods


@pytest.mark.parametrize("old, new, field, words", [
    ("times = [0.1, 0.3, 0.35,", "times = [0.1, 0.35, 0.3,", "measurement.times", "0.3 (entry 2) after 0.35"),
    ("times = [0.1, 0.3, 0.35,", "times = [0.1, 0.3, 0.3,", "measurement.times", "0.3 twice (entries 1 and 2)"),
    ("times = [0.1,", "times = [0.0,", "measurement.times", "after the prior's time"),
    ('names = ["y"]', 'names = ["y"]\ndt = 0.1', "measurement.times", "both dt and times"),
    ('names = ["y"]', 'names = ["t"]', "measurement.names", "other than 't'"),
    ('names = ["y"]', 'names = ["y", "z"]', "measurement.names", "expected 1"),
])
def test_file_times_and_names_refused(ou, old, new, field, words):
    ou.write_text(OU.replace(old, new))
    with pytest.raises(ModelFileError, match=f"^{ou}:\\d+: {field}: got ") as info:
        load_model(ou)
    assert words in str(info.value)


def test_irregular_times_in_python():
    """At regular times given as ``times`` the numbers are the ``dt`` ones (simulation and filter,
    to rounding); at irregular times the filter built with ``dt=None`` takes the Simulation's;
    unsorted or repeated times, or data of another length, are refused naming them."""
    x = sp.Symbol("x")
    md = SDEModel([x], [-x + sp.sin(x)], [x + x**2 / 5], Q=0.5, R=0.1)
    kw = dict(paths=3, rng=1, m0=[0.0], P0=[[1.0]])
    a = simulate_continuous_discrete(md, 8, dt=0.2, **kw)
    b = simulate_continuous_discrete(md, 8, times=0.2 * np.arange(1, 9), **kw)
    assert b.timing.dt is None and len(b.timing.times) == 8
    np.testing.assert_allclose(b.xs, a.xs, rtol=0, atol=1e-14)  # the grid's rounding only
    e1 = ContinuousDiscreteUKF(md, 0.2, substeps=2).run(a, [0.0], [[1.0]], loglik=True)
    e2 = ContinuousDiscreteUKF(md, None, substeps=2).run(b, [0.0], [[1.0]], loglik=True)
    np.testing.assert_allclose(e2.means, e1.means, rtol=0, atol=1e-13)
    np.testing.assert_allclose(e2.loglik, e1.loglik, rtol=1e-13)
    c = simulate_continuous_discrete(md, 4, times=[0.5, 0.6, 2.0, 2.01], **kw)
    e3 = ContinuousDiscreteEKF(md, None).run(c, [0.0], [[1.0]])
    e4 = ContinuousDiscreteEKF(md, None).at_times([0.5, 0.6, 2.0, 2.01]).run(c.ys, [0.0], [[1.0]])
    assert np.array_equal(e3.means, e4.means) and np.isfinite(e3.means).all()
    # one interval of 1.4 integrated in one RK4 step differs from the same data read at dt = 0.5
    e5 = ContinuousDiscreteEKF(md, 0.5).run(c.ys, [0.0], [[1.0]])
    assert np.abs(e5.means[:, 2:] - e3.means[:, 2:]).max() > 1e-3
    for times, words in (([0.5, 0.5, 1, 2], "0.5 twice"), ([0.5, 0.4, 1, 2], r"0.4 \(entry 1\) after 0.5")):
        with pytest.raises(ValueError, match=f"^times: got the time {words}"):
            simulate_continuous_discrete(md, 4, times=times, **kw)
        with pytest.raises(ValueError, match=f"^times: got the time {words}"):
            ContinuousDiscreteEKF(md, None).at_times(times)
    with pytest.raises(ValueError, match="^dt: ContinuousDiscreteEKF was built with dt=0.5, but the Simulation's"):
        ContinuousDiscreteEKF(md, 0.5).run(c, [0.0], [[1.0]])
    with pytest.raises(ValueError, match="^dt: ContinuousDiscreteEKF was built with dt=None"):
        ContinuousDiscreteEKF(md, None).run(c.ys, [0.0], [[1.0]])
    with pytest.raises(ValueError, match="^ys: got 4 measurement step"):
        ContinuousDiscreteEKF(md, None).at_times([1.0, 2.0]).run(c.ys, [0.0], [[1.0]])


def test_simulate_writes_the_simulation(ou, tmp_path, capsys):
    """``nlfilter simulate`` writes ``simulate_continuous_discrete`` at the file's times (exactly:
    numbers written by repr), read back by :func:`read_csv` with the truth."""
    out = tmp_path / "data.csv"
    assert cli.main(["simulate", str(ou), "--out", str(out), "--paths", "2", "--seed", "5", "--states"]) == 0
    capsys.readouterr()
    assert out.read_text().splitlines()[0] == "path,t,y,x"
    spec = load_model(ou)
    data = read_csv(out, spec)
    sim = simulate_continuous_discrete(spec.model, 20, paths=2, rng=5, m0=spec.m0, P0=spec.P0, times=TIMES,
                                       process="euler-maruyama")
    assert data.times.tolist() == TIMES and data.paths == ("0", "1")
    assert np.array_equal(data.ys, sim.ys) and np.array_equal(data.xs, sim.xs)
    # --times overrides the file's; a discrete model's t is its step
    assert cli.main(["simulate", str(ou), "--out", str(out), "--times", "0.5,1,4"]) == 0
    assert read_csv(out, spec).times.tolist() == [0.5, 1.0, 4.0]
    assert cli.main(["simulate", str(ou), "--out", str(out), "--times", "0.5,1,1"]) == 2
    _one_error(capsys, "--times: got the time 1.0 twice (entries 1 and 2)")


def _csv(tmp_path, text):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, line, column, words", [
    ("t,y,z\n0.1,1,2\n", 1, "z", "unknown column 'z'"),
    ("t,x\n0.1,1\n", 1, "y", "got no column 'y'"),
    ("t,y,y\n0.1,1,2\n", 1, "y", "2 times"),
    ("t,y\n0.1,1\n0.3,2\n0.3,3\n", 4, "t", "got the time 0.3 again (lines 3 and 4)"),
    ("t,y\n0.1,1\n0.35,2\n0.3,3\n", 4, "t", "after 0.35 (line 3)"),
    ("t,y\n0.1,one\n", 2, "y", "got 'one'; expected a number"),
    ("t,y\n0.1,1,2\n", 2, "line", "got 3 values; expected 2"),
    ("y\n1\n", 1, "t", "got no column 't'"),
    ("path,t,y\n0,0.1,1\n0,0.2,1\n1,0.1,1\n", 4, "path", "different lengths"),
    ("t,y\n0,1\n", 2, "t", "after the prior's, 0"),
])
def test_data_file_refused_in_one_line(ou, tmp_path, capsys, text, line, column, words):
    """A CSV whose columns do not match the model, or whose times are repeated or unsorted: one
    line naming the file, the line and the column, exit code 2 (``nlfilter fit``)."""
    path = _csv(tmp_path, text)
    assert cli.main(["fit", str(ou), str(path), "--params", "q"]) == 2
    _one_error(capsys, f"{path}:{line}: {column}: ", words, "expected")
    with pytest.raises(DataFileError):
        read_csv(path, load_model(ou))


def test_fit_options_refused(ou, tmp_path, capsys):
    out = tmp_path / "data.csv"
    assert cli.main(["simulate", str(ou), "--out", str(out)]) == 0
    capsys.readouterr()
    for opts, words in ((["--params", "q,s"], "--params: got the unknown parameter 's'; expected names from "
                                              "the file's [parameters] ['a', 'q', 'r']"),
                        (["--params", "q,,r"], "--params: got 'q,,r'"),
                        (["--params", "q", "--filter", "ukf"], "--filter: ukf does not give a log-likelihood of a "
                                                               "continuous-discrete model's measurements"),
                        (["--params", "q", "--filter", "nope"], "--filter: got 'nope'")):
        assert cli.main(["fit", str(ou), str(out), *opts]) == 2
        _one_error(capsys, words)


def test_a_file_without_times_asks_for_them(ou, tmp_path, capsys):
    """A continuous-discrete file with neither ``dt`` nor ``times``: ``simulate`` and ``compare`` ask
    for the times (``simulate`` names ``--times``, which it takes), ``fit`` reads them from the
    data's ``t`` column and refuses data without one; ``simulate --times`` then works."""
    bare = tmp_path / "bare.toml"
    bare.write_text(OU.replace("times = [" + ", ".join(map(str, TIMES)) + "]\n", ""))
    expected = "measurement: a continuous-discrete model with neither dt nor times; expected the measurement times"
    assert cli.main(["simulate", str(bare), "--out", str(tmp_path / "d.csv"), "--steps", "5"]) == 2
    assert "--times" in _one_error(capsys, "bare.toml", expected)
    assert cli.main(["compare", str(bare), "--paths", "4"]) == 2
    assert "--times" not in _one_error(capsys, "bare.toml", expected)
    data = tmp_path / "d.csv"
    assert cli.main(["simulate", str(bare), "--out", str(data), "--times", "0.5,1,2.5"]) == 0
    capsys.readouterr()
    lines = data.read_text().splitlines()
    assert lines[0] == "t,y" and [float(l.split(",")[0]) for l in lines[1:]] == [0.5, 1.0, 2.5]
    data.write_text("y\n" + "\n".join(l.split(",")[1] for l in lines[1:]) + "\n")
    assert cli.main(["fit", str(bare), str(data), "--params", "q"]) == 2
    _one_error(capsys, "t", "expected the measurement times")


def test_compare_on_a_continuous_discrete_file(ou, tmp_path, capsys):
    """``nlfilter compare`` on a continuous-discrete file: its continuous-discrete filters at the
    file's irregular times against the certified particle reference through the simulator's
    Euler–Maruyama steps (500 particles, its check 2000: plenty for a 1-D Gaussian posterior, and a
    quarter of the default's cost); the model is linear, so the EKF and the UKF are the same filter (to
    rounding) with a NEES near 1, and near-optimal: no gap beyond 3 s.e. and the reference's
    tolerance (RK4 moments for the simulator's Euler steps: a change of the transition below 1 %)."""
    out = tmp_path / "out.json"
    assert cli.main(["compare", str(ou), "--paths", "40", "--filters", "continuous-discrete-ekf,continuous-discrete-ukf",
                     "--max-particles", "500", "--no-progress", "--no-store", "--json", str(out)]) == 0
    capsys.readouterr()
    d = json.loads(out.read_text())
    ref = d["params"]["reference"]
    assert d["params"]["times"] == TIMES and ref["certified"] and ref["kind"] == "particle" and d["params"]["steps"] == 20
    rows = {(r["filter"], r["quantity"]): r for r in d["rows"]}
    mse = [rows[(f, "mse")]["value"] for f in ("continuous-discrete-ekf", "continuous-discrete-ukf")]
    assert mse[0] == pytest.approx(mse[1], rel=1e-10) and 0 < mse[0] < 0.1  # below R = 0.1: the filter helps
    nees = rows[("continuous-discrete-ekf", "nees")]
    assert abs(nees["value"] - 1.0) < 3 * nees["stderr"] + 0.05, nees  # a consistent filter: NEES ≈ n = 1
    gap = rows[("continuous-discrete-ekf", "gap_to_optimal")]
    assert abs(gap["value"]) <= 3 * gap["stderr"] + ref["rungs"][-1]["tolerance"][0], gap
    assert not any("no reference" in n for n in d["notes"])
    assert cli.main(["compare", str(ou), "--paths", "4", "--steps", "5", "--no-progress", "--no-store"]) == 2
    _one_error(capsys, "--steps: got 5; the measurement times are 20")
    assert cli.main(["compare", str(ou), "--paths", "4", "--reference", "grid", "--no-progress", "--no-store"]) == 2
    _one_error(capsys, "reference: no grid filter reads an SDE measured at discrete times")


def test_fit_coverage_over_seeds(ou, tmp_path, capsys):
    """``nlfilter simulate`` then ``nlfilter fit --params a,q`` on 12 seeds (8 records × 10
    irregular times each, the times given with the data): the nominal 95 % Wald intervals cover
    the true (a, q) = (1, 0.5). Of
    24 intervals, at least 20 must cover: with a true rate of 0.95 fewer than 20 has probability
    0.6 % (binomial, the two intervals of a seed taken as independent), while a rate of 0.8
    (intervals a third too narrow) passes with probability 0.46 only. The continuous-discrete EKF's
    likelihood is exact up to its RK4 step on this linear model; every fit must converge."""
    data, res = tmp_path / "data.csv", tmp_path / "fit.json"
    covered, estimates = 0, []
    for seed in range(12):
        assert cli.main(["simulate", str(ou), "--out", str(data), "--paths", "8", "--seed", str(seed),
                         "--times", "0.2,0.5,0.6,1.4,1.5,2.5,3.3,3.35,4.5,5.0"]) == 0
        assert cli.main(["fit", str(ou), str(data), "--params", "a,q", "--filter", "continuous-discrete-ekf",
                         "--json", str(res)]) == 0
        d = json.loads(res.read_text())
        assert d["converged"], d["message"]
        assert d["notes"] == ["the prior's cov is written in ['a', 'q']: it is held at the file's values (P0 = "
                              "[[0.25]]), not moved with the estimate"]
        for name, truth in (("a", 1.0), ("q", 0.5)):
            lo, hi = d["intervals95"][name]
            covered += lo <= truth <= hi
        estimates.append([d["params"]["a"], d["params"]["q"]])
    assert "95 % interval" in capsys.readouterr().out
    assert covered >= 20, covered
    # and the estimates centre on the truth: the mean of 12 within 3 of its standard errors
    est = np.array(estimates)
    assert np.all(np.abs(est.mean(axis=0) - [1.0, 0.5]) < 3 * est.std(axis=0, ddof=1) / np.sqrt(12)), est.mean(axis=0)


NOISY = """\
[model]
kind = "discrete"
states = ["x"]

[parameters]
s = 0.3
r = 0.1

[dynamics]
noise = ["w"]
f = ["0.9*x + exp(s*w) - 1"]
Q = [[1.0]]

[measurement]
h = ["x"]
R = [["r + x**2/10"]]

[prior]
mean = [1.0]
cov = [0.5]
"""


def test_non_additive_noise_and_state_dependent_R(tmp_path, capsys):
    """``noise = [...]`` in ``[dynamics]`` or ``[measurement]`` (the model's ``noise=``,
    ``meas_noise=``) and ``R`` in the states (``R(x)``, checked at the prior's mean), simulated and
    fitted from the command line: the UKF's estimate of ``s`` within 3 of its standard errors of
    the truth 0.3 (4 records × 100 steps)."""
    path = tmp_path / "noisy.toml"
    path.write_text(NOISY)
    spec = load_model(path)
    assert spec.model.structure == {"non-additive noise", "state-dependent R"}
    assert spec.model.R_of(np.array([[2.0]]), 0)[0].tolist() == [[pytest.approx(0.1 + 0.4, rel=1e-15)]]
    assert spec.with_params(r=0.5).model.R_of(np.array([[0.0]]), 0)[0].tolist() == [[0.5]]
    w = sp.Symbol("w")
    v_file = NOISY.replace('h = ["x"]', 'noise = ["v"]\nh = ["x*(1 + v)"]').replace('R = [["r + x**2/10"]]', 'R = [["r"]]')
    path.write_text(v_file)
    assert load_model(path).model.structure == {"non-additive noise", "non-additive measurement noise"}
    assert load_model(path).model.noise_symbols == (w,)
    path.write_text(NOISY)
    data, res = tmp_path / "d.csv", tmp_path / "f.json"
    assert cli.main(["simulate", str(path), "--out", str(data), "--paths", "4", "--steps", "100", "--seed", "2"]) == 0
    assert cli.main(["fit", str(path), str(data), "--params", "s", "--json", str(res)]) == 0
    d = json.loads(res.read_text())
    assert d["converged"] and abs(d["params"]["s"] - 0.3) < 3 * d["se"]["s"], (d["params"], d["se"])
    capsys.readouterr()
    for old, new, field, words in (
            ('R = [["r + x**2/10"]]', 'R = [["r - x**2"]]', "measurement.R", "not positive definite at the prior's "
                                                                             "mean [1.0]"),
            ("Q = [[1.0]]", 'Q = [[1.0]]\nG = [["1"]]', "dynamics.G", "non-additive noise"),
            ('noise = ["w"]', 'noise = ["x"]', "dynamics.noise", "already a state")):
        path.write_text(NOISY.replace(old, new))
        assert cli.main(["compare", str(path), "--no-progress"]) == 2
        _one_error(capsys, f"{path}:", f": {field}: got ", words)
