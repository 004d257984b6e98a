"""Sample paths of a model: true states and measurements for many trajectories at once.

Every filter in a comparison is run on the same :class:`Simulation`, so they all see identical
noise (common random numbers). Each path draws from a stream of its own
(:mod:`nlfilter.streams`: path ``p`` from ``SeedSequence(seed).spawn(P)[p]``), in a fixed order
per path documented by each simulator (initial state, then process noise, then measurement
noise), so a path depends on the seed and its index only: ``paths=range(a, b)`` simulates the
rows ``a..b-1`` of the run on all paths, bitwise, and a run can be split into chunks or spread
over processes.

* Discrete models: ``xs[..., k, :]`` is the state measured by ``ys[..., k, :]``; the step
  convention (``start``) is that of :mod:`nlfilter.filters.base`.
* SDE models (Euler–Maruyama, strong order 1/2, weak order 1, with ``substeps`` steps per
  measurement step ``dt``): ``ys[..., k, :]`` is the increment ``dy`` over ``[t_k, t_{k+1}]``
  and ``xs[..., k, :]`` the state at ``t_{k+1}``, which is what a continuous filter estimates
  after that increment.

Every :class:`Simulation` carries its :class:`Timing` (``sim.timing``: the kind of measurement,
``start``, ``t0``, ``dt``); a filter run on the Simulation itself (``flt.run(sim, m0, P0)``) reads
it, so that the data and the filter cannot silently disagree (:meth:`~nlfilter.filters.base.Filter.for_timing`).
"""

from __future__ import annotations

import math
import numpy as np

from . import _validate as V
from .angles import angles_of, wrap_components
from .errors import DivergenceError
from .filters.linalg import sqrt_psd
from .model_noise import check_horizon
from .noise import Gaussian, NoiseLaw, initial_states  # noqa: F401  (initial_states: the simulators' first draw)
from .ode import ode_step
from .sde_step import SUBSTEPS, euler_maruyama
from .simulation import Simulation, Timing
from .streams import PathRNG, as_paths

_BLOCK = 2 ** 20  # SDE simulators: standard normals drawn per block of steps (bounded memory)


class _Screen:
    """The divergence screen of a simulation (``on_divergence``): a state or measurement that became
    non-finite raises a :class:`~nlfilter.errors.DivergenceError` naming the step and the paths, or
    (``"mark"``) the path is recorded, goes on harmlessly from its initial state, and its ``xs``/``ys``
    are NaN from that step on (:meth:`finish`). One finite-sum test per check when all is well."""

    def __init__(self, on_divergence, rng, name):
        self.on = V.choice("on_divergence", on_divergence, {"raise", "mark"})
        self.paths, self.name = rng.paths, name
        self.step = np.full(len(rng), -1)

    def check(self, k, *arrays, x=None, restart=None):
        """Screen step ``k`` of the ``(P, ...)`` arrays; return ``x`` with the diverged paths restarted."""
        if all(math.isfinite(np.add.reduce(a, axis=None)) for a in arrays):
            return x
        P = self.step.size
        bad = np.zeros(P, bool)
        for a in arrays:
            bad |= ~np.isfinite(a.reshape(P, -1)).all(axis=1)
        new = bad & (self.step < 0)
        if new.any():
            idx = np.flatnonzero(new)
            if self.on == "raise":
                first = [self.paths[i] for i in idx[:5]]
                raise DivergenceError(
                    f"{self.name}: the simulated state or measurement became non-finite at step {k} on {idx.size} "
                    f"path(s), first {first}; pass on_divergence='mark' to record such paths (NaN from that "
                    "step on) and go on", step=k, paths=[self.paths[i] for i in idx], what="state")
            self.step[new] = k
        return x if x is None else np.where(bad[:, None], restart, x)

    def finish(self, xs, ys):
        """NaN in ``xs``, ``ys`` of the diverged paths from their step on."""
        for p in np.flatnonzero(self.step >= 0):
            xs[p, self.step[p]:] = np.nan
            ys[p, self.step[p]:] = np.nan


def _start(model, steps, paths, rng, m0, P0, x0, initial, width=0):
    """Checked sizes, the per-path generators, the initial states (each path's first draw) and
    their copy, and the state buffer ``(P, steps, n)`` of a simulation (``width``: the numbers
    per path and step besides the states, for the memory bound)."""
    _sizes(steps, paths, model.n + width)
    rng = PathRNG.of(rng, paths)
    x = initial_states(model.n, paths, rng, m0=m0, P0=P0, x0=x0, initial=initial)
    return rng, x, x.copy(), np.empty((len(rng), steps, model.n))


def _sizes(steps, paths, width):
    """``steps`` and ``paths`` checked, and the ``paths × steps × width`` float64 numbers of the
    outputs and noises bounded (:data:`~nlfilter._validate.MEMORY_BOUND`), before any draw."""
    V.positive("steps", steps, integer=True)
    P = len(paths) if isinstance(paths, PathRNG) else len(as_paths(paths))
    V.memory("steps/paths", 8.0 * P * steps * width,
             f"steps={steps} × paths={P} ({width} number(s) per path and step: states, measurements, noises)")


def _path_rows(model, rng, paths):
    """The model restricted to the simulated paths: per-path parameter or input arrays
    ``(P, T)`` (:meth:`~nlfilter.models.Model.with_params`) give rows ``a..b-1`` for
    ``paths=range(a, b)``; for ``paths=P`` they must have exactly ``P`` rows."""
    rows = getattr(model, "_rows", None)
    per = {p: model._values.values[p] for p in getattr(getattr(model, "_values", None), "per_path", ())}
    per.update({nm: a for nm, a in getattr(model, "_steps", {}).items() if a.ndim == 4})  # per-path Q/R per step
    if rows is None or not per:
        return model
    if not isinstance(paths, range) and not isinstance(paths, PathRNG):
        for p in per:
            B = per[p].shape[0]
            if B != len(rng):
                raise ValueError(f"{p}: a per-path array with {B} row(s) for paths={paths!r}; expected "
                                 f"{len(rng)} rows (or paths=range(a, b) to take rows a..b-1)")
    return rows(rng.paths)


def _blocks(steps, paths, width):
    """Steps ``[(k0, k1), ...]`` in blocks of at most ``_BLOCK`` numbers over all paths
    (``width`` per path and step). Numpy fills ``standard_normal`` sequentially, so per-path
    draws of consecutive blocks equal one draw of all steps: the result does not depend on it."""
    K = max(1, _BLOCK // max(1, paths * width))
    return [(k, min(k + K, steps)) for k in range(0, steps, K)]


def simulate(model, steps: int, *, paths: int | range = 1, rng=None, m0=None, P0=None, x0=None,
             initial: NoiseLaw | None = None, start: str = "update", dt: float | None = None,
             substeps: int = SUBSTEPS, t0: float = 0.0, on_divergence: str = "raise") -> Simulation:
    """Simulate ``paths`` trajectories of ``steps`` measurement steps.

    Parameters
    ----------
    model : DiscreteModel or SDEModel
    steps : number of measurements T
    paths : number of independent trajectories (the leading axis of every output), or a
        ``range`` of path indices: ``paths=range(a, b)`` gives rows ``a..b-1`` of the run on all paths
    rng : seed, ``SeedSequence``, ``Generator`` or :class:`~nlfilter.streams.PathRNG` (the root of
        the per-path streams, :mod:`nlfilter.streams`).
        Draws of a path, in order: its initial state (unless ``x0``); discrete models: the process
        noises of all steps, then the measurement noises of all steps; SDE models: per measurement
        step, the ``substeps × r`` standard normals of the Brownian increments, then the ``m`` of
        the measurement noise.
    m0, P0, x0, initial : the initial state: drawn from N(m0, P0), fixed ``x0``, or drawn from
        the noise law ``initial`` (a non-Gaussian prior)
    start : discrete models only, ``"update"`` or ``"predict"`` (see :mod:`nlfilter.filters.base`)
    dt, substeps, t0 : SDE models only: measurement step, Euler–Maruyama steps per measurement
        step (default :data:`~nlfilter.sde_step.SUBSTEPS`, recorded in ``sim.timing.substeps``),
        initial time
    on_divergence : ``"raise"`` (default): a state or measurement that becomes non-finite (an
        unstable map, an Euler step too large for the drift) raises a
        :class:`~nlfilter.errors.DivergenceError` naming the step and the paths; ``"mark"``: such a
        path has NaN ``xs``/``ys`` from that step on (:attr:`Simulation.diverged`,
        :attr:`Simulation.diverged_step`), the other paths are unchanged

    Notes
    -----
    A state-dependent measurement noise (``R_of``) draws ``v_k = L(x_k) z_k``, ``L Lᵀ = R(x_k)``
    (Cholesky), ``z_k`` standard normal in the place of the measurement noise. Correlated noise
    (``cross_noise``) draws ``(w_k, v_k)`` jointly, one ``N(0, [[Q, S], [Sᵀ, R]])`` vector per step
    (``steps`` pairs, one more with ``start="predict"``, in place of the process then
    measurement noises); ``w_j`` drives ``x[j+1]`` and ``v_j`` corrupts ``y_j`` (the filters'
    convention). Non-additive noise
    (``noise=``, ``meas_noise=``): ``x[k+1] = f(x[k], w[k])``, ``y[k] = h(x[k], v[k])``.

    Parameters or inputs given as arrays (:meth:`~nlfilter.models.Model.with_params`,
    :meth:`~nlfilter.models.Model.with_inputs`) are read at step ``k`` as a filter reads them
    (``x[k+1] = f(x[k], k) + ...`` uses entry ``k``); per-path arrays ``(P, T)`` give row ``p``
    to path ``p`` (rows ``a..b-1`` for ``paths=range(a, b)``).

    Examples
    --------
    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> sim = simulate(SDEModel([x], [-x], [x], Q=1.0, R=1.0), 5, paths=3, rng=0, m0=0.0, P0=1.0, dt=0.1)
    >>> sim.xs.shape, sim.ys.shape, sim.t.round(2).tolist()
    ((3, 5, 1), (3, 5, 1), [0.1, 0.2, 0.3, 0.4, 0.5])
    """
    t0 = V.real("t0", t0)
    V.choice("on_divergence", on_divergence, {"raise", "mark"})
    if getattr(model, "kind", None) not in ("discrete", "sde"):
        raise TypeError(f"model: expected a DiscreteModel or an SDEModel, got {type(model).__name__} {V.shown(model)}")
    rng, x, x_init, xs = _start(model, steps, paths, rng, m0, P0, x0, initial,
                                width=2 * getattr(model, "m", 0) + getattr(model, "r", 0))
    screen = _Screen(on_divergence, rng, "simulate")
    model = _path_rows(model, rng, paths)
    m, paths = model.m, len(rng)
    ys = np.empty((paths, steps, m))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # what overflows is screened
        sim = _simulate(model, steps, paths, rng, x, x_init, xs, ys, m, start, dt, substeps, t0, screen)
    screen.finish(sim.xs, sim.ys)
    return sim


def _simulate(model, steps, paths, rng, x, x_init, xs, ys, m, start, dt, substeps, t0, screen):
    """The loops of :func:`simulate`, its checks done."""
    if model.kind == "discrete":
        if dt is not None:
            raise ValueError(f"dt: a DiscreteModel has no time step; expected None, got {dt!r}")
        offset = 1 if V.choice("start", start, {"update", "predict"}) == "predict" else 0
        check_horizon(model, steps, paths, offset)  # Q/R given per step: long enough, one row per path
        Rx = not getattr(model, "R_constant", True)  # v_k ~ N(0, R(x_k)): standard normals, scaled at the state
        if getattr(model, "cross_noise", None) is not None:  # (w_j, v_j) jointly Gaussian, E[w_j v_jᵀ] = S
            # pair j at model time j: v_j corrupts y_j, w_j drives x_{j+1}
            wv = rng.draw(lambda g, s: model._joint_noise.sample(g, s), (steps + offset,))
            w, v = wv[:, :steps, :model.r], wv[:, offset:, model.r:]  # w[:, k]: the noise into step k + offset
            w = np.concatenate([np.full_like(w[:, :1], np.nan), w[:, :-1]], axis=1) if not offset else w
        else:
            vlaw = Gaussian(np.eye(m)) if Rx else model.measurement_noise
            w, v = rng.draw(lambda g, s: (model.process_noise.sample(g, s), vlaw.sample(g, s)), (steps,))
        ang = angles_of(model)  # angular states and measurements wrapped to (−π, π] (nlfilter.angles)
        x = wrap_components(x, ang.states)
        for k in range(steps):
            if k > 0 or offset:
                j = k + offset - 1
                x = wrap_components(model.transition(x, w[:, k], j), ang.states)
                x = screen.check(k, x, x=x, restart=x_init)
            xs[:, k] = x
            vk = v[:, k]
            if Rx:  # R(x_k) = L Lᵀ (R_of raises where it is not positive definite); R_k per step: a PSD root
                Rk = model.R_of(x, k + offset)
                L = sqrt_psd(Rk)[0] if model._R_kind == "time" else np.linalg.cholesky(Rk)
                vk = np.einsum("...ij,...j->...i", L, vk)
            ys[:, k] = wrap_components(model.h(x, k + offset) + vk if getattr(model, "additive_measurement", True)
                                       else model.measurement(x, vk, k + offset), ang.measurements)
            screen.check(k, ys[:, k])
        return Simulation(xs, ys, x_init, np.arange(steps) + offset, Timing("discrete", start, 0.0, None))
    if model.kind != "sde":
        raise TypeError(f"model: expected a DiscreteModel or SDEModel, got {type(model).__name__}")
    if dt is None:
        raise ValueError("dt: expected the measurement step of the SDE, got None")
    dt = float(V.positive("dt", dt))
    V.positive("substeps", substeps, integer=True)
    V.time_grid(t0, dt, steps)
    sq_h = np.sqrt(dt / substeps)
    LQ = model.process_noise._sqrt
    LR = model.measurement_noise._sqrt
    r = model.r
    for k0, k1 in _blocks(steps, paths, substeps * r + m):
        z = rng.standard_normal((k1 - k0, substeps * r + m))  # (paths, K, substeps·r + m)
        for k in range(k0, k1):
            dB = z[:, k - k0, :substeps * r].reshape(paths, substeps, r) @ LQ.T * sq_h
            x, ydt = euler_maruyama(model, x, t0 + k * dt, dt, substeps, dB)  # ∫ h dt, left point
            x = wrap_components(x, angles_of(model).states)  # angular states (increments dy are not angles)
            xs[:, k] = x
            ys[:, k] = ydt + z[:, k - k0, substeps * r:] @ LR.T * np.sqrt(dt)
            x = screen.check(k, x, ys[:, k], x=x, restart=x_init)
    return Simulation(xs, ys, x_init, t0 + dt * np.arange(1, steps + 1), Timing("increments", None, t0, dt, int(substeps)))


def simulate_phase(q: float, r: float, dt: float, steps: int, paths: int | range, rng, *, substeps: int = 4,
                   theta0=None):
    """The phase-tracking problem (seed 001 ch. 4, :class:`~nlfilter.bilinear.PhaseModel`):
    phase paths ``theta (paths, steps)`` at ``t_k = k dt`` (k = 1..steps, aligned with a filter's
    estimates) and baseband increments ``dzs (paths, steps, 2)``: θ exact Brownian increments on
    ``substeps`` sub-intervals, ``∫ (sin θ, cos θ) dt`` by the trapezoidal rule,
    ``dn ~ N(0, 2 r dt I)`` (001 eq. 4.14). θ0 uniform on the circle unless ``theta0`` is given.
    ``paths``, ``rng``: as :func:`simulate`. Draws of a path: θ0, then per step the ``substeps``
    normals of θ, then the 2 of ``dn``."""
    for nm, v in (("q", q), ("r", r), ("dt", dt)):
        V.positive(nm, v)
    _sizes(steps, paths, 3)
    V.positive("substeps", substeps, integer=True)
    rng = PathRNG.of(rng, paths)
    paths = len(rng)
    h = dt / substeps
    if theta0 is not None:
        theta0 = V.finite("theta0", V.as_float_array("theta0", theta0))
        if theta0.ndim > 1 or theta0.size not in (1, paths):
            raise ValueError(f"theta0: expected a number or one per path ({paths},), got shape {theta0.shape}")
    th = rng.uniform(-np.pi, np.pi, ()) if theta0 is None else np.broadcast_to(theta0, (paths,)).astype(float)
    thetas = np.empty((paths, steps))
    dzs = np.empty((paths, steps, 2))
    sq = np.sqrt(q * h)
    sn = np.sqrt(2 * r * dt)
    for k0, k1 in _blocks(steps, paths, substeps + 2):
        z = rng.standard_normal((k1 - k0, substeps + 2))
        for k in range(k0, k1):
            acc1 = np.zeros(paths)
            acc2 = np.zeros(paths)
            for j in range(substeps):
                tn = th + sq * z[:, k - k0, j]
                acc1 += 0.5 * h * (np.sin(th) + np.sin(tn))
                acc2 += 0.5 * h * (np.cos(th) + np.cos(tn))
                th = tn
            thetas[:, k] = th
            dzs[:, k, 0] = acc1 + sn * z[:, k - k0, substeps]
            dzs[:, k, 1] = acc2 + sn * z[:, k - k0, substeps + 1]
    return thetas, dzs


def simulate_ou(q: float, r: float, dt: float, steps: int, paths: int | range, rng, *, h=None, rate: float = 1.0,
                substeps: int = 4, on_divergence: str = "raise") -> Simulation:
    """A stationary Ornstein–Uhlenbeck state ``dx = −rate · x dt + dw`` (``E dw² = q dt``) seen
    through ``dy = h(x) dt + dv`` (``E dv² = r dt``; ``h`` a vectorized function, default the
    cubic sensor's ``x³``, seed 001 eqs. 5.1-5.4), as a :class:`Simulation` (``xs (paths, steps, 1)``
    at ``t_k = k dt``, k = 1..steps, ``ys`` the increments ``dy``): x by its *exact* Gaussian
    transition on ``substeps`` sub-intervals (no Euler bias in the state), ``∫ h(x) dt`` by the
    trapezoidal rule on them; ``x0 ~ N(0, q / (2 rate))``, the stationary law. ``paths``, ``rng``:
    as :func:`simulate`. Draws of a path: ``x0``, then per step the ``substeps`` transitions and
    the measurement noise. ``on_divergence``: as :func:`simulate` (an ``h`` that overflows).

    >>> sim = simulate_ou(2.0, 1.0, 0.01, 5, 3, np.random.default_rng(0))
    >>> sim.xs.shape, sim.ys.shape, sim.x0.shape
    ((3, 5, 1), (3, 5, 1), (3, 1))
    """
    for nm, v in (("q", q), ("r", r), ("dt", dt), ("rate", rate)):
        V.positive(nm, v)
    _sizes(steps, paths, 2)
    V.positive("substeps", substeps, integer=True)
    V.choice("on_divergence", on_divergence, {"raise", "mark"})
    rng = PathRNG.of(rng, paths)
    screen = _Screen(on_divergence, rng, "simulate_ou")
    paths = len(rng)
    if h is None:
        h = lambda x: x ** 3  # noqa: E731
    dh = dt / substeps
    a = np.exp(-rate * dh)
    var = q / (2 * rate)
    sd = np.sqrt(var * (1 - a * a))
    x = np.sqrt(var) * rng.standard_normal(())
    x0 = x.copy()
    xs = np.empty((paths, steps))
    dys = np.empty((paths, steps, 1))
    with np.errstate(over="ignore", invalid="ignore"):  # what overflows is screened
        for k0, k1 in _blocks(steps, paths, substeps + 1):
            z = rng.standard_normal((k1 - k0, substeps + 1))
            for k in range(k0, k1):
                acc = np.zeros(paths)
                for j in range(substeps):
                    xn = a * x + sd * z[:, k - k0, j]
                    acc += 0.5 * dh * (h(x) + h(xn))
                    x = xn
                xs[:, k] = x
                dys[:, k, 0] = acc + np.sqrt(r * dt) * z[:, k - k0, substeps]
                screen.check(k, dys[:, k])
    sim = Simulation(xs[..., None], dys, x0[:, None], dt * np.arange(1, steps + 1), Timing("increments", None, 0.0, float(dt)))
    screen.finish(sim.xs, sim.ys)
    return sim


def simulate_continuous_discrete(model, steps: int, *, paths: int | range = 1, rng=None, m0=None, P0=None, x0=None,
                                 initial: NoiseLaw | None = None, dt: float | None = None,
                                 substeps: int = SUBSTEPS, t0: float = 0.0, on_divergence: str = "raise", times=None,
                                 process: str = "euler-maruyama") -> Simulation:
    """An :class:`~nlfilter.models.SDEModel` with *discrete* measurements (the continuous-discrete
    setting of :class:`~nlfilter.filters.second_order.ContinuousDiscreteSecondOrderFilter`: the
    model's ``h``/``R`` read as ``y_k = h(x(t_k)) + v_k``, ``v_k ~ N(0, R)``, ``t_k = t0 + k dt``,
    k = 1..steps). Between measurements, ``process="euler-maruyama"`` (the default): the SDE
    ``dx = f dt + G dβ`` by ``substeps`` Euler–Maruyama steps per interval (default
    :data:`~nlfilter.sde_step.SUBSTEPS`, whatever the interval's length), ``x += f(x, s) h +
    G(x, s) w``, ``w ~ N(0, Q h)``, ``h`` the interval over ``substeps`` (the SDE's law up to the
    scheme's O(h) error, whatever the dynamics; ``timing.substeps`` records ``substeps``). It is
    the scheme of :class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter` (which
    takes the data's ``substeps``, and :data:`~nlfilter.sde_step.SUBSTEPS` too when not told),
    of :func:`~nlfilter.comparison.compare` and of ``nlfilter simulate`` on a continuous-discrete
    model file, which read these defaults: the reference has the simulator's model exactly.
    ``process="flow"`` (only when asked for): the drift integrated by classical RK4 in ``substeps``
    steps (:func:`~nlfilter.ode.ode_step`), and when ``Q ≠ 0`` one Euler–Maruyama noise increment
    ``G(x, t_k) w``, ``w ~ N(0, Q dt)``, added per interval after the flow (a coarse model of the
    process noise, for nearly deterministic dynamics such as the falling body, whose RK4 flow is
    far more accurate than Euler steps; ``timing.substeps`` None: no particle reference has this
    model). Draws ``steps × substeps × r`` process normals (``steps × r`` with the flow).
    Returns a :class:`Simulation` with ``xs[:, k] = x(t_{k+1})``, ``ys[:, k]`` its measurement, and
    ``timing = Timing("continuous-discrete", "predict", t0, dt)``: the prior at ``t0``, the first
    measurement one interval later (the continuous-discrete filters' default). ``times`` in place
    of ``dt``: the measurement times ``t_1 < ... < t_steps`` after ``t0`` (irregular intervals, each
    integrated in ``substeps`` steps; ``timing.times`` carries them, ``timing.dt`` is None, and a
    continuous-discrete filter built with ``dt=None`` takes them: :mod:`nlfilter.filters.irregular`).
    ``paths``, ``rng``: as :func:`simulate`. Draws of a path: its initial state (unless ``x0``),
    the standard normals of the process noise (only when ``Q ≠ 0``), then the ``steps × m`` of
    the measurement noise. ``on_divergence``: as :func:`simulate`.

    >>> from nlfilter import problems
    >>> p = problems.falling_body()
    >>> sim = simulate_continuous_discrete(p.model, 4, paths=2, rng=0, x0=p.x0, dt=p.dt)
    >>> sim.xs.shape, sim.ys.shape, sim.t.tolist()
    ((2, 4, 3), (2, 4, 1), [1.0, 2.0, 3.0, 4.0])
    """

    if getattr(model, "kind", None) != "sde":
        raise TypeError(f"model: expected an SDEModel (continuous dynamics), got {type(model).__name__}")
    t0 = V.real("t0", t0)
    if (dt is None) == (times is None):
        raise ValueError(f"dt, times: expected one of them (a regular interval or the measurement times), got "
                         f"dt={dt!r} and times={'None' if times is None else 'an array'}")
    if times is not None:
        times = V.measurement_times("times", times, t0)
        if len(times) != steps:
            raise ValueError(f"times: got {len(times)} times; expected steps = {steps}")
    else:
        dt = float(V.positive("dt", dt))
    V.positive("substeps", substeps, integer=True)
    V.choice("on_divergence", on_divergence, {"raise", "mark"})
    em = V.choice("process", process, {"flow", "euler-maruyama"}) == "euler-maruyama"
    rng, x, x_init, xs = _start(model, steps, paths, rng, m0, P0, x0, initial, width=2 * model.m + model.r)
    screen = _Screen(on_divergence, rng, "simulate_continuous_discrete")
    model = _path_rows(model, rng, paths)
    m, paths = model.m, len(rng)
    noisy = np.any(model.Q != 0)
    L = np.linalg.cholesky(model.R)
    grid = None if times is None else np.concatenate([[t0], times])
    SQ = Gaussian(model.Q * dt)._sqrt if times is None else None  # Q dt = SQ SQᵀ (Q may be singular)
    wshape = (substeps, model.r) if em else (model.r,)
    w, v = rng.draw(lambda g, s: (g.standard_normal((*s, *wshape)) if noisy else np.empty((*s, 0)),
                                  g.standard_normal((*s, m))), (steps,))
    v = v @ L.T
    if times is None:
        V.time_grid(t0, dt, steps)
    t = t0 + dt * np.arange(1, steps + 1) if times is None else np.array(times)
    ys = np.empty((paths, steps, m))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # what overflows is screened
        for k in range(steps):
            tk, dk = (t0 + k * dt, dt) if times is None else (grid[k], grid[k + 1] - grid[k])
            if em:
                x = _euler_maruyama(model, x, tk, dk, substeps, w[:, k] if noisy else None)
            else:
                x = ode_step(model.f, x, tk, dk, substeps=substeps, scheme="rk4")
            if noisy and not em:
                S = SQ if times is None else Gaussian(model.Q * dk)._sqrt
                x = x + np.einsum("pia,pa->pi", model.G(x, tk), w[:, k] @ S.T)
            x = wrap_components(x, angles_of(model).states)  # angles wrapped (nlfilter.angles)
            xs[:, k] = x
            ys[:, k] = wrap_components(model.h(xs[:, k], t[k]) + v[:, k], angles_of(model).measurements)
            x = screen.check(k, x, ys[:, k], x=x, restart=x_init)
    screen.finish(xs, ys)
    timing = Timing("continuous-discrete", "predict", t0, dt, substeps if em else None,
                    None if times is None else tuple(times.tolist()))
    return Simulation(xs, ys, x_init, t, timing)


def _euler_maruyama(model, x, t, dt, substeps, z):
    """``substeps`` Euler–Maruyama steps of ``dx = f dt + G dβ`` over ``[t, t + dt]`` from ``x (P, n)``;
    ``z (P, substeps, r)`` standard normals (None: no process noise)."""
    h = dt / substeps
    S = Gaussian(model.Q * h)._sqrt if z is not None else None
    for j in range(substeps):
        s = t + j * h
        step = model.f(x, s) * h
        if z is not None:
            step = step + np.einsum("pia,pa->pi", model.G(x, s), z[:, j] @ S.T)
        x = x + step
    return x

