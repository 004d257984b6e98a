"""Every filter of nlfilter, one protocol (:mod:`nlfilter.filters.base`), one registry
(:data:`REGISTRY`: name -> class; ``nlfilter list --filters``).

========================  ==================================================================
module                    filters
========================  ==================================================================
kalman, ekf, ukf          KalmanFilter, KalmanBucy, EKF, IteratedEKF, ContinuousEKF, UKF,
                          ContinuousDiscreteEKF, ContinuousDiscreteIEKF, ContinuousDiscreteUKF
cubature                  CKF, GHKF, ContinuousDiscreteCKF, ContinuousDiscreteGHKF, the statistically
                          linearized filters (exact Gaussian moments of polynomial models)
imm                       IMM (interacting multiple models over Gaussian filters), TwoModeIMM (registry)
gaussian, rules           GaussianFilter, ContinuousDiscreteGaussianFilter over a moment rule
                          (Taylor1, Unscented, Cubature, GaussHermite, Cubature5)
rule_filter               rule_filter: a registered filter class from a rule (the ckf5 line)
square_root               SquareRootFilter: the belief a Cholesky factor, QR (array) steps, downdates for
                          negative weights, the square-root RTS smoother
square_root_filters       SquareRootKF, SquareRootEKF, SquareRootIEKF, SquareRootUKF, SquareRootCKF,
                          SquareRootGHKF, SquareRootSLF (sr-kf, ... sr-slf)
square_root_second_order  SquareRootSecondOrderFilter (sr-second-order; seed 004's forms on a factor)
square_root_continuous    SquareRootContinuousDiscreteEKF, -UKF, -CKF (sr-continuous-discrete-ekf, ...):
                          the square-root moment ODE between measurements
second_order              SecondOrderFilter, ContinuousSecondOrderFilter,
                          ContinuousDiscreteSecondOrderFilter (seed 004; ``form=`` FORMS)
skeleton                  the Gaussian steps as functions (predict, condition, moment_rhs, ito_rhs) that
                          the classes of gaussian, ekf, ukf, cubature, second_order configure
offline                   the off-line-gain runner (schedule + affine recursion) of every off-line-gain
                          filter below but the PLL
quasilinear               QLF, MQLF, QuasilinearFilter, DiscreteQuasilinearFilter (seed 003)
linear_bilinear           OptimalLinearFilter, DiscreteOptimalLinearFilter (001; re-exported by bilinear)
moment_filters            ConditionalMomentFilter, DiscreteConditionalMomentFilter
bilinear                  TensorFilter, UpdatedInnovationsFilter (001 §3.3)
pseudo_observables        PseudoObservablesFilter (001 §3.2)
phase                     PLL, LinearQuadratureFilter, PhaseTensorFilter, CircleGridFilter (001)
moment_bayes              ZeroOrderMomentFilter, FirstOrderMomentFilter, SecondOrderMomentFilter,
                          ScaledNoiseZeroOrderFilter (000)
reference.bounded         BoundedGridFilter1D, BoundedParticleFilter: the yardsticks of moment_bayes
reference                 GridFilter, ParticleFilter, ResampleMoveParticleFilter, ContinuousDiscreteParticleFilter:
                          the near-optimal yardsticks
========================  ==================================================================
"""

from .base import ContinuousFilter, DiscreteFilter, Estimates, GaussianState
from .bilinear import (DiscreteOptimalLinearFilter, OptimalLinearFilter, PseudoObservablesFilter, TensorFilter,
                       UpdatedInnovationsFilter)
from .cubature import (CKF, GHKF, ContinuousDiscreteCKF, ContinuousDiscreteGHKF, ContinuousDiscreteSLF,
                       StatisticallyLinearizedFilter)
from .ekf import EKF, ContinuousDiscreteEKF, ContinuousDiscreteIEKF, ContinuousEKF, IteratedEKF
from .gaussian import ContinuousDiscreteGaussianFilter, GaussianFilter
from .imm import IMM, TwoModeIMM
from .kalman import KalmanBucy, KalmanFilter
from .moment_bayes import (FirstOrderMomentFilter, ScaledNoiseZeroOrderFilter, SecondOrderMomentFilter,
                           ZeroOrderMomentFilter)
from .moment_filters import ConditionalMomentFilter, DiscreteConditionalMomentFilter
from .phase import PLL, CircleGridFilter, LinearQuadratureFilter, PhaseTensorFilter
from .quasilinear import MQLF, QLF, DiscreteQuasilinearFilter, QuasilinearFilter
from .reference import ContinuousDiscreteParticleFilter, GridFilter, ParticleFilter, ResampleMoveParticleFilter
from .reference.bounded import BoundedGridFilter1D, BoundedParticleFilter
from .square_root_filters import (SquareRootCKF, SquareRootEKF, SquareRootGHKF, SquareRootIEKF, SquareRootKF,
                                  SquareRootSLF, SquareRootUKF)
from .square_root_second_order import SquareRootSecondOrderFilter
from .square_root_continuous import (SquareRootContinuousDiscreteCKF, SquareRootContinuousDiscreteEKF,
                                     SquareRootContinuousDiscreteUKF)
from .second_order import (FORMS, ContinuousDiscreteSecondOrderFilter, ContinuousSecondOrderFilter,
                           SecondOrderFilter)
from .ukf import UKF, ContinuousDiscreteUKF
from .rule_filter import rule_filter
from .rules import Cubature5

from . import registry as _registry

#: Every public filter by name (a plain dict; see :mod:`nlfilter.filters.registry`).
REGISTRY = {
    "kf": KalmanFilter, "kalman-bucy": KalmanBucy,
    "ekf": EKF, "iekf": IteratedEKF, "ukf": UKF, "ckf": CKF, "ghkf": GHKF, "slf": StatisticallyLinearizedFilter,
    "ckf5": rule_filter(Cubature5(), name="ckf5", source="Jia, Xin & Cheng 2013, High-degree cubature Kalman filter, "
                        "Automatica 49; Stroud 1971, Approximate calculation of multiple integrals (degree-5 rule)"),
    "sr-kf": SquareRootKF, "sr-ekf": SquareRootEKF, "sr-ukf": SquareRootUKF, "sr-ckf": SquareRootCKF,
    "sr-ghkf": SquareRootGHKF, "sr-slf": SquareRootSLF, "sr-iekf": SquareRootIEKF,
    "sr-second-order": SquareRootSecondOrderFilter, "sr-continuous-discrete-ekf": SquareRootContinuousDiscreteEKF,
    "sr-continuous-discrete-ukf": SquareRootContinuousDiscreteUKF,
    "sr-continuous-discrete-ckf": SquareRootContinuousDiscreteCKF,
    "continuous-ekf": ContinuousEKF,
    "continuous-discrete-ekf": ContinuousDiscreteEKF, "continuous-discrete-iekf": ContinuousDiscreteIEKF,
    "continuous-discrete-ukf": ContinuousDiscreteUKF, "continuous-discrete-ckf": ContinuousDiscreteCKF,
    "continuous-discrete-ghkf": ContinuousDiscreteGHKF, "continuous-discrete-slf": ContinuousDiscreteSLF,
    "second-order": SecondOrderFilter, "continuous-second-order": ContinuousSecondOrderFilter,
    "continuous-discrete-second-order": ContinuousDiscreteSecondOrderFilter,
    "conditional-moment": ConditionalMomentFilter, "discrete-conditional-moment": DiscreteConditionalMomentFilter,
    "quasilinear": QuasilinearFilter, "discrete-quasilinear": DiscreteQuasilinearFilter,
    "optimal-linear": OptimalLinearFilter, "discrete-optimal-linear": DiscreteOptimalLinearFilter,
    "tensor": TensorFilter, "updated-innovations": UpdatedInnovationsFilter,
    "pseudo-observables": PseudoObservablesFilter,
    "pll": PLL, "lqf": LinearQuadratureFilter, "phase-tensor": PhaseTensorFilter, "circle-grid": CircleGridFilter,
    "zero-order-moment": ZeroOrderMomentFilter, "first-order-moment": FirstOrderMomentFilter,
    "second-order-moment": SecondOrderMomentFilter, "scaled-noise-zero-order-moment": ScaledNoiseZeroOrderFilter,
    "bounded-grid": BoundedGridFilter1D, "bounded-particle": BoundedParticleFilter,
    "grid": GridFilter, "particle": ParticleFilter, "continuous-discrete-particle": ContinuousDiscreteParticleFilter,
    "resample-move": ResampleMoveParticleFilter,
    "imm": TwoModeIMM,
}


def get(name: str):
    """The filter class registered under ``name`` (ValueError listing the choices otherwise)."""
    return _registry.get(REGISTRY, name)


__all__ = ["REGISTRY", "get", "GaussianState", "Estimates", "DiscreteFilter", "ContinuousFilter", "KalmanFilter", "KalmanBucy",
           "EKF", "ContinuousEKF", "UKF", "SecondOrderFilter", "ContinuousSecondOrderFilter",
           "ContinuousDiscreteSecondOrderFilter", "FORMS", "QLF", "MQLF", "QuasilinearFilter",
           "DiscreteQuasilinearFilter", "ConditionalMomentFilter", "DiscreteConditionalMomentFilter",
           "OptimalLinearFilter", "DiscreteOptimalLinearFilter", "TensorFilter", "UpdatedInnovationsFilter",
           "PseudoObservablesFilter", "PLL",
           "LinearQuadratureFilter", "PhaseTensorFilter", "CircleGridFilter", "ZeroOrderMomentFilter",
           "FirstOrderMomentFilter", "SecondOrderMomentFilter", "ScaledNoiseZeroOrderFilter", "GridFilter",
           "ParticleFilter", "BoundedGridFilter1D", "BoundedParticleFilter", "ResampleMoveParticleFilter",
           "ContinuousDiscreteParticleFilter",
           "CKF", "GHKF", "IteratedEKF", "ContinuousDiscreteEKF", "ContinuousDiscreteIEKF", "ContinuousDiscreteUKF",
           "ContinuousDiscreteCKF", "ContinuousDiscreteGHKF", "GaussianFilter", "ContinuousDiscreteGaussianFilter",
           "StatisticallyLinearizedFilter", "ContinuousDiscreteSLF", "rule_filter", "IMM", "TwoModeIMM",
           "SquareRootKF", "SquareRootEKF",
           "SquareRootUKF", "SquareRootCKF", "SquareRootGHKF", "SquareRootIEKF", "SquareRootSLF",
           "SquareRootSecondOrderFilter", "SquareRootContinuousDiscreteEKF", "SquareRootContinuousDiscreteUKF",
           "SquareRootContinuousDiscreteCKF"]
