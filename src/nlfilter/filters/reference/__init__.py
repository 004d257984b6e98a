"""The near-optimal yardsticks: a grid (point-mass) Bayesian filter for 1-D and 2-D states and a
bootstrap particle filter, both batched over Monte Carlo paths and both on the one run loop of
:class:`~nlfilter.filters.base.Filter`.

Every experiment reports the gap of each suboptimal filter to the MSE of one of these.

================  ==========================================================================
module            contents
================  ==========================================================================
grid              :class:`GridFilter` over a :class:`GridBelief` (probability vectors on a grid)
particle          :class:`ParticleFilter` over a :class:`ParticleBelief` (weighted particles)
jump_particle     :class:`JumpParticleFilter`: particles over (mode, state) of a switching model
resample_move     :class:`ResampleMoveParticleFilter`: noise-free continuous dynamics, moves on x0
cd_particle       :class:`ContinuousDiscreteParticleFilter`: an SDE measured at discrete times
bounded           the grid and particle yardsticks of the bounded-noise problems (seed 000)
forward_backward  their optimal smoothers: forward–backward on the grid, FFBSm on particles
_reference_base   what both share: the time-step check, the registry attributes
================  ==========================================================================

Grid filter
-----------
The conditional density is kept on a fixed grid ``x_1 .. x_N`` (a regular grid over ``bounds``,
``size`` points per axis), as a probability vector ``p`` per path.

* Discrete model: ``p⁻_j ∝ Σ_i p_i τ(x_j | x_i)`` with the transition density τ of
  ``x' = f(x) + G(x) w`` (any noise law with a density when ``G`` is square and invertible;
  Gaussian ``N(f, G Q Gᵀ)`` otherwise), then ``p⁺ ∝ p⁻ · p_v(y − h(x))``.
* SDE model: the Fokker–Planck operator is approximated by Kushner's Markov chain on the grid
  (central differences where they keep the rates positive, upwind otherwise; reflecting edges),
  its generator ``L`` exponentiated once, ``p⁻ = p · expm(L dt)``; then the Kallianpur–Striebel
  likelihood of the increment ``exp(hᵀ R⁻¹ dy − ½ hᵀ R⁻¹ h dt)`` at the grid points. In 2-D the
  diffusion ``G Q Gᵀ`` must be diagonal.

The mean and covariance of ``p`` are returned as :class:`~nlfilter.filters.estimates.Estimates`.
Choose ``bounds`` to cover the states with margin and ``size`` so that the grid spacing is small
against the noise: the filter is exact as the grid is refined.

Particle filter
---------------
Bootstrap filter: particles propagated through the model (Euler–Maruyama substeps for SDEs),
weighted by the measurement likelihood, resampled (systematic) when the effective sample size
falls below ``threshold · particles``. The estimate is the weighted mean/covariance before
resampling: the weights of an update are kept in the belief, and the next ``predict`` (``step``
for SDEs) resamples first. An SDE measured at discrete times (``y_k = h(x(t_k)) + v_k``, regular
or irregular ``t_k``) has :class:`ContinuousDiscreteParticleFilter`: the same filter, its
particles moved between measurements by the simulator's Euler–Maruyama steps
(:mod:`~nlfilter.filters.reference.cd_particle`).

Both filters flag a measurement that is impossible under every grid point / particle (zero
likelihood everywhere, e.g. bounded noise and a too-narrow grid) as a divergence of that path.
The grid filter also flags a path that left its grid: its density at an outermost point reaches
``edge_limit`` (default 0.9) of its peak (the mean would sit at the edge).

Any split of the paths gives the same numbers: the particle filters draw path ``p`` from its own
stream (:mod:`nlfilter.streams`; bitwise), the grid filters choose nothing from the batch (to the
last bits of the BLAS products over the batch).
"""

from .bounded import BoundedGridFilter1D, BoundedParticleFilter
from .cd_particle import ContinuousDiscreteParticleFilter
from .grid import GridBelief, GridFilter
from .jump_particle import JumpParticleFilter
from .particle import ParticleBelief, ParticleFilter
from .resample_move import ResampleMoveBelief, ResampleMoveParticleFilter

__all__ = ["GridFilter", "GridBelief", "ParticleFilter", "ParticleBelief", "BoundedGridFilter1D", "BoundedParticleFilter",
           "ResampleMoveParticleFilter", "ResampleMoveBelief", "ContinuousDiscreteParticleFilter",
           "JumpParticleFilter"]
