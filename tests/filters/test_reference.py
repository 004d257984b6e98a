import numpy as np
import pytest
import scipy.stats as st
import sympy as sp

from nlfilter import DiscreteModel, Independent, SDEModel
from nlfilter.evaluate import mse
from nlfilter.experiments.linear_gaussian import model as lg_model
from nlfilter.filters.kalman import KalmanBucy, KalmanFilter, steady_state
from nlfilter.filters.reference import GridFilter, ParticleFilter
from nlfilter.simulate import simulate

x = sp.Symbol("x")


def test_grid_equals_kf_on_scalar_linear_model():
    md = DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=1.0)
    sim = simulate(md, 100, paths=20, rng=1, m0=0.0, P0=1.0)
    a = KalmanFilter(md).run(sim.ys, 0.0, 1.0)
    g = GridFilter(md, (-14, 14), 701).run(sim.ys, 0.0, 1.0)
    # exact but for the grid's quadrature error, far below 1e-8 at this spacing (0.04 vs sd 0.7)
    np.testing.assert_allclose(g.means, a.means, atol=1e-8)
    np.testing.assert_allclose(g.covs, a.covs, atol=1e-8)


def test_grid_mse_on_linear_gaussian_model_within_3pct_of_riccati():
    """The 2-D grid (51 × 51 cells, spacing 0.28 × 0.24 against posterior standard deviations of
    0.4-1) is the Kalman filter on a linear-Gaussian model but for its discretization, so its MSE
    is the Riccati value. Paired with the KF on the same data, the Monte Carlo noise cancels: 20
    paths (400 unpaired before: a 1.2 % standard error for a 3 % tolerance, 12 s)."""
    md = lg_model()
    P = np.array([[1.6, 0.4], [0.4, 1.1]])
    sim = simulate(md, 60, paths=20, rng=2, m0=[0, 0], P0=P)
    g = GridFilter(md, [(-7, 7), (-6, 6)], 51).run(sim.ys, [0, 0], P)
    k = KalmanFilter(md).run(sim.ys, [0, 0], P)
    _, Pf = steady_state(md)
    # deterministic part: the grid posterior variance is the Riccati value (discretization only:
    # measured 4e-9 relative; 1 % as before)
    np.testing.assert_allclose(g.covs[:, -1, 0, 0].mean(), Pf[0, 0], rtol=0.01)
    # path by path the grid's means are the KF's (quadrature error of the grid, measured 6e-6)
    np.testing.assert_allclose(g.means, k.means, rtol=0, atol=1e-4)
    s, sk = mse(g, sim.xs, window=0.5), mse(k, sim.xs, window=0.5)
    # so its MSE is the KF's (whose expectation is the Riccati value) to far below 3 % of it
    assert abs(s.value - sk.value) < 1e-3 * Pf[0, 0]
    assert abs(sk.value - Pf[0, 0]) < 3 * sk.stderr  # and the KF's is the Riccati value in 3 s.e.


def test_grid_sde_matches_kalman_bucy():
    md = SDEModel([x], [-x], [x], Q=1.0, R=0.5)
    sim = simulate(md, 200, paths=10, rng=1, m0=0.0, P0=0.5, dt=0.01)
    a = KalmanBucy(md, 0.01).run(sim.ys, 0.0, 0.5)
    g = GridFilter(md, (-5, 5), 301, dt=0.01).run(sim.ys, 0.0, 0.5)
    # the Markov-chain approximation is first order in the grid step (0.033) and time step
    np.testing.assert_allclose(g.means, a.means, atol=0.01)
    np.testing.assert_allclose(g.covs[:, 50:], a.covs[:, 50:], rtol=0.02)


def test_particle_filter_close_to_kf():
    md = DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=1.0)
    sim = simulate(md, 50, paths=50, rng=3, m0=0.0, P0=1.0)
    a = KalmanFilter(md).run(sim.ys, 0.0, 1.0)
    p = ParticleFilter(md, 4000).run(sim.ys, 0.0, 1.0, rng=4)
    # Monte Carlo error of a 4000-particle mean: sd/sqrt(ESS) ≈ 0.68/sqrt(2000) ≈ 0.015
    assert np.sqrt(np.mean((p.means - a.means) ** 2)) < 0.03


def test_grid_with_bounded_noise_and_impossible_measurement():
    md = DiscreteModel([x], [0.5 * x], [x], R=1 / 3, Q=1 / 3, process_noise=Independent(st.uniform(-1, 2)),
                       measurement_noise=Independent(st.uniform(-1, 2)))
    ys = np.array([[[0.2], [0.1]], [[0.2], [50.0]]])
    est = GridFilter(md, (-3, 3), 301).run(ys, initial=Independent(st.uniform(-1, 2)), m0=None, P0=None,
                                          on_divergence="mark")
    assert est.diverged.tolist() == [False, True]
    assert -1 <= est.means[0, 0, 0] <= 1


def test_grid_rejects_bad_input():
    md = DiscreteModel([x], [0.9 * x], [x], Q=0.5, R=1.0)
    with pytest.raises(ValueError, match="bounds"):
        GridFilter(md, (3, -3))
    with pytest.raises(ValueError, match="size"):
        GridFilter(md, (-3, 3), 2)
    with pytest.raises(ValueError, match="dt"):
        GridFilter(md, (-3, 3), dt=0.1)


# -- the protocol's step functions by hand = run ------------------------------------------------------
x1, x2 = sp.symbols("x1 x2")
D2 = DiscreteModel([x1, x2], [0.9 * x1 + 0.1 * x2, 0.8 * x2 - 0.05 * x1**3], [x1 + 0.1 * x2**2, x2],
                   Q=np.diag([0.1, 0.05]), R=[[0.2, 0.08], [0.08, 0.1]])
S1 = SDEModel([x], [-x**3], [x], Q=0.5, R=0.1)
M2, P2 = np.array([0.3, -0.2]), np.array([[0.5, 0.1], [0.1, 0.4]])


def _by_hand(flt, ys, m0, P0, rng):
    """The loop of ``Filter.run`` written with the public step functions (under the BLAS thread
    limit ``run`` sets for the filter, ``blas_threads``: a threaded product may sum in another
    order, and the comparison is bitwise)."""
    from nlfilter.filters.base import _blas_limit
    with _blas_limit(flt.blas_threads):
        return _by_hand_steps(flt, ys, m0, P0, rng)


def _by_hand_steps(flt, ys, m0, P0, rng):
    b = flt.init(m0, P0, ys.shape[:-2], rng=rng)
    means, covs = [], []
    for k in range(ys.shape[-2]):
        if flt.time == "continuous":
            b = flt.step(b, ys[:, k], k * flt.dt)
        else:
            off = 0 if flt.start == "update" else 1
            if k > 0 or off:
                b = flt.predict(b, k + off - 1)
            b = flt.update(b, ys[:, k], k + off)
        m, c = flt.summary(b)
        means.append(m)
        covs.append(c)
    return np.stack(means, axis=1), np.stack(covs, axis=1)


@pytest.mark.parametrize("start", ["update", "predict"])
@pytest.mark.parametrize("make", [lambda s: GridFilter(D2, [(-4.0, 4.0), (-4.0, 4.0)], 25, start=s),
                                  lambda s: ParticleFilter(D2, 300, start=s)], ids=["grid", "particle"])
def test_predict_update_by_hand_reproduce_run(make, start):
    flt = make(start)
    assert flt.time == "discrete" and flt.family == "reference" and flt.accepts == ("discrete", "sde")
    ys = simulate(D2, 8, paths=4, rng=2, m0=M2, P0=P2, start=start).ys
    ys[:, 3] = np.nan  # a fully missing step: the loop only predicts, update(NaN) leaves the belief
    ys[1, 5, 0] = np.nan  # a partly missing measurement
    est = flt.run(ys, M2, P2, rng=7)
    means, covs = _by_hand(flt, ys, M2, P2, 7)  # the same per-path streams as run(rng=7)
    np.testing.assert_array_equal(est.means, means)  # the same arithmetic, the same draws
    np.testing.assert_array_equal(est.covs, covs)
    again = flt.run(ys, M2, P2, rng=7, progress=True)
    np.testing.assert_array_equal(again.means, est.means)


@pytest.mark.parametrize("make", [lambda: GridFilter(S1, (-3.0, 3.0), 61, dt=0.05),
                                  lambda: ParticleFilter(S1, 300, dt=0.05)], ids=["grid", "particle"])
def test_step_by_hand_reproduces_run_on_an_sde(make):
    flt = make()
    assert flt.time == "continuous"
    ys = simulate(S1, 10, paths=3, rng=4, m0=[0.5], P0=[[0.3]], dt=0.05).ys
    ys[:, 4] = np.nan  # a missing increment: prediction only
    est = flt.run(ys, [0.5], [[0.3]], rng=9)
    means, covs = _by_hand(flt, ys, [0.5], [[0.3]], 9)
    np.testing.assert_array_equal(est.means, means)
    np.testing.assert_array_equal(est.covs, covs)
    with pytest.raises(TypeError, match="^predict"):
        flt.predict(flt.init([0.5], [[0.3]], (3,), rng=0), 0)


def test_step_functions_flag_an_impossible_measurement_and_reset_keeps_the_stream():
    from nlfilter.errors import DivergenceError
    md = DiscreteModel([x], [0.5 * x], [x], R=1 / 3, Q=1 / 3, process_noise=Independent(st.uniform(-1, 2)),
                       measurement_noise=Independent(st.uniform(-1, 2)))
    y = np.array([[0.2], [50.0]])
    for flt in (GridFilter(md, (-3, 3), 301), ParticleFilter(md, 200)):
        b = flt.init(None, None, (2,), initial=Independent(st.uniform(-1, 2)), rng=1)
        _, bad = flt._update_unchecked(b, y, 0)
        assert bad.tolist() == [False, True]
        with pytest.raises(DivergenceError) as info:
            flt.update(b, y, 0)
        assert info.value.paths == (1,)
        with pytest.raises(TypeError, match="^step"):
            flt.step(b, y, 0.0)
    b = flt.init(None, None, (2,), initial=Independent(st.uniform(-1, 2)), rng=1)
    moved = flt.predict(b, 0)
    r = flt.reset(moved, np.array([False, True]), b)
    assert r.rng is b.rng
    np.testing.assert_array_equal(r.x[1], b.x[1])
    np.testing.assert_array_equal(r.x[0], moved.x[0])


def test_grid_filter_reads_time_of_from_functions_model():
    """issue 10 item 8.1 (same defect as the KF's): the grid filter cached its transition kernel of
    k = 0 for every model without a time symbol; on a time-varying linear from_functions model it
    must equal the EKF, exact on a linear model (the grid's discretization error, ~1e-7 here, aside)."""
    from nlfilter.filters.ekf import EKF
    a = lambda k: 0.9 + 0.3 * np.sin(k)  # noqa: E731
    md = DiscreteModel.from_functions(1, 1, lambda x, k=0: a(k) * x + 0.3 * np.cos(k), lambda x, k=0: x,
                                      f_x=lambda x, k=0: np.full((*np.shape(x)[:-1], 1, 1), a(k)),
                                      h_x=lambda x, k=0: np.ones((*np.shape(x)[:-1], 1, 1)),
                                      Q=[[0.1]], R=[[0.2]], is_linear=True)
    ys = np.random.default_rng(1).normal(size=(2, 25, 1))
    kf = EKF(md).run(ys, [0.0], [[0.5]])
    g = GridFilter(md, (-6, 6), 801).run(ys, 0.0, 0.5)
    np.testing.assert_allclose(g.means, kf.means, atol=1e-5)
    np.testing.assert_allclose(g.covs, kf.covs, atol=1e-5)


def test_grid_blas_threads_do_not_change_the_numbers():
    """The grid filters run with one BLAS thread (``blas_threads = 1``, threadpoolctl once per run:
    no thread cliff on small products); the BLAS library's default threads give the same
    estimates (to 1e-12: a threaded product may sum in another order)."""
    import sympy as sp
    from nlfilter import DiscreteModel, simulate
    from nlfilter.filters import GridFilter
    from threadpoolctl import threadpool_info
    x = sp.Symbol("x")
    md = DiscreteModel([x], [0.9 * x + 0.5 * sp.sin(x)], [x**3 / 10], Q=0.5, R=0.1)
    ys = simulate(md, 20, paths=30, rng=0, m0=[0.0], P0=[[1.0]]).ys
    flt = GridFilter(md, (-6.0, 6.0), 201)
    before = [i["num_threads"] for i in threadpool_info()]
    one = flt.run(ys, [0.0], [[1.0]])
    assert [i["num_threads"] for i in threadpool_info()] == before  # restored after the run
    flt.blas_threads = None
    default = flt.run(ys, [0.0], [[1.0]])
    np.testing.assert_allclose(one.means, default.means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(one.covs, default.covs, rtol=0, atol=1e-12)


def test_particle_filter_batched_draws_weights_and_moments():
    """issue 28 item 6: the particle filter draws a Gaussian noise for all paths at once, keeps
    each step's normalized weights in its belief and takes the cloud moments by matrix products.
    The draws are ``PathRNG.sample``'s, bitwise (common random numbers: path p's numbers do not
    depend on how they are batched); the weights are ``weights(logw)``, bitwise, on live and dead
    paths alike; the moments agree with a long-double evaluation of their definition to 1e-13
    (a sum of 500 doubles: rounding ≲ 500 · 2⁻⁵³ ≈ 6e-14 of the terms' size)."""
    from nlfilter import Gaussian
    from nlfilter.filters.pointmass import cloud_moments, weights
    from nlfilter.filters.reference.particle import _draw
    from nlfilter.streams import PathRNG
    for cov in ([[0.3]], [[0.5, 0.1], [0.1, 0.2]]):
        law = Gaussian(cov, mean=np.arange(len(cov)) + 0.5)
        np.testing.assert_array_equal(_draw(law, PathRNG(3, 4), (50,)), PathRNG(3, 4).sample(law, (50,)))
    rng = np.random.default_rng(0)
    logw = 3.0 * rng.standard_normal((4, 500))
    dead = logw.copy()
    dead[2] = -np.inf
    with np.errstate(invalid="ignore"):  # the dead row's 0/0, replaced by uniform weights (as in run)
        wd = weights(dead)
    np.testing.assert_array_equal(wd[[0, 1, 3]], weights(logw)[[0, 1, 3]])
    np.testing.assert_array_equal(wd[2], np.full(500, 1 / 500))
    x = 5.0 + rng.standard_normal((4, 500, 3)) * [0.1, 1.0, 3.0]
    w = weights(logw)
    mean, cov = cloud_moments(w, x)
    xl, wl = x.astype(np.longdouble), w.astype(np.longdouble)
    ml = np.einsum("bp,bpi->bi", wl, xl)
    d = xl - ml[:, None, :]
    np.testing.assert_allclose(mean, ml.astype(float), rtol=1e-13, atol=0)
    np.testing.assert_allclose(cov, np.einsum("bp,bpi,bpj->bij", wl, d, d).astype(float), rtol=1e-13, atol=1e-16)
    flt = ParticleFilter(D2, 200)
    b = flt.update(flt.init(M2, P2, (3,), rng=1), np.array([[0.3, 0.1], [np.nan, np.nan], [1.0, -0.5]]), 0)
    np.testing.assert_array_equal(b.w, weights(b.logw))  # the update's weights, kept for summary, ESS, resampling
    assert flt.reset(b, np.array([True, False, False]), flt.init(M2, P2, (3,), rng=1)).w is None


def test_particle_filter_means_only_gives_the_same_means():
    """The certificate's refinement run reads only its MSE (yardstick._check sets ``means_only``):
    the same means, bitwise (the same draws and weights), and no covariances (NaN)."""
    ys = simulate(D2, 6, paths=3, rng=2, m0=M2, P0=P2).ys
    flt = ParticleFilter(D2, 100)
    full = flt.run(ys, M2, P2, rng=5)
    flt.means_only = True
    lean = flt.run(ys, M2, P2, rng=5)
    np.testing.assert_array_equal(lean.means, full.means)
    np.testing.assert_array_equal(lean.extras["ess"], full.extras["ess"])
    assert np.isnan(lean.covs).all()
