"""Every filter of nlfilter, one protocol (:mod:`nlfilter.filters.base`).

========================  ==================================================================
module                    filters
========================  ==================================================================
kalman, ekf, ukf          KalmanFilter, KalmanBucy, EKF, ContinuousEKF, UKF
second_order              SecondOrderFilter, ContinuousSecondOrderFilter,
                          ContinuousDiscreteSecondOrderFilter (seed 004; ``form=`` FORMS)
offline                   the off-line-gain runner (schedule + affine recursion) of the two below
quasilinear               QLF, MQLF, QuasilinearFilter, DiscreteQuasilinearFilter (seed 003)
linear_bilinear           OptimalLinearFilter, DiscreteOptimalLinearFilter (001; re-exported by bilinear)
moment_filters            ConditionalMomentFilter, DiscreteConditionalMomentFilter
bilinear                  OptimalLinearFilter, DiscreteOptimalLinearFilter, TensorFilter ... (001)
phase                     PLL, LinearQuadratureFilter, PhaseTensorFilter, CircleGridFilter (001)
moment_bayes              ZeroOrderMomentFilter, FirstOrderMomentFilter, SecondOrderMomentFilter (000)
reference                 GridFilter, ParticleFilter: the near-optimal yardsticks
========================  ==================================================================
"""

from .base import ContinuousFilter, DiscreteFilter, Estimates, GaussianState
from .bilinear import DiscreteOptimalLinearFilter, OptimalLinearFilter, TensorFilter
from .ekf import EKF, ContinuousEKF
from .kalman import KalmanBucy, KalmanFilter
from .moment_bayes import FirstOrderMomentFilter, SecondOrderMomentFilter, ZeroOrderMomentFilter
from .moment_filters import ConditionalMomentFilter, DiscreteConditionalMomentFilter
from .phase import PLL, CircleGridFilter, LinearQuadratureFilter, PhaseTensorFilter
from .quasilinear import MQLF, QLF, DiscreteQuasilinearFilter, QuasilinearFilter
from .reference import GridFilter, ParticleFilter
from .second_order import (FORMS, ContinuousDiscreteSecondOrderFilter, ContinuousSecondOrderFilter,
                           SecondOrderFilter)
from .ukf import UKF

__all__ = ["GaussianState", "Estimates", "DiscreteFilter", "ContinuousFilter", "KalmanFilter", "KalmanBucy",
           "EKF", "ContinuousEKF", "UKF", "SecondOrderFilter", "ContinuousSecondOrderFilter",
           "ContinuousDiscreteSecondOrderFilter", "FORMS", "QLF", "MQLF", "QuasilinearFilter",
           "DiscreteQuasilinearFilter", "ConditionalMomentFilter", "DiscreteConditionalMomentFilter",
           "OptimalLinearFilter", "DiscreteOptimalLinearFilter", "TensorFilter", "PLL",
           "LinearQuadratureFilter", "PhaseTensorFilter", "CircleGridFilter", "ZeroOrderMomentFilter",
           "FirstOrderMomentFilter", "SecondOrderMomentFilter", "GridFilter", "ParticleFilter"]
