"""The adaptive method-of-moments Bayesian filters for bounded, non-Gaussian noise (seed 000).

=====================  =============================================================================
``zero_order``         :class:`ZeroOrderMomentFilter` (000 Chapter III, Fig. 7) and the non-additive
                       :class:`ScaledNoiseZeroOrderFilter`; ``zero_order_estimate``, ``power_density_estimate``
``first_order``        :class:`FirstOrderMomentFilter`: ``x' = h x + w``, ``z = x + v`` (000 eqs. 2.4-2.5)
``two_state``          :class:`SecondOrderMomentFilter`: ``x' = A x + b w``, ``z = c.x + v`` (eqs. 2.6-2.8)
``_moment_base``       option checks, the (pure) adaptive-input learner, :class:`MomentFilterWarning`,
                       :data:`INVALID_MOMENTS` and :func:`refresh_failure_rate`
=====================  =============================================================================

All are :class:`~nlfilter.filters.base.Filter` s on a :class:`~nlfilter.bounded.BoundedNoiseModel`
(``kind = "bounded"``; the zero-order estimator takes its support and noise width directly):
``run(ys)`` with scalar measurements ``ys (..., T, 1)`` (NaN: missing) returns
:class:`~nlfilter.filters.estimates.Estimates` whose ``means`` are the posterior means, ``covs`` the
posterior covariances from the carried moments (NaN where none: N = 1, and the zero-order
estimator), and ``extras`` the family's flags and bounds (``fallback``, ``invalid``, ``lower``,
``upper``, the moments in use, and for the adaptive filters the refresh flags ``refreshed`` and
``refresh_failed``). Every adaptive filter tests each refresh's moments against the moment space
(:func:`~nlfilter.moments.densities.is_moment_sequence`) and takes ``invalid_moments=`` ("warn",
"keep", "ignore"; :data:`INVALID_MOMENTS`) with one meaning everywhere. The prior is the
filter's own (``m0 = P0 = None``). The adaptive learners' running statistics are per path in the
belief: a filter object never changes.
The reference (grid/particle) yardsticks are in :mod:`nlfilter.filters.reference.bounded`.
"""

from ._moment_base import INVALID_MOMENTS, MomentFilterWarning, impulse_power_sums, refresh_failure_rate
from .first_order import FirstOrderMomentFilter, IntervalBelief
from .two_state import PolygonBelief, SecondOrderMomentFilter, linear_map_moments, moment_map_tensor
from .zero_order import (ScaledNoiseZeroOrderFilter, ZeroOrderBelief, ZeroOrderMomentFilter, power_density_estimate,
                         zero_order_estimate)

__all__ = ["ZeroOrderMomentFilter", "ScaledNoiseZeroOrderFilter", "FirstOrderMomentFilter", "SecondOrderMomentFilter",
           "ZeroOrderBelief", "IntervalBelief", "PolygonBelief", "zero_order_estimate", "power_density_estimate",
           "impulse_power_sums", "linear_map_moments", "moment_map_tensor", "MomentFilterWarning", "INVALID_MOMENTS",
           "refresh_failure_rate"]
