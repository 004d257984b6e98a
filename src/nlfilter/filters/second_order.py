"""Second-order nonlinear filters (seed 004, Henriksen 1979), discrete, continuous and
continuous-discrete time, in the forms the paper discusses.

One family, one ``form=`` option:

=========================  =====================================================================
form                       what it is
=========================  =====================================================================
``"truncated"``            Henriksen's correct truncated second-order filter (default):
                           discrete 004 eqs. 18-23, continuous 004 eqs. 35-37. Third *and*
                           fourth central moments neglected, so no −¼ terms and ``C = 0``.
``"truncated-jazwinski"``  the truncated filter before the correction (Jazwinski 1966/1970,
                           Bass et al. 1966): −¼(X f_xx)(X f_xx)ᵀ in the predicted covariance
                           (004 eq. 11 without its fourth-moment term), −¼(X h_xx)(X h_xx)ᵀ in the
                           gain's inverse (004 text after eq. 23), and the random forcing
                           term −½ X_ij (X h_xx) of 004 eq. 33 in the covariance update.
``"modified"``             Jazwinski's *modified* truncated filter (``C = 0``): eq. 19 prediction,
                           −¼(X h_xx)(X h_xx)ᵀ kept inside the gain's inverse. In continuous time
                           it is the correct filter (004 sec. 3: "identical to the filter which has
                           been derived here"), so there ``"modified"`` = ``"truncated"``.
``"gaussian"``             Gaussian second-order filter: fourth central moments of a Gaussian,
                           ½ tr(f_xx⁽ⁱ⁾ X f_xx⁽ʲ⁾ X) in the prediction, ½ tr(h_xx⁽ⁱ⁾ X h_xx⁽ʲ⁾ X) in
                           the innovation covariance, the Gaussian fourth-moment term of G(x) V Gᵀ(x),
                           and the forcing term Σ_k (X h_xx⁽ᵏ⁾ X)[·]_k (opposite sign to 004 eq. 33).
``"modified-gaussian"``    the Gaussian filter with ``C = 0`` (no forcing term), Jazwinski's other
                           modified form.
``"first-order"``          all second-order terms dropped: the extended Kalman filter (the baseline,
                           given here so that the continuous-discrete EKF exists too).
=========================  =====================================================================

All three are configurations of the skeletons of :mod:`nlfilter.filters.gaussian` (discrete,
continuous-discrete, continuous Itô) with the moment rule :class:`~nlfilter.filters.rules.Taylor2`
parametrised by ``form`` (which fourth-moment terms, the −¼ terms, the forcing term C); the
contractions below live in :mod:`nlfilter.filters.rules` and are re-exported here.

Notation (004): X the error covariance, V = ``model.Q``, W = ``model.R``; a state batch is
``(..., n)``, a covariance batch ``(..., n, n)``. The contractions (004 eqs. 9, 13, 14, 23):

* ``(X f_xx)_i = Σ_jl X_jl ∂²f_i/∂x_j∂x_l``  → :func:`hessian_trace`
* ``(X V G_x²)_iq = Σ X_pt V_jl ∂G_ij/∂x_p ∂G_ql/∂x_t`` and
  ``(X V G_xx G)_iq = Σ X_pt V_jl ∂²G_ij/∂x_p∂x_t G_ql`` → :func:`noise_covariance`

The discrete ``C`` tensor of 004 eq. 17 is not printed in the paper (its footnote 1); we use its
regression form ``X⁺ += Σ_k M_k [S⁻¹(y − ŷ)]_k`` with ``M_k,ij ≈ E[δ_i δ_j (h_k − ĥ_k)]`` under each
form's moment assumption (−½ X_ij (X h_xx)_k truncated-Jazwinski, (X h_xx⁽ᵏ⁾ X)_ij Gaussian), whose
limit for ``S → W/dt`` is the continuous forcing term of 004 eqs. 32-33.

Continuous time: between measurement increments the deterministic part of the moment equations is
integrated by Euler or RK4 (``scheme``); the innovation part ``K dy`` (and any forcing term) enters
as an Itô increment evaluated at the start of the step, so that the scheme converges to the Itô
filter of 004 eq. 27-37 (holding ``dy/dt`` constant inside an RK4 step would converge to the
Stratonovich/Wong-Zakai reading instead whenever the gain depends on the state).

Example
-------
>>> import sympy as sp; from nlfilter import DiscreteModel
>>> x = sp.Symbol("x")
>>> model = DiscreteModel([x], [0.9 * x], [x + 0.5 * x**2], Q=0.1, R=0.1)
>>> flt = SecondOrderFilter(model)
>>> s = flt.predict(GaussianState(np.array([1.0]), np.array([[0.2]])), 0)
>>> round(float(s.mean[0]), 6), round(float(s.cov[0, 0]), 6)
(0.9, 0.262)
"""

from __future__ import annotations

import numpy as np  # noqa: F401  (the doctests use it)

from .. import _validate as V
from .base import ContinuousFilter, DiscreteFilter, GaussianState  # noqa: F401  (GaussianState: the doctests)
from .contractions import gaussian_quartic, hessian_trace, noise_covariance, quarter_outer
from .gaussian import ContinuousDiscreteGaussianFilter, ContinuousGaussianFilter, GaussianFilter
from .rules import FORMS, Taylor2


def _forcing(form, X, h_xx):
    """The covariance forcing tensor of ``form`` (:meth:`~nlfilter.filters.rules.Taylor2.forcing`)."""
    return Taylor2(form).forcing(X, h_xx)


def _form(flt, form):
    """The form checked and named on the filter ``flt``, and its Taylor-2 rule (the configuration
    shared by the three time settings)."""
    flt.form = V.choice("form", form, set(FORMS))
    flt.name = "ekf" if form == "first-order" else form
    return Taylor2(form)


class SecondOrderFilter(GaussianFilter):
    """Second-order filter for a :class:`~nlfilter.models.DiscreteModel` (batched): the
    :class:`~nlfilter.filters.gaussian.GaussianFilter` skeleton with the rule
    :class:`Taylor2(form) <nlfilter.filters.rules.Taylor2>`.

    ``x[k+1] = f(x[k]) + G(x[k]) v[k]``, ``y[k] = h(x[k]) + w[k]`` (004 eqs. 1-2).

    Prediction (004 eqs. 18-19)::

        m⁻ = f(m) + ½(X f_xx)
        X⁻ = F X Fᵀ + G V Gᵀ + (X V G_x²) + ½(X V G_xx G) + ½(X V G_xx G)ᵀ   [+ form term]

    Update (004 eqs. 20-22)::

        ŷ = h(m⁻) + ½(X⁻ h_xx),   S = H X⁻ Hᵀ + W   [+ form term],   K = X⁻ Hᵀ S⁻¹
        m⁺ = m⁻ + K (y − ŷ),      X⁺ = (I − K H) X⁻   [+ C (y − ŷ) for jazwinski/gaussian]

    Parameters
    ----------
    model : DiscreteModel with ``f_xx``, ``h_xx`` (and ``G_x``, ``G_xx`` when G depends on x)
    form : one of :data:`FORMS` (default ``"truncated"``, the paper's correct form)
    start : ``"update"`` or ``"predict"`` (see :mod:`nlfilter.filters.base`)

    Notes
    -----
    ``predict``/``update`` raise :class:`~nlfilter.errors.DivergenceError` when the covariance (or
    the innovation covariance) is not positive (semi)definite; ``run`` raises or, with
    ``on_divergence="mark"``, records such paths.
    """

    source = "seed 004 eqs. 18-23 (discrete), Henriksen 1979"
    family = "second-order"
    needs = ("f_x", "f_xx", "h_x", "h_xx")
    raises = True
    compiled = True  # its steps are the family's (backend="numba")

    def __init__(self, model, *, form: str = "truncated", start: str | None = None):
        DiscreteFilter.__init__(self, model, start=start)
        self._set_rule(_form(self, form), by=f"SecondOrderFilter(form={form!r})")


class ContinuousDiscreteSecondOrderFilter(ContinuousDiscreteGaussianFilter):
    """Continuous dynamics, discrete measurements: the moment ODEs of 004 eqs. 35-36 without their
    measurement terms between measurements, the discrete update of 004 eqs. 20-22 at them (the
    :class:`~nlfilter.filters.gaussian.ContinuousDiscreteGaussianFilter` skeleton with the rule
    :class:`Taylor2(form) <nlfilter.filters.rules.Taylor2>`).

    The model is an :class:`~nlfilter.models.SDEModel` whose ``h`` and ``R`` are read as the
    *discrete* measurement ``y_k = h(x(t_k)) + w_k``, ``w_k ~ (0, R)``, ``t_k = t0 + k dt``.
    Between measurements (004 eq. 35-36 with K = 0; third moments neglected, so f_xx enters the
    mean only; the Gaussian form adds its fourth-moment term of E[G V Gᵀ])::

        dm/dt = f(m) + ½(X f_xx),   dX/dt = F X + X Fᵀ + E[G V Gᵀ]   (second order)

    integrated by ``scheme`` (``"rk4"`` default or ``"euler"``) with ``substeps`` steps per interval.
    ``start="predict"`` (default): ``ys[..., 0, :]`` is taken at ``t0 + dt``; ``"update"``: at ``t0``.

    >>> from nlfilter.problems import falling_body
    >>> p = falling_body()
    >>> flt = ContinuousDiscreteSecondOrderFilter(p.model, p.dt, substeps=10, start="predict")
    >>> est = flt.run(np.full((2, 3, 1), 2.0e5), p.m0, p.P0)   # 2 paths, 3 range measurements
    >>> est.means.shape, bool(est.diverged.any())
    ((2, 3, 3), False)
    """

    source = "seed 004 eqs. 35-36 between measurements, eqs. 20-22 at them"
    accepts = ("sde",)
    family = "second-order"
    needs = ("f_x", "f_xx", "h_x", "h_xx")
    raises = True

    def __init__(self, model, dt: float, *, form: str = "truncated", scheme: str = "rk4",
                 substeps: int = 1, start: str | None = None, t0: float | None = None):
        # the continuous-discrete skeleton with Taylor2(form)
        super().__init__(model, dt, _form(self, form), scheme=scheme, substeps=substeps, start=start, t0=t0,
                         by=f"ContinuousDiscreteSecondOrderFilter(form={form!r})")


class ContinuousSecondOrderFilter(ContinuousGaussianFilter):
    """Second-order filter for an Itô :class:`~nlfilter.models.SDEModel` observed through increments
    ``dy`` (004 eqs. 35-37): the :class:`~nlfilter.filters.gaussian.ContinuousGaussianFilter`
    skeleton with the rule :class:`Taylor2(form) <nlfilter.filters.rules.Taylor2>`::

        dm = [f + ½(X f_xx)] dt + K {dy − [h + ½(X h_xx)] dt},     K = X Hᵀ W⁻¹
        dX = [F X + X Fᵀ + G V Gᵀ + (X V G_x²) + ½(X V G_xx G) + ½(·)ᵀ − K W Kᵀ] dt
             [+ Σ_k M_k [W⁻¹(dy − ĥ dt)]_k   for "truncated-jazwinski" (004 eq. 33) and "gaussian"]

    One step, ``innovation="ito"`` (default): the ``dt`` terms are integrated by ``scheme`` (Euler or
    RK4, ``substeps`` per step); the ``dy`` terms are added as an Itô increment with the gain at the
    start of the step. With ``scheme="euler"`` this is exactly the Euler–Maruyama step of the filter
    equations. It is explicit: it goes unstable when ``‖K H‖ dt ≳ 2`` (large gains).
    ``innovation="update"``: the increment is first absorbed by the discrete update of the same form
    (004 eqs. 20-22 with ``y = dy/dt``, ``R = W/dt``, state at the step start: the left-point Itô
    reading), then the moments are propagated over ``dt`` without measurement terms. Stable for any
    gain; the same limit as ``dt → 0`` (the discrete gain is ``X Hᵀ (H X Hᵀ dt + W)⁻¹ dt``).
    ``"modified"`` is the same filter as ``"truncated"`` here (004 sec. 3).

    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x + 0.5 * x**2], G=[[0.5 + 0.2 * x]], Q=1.0, R=0.1)
    >>> flt = ContinuousSecondOrderFilter(model, 0.01, scheme="euler")
    >>> s = flt.step(GaussianState(np.array([0.0]), np.array([[1.0]])), np.array([0.0]), 0.0)
    >>> round(float(s.mean[0]), 6), round(float(s.cov[0, 0]), 6)   # −K·½X h_xx dt; X(1 − 2dt) + (0.25 + 0.04 X − X²/0.1) dt
    (-0.05, 0.8829)
    """

    source = "seed 004 eqs. 35-37 (continuous), Henriksen 1979"
    family = "second-order"
    needs = ("f_x", "f_xx", "h_x", "h_xx")
    raises = True

    def __init__(self, model, dt, *, form: str = "truncated", scheme: str = "rk4", substeps: int = 1,
                 innovation: str = "ito"):
        ContinuousFilter.__init__(self, model, dt, scheme=scheme, substeps=substeps)
        self.innovation = V.choice("innovation", innovation, {"ito", "update"})
        _form(self, form)
        # 004 sec. 3: no −¼ term exists in continuous time, "modified" is the truncated filter
        self._set_rule(Taylor2("truncated" if form == "modified" else form),
                       by=f"ContinuousSecondOrderFilter(form={form!r})")


__all__ = ["FORMS", "SecondOrderFilter", "ContinuousSecondOrderFilter",
           "ContinuousDiscreteSecondOrderFilter", "hessian_trace", "quarter_outer", "gaussian_quartic",
           "noise_covariance"]
