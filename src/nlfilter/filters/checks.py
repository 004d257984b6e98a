"""What a filter checks of its model and its prior: the model structures it handles
(:func:`check_structure`), a continuous-time measurement's precision (:func:`continuous_precision`)
and the Gaussian prior ``N(m0, P0)`` broadcast to the batch (:func:`gaussian_prior`); below the
protocol of :mod:`nlfilter.filters.base`, which re-exports them."""

from __future__ import annotations

import math

import numpy as np

from .. import _validate as V
from ..model_noise import check_horizon
from .beliefs import GaussianState

__all__ = ["gaussian_prior", "check_structure", "continuous_precision", "refuse_infinite", "DIFFUSE_FILTERS"]

#: the registered filters with an exact diffuse form of a prior with infinite variance (their
#: ``diffuse_prior`` attribute: :mod:`nlfilter.filters.diffuse_prior`)
DIFFUSE_FILTERS = ("kf", "ekf", "iekf")


def is_diffuse(P0) -> bool:
    """Whether ``P0`` states a diffuse prior (an infinite entry)."""
    if type(P0) is float or type(P0) is int:  # (a scalar variance, the common case: no array)
        return P0 == math.inf
    try:
        P = np.asarray(P0)
        P = np.asarray(P.real if P.dtype.kind == "c" else P, dtype=float)  # complex: refused later, naming P0
    except (TypeError, ValueError):
        return False
    return bool(np.isposinf(P).any())


def refuse_infinite(P0, who) -> None:
    """Refuse, for ``who`` (the name of a function, or a filter, with no diffuse form), a ``P0``
    with an infinite variance: a ValueError naming ``P0``, what was given and the filters that run
    it exactly (a filter with ``diffuse_prior`` reaches here from its step functions' ``init``)."""
    if is_diffuse(P0):
        if not isinstance(who, str):
            who = type(who).__name__ + ("'s init (the step functions, fixed_lag; its run, smooth and "
                                        "sample_posterior take it)" if getattr(who, "diffuse_prior", False) else "")
        raise ValueError(f"P0: an infinite variance (a diffuse prior) has an exact form only in the filters "
                         f"{', '.join(DIFFUSE_FILTERS)} (the exact diffuse initialisation, nlfilter.filters.diffuse_prior); "
                         f"{who} has none; got P0 = {V.shown(P0)}; give a finite P0 (e.g. a large variance)")


def gaussian_prior(m0, P0, n: int, batch: tuple, *, data: str = "ys", one: bool = False,
                   definite: bool = False, who="this filter") -> GaussianState:
    """The prior ``N(m0, P0)`` checked and broadcast to ``B = prod(batch)`` paths: ``m0`` a scalar,
    ``(n,)`` or per path ``(*batch, n)``; ``P0`` ``(n, n)`` (a scalar for n = 1) or per path.
    ``one``: the filter takes one prior for all paths (off-line gains), so a per-path ``m0`` is
    refused; ``definite``: ``P0`` must be positive definite (a prior density); ``who``: the filter
    named when ``P0`` has an infinite variance (:func:`refuse_infinite`)."""
    if m0 is None or P0 is None:
        raise ValueError(f"m0/P0: expected the prior mean and covariance, got m0={m0!r}, P0={P0!r}")
    m0 = V.mean("m0", m0, n)
    refuse_infinite(P0, who)  # a diffuse P0 reaches here only in a filter without its exact form
    P0 = V.covariance("P0", P0, n, batch=True)
    if one and (m0.ndim > 1 or P0.ndim > 2):
        raise ValueError(f"m0/P0: this filter takes one prior for all paths, shapes ({n},) and ({n}, {n}); "
                         f"got shapes {m0.shape}, {P0.shape}".replace("m0/P0", "m0" if m0.ndim > 1 else "P0", 1))
    if definite and not np.all(np.linalg.eigvalsh(P0)[..., 0] > 0):
        raise ValueError("P0: expected a positive definite covariance (a prior density), got a singular one")
    B = math.prod(batch)
    try:
        mean = np.broadcast_to(m0, (*batch, n)).reshape(B, n).copy()
        cov = np.broadcast_to(P0, (*batch, n, n)).reshape(B, n, n).copy()
    except ValueError:
        raise ValueError(f"m0/P0: shapes {m0.shape}, {P0.shape} do not broadcast to the batch {batch} of {data}") from None
    return GaussianState(mean, cov)


def check_structure(flt, model) -> None:
    """Refuse, naming it, a model structure (:attr:`~nlfilter.models.Model.structure`: a
    state-dependent R, correlated process and measurement noise, non-additive noise) that the
    filter ``flt`` does not handle (its ``structures``): a filter never ignores one silently.
    Returns the model."""
    has = getattr(model, "structure", frozenset())
    missing = sorted(set(has) - set(flt.structures))
    if missing:
        what = {"state-dependent R": "R: the model's measurement noise covariance depends on the state (R(x))",
                "time-varying R": "R: the model's measurement noise covariance varies over the steps (R_k)",
                "cross noise": "cross_noise: the model's process and measurement noises are correlated",
                "non-additive noise": "noise: the model's process noise enters f non-additively",
                "non-additive measurement noise": "meas_noise: the model's measurement noise enters h non-additively",
                "angles": "angles: the model declares angular components (wrapped residuals, circular means: nlfilter.angles)"}
        raise ValueError(f"{'; '.join(what[k] for k in missing)}; {type(flt).__name__} handles "
                         f"{list(flt.structures) or 'none of these'} (see each filter's structures attribute: "
                         "the Gaussian filters take R(x), R_k and cross noise, the Kalman filter R_k, the UKF non-additive noise (augmented "
                         "sigma points), GridFilter and ParticleFilter R(x), ParticleFilter non-additive process noise; angles: the "
                         "discrete and continuous-discrete Gaussian, Kalman, square-root and IMM filters, GridFilter, ParticleFilter)")
    return model


def noise_horizon(flt, T: int, B: int) -> None:
    """The data ``(B paths, T steps)`` of a discrete-time filter ``flt`` against its model's ``Q``/``R``
    given per step (:func:`~nlfilter.model_noise.check_horizon`): long enough for the steps read
    (one further when the filter starts by a prediction), one row per path of a per-path array."""
    if getattr(flt, "time", None) == "discrete":
        check_horizon(getattr(flt, "model", None), T, B, 0 if flt.start == "update" else 1)


def continuous_precision(model) -> np.ndarray:
    """``R⁻¹`` of a continuous-time measurement ``dy = h dt + dη`` (``E dη dηᵀ = R dt``): a filter
    of increments weighs them by it, so R must be positive definite (relative to its largest
    eigenvalue, as :class:`~nlfilter.noise.Gaussian`'s density)."""
    R = np.asarray(model.R, dtype=float)
    w = np.linalg.eigvalsh(R)
    if not w[0] > 1e-14 * w[-1]:
        raise ValueError(f"R: must be positive definite: a noise-free measurement has no continuous-time filter, "
                         f"got {R.tolist()} (smallest eigenvalue {w[0]:.3g})")
    return np.linalg.inv(R)
