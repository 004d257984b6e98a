"""The compiled run loop (``run(..., backend="numba")``): the discrete Gaussian filters, and the
continuous-time (Itô) EKF and second-order filters, and the continuous-discrete Gaussian filters
but the iterated one, in one numba-compiled loop over paths and steps.

The NumPy loop of :meth:`~nlfilter.filters.base.Filter.run` is the reference; this is the same
filter, step for step, with the model's f, h, G and their derivatives generated from its SymPy
expressions as scalar code (:func:`model_kernels`) and the predict/update of the skeleton of
:mod:`nlfilter.filters.gaussian` written out for one path at a time, without temporaries:

==============================  ================================================================
rule (filters)                  compiled step
==============================  ================================================================
Taylor-1 (``ekf``)              ``m⁻ = f(m)``, ``P⁻ = F P Fᵀ + G Q Gᵀ``; Joseph-form update
node rules (``ukf``, ``ckf``,   ``X_i = m + L z_i`` (``P = L Lᵀ``, Cholesky; eigen root where P is
``ghkf``, ``slf``)              only semi-definite), weighted sums as :class:`~nlfilter.filters.rules.NodeRule`
Taylor-2 (``truncated``, …,     seed 004 eqs. 18-23 in every form of :data:`~nlfilter.filters.rules.FORMS`:
``modified-gaussian``)          ½(P g_xx), the fourth-moment terms, the forcing tensor, S screened
Kalman (``kf``)                 the model's matrices F, b, H, d, G Q Gᵀ read as data (per time when
                                they vary): one loop for every linear model (:mod:`.kalman_loop`)
square-root Taylor-1            the loop's ``P`` holds the factor S: ``S⁻ = tria([F S, G Q^½])``
(``sr-ekf``, ``sr-kf``)         (Householder), the array update ``tria([[H S, R^½], [S, 0]])``
square-root nodes (``sr-ukf``,  ``tria`` of the weighted deviations, Cholesky downdates for negative
``sr-ckf``, ``sr-ghkf``,        weights (a failed one: the path diverges, as on NumPy); the run
``sr-slf``)                     reports ``S Sᵀ`` (:mod:`.sqrt_kernels`; always the general loop)
continuous Itô (the             the whole step in the template's update (:mod:`.ito_kernels`): the
continuous ``ekf`` and          gain ``K = P Hᵀ R⁻¹`` and forcing at the step's start, the ``dt``
second-order filters)           terms by RK4/Euler in ``substeps``, then ``+ K dy``; the likelihood
                                of ``dy/dt`` (not for ``truncated-jazwinski``: NumPy screens its S
                                over the batch)
continuous-discrete (``cd-``    ``dm/dt = E[f]``, ``dP/dt = Cov[x, f] + Cov[f, x] + E[G Q Gᵀ]`` by
``ekf``, ``ukf``, ``ckf``,      the rule (Taylor-1, Taylor-2: ``f [+ ½(P f_xx)]``, ``P Fᵀ``; nodes at
``ghkf``, ``slf``,              every stage point) in RK4/Euler ``substeps`` over each interval
``second-order``)               (:mod:`.cd_kernels`); the discrete rule's update
==============================  ================================================================

A model with one state, one measurement and one noise runs the EKF's scalar batch loop
(:func:`~.loops.steps_scalar_`: every path at each step, the arithmetic of NumPy's scalar branch, bit for
bit); models up to :data:`~.build.SPECIALIZE_UP_TO` states and measurements (the node rules: up to
:data:`~.build.SPECIALIZE_NODES_UP_TO`, the Taylor-2 rule: :data:`~.build.SPECIALIZE_TAYLOR2_UP_TO`) get loops with their dimensions compiled in and the helpers
inlined (the same bits, faster, longer to compile); the EKF
on 4 to 16 states runs blocks of paths with the paths innermost (:mod:`.batch_loop`: vectorized over
paths, the same numbers to rounding).

The same conventions as the NumPy loop, which the tests hold it to (1e-12): both starts, partly
missing measurements (the observed block, exactly; a step missing on every path only predicts),
the divergence test after each predict and update (finite, smallest eigenvalue of the
symmetrized covariance ≥ −1e-9·max(1, max|P|); a failed square root, a singular or, for Taylor-2,
indefinite innovation covariance), ``on_divergence`` raise/mark with NaN from the step on, and
``loglik=True`` (:func:`~nlfilter.filters.linalg.innovation_info`'s outputs). Where a covariance
is only semi-definite the node rules take the eigen root ``U √w`` of cyclic Jacobi rotations
(:func:`~.path_linalg.jacobi_`, no LAPACK inside the loop): the same points as NumPy's root up to the signs of
the eigenvectors, which a symmetric rule does not see; only repeated nonzero eigenvalues leave a
rotation free (then any root is as right, and the moments agree to the rule's exactness).

What it takes: a filter whose class declares ``compiled = True`` (the discrete Gaussian filters
above, their square-root forms but the iterated and second-order ones; the continuous
``ContinuousGaussianFilter`` with ``innovation="ito"`` on an SDEModel in SymPy whose f, h, G do not
depend on the time, a G free of the state for a second-order rule; ``ContinuousDiscreteEKF`` and
``ContinuousDiscreteSecondOrderFilter`` and the continuous-discrete UKF, CKF, GHKF and SLF on
such a model, on a regular grid of a given ``dt``), with no step overridden below it (:func:`steps_refusal`); a :class:`~nlfilter.models.DiscreteModel` stated in SymPy, additive noise, constant
Q and R, no correlated noise, parameters with one value each (arrays over time, inputs: the NumPy
loop); Taylor-2 also a G free of the states; the Kalman filter any linear DiscreteModel (SymPy or
matrices, time-varying too) without correlated noise or parameters per path. :func:`unsupported` names what a filter or model
lacks; ``run`` then raises a TypeError naming ``backend``. Compilation (numba) happens at the first
run of each model and rule kind (seconds), shared by every :meth:`~nlfilter.models.Model.with_params`
copy; later runs reuse it. ``backend="numba-shared"`` runs the same filters on the model-free loop
of the rule kind and shape (:mod:`.template`: compiled once for every model of that shape and kept
on disk, the model's functions compiled alone and passed to it: a new model then costs about a
second; the model's own loop's numbers, bit for bit).

The package, one concept a module:

======================  ============================================================================
:mod:`.support`         numba, the filter's declaration (``compiled = True``, :func:`steps_refusal`)
                        and :func:`unsupported`
:mod:`.kernels`         the model's functions as numba scalar code (:func:`model_kernels`)
:mod:`.path_linalg`     one-path linear algebra: Cholesky, the divergence test, Jacobi, LU, products
:mod:`.step_kernels`    one-path step pieces: covariances, node moments, Taylor-2 terms, the update
:mod:`.rule_kernels`    one predict and one update kernel per rule kind, and their work arrays
:mod:`.sqrt_kernels`    the square-root filters' kernels: Householder ``tria``, downdates, the array update
:mod:`.ito_kernels`     the continuous Itô filters' step: RK4/Euler substeps, the Itô gain, the likelihood
:mod:`.cd_kernels`      the continuous-discrete prediction: the moment equations by RK4/Euler
:mod:`.kalman_loop`     the Kalman filter's kernels: the matrices as data (the template's, and the scalar
                        batch loop's f, h, G reading them from ``p``)
:mod:`.loops`           one loop template for every rule kind; the scalar EKF's batch loop
:mod:`.batch_kernels`   the EKF's batch-inner loop: blocks of paths, the paths innermost
:mod:`.batch_screen`    its divergence test: the block's screen, the one-path test on a lane it does not pass
:mod:`.batch_loop`      that loop's dispatch, the model's functions over a block, its module text
:mod:`.build`           the template with a kind's kernels and the model's functions, as one module's text
:mod:`.template`        the same text without the model: one loop per rule kind and shape for every
                        model, the model's functions as ``cfunc`` arguments
:mod:`.cache`           that module written to the disk cache and imported, numba's code kept beside it
:mod:`.run`             :func:`run_compiled`, :func:`~.run.run_shared` and :func:`~.run.finish`
:mod:`.choice`          ``backend="auto"``: compiled when loaded, cached or repaid (:func:`choose`)
======================  ============================================================================
"""

from __future__ import annotations

import importlib

# the names below are imported on first use (PEP 562): the automatic backend reads the declaration
# rule (.support), the cost rule (.choice) and the disk cache (.cache) without importing numba
_WHERE = {"available": "support", "unsupported": "support", "steps_refusal": "support",
          "ALLOWED_OVERRIDES": "support", "model_kernels": "kernels", "scalar_kernels": "kernels",
          "run_compiled": "run", "choose": "choice"}

__all__ = ["available", "unsupported", "steps_refusal", "ALLOWED_OVERRIDES", "model_kernels", "scalar_kernels",
           "run_compiled", "choose"]


def __getattr__(name):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    globals()[name] = value  # (looked up once: the automatic backend asks at every run)
    return value
