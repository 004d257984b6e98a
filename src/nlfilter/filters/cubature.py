"""Cubature and Gauss–Hermite Kalman filters, discrete and continuous-discrete time.

Both are the skeletons of :mod:`nlfilter.filters.gaussian` with a node rule of
:mod:`nlfilter.filters.rules`: the Gaussian expectations of the predict and update steps are
weighted sums over points ``X_i = m + L z_i`` (``P = L Lᵀ``)::

    m⁻ = Σ w_i f(X_i),        P⁻ = Σ w_i (f_i − m⁻)(f_i − m⁻)ᵀ + E[G Q Gᵀ]
    ŷ = Σ w_i h(X_i),         S = Σ w_i (h_i − ŷ)(h_i − ŷ)ᵀ + R,   C = Σ w_i (X_i − m⁻)(h_i − ŷ)ᵀ
    K = C S⁻¹,  m⁺ = m⁻ + K (y − ŷ),  P⁺ = P⁻ − K S Kᵀ     (points redrawn from (m⁻, P⁻))

* CKF (Arasaratnam & Haykin 2009, Cubature Kalman filters, IEEE TAC 54(6) 1254-1269): the
  third-degree spherical-radial rule, ``z_{±i} = ±√n e_i``, ``w_i = 1/(2n)`` (2n points);
* SLF: the GHKF at :func:`exact_order` — for polynomial f, h, G the rule then computes the
  Gaussian moments exactly, so the filter is the (on-line) statistically linearized filter of
  Gelb 1974 §6.2 (the quasilinear filter of seed 003 with gains from the data's own belief), and
  its RTS smoother the statistically linearized smoother;
* GHKF (Ito & Xiong 2000, Gaussian filters for nonlinear filtering problems, IEEE TAC 45(5)
  910-927): the tensor-product Gauss–Hermite
  rule with ``order`` nodes per axis (``order**n`` points, exact for polynomials of degree
  ``2·order − 1`` in each variable).

Continuous-discrete versions integrate ``dm/dt = E[f]``, ``dP/dt = Cov[x, f] + Cov[f, x] +
E[G Q Gᵀ]`` between the measurements (Särkkä 2007; Arasaratnam, Haykin & Hurd 2010 for the
continuous-discrete CKF) with the same rule at every integrator stage.
"""

from __future__ import annotations

import numpy as np  # noqa: F401  (the doctests use it)
import sympy as sp

from .base import check_structure
from .gaussian import ContinuousDiscreteGaussianFilter, GaussianFilter
from .rules import Cubature, GaussHermite

__all__ = ["CKF", "GHKF", "ContinuousDiscreteCKF", "ContinuousDiscreteGHKF", "StatisticallyLinearizedFilter",
           "ContinuousDiscreteSLF", "exact_order"]

_CKF_SOURCE = "Arasaratnam & Haykin 2009, Cubature Kalman filters, IEEE TAC 54(6) 1254-1269"
_GHKF_SOURCE = "Ito & Xiong 2000, Gaussian filters for nonlinear filtering problems, IEEE TAC 45(5) 910-927"


class CKF(GaussianFilter):
    """Cubature Kalman filter (Arasaratnam & Haykin 2009) for a :class:`~nlfilter.models.DiscreteModel`.

    Points ``m ± √n L e_i`` with weights ``1/(2n)``; equations in the module docstring.

    >>> import numpy as np, sympy as sp; from nlfilter import DiscreteModel
    >>> from nlfilter.filters import GaussianState
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [x**2], [x], Q=0.1, R=1.0)
    >>> s = CKF(model).predict(GaussianState(np.array([1.0]), np.array([[0.5]])), 0)
    >>> float(s.mean[0]), float(s.cov[0, 0])       # E[x²] = m² + P exactly; Cov: 4 m² P (third degree)
    (1.5, 2.1)
    """

    name = "ckf"
    compiled = True  # its steps are the family's (backend="numba")
    source = _CKF_SOURCE

    def __init__(self, model, *, start: str | None = None):
        super().__init__(model, Cubature(), start=start)


class GHKF(GaussianFilter):
    """Gauss–Hermite Kalman filter (Ito & Xiong 2000) for a :class:`~nlfilter.models.DiscreteModel`.

    ``order`` Gauss–Hermite nodes per state axis (``order**n`` points per expectation; default 3).

    >>> import numpy as np, sympy as sp; from nlfilter import DiscreteModel
    >>> from nlfilter.filters import GaussianState
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [x**2], [x], Q=0.1, R=1.0)
    >>> s = GHKF(model, order=3).predict(GaussianState(np.array([1.0]), np.array([[0.5]])), 0)
    >>> round(float(s.mean[0]), 12), round(float(s.cov[0, 0]), 12)   # exact: 4 m² P + 2 P² + Q
    (1.5, 2.6)
    """

    name = "ghkf"
    compiled = True  # its steps are the family's (backend="numba")
    source = _GHKF_SOURCE

    def __init__(self, model, *, order: int = 3, start: str | None = None):
        super().__init__(model, GaussHermite(order), start=start)
        self.order = self.rule.order


class ContinuousDiscreteCKF(ContinuousDiscreteGaussianFilter):
    """Continuous-discrete cubature Kalman filter (Arasaratnam, Haykin & Hurd 2010; rule of
    Arasaratnam & Haykin 2009) on an :class:`~nlfilter.models.SDEModel` with measurements
    ``y_k = h(x(t_k)) + v_k`` at ``t_k = t0 + k dt``; see
    :class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter` for the parameters.

    >>> import numpy as np, sympy as sp; from nlfilter import SDEModel
    >>> from nlfilter.filters import GaussianState
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x], Q=2.0, R=1.0)
    >>> s = ContinuousDiscreteCKF(model, 0.1, substeps=4).predict(GaussianState(np.array([1.0]), np.array([[0.5]])), 0)
    >>> round(float(s.mean[0]), 6), round(float(s.cov[0, 0]), 6)   # linear: e^{-0.1}, 1 − 0.5 e^{-0.2}
    (0.904837, 0.590635)
    """

    name = "cd-ckf"
    source = _CKF_SOURCE + "; Arasaratnam, Haykin & Hurd 2010, IEEE TSP 58(10) (continuous-discrete)"

    def __init__(self, model, dt: float, *, scheme: str = "rk4", substeps: int = 1, start: str | None = None,
                 t0: float | None = None):
        super().__init__(model, dt, Cubature(), scheme=scheme, substeps=substeps, start=start, t0=t0)


class ContinuousDiscreteGHKF(ContinuousDiscreteGaussianFilter):
    """Continuous-discrete Gauss–Hermite Kalman filter (Ito & Xiong 2000 rule; Särkkä 2007 moment
    equations), ``order`` nodes per axis; see
    :class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter` for the other parameters.

    >>> import numpy as np, sympy as sp; from nlfilter import SDEModel
    >>> from nlfilter.filters import GaussianState
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x**3], [x], Q=1.0, R=1.0)
    >>> s = ContinuousDiscreteGHKF(model, 0.01, order=5).predict(GaussianState(np.array([0.0]), np.array([[1.0]])), 0)
    >>> round(float(s.cov[0, 0]), 5)     # dP/dt = 2 Cov[x, −x³] + Q = −6P² + 1 (E[x⁴] = 3P², exact here)
    0.95284
    """

    name = "cd-ghkf"
    source = _GHKF_SOURCE + "; Särkkä 2007 (continuous-discrete moment equations)"

    def __init__(self, model, dt: float, *, order: int = 3, scheme: str = "rk4", substeps: int = 1,
                 start: str | None = None, t0: float | None = None):
        super().__init__(model, dt, GaussHermite(order), scheme=scheme, substeps=substeps, start=start, t0=t0)
        self.order = self.rule.order


def exact_order(model) -> int:
    """The Gauss–Hermite order (points per axis) at which the rule computes the Gaussian moments of a
    polynomial model *exactly* — its statistical linearization (Gelb 1974, *Applied Optimal
    Estimation* §6.2; Särkkä 2013 §5.5): the tensor rule with p points is exact for degree
    ≤ 2p − 1 in each variable, and the filter needs Cov[f], Cov[h] (degree 2·deg in each state),
    Cov[x, f], Cov[x, h] (deg + 1) and E[G Q Gᵀ] (2·deg G). A term that is not polynomial in the
    states is a ValueError naming it.

    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> x, y = sp.symbols("x y")
    >>> exact_order(DiscreteModel([x, y], [0.9 * x, x * y**2], [x**3], Q=0.1 * np.eye(2), R=1.0))  # 2·3 + 1 ≤ 2p − 1
    4
    """
    sym = getattr(model, "expressions", None)  # parameters as symbols: the degrees hold for every value
    if sym is None:
        raise TypeError("model: the statistically linearized filter needs a model stated in SymPy (polynomial f, h, G)")
    deg = 0
    for key, M in sym.items():
        for e in M:
            e = sp.expand(e)
            if not e.is_polynomial(*model.states):
                raise ValueError(f"model: {key} has the term {e} that is not polynomial in the states "
                                 f"{[str(s) for s in model.states]}; use GHKF(model, order=...) for a quadrature")
            if e.free_symbols & set(model.states):
                p = sp.Poly(e, *model.states)
                d = max(max(m) for m in p.monoms())  # the largest degree in any one state
                deg = max(deg, 2 * d, d + 1)
    return max(1, (deg + 2) // 2)  # smallest p with 2p − 1 ≥ deg


_SLF_SOURCE = ("Gelb 1974, Applied Optimal Estimation §6.2 (statistical linearization); exact Gaussian moments of "
               "polynomial f, h, G by the Gauss–Hermite rule of exact_order")


class StatisticallyLinearizedFilter(GaussianFilter):
    """Statistically linearized filter for a polynomial :class:`~nlfilter.models.DiscreteModel`:
    f and h replaced by their Gaussian statistical linearizations, ``E[f]``, ``Cov[x, f]``,
    ``Cov[f]`` (and those of h) computed exactly — the Gauss–Hermite rule at :func:`exact_order`.
    Its smoother is the statistically linearized RTS smoother (:mod:`~nlfilter.filters.smoothing`).

    >>> import numpy as np, sympy as sp; from nlfilter import DiscreteModel
    >>> from nlfilter.filters import GaussianState
    >>> x = sp.Symbol("x")
    >>> flt = StatisticallyLinearizedFilter(DiscreteModel([x], [x**3], [x], Q=0.1, R=1.0))
    >>> s = flt.predict(GaussianState(np.array([1.0]), np.array([[0.5]])), 0)
    >>> flt.order, round(float(s.mean[0]), 12)      # E[x³] = m³ + 3 m P, exactly
    (4, 2.5)
    """

    name = "slf"
    compiled = True  # its steps are the family's (backend="numba")
    source = _SLF_SOURCE
    needs = ("polynomial",)

    def __init__(self, model, *, start: str | None = None):
        check_structure(self, model)  # a structure it does not take is named before the degrees are read
        super().__init__(model, GaussHermite(exact_order(model)), start=start)
        self.order = self.rule.order


class ContinuousDiscreteSLF(ContinuousDiscreteGaussianFilter):
    """Continuous-discrete statistically linearized filter for a polynomial
    :class:`~nlfilter.models.SDEModel` (the moment equations of the Gaussian closure with exact
    Gaussian expectations, the rule at :func:`exact_order`); see
    :class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter` for the parameters.

    >>> import numpy as np, sympy as sp; from nlfilter import SDEModel
    >>> from nlfilter.filters import GaussianState
    >>> x = sp.Symbol("x")
    >>> s = ContinuousDiscreteSLF(SDEModel([x], [-x**3], [x], Q=1.0, R=1.0), 0.01).predict(
    ...     GaussianState(np.array([0.0]), np.array([[1.0]])), 0)
    >>> round(float(s.cov[0, 0]), 5)     # dP/dt = −6P² + 1, as the exact Gaussian closure
    0.95284
    """

    name = "cd-slf"
    source = _SLF_SOURCE + "; Särkkä 2007 (continuous-discrete moment equations)"
    needs = ("polynomial",)

    def __init__(self, model, dt: float, *, scheme: str = "rk4", substeps: int = 1, start: str | None = None,
                 t0: float | None = None):
        super().__init__(model, dt, GaussHermite(exact_order(model)), scheme=scheme, substeps=substeps, start=start,
                         t0=t0)
        self.order = self.rule.order
