"""The particle reference of an SDE measured at discrete, possibly irregular times (the
continuous-discrete setting of :func:`~nlfilter.simulate.simulate_continuous_discrete`):

    dx = f(x, t) dt + G(x, t) dβ,    E dβ dβᵀ = Q dt,
    y_k = h(x(t_k), t_k) + v_k,      v_k ~ N(0, R),   t_0 < t_1 < t_2 < ...

A bootstrap particle filter (:class:`~nlfilter.filters.reference.ParticleFilter`'s resampling,
weights, moments and per-path streams): between ``t_{k-1}`` and ``t_k`` every particle takes the
``substeps`` Euler–Maruyama steps of length ``δ_k = (t_k − t_{k-1}) / substeps``

    x_{j+1} = x_j + f(x_j, s_j) δ_k + G(x_j, s_j) ΔB_j,   ΔB_j ~ N(0, Q δ_k),   s_j = t_{k-1} + j δ_k,

which is :func:`~nlfilter.simulate.simulate_continuous_discrete`'s default scheme
(``process="euler-maruyama"``, :data:`~nlfilter.sde_step.SUBSTEPS` steps) term by term (the
same number of steps per interval, whatever its length): at equal ``substeps`` the filter has
the simulator's model exactly, and is the optimal filter of the data
as the particles grow (a reference integrating more finely would have another model, which a
filter can beat). Each particle is then weighted by the measurement density ``N(y_k; h(x_i,
t_k), R)`` (missing components: their marginal; angular measurements: wrapped residuals).

``substeps`` None takes the data's when run on a Simulation that records them
(``sim.timing.substeps``, made by the default ``process="euler-maruyama"``), else
:data:`~nlfilter.sde_step.SUBSTEPS`. The times are those of the data (``dt=None``: a Simulation's
``times`` or ``dt``), a regular ``dt``, or :meth:`at_times` (:mod:`nlfilter.filters.irregular`),
with the prior at ``t0`` and the first measurement at ``t_1`` (``start="predict"``, the default)
or at ``t0`` itself (``start="update"``).
"""

from __future__ import annotations

from ... import _validate as V
from ...angles import angles_of, wrap_components
from ..checks import check_structure
from ..irregular import at_times, belief_time, check_length, interval
from ..timing import set_start, set_t0
from .particle import ParticleFilter


class ContinuousDiscreteParticleFilter(ParticleFilter):
    """Bootstrap particle filter of an SDE measured at discrete times (module docstring):
    ``predict`` moves the particles through the Euler–Maruyama steps of the interval, ``update``
    weighs them by ``N(y; h(x), R)``.

    Parameters
    ----------
    model : SDEModel; its ``h`` and ``R`` read as ``y_k = h(x(t_k)) + v_k``, ``v_k ~ N(0, R)``
    dt : the measurement interval; None: the data's (a Simulation's ``dt`` or ``times``), or
        :meth:`at_times`
    particles : particles per path
    substeps : Euler–Maruyama steps per measurement interval; None: the data's (a Simulation
        made with ``process="euler-maruyama"``) or :data:`~nlfilter.sde_step.SUBSTEPS`
    threshold : resample when ESS < threshold · particles
    start, t0 : as :class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter`: the
        prior at ``t0`` (default 0.0), the first measurement one interval later (``"predict"``,
        default) or at ``t0`` (``"update"``)

    Examples
    --------
    >>> import numpy as np, sympy as sp; from nlfilter import SDEModel
    >>> from nlfilter.simulate import simulate_continuous_discrete
    >>> x = sp.Symbol("x")
    >>> md = SDEModel([x], [-x], [x], Q=1.0, R=0.1)
    >>> sim = simulate_continuous_discrete(md, 3, paths=2, rng=0, m0=[0.0], P0=[[0.5]], times=[0.2, 0.5, 1.5],
    ...                                    substeps=4)    # Euler–Maruyama, the default process
    >>> flt = ContinuousDiscreteParticleFilter(md, None, 500)
    >>> est = flt.run(sim, [0.0], [[0.5]], rng=1)          # the data's times and substeps
    >>> est.means.shape, flt.for_timing(sim.timing)[0].substeps
    ((2, 3, 1), 4)
    """

    name = "cd-particle"
    source = ("bootstrap particle filter (Gordon, Salmond & Smith 1993) through the Euler–Maruyama steps of "
              "the SDE between discrete measurements (Kloeden & Platen 1992, §9.1), systematic resampling")
    accepts = ("sde",)
    structures = ("angles",)
    measurement_convention = ""  # discrete measurements: no increments
    smoother = None  # the Euler–Maruyama path of an interval has no transition density for FFBSm
    time = "discrete"  # predict/update (the run loop's discrete steps) at the measurement times
    start = "predict"
    times = None  # the measurement times t_1 < t_2 < ... when irregular (at_times)

    def __init__(self, model, dt: float | None = None, particles: int = 2000, *, substeps: int | None = None,
                 threshold: float = 0.5, start: str | None = None, t0: float | None = None):
        if getattr(model, "kind", None) != "sde":
            raise TypeError(f"model: {type(self).__name__} expects an SDEModel, got {type(model).__name__}")
        self._options(particles, substeps, threshold)
        check_structure(self, model)
        if not model.measurement_noise.has_density:  # the weights are the density of y_k = h + v_k
            raise ValueError(f"measurement_noise: the continuous-discrete particle filter needs a law with a density "
                             f"(logpdf); got {model.measurement_noise!r} (a Gaussian has none when its covariance R "
                             "is singular)")
        self.model = model
        set_start(self, start)
        self.dt = None if dt is None else float(V.positive("dt", dt))
        set_t0(self, t0)

    def _set_smoother(self):
        """No smoother (the class's ``smoother`` is None)."""

    at_times = at_times  # flt.at_times(times): a copy measuring at t_1 < t_2 < ... (nlfilter.filters.irregular)

    def check_data(self, ys):
        ys = super().check_data(ys)
        check_length(self, ys.shape[-2])
        return ys

    def _at(self, k):
        return belief_time(self, k)

    def _propagate(self, x, k, rng):
        """The particles from the belief time of ``k`` to that of ``k + 1``: ``substeps``
        Euler–Maruyama steps (angular states wrapped at the end, as the simulator does)."""
        x, _ = self._euler_maruyama(x, belief_time(self, k), interval(self, k), rng)
        return wrap_components(x, angles_of(self.model).states)


__all__ = ["ContinuousDiscreteParticleFilter"]
