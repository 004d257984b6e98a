"""Fading memory for the discrete-measurement Gaussian filters: old data forgotten geometrically.

``flt.fading_memory(alpha)`` (``alpha = α ≥ 1``) is the filter whose prediction starts from the
filtered belief with its covariance inflated by ``α²``, ``N(m_k, α² P_k)``; on a linear model::

    P⁻_{k+1} = α² F P_k Fᵀ + G Q Gᵀ

the fading-memory (exponential data weighting) filter of Fagin (1964) and Sorenson & Sacks (1971):
the Kalman filter of a cost that weighs the measurement ``j`` steps old by ``α^{-2j}`` (Simon
2006, *Optimal State Estimation*, §7.4; filterpy's ``KalmanFilter.alpha``). ``α = 1`` is the filter
itself, bit for bit (nothing is multiplied). Every rule takes it alike — the nodes of the UKF, CKF,
GHKF and the Taylor expansions of the EKF and second-order filters are spread by ``α`` — as do the
continuous-discrete filters (their moment ODEs integrated from ``α² P_k``).

The smoother, the posterior sampler and the fixed-lag smoother of such a filter read its
prediction as the model's with the extra process noise that the inflation adds: the predicted
covariance is the filter's, and the cross-covariance ``D = Cov[x_k, x_{k+1}]`` is the rule's slope
``A = Cov[x, f] (α² P)⁻¹`` under the inflated belief times ``P_k`` (``D / α²``; ``P Fᵀ`` on a
linear model), so that the joint law of ``(x_k, x_{k+1})`` stays positive semi-definite (its
conditional covariance gains ``(α² − 1) A P Aᵀ``).

The compiled loop has no fading memory: it refuses such a filter (``backend="auto"`` runs it on
the NumPy loop), as does the Kalman filter's exact diffuse initialisation.
"""

from __future__ import annotations

import copy
import math
import numbers

import numpy as np

from .. import _validate as V

__all__ = ["FadingMemory"]


class FadingMemory:
    """The fading-memory option of the Gaussian filters (module docstring): a mixin of
    :class:`~nlfilter.filters.gaussian.GaussianFilter` and
    :class:`~nlfilter.filters.kalman.KalmanFilter`, whose predictions call its ``_inflate``."""

    fading = 1.0  # α: 1.0 is no fading (the class's value; fading_memory sets an instance's)

    def fading_memory(self, alpha: float):
        """A copy of the filter with fading memory ``alpha`` (``α ≥ 1``, finite; 1: the filter
        itself): its prediction starts from ``N(m_k, α² P_k)``, ``P⁻ = α² F P Fᵀ + G Q Gᵀ`` on a
        linear model (Sorenson & Sacks 1971; Simon 2006, §7.4).

        >>> import numpy as np, sympy as sp; from nlfilter import DiscreteModel
        >>> from nlfilter.filters import KalmanFilter, GaussianState
        >>> x = sp.Symbol("x")
        >>> kf = KalmanFilter(DiscreteModel([x], f=[0.5 * x], h=[x], Q=1.0, R=1.0)).fading_memory(2.0)
        >>> float(kf.predict(GaussianState(np.zeros(1), np.eye(1)), 0).cov[0, 0])   # 4 · 0.25 · 1 + 1
        2.0
        """
        if isinstance(alpha, (bool, np.bool_)) or not isinstance(alpha, numbers.Real):
            raise TypeError(f"alpha: expected a real number >= 1 (the fading-memory factor), got {V.shown(alpha)}")
        if not (math.isfinite(alpha) and alpha >= 1.0):
            raise ValueError(f"alpha: expected a finite number >= 1 (the fading-memory factor; 1: no fading), "
                             f"got {V.shown(alpha)}")
        new = copy.copy(self)
        new.fading = float(alpha)
        return new

    def _inflate(self, state):
        """The belief the prediction starts from: ``state`` itself without fading, else its
        covariance times ``α²`` (the same belief type)."""
        if self.fading == 1.0:
            return state
        return state._replace(cov=state.cov * self.fading**2)

    def _deflate(self, D):
        """The smoother's cross-covariance ``Cov[x_k, x_{k+1}]`` from the one under the inflated
        belief (module docstring): ``D / α²``; ``D`` itself without fading."""
        return D if self.fading == 1.0 else D / self.fading**2
