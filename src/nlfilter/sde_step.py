"""The measurement convention of a continuously measured SDE, written once.

An :class:`~nlfilter.models.SDEModel` ``dx = f(x, t) dt + G(x, t) dw``, ``dy = h(x, t) dt + dv``
(``E dw dwᵀ = Q dt``, ``E dv dvᵀ = R dt``) is simulated, and read by the particle reference, on
measurement intervals ``[t, t + dt]`` of ``substeps`` Euler–Maruyama steps of length
``δ = dt / substeps``:

    x_{j+1} = x_j + f(x_j, s_j) δ + G(x_j, s_j) ΔB_j,    s_j = t + j δ,
    ∫ h ds  = Σ_j h(x_j, s_j) δ                          (left point: the Itô sum),
    dy      = ∫ h ds + R^{1/2} (v_{t+dt} − v_t).

Given the path of one interval, the increment is exactly ``dy ~ N(∫ h ds, R dt)``; with
``h̄ = ∫ h ds / dt`` its log-likelihood ratio against pure noise ``N(0, R dt)`` is the
Kallianpur–Striebel form ``h̄ᵀ R⁻¹ dy − ½ dt h̄ᵀ R⁻¹ h̄`` (:func:`increment_loglik`). So a filter
that propagates its particles with :func:`euler_maruyama` at the simulator's ``substeps`` and
weighs ``dy`` with that ratio has the simulator's model exactly (not only to an order in ``dt``).

:func:`~nlfilter.simulate.simulate` and :class:`~nlfilter.filters.reference.ParticleFilter`
call :func:`euler_maruyama`, both with :data:`SUBSTEPS` steps per interval unless told otherwise
(a particle filter built without ``substeps`` and run on a Simulation takes the simulator's:
``sim.timing.substeps``); :func:`~nlfilter.simulate.simulate_continuous_discrete` (its default
``process="euler-maruyama"``: ``x(t_k)`` through the same steps, no sum of h) and
:class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter` take :data:`SUBSTEPS` too;
the other continuous filters approximate this convention to a stated order (their
``measurement_convention`` attribute, shown by ``nlfilter list --filters``).
"""

from __future__ import annotations

import numpy as np

# Euler–Maruyama steps per measurement interval when none is given: the default of
# :func:`~nlfilter.simulate.simulate`, :func:`~nlfilter.simulate.simulate_continuous_discrete` (and
# ``compare``, ``nlfilter simulate``), :class:`~nlfilter.filters.reference.ParticleFilter` and
# :class:`~nlfilter.filters.reference.ContinuousDiscreteParticleFilter`, so that a particle reference
# built without ``substeps`` has the simulator's model; a Simulation records the substeps it was
# made with (``sim.timing.substeps``), which such a filter takes.
SUBSTEPS = 10  #: Euler–Maruyama steps per measurement interval, the simulators' and particle filters' default

# What each continuous filter's ``measurement_convention`` says (``nlfilter list --filters``): how it
# reads the increment dy of one interval, and to what order in dt it is the simulator's convention.
LEFT_POINT = ("exact: N(dy; ∫h ds, R dt) along each particle's Euler–Maruyama path, ∫h ds the left-point "
              "sum (the simulator's, sde_step); the simulator's model at equal substeps")
ITO_EULER = ("Itô: dy enters as the increment K dy with the gain of the belief at the interval's start (left "
             "point), −K E[h] dt with the filter's dt terms; first order in dt")
HELD = ("held: dy/dt held constant over the interval inside the filter's ODE step (Wong–Zakai); "
        "first order in dt")
END_POINT = ("end point: the transition over the interval, then the likelihood of dy with h at the "
             "interval's end point; first order in dt (its error per interval grows with the movement of "
             "h within it against the measurement noise √(R/dt))")


def euler_maruyama(model, x, t, dt, substeps, dB):
    """``(x at t + dt, ∫ h ds)``: the states ``x (..., n)`` advanced through the ``substeps``
    Euler–Maruyama steps of one measurement interval ``[t, t + dt]`` (module docstring), and the
    left-point sum ``Σ_j h(x_j, s_j) δ`` of h along them ``(..., m)``.

    ``dB``: the Brownian increments already scaled to the process noise (``G(x) dB`` is the
    noise of a step, ``E dB dBᵀ = Q δ``): an array ``(..., substeps, r)``, or a callable ``j ->
    (..., r)`` drawing the increment of substep ``j`` when it is reached (the particle filter's
    draw order). The arithmetic is the simulator's, term by term."""
    h = dt / substeps
    ih = np.zeros((*np.shape(x)[:-1], model.m))
    for j in range(substeps):
        s = t + j * h
        ih += model.h(x, s) * h  # ∫ h dt, left point
        d = dB(j) if callable(dB) else dB[..., j, :]
        x = x + model.f(x, s) * h + model.Gw(x, d, s)
    return x, ih


def increment_loglik(hbar, dy, Rinv, dt):
    """``(..., p)``: ``log N(dy; h̄ dt, R dt) − log N(dy; 0, R dt) = h̄ᵀ R⁻¹ dy − ½ dt h̄ᵀ R⁻¹ h̄``
    for ``h̄ (..., p, m)`` (one per particle or grid point; ``∫ h ds / dt`` over the interval),
    ``dy (..., m)`` (missing components zeroed, with ``Rinv`` the precision of the observed
    ones, :func:`~nlfilter.filters.linalg.observed_precision`) and ``Rinv (m, m)`` or
    ``(..., m, m)``."""
    hR = np.einsum("...pa,...ab->...pb", hbar, Rinv)
    return np.einsum("...a,...pa->...p", dy, hR) - 0.5 * dt * np.einsum("...pa,...pa->...p", hR, hbar)
