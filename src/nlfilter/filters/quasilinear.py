"""Statistical linearization, the quasilinear filter (QLF) and the modified quasilinear filter
(MQLF) of seed 003 (Oh & Shin), in continuous and discrete time, with the off-line accuracy
analysis from the joint moments of (x, x̂).

Statistical linearization (003 eqs. 3-5) of ``f`` about the *prior* law of ``x(t)``::

    f(x) ≈ a0 + a1 (x − m),   a0 = E f,   a1 = E[f (x − m)ᵀ] K⁻¹        (same for h: b0, b1)

The expectations come from the moment engine: polynomial models use the exact moment equations
of ``x`` (003 eq. 11) closed by a closure — the Gaussian closure gives the QLF, a higher closure
(default: 4th-order Edgeworth / Hermite quasi-moments, 003 eqs. 12-15, 28-33) the MQLF;
non-polynomial models use Gauss-Hermite expectations under the Gaussian closure (QLF only).

Theorem 4.1 (003 eqs. 16-17), continuous time, measurement increments ``dy = h dt + dη``::

    dx̂ = [a1 x̂ + a0 − a1 m] dt + P b1ᵀ R⁻¹ (dy − [b1 x̂ + b0 − b1 m] dt)
    dP/dt = a1 P + P a1ᵀ − P b1ᵀ R⁻¹ b1 P + E[G Q Gᵀ]

Everything but ``x̂`` — the moments, a0, a1, b0, b1, P and the gain — depends on the prior only,
so :meth:`QuasilinearFilter.offline` computes it once (one ``solve_ivp`` of the moment and
Riccati equations, dense output); :meth:`~QuasilinearFilter.run` then integrates one linear equation per step for
the whole batch: the ``dt`` terms by RK4 (or Euler) substeps, the innovation ``Kg(t_k) dy`` added
as an Itô increment with the gain at the start of the step (the convention of
:class:`~nlfilter.filters.ekf.ContinuousEKF`, so the QLF is the Kalman-Bucy filter on linear
models). ``Estimates.covs`` holds ``P``, which is NOT the
error covariance (003, below eq. 8); the true error comes from :meth:`~QuasilinearFilter.error_analysis`.

Off-line accuracy (003 Fig. 2): (x, x̂) is a polynomial SDE with time-varying coefficients::

    dx = f(x) dt + G dβ,   dx̂ = [F(t) x̂ + u(t) + Kg(t) h(x)] dt + Kg(t) dη,
    F = a1 − Kg b1,  u = a0 − a1 m − Kg (b0 − b1 m),  Kg = P b1ᵀ R⁻¹

whose moments the engine propagates (closed by a closure, by default Edgeworth of order 4 as in
the paper); the MSE is ``E x² − 2 E x x̂ + E x̂²``.

Discrete time (:class:`DiscreteQuasilinearFilter`): the Kalman filter of the statistically
linearized model, with the prior moments of ``x[k]`` from the discrete moment equations. Its
off-line accuracy (the library's extension; the paper is continuous) comes from the moments of the
prior pair (x[k], x̂⁻[k]), a polynomial map with time-varying coefficients driven by (w, v)::

    x[k+1] = f(x) + G(x) w,   x̂⁻[k+1] = a1 (I − Kg b1) x̂⁻ + a1 Kg (h(x) + v) + e − a1 Kg d

(:func:`~nlfilter.filters.offline_analysis.gain_error_analysis`, any filter of that form;
``d = b0 − b1 m``, ``e = a0 − a1 m``; the joint analyses live in :mod:`.offline_analysis`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from .. import _validate as V
from ..errors import ClosureDivergedError, NotPolynomialError
from ..moments.closures import Closure, EdgeworthClosure, GaussianClosure
from .base import ContinuousFilter, check_structure, continuous_precision, set_start
from .linalg import symmetrize
from .linearization import _Linearizer, statistical_linearization
from .offline import ContinuousSchedule, DiscreteSchedule, OfflineGainFilter
from .offline_analysis import ErrorAnalysis, _prior, gain_error_analysis

__all__ = ["statistical_linearization", "QuasilinearFilter", "DiscreteQuasilinearFilter", "QLF", "MQLF",
           "OfflineGains", "ErrorAnalysis", "gain_error_analysis"]


@dataclass
class OfflineGains:
    """Everything the QLF/MQLF computes before the data: on the grid ``t (T+1,)``: prior moments
    ``moments (T+1, size)``, ``m (T+1, n)``, ``K`` (prior covariance), ``a0, a1, b0, b1``, ``P``,
    ``gain = P b1ᵀ R⁻¹``; ``dense(t)`` evaluates ``(μ, P)`` at any t in range."""

    t: np.ndarray
    moments: np.ndarray
    m: np.ndarray
    K: np.ndarray
    a0: np.ndarray
    a1: np.ndarray
    b0: np.ndarray
    b1: np.ndarray
    P: np.ndarray
    gain: np.ndarray
    dense: object


class _QLFSchedule(ContinuousSchedule):
    """The QLF's gains on the stage grid of its scheme, from the dense off-line solution."""

    convention = "ito"

    def __init__(self, flt, g: OfflineGains, t0: float):
        self.dt, self.substeps, self.scheme = flt.dt, flt.substeps, flt.scheme
        self.gains = g
        T = g.t.size - 1
        h = flt.dt / flt.substeps
        ts = t0 + 0.5 * h * np.arange(2 * flt.substeps * T + 1)  # every RK4 stage time t_k + j h/2
        self.F, self.u, self.Kg, self.A, self.b, self.H, self.d, self.Q = flt._tables(g.dense(ts).T)
        self.S = flt.model.R

    def cov(self, k):
        return self.gains.P[k]

    def drift(self, i):
        return self.F[i], self.u[i]

    def coeffs(self, i):
        return self.A[i], self.b[i], self.H[i], self.d[i], self.Kg[i], self.Q[i], self.S


OFFLINE_SECONDS = 30.0  # wall-clock bound of one off-line solve (a stiff or stalled solve is refused)
OFFLINE_SCALE = 1e150  # bound of the prior moments and their rates: products of two stay finite in float64


class _Stalled(Exception):
    pass


def _bounded_solve(rhs, t, y0, flt, m0, P0):
    """``solve_ivp`` (LSODA, dense) of the QLF's off-line equations on the times ``t``, stopped with a
    :class:`ClosureDivergedError` naming the prior when it takes more than :data:`OFFLINE_SECONDS`
    (the same numbers as an unbounded solve otherwise)."""
    deadline = time.monotonic() + OFFLINE_SECONDS
    now = [float(t[0])]

    def bounded(s, y):
        now[0] = s
        if time.monotonic() > deadline:
            raise _Stalled
        return rhs(s, y)

    try:
        return solve_ivp(bounded, (t[0], t[-1]), y0, method="LSODA", t_eval=t, dense_output=True,
                         rtol=flt.rtol, atol=flt.atol)
    except _Stalled:
        raise ClosureDivergedError(
            f"{flt.name}: the off-line moment/Riccati equations did not reach t = {t[-1]:.6g} within "
            f"{OFFLINE_SECONDS:g} s (stalled at t = {now[0]:.6g}): the prior m0/P0 (max |m0| = "
            f"{np.max(np.abs(m0)):.3g}, max |P0| = {np.max(np.abs(P0)):.3g}) or the horizon is too stiff for "
            f"rtol={flt.rtol:g}, atol={flt.atol:g}", time=now[0]) from None


class QuasilinearFilter(OfflineGainFilter, ContinuousFilter):
    """QLF / MQLF for an :class:`~nlfilter.models.SDEModel` (003 Theorem 4.1, eqs. 16-17).

    Parameters
    ----------
    model : SDEModel (SymPy). Polynomial f, GQGᵀ, h: any closure; otherwise Gaussian closure only.
    dt : measurement step of the increments ``dy``
    closure : a :class:`~nlfilter.moments.closures.Closure`; default Gaussian (QLF)
    order : order N of the prior moment set (default: the closure's order)
    substeps, scheme : steps per measurement step and scheme (``"rk4"`` or ``"euler"``) of the
        on-line equation
    rtol, atol : tolerances of the off-line ``solve_ivp``

    Notes
    -----
    The gains depend on the prior ``(m0, P0)``, which must be the same for every path; they are
    computed at the first ``run`` (or by :meth:`offline`) and cached.

    Examples
    --------
    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> model = SDEModel([x], [-x], [x], Q=1.0, R=1.0)          # linear: QLF = Kalman-Bucy
    >>> g = QuasilinearFilter(model, 0.01).offline([0.0], [[1.0]], 1000)
    >>> round(float(g.P[-1, 0, 0]), 4)                        # Riccati: P' = −2P − P² + 1 → √2 − 1
    0.4142
    """

    covariance = "model"  # P(t) of the statistically linearized model (003, below eq. 8)

    name = "qlf"
    family = "off-line gains"
    source = "seed 003 eqs. 3-8, 11, 16-17 (Theorem 4.1)"
    accepts = ("sde",)
    needs = ("sympy",)
    time = "continuous"

    def __init__(self, model, dt, *, closure: Closure | None = None, order: int | None = None,
                 substeps: int = 4, scheme: str = "rk4", rtol: float = 1e-9, atol: float = 1e-12):
        ContinuousFilter.__init__(self, model, dt, scheme=scheme, substeps=substeps)
        closure = GaussianClosure() if closure is None else closure
        if not isinstance(closure, Closure):
            raise TypeError(f"closure: expected a Closure instance, got {type(closure).__name__}")
        self.closure = closure
        self.lin = _Linearizer(model, closure, order, "continuous")
        self._Rinv = continuous_precision(model)
        self.rtol, self.atol = float(V.positive("rtol", rtol)), float(V.positive("atol", atol))
        self._cache = {}

    # -- off-line ------------------------------------------------------------------------------
    def _prior(self, m0, P0):
        return _prior(self.model.n, m0, P0)

    def offline(self, m0, P0, steps: int, *, t0: float = 0.0) -> OfflineGains:
        """Solve the prior-moment and Riccati equations (003 eqs. 11, 17) on ``t0 .. t0 + steps·dt``."""
        m0, P0 = self._prior(m0, P0)
        V.positive("steps", steps, integer=True)
        t0 = V.real("t0", t0)
        key = (m0.tobytes(), P0.tobytes(), int(steps), float(t0))
        if key in self._cache:
            return self._cache[key]
        lin, n, Rinv = self.lin, self.model.n, self._Rinv
        S = lin.size

        def rhs(t, y):
            mu, P = y[:S], y[S:].reshape(n, n)
            c = lin.coeffs(mu, t)
            _, _, a0, a1, b0, b1, sig = c
            dP = a1 @ P + P @ a1.T - P @ b1.T @ Rinv @ b1 @ P + sig  # 003 eq. 17
            return np.concatenate([lin.deriv(mu, t, c), dP.ravel()])

        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            y0 = np.concatenate([lin.init(m0, P0), P0.ravel()])
            size = max(np.max(np.abs(y0)), np.max(np.abs(rhs(t0, y0))))
        if not size < OFFLINE_SCALE:  # LSODA would retry the first step for ever (P0 = 1e150: 6 P0² ~ 1e301)
            raise ValueError(f"P0: the off-line moment/Riccati equations of this prior cannot be integrated in "
                             f"float64: expected its moments and their rates below {OFFLINE_SCALE:g}, got "
                             f"{size:.3g} (max |m0| = {np.max(np.abs(m0)):.3g}, max |P0| = {np.max(np.abs(P0)):.3g})")
        t = t0 + self.dt * np.arange(steps + 1)
        sol = _bounded_solve(rhs, t, y0, self, m0, P0)
        if sol.status != 0 or not np.all(np.isfinite(sol.y)):
            raise ClosureDivergedError(f"{self.name}: the off-line moment/Riccati equations failed at "
                                       f"t = {sol.t[-1]:.6g}: {sol.message}", time=float(sol.t[-1]))
        Y = sol.y.T
        mu, P = Y[:, :S], Y[:, S:].reshape(-1, n, n)
        mean, K, a0, a1, b0, b1, _ = lin.coeffs(mu)
        bad = np.flatnonzero(np.linalg.eigvalsh(K)[:, 0] <= 0)
        if bad.size:
            raise ClosureDivergedError(f"{self.name}: the prior variance turned non-positive at t = {t[bad[0]]:.6g}",
                                       time=float(t[bad[0]]), moment=(2,) if n == 1 else None)
        gain = P @ np.swapaxes(b1, -1, -2) @ Rinv
        out = OfflineGains(t, mu, mean, K, a0, a1, b0, b1, symmetrize(P), gain, sol.sol)
        self._cache = {key: out}
        return out

    def _tables(self, y):
        """Coefficients at dense states ``y (..., S + n²)``: ``(F, u, Kg, a1, b, b1, d, σ̄)`` with
        ``F = a1 − Kg b1``, ``u = b − Kg d``, ``b = a0 − a1 m``, ``d = b0 − b1 m``."""
        lin, n, Rinv = self.lin, self.model.n, self._Rinv
        S = lin.size
        mu, P = y[..., :S], y[..., S:].reshape(*y.shape[:-1], n, n)
        mean, K, a0, a1, b0, b1, sig = lin.coeffs(mu)
        Kg = P @ np.swapaxes(b1, -1, -2) @ Rinv
        F = a1 - Kg @ b1
        b = a0 - np.einsum("...ij,...j->...i", a1, mean)
        d = b0 - np.einsum("...ij,...j->...i", b1, mean)
        u = b - np.einsum("...ij,...j->...i", Kg, d)
        return F, u, Kg, a1, b, b1, d, sig

    def _coeff(self, y):
        """On-line coefficients F, u, Kg at dense states ``y (..., S + n²)``."""
        return self._tables(y)[:3]

    # -- on-line (the affine runner of :mod:`.offline`) -------------------------------------------
    def schedule(self, m0, P0, batch, steps, t0):
        """The gain schedule of a run of ``steps`` increments from ``t0`` (:meth:`offline`, then the
        coefficients at every stage time ``t_k + j h/2`` of the scheme)."""
        if steps is None:
            raise ValueError("steps: the QLF's off-line gains are solved for a horizon; pass steps= to init")
        m0, P0 = self._prior(m0, P0)
        g = self.offline(m0, P0, max(int(steps), 1), t0=t0)
        return _QLFSchedule(self, g, t0), m0, P0

    # ``run`` is :meth:`OfflineGainFilter.run` (003 eq. 16); ``covs`` holds P(t) (not the error covariance)

    # -- accuracy ------------------------------------------------------------------------------
    def error_analysis(self, m0, P0, steps: int, *, closure: Closure | None = None, order: int | None = None,
                       t0: float = 0.0) -> ErrorAnalysis:
        """True MSE E(x − x̂)² at ``t0 + (k + 1) dt``, k = 0 .. steps − 1 (the rows of :meth:`run`'s
        estimates; the prior's in ``.prior``), from the moments of the joint process (x, x̂) (003
        Fig. 2, eq. 11) with the off-line coefficients of eqs. 4-8, 16, through
        :func:`~nlfilter.filters.offline_analysis.gain_error_analysis`; closed by ``closure``
        (default Edgeworth of ``order`` 4 as in the paper); ``order`` defaults to the closure's
        order (:func:`~nlfilter.moments.closures.kept_order`). Polynomial models. An ``order``
        whose joint moment system exceeds
        :data:`~nlfilter.filters.offline_analysis.MAX_ANALYSIS_MOMENTS` moments (order > 14 for a
        scalar state) is a ``ValueError`` naming ``order``."""
        if not self.lin.polynomial:
            raise NotPolynomialError("model: the off-line accuracy analysis needs polynomial f, GQGᵀ and h")
        m0, P0 = self._prior(m0, P0)
        g = self.offline(m0, P0, steps, t0=t0)
        return gain_error_analysis(self.model, lambda t: self._coeff(g.dense(t)), m0, P0, steps, dt=self.dt,
                                   t0=t0, closure=closure, order=order)


def QLF(model, dt, *, order: int | None = None, substeps: int = 4, scheme: str = "rk4", rtol: float = 1e-9,
        atol: float = 1e-12) -> QuasilinearFilter:
    """The quasilinear filter: statistical linearization under the Gaussian closure (003 eqs. 3-8);
    the other arguments as :class:`QuasilinearFilter`'s."""
    f = QuasilinearFilter(model, dt, closure=GaussianClosure(), order=order, substeps=substeps, scheme=scheme,
                          rtol=rtol, atol=atol)
    f.name = "qlf"
    return f


def MQLF(model, dt, *, closure: Closure | None = None, order: int | None = None, substeps: int = 4,
         scheme: str = "rk4", rtol: float = 1e-9, atol: float = 1e-12) -> QuasilinearFilter:
    """The modified quasilinear filter (003 Theorem 4.1): coefficients from the method of moments
    closed by ``closure`` (default: Edgeworth / Hermite quasi-moments of order 4, 003 eqs. 27-33);
    the other arguments as :class:`QuasilinearFilter`'s."""
    f = QuasilinearFilter(model, dt, closure=EdgeworthClosure(4) if closure is None else closure, order=order,
                          substeps=substeps, scheme=scheme, rtol=rtol, atol=atol)
    f.name = "mqlf"
    f.needs = ("sympy", "polynomial")  # a closure beyond Gaussian needs the exact polynomial moments
    return f


class _DQLFSchedule(DiscreteSchedule):
    """The discrete QLF's gains: the Kalman recursion (Joseph form) of the statistically
    linearized model, the coefficients from the prior moments of x[k], extended along k."""

    def __init__(self, flt, m0, P0, start):
        super().__init__(P0, start)
        self.lin, self.R, self.name = flt.lin, flt.model.R, flt.name
        self.mu = flt.lin.init(m0, P0)
        self.rows = []  # (mean, a0, a1, b0, b1) per step, for error_analysis

    def model(self, k):
        mean, _, a0, a1, b0, b1, sig = self.lin.coeffs(self.mu, k)
        self.rows.append((mean, a0, a1, b0, b1))
        self.mu = self.lin.step(self.mu, k)
        if not np.all(np.isfinite(self.mu)):
            raise ClosureDivergedError(f"{self.name}: prior moments blew up at k = {k + 1}: the off-line moments "
                                       "from the prior m0, P0 overflowed (expected a prior whose moments the "
                                       "model's map keeps finite)", time=k + 1)
        return a1, a0 - a1 @ mean, b1, b0 - b1 @ mean, sig, self.R

    def gain(self, P, H, S):
        Kg = P @ H.T @ np.linalg.inv(H @ P @ H.T + S)
        IKH = np.eye(P.shape[0]) - Kg @ H
        return Kg, symmetrize(IKH @ P @ IKH.T + Kg @ S @ Kg.T)  # Joseph form


class DiscreteQuasilinearFilter(OfflineGainFilter):
    """Discrete-time QLF/MQLF for a :class:`~nlfilter.models.DiscreteModel`: the Kalman filter of
    the statistically linearized model ``x[k+1] ≈ a1 x + a0 − a1 m + G w``,
    ``y ≈ b1 x + b0 − b1 m + v`` with coefficients from the prior moments of ``x[k]`` (discrete
    moment equations + closure). Gains off-line (:mod:`.offline`: ``predict``/``update`` run the
    affine recursion; NaN components of ``y`` are missing); step convention ``start`` as
    :class:`~nlfilter.filters.base.DiscreteFilter` (default ``"update"``: ``ys[k]`` measures
    ``x[k]``, ``x[0] ~ (m0, P0)``).

    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> x = sp.Symbol("x")
    >>> est = DiscreteQuasilinearFilter(DiscreteModel([x], [0.5 * x], [x], Q=1.0, R=1.0)).run(
    ...     np.array([[[1.0], [0.0]]]), [0.0], [[1.0]])
    >>> est.means[0, :, 0].round(6).tolist()       # Kalman filter: 0.5, then 0.25 / 2.125
    [0.5, 0.117647]
    """

    covariance = "model"  # P(t) of the statistically linearized model (003, below eq. 8)

    name = "qlf"
    source = "seed 003 eqs. 3-5, 11 in discrete form (the library's extension)"
    accepts = ("discrete",)
    needs = ("sympy",)
    time = "discrete"

    def __init__(self, model, *, closure: Closure | None = None, order: int | None = None, start: str | None = None):
        if getattr(model, "kind", None) != "discrete":
            raise TypeError(f"model: DiscreteQuasilinearFilter expects a DiscreteModel, got {type(model).__name__}")
        check_structure(self, model)
        self.model = model
        self.closure = GaussianClosure() if closure is None else closure
        set_start(self, start)
        self.lin = _Linearizer(model, self.closure, order, "discrete")

    def schedule(self, m0, P0, batch, steps, t0):
        m0, P0 = _prior(self.model.n, m0, P0)
        return _DQLFSchedule(self, m0, P0, self.start), m0, P0

    def offline(self, m0, P0, steps: int):
        """Rows ``(mean, a0, a1, b0, b1, Kg, P⁺)`` on k = 0..T−1 (update then predict)."""
        sch = _DQLFSchedule(self, m0, P0, "update")
        sch.ensure(steps - 1)
        return [(*sch.rows[k], sch.gains[k], sch.filt[k]) for k in range(steps)]

    def error_analysis(self, m0, P0, steps: int, *, closure: Closure | None = None,
                       order: int | None = None) -> ErrorAnalysis:
        """True MSE E(x[k] − x̂⁺[k])² at k = 0 .. steps − 1 (the estimates of :meth:`run` on
        ``steps`` measurements, ``start="update"``) from the moments of the joint process (x, x̂),
        closed by ``closure`` (default Edgeworth of ``order`` 4, as 003 Fig. 2 in continuous time;
        ``order`` defaults to the closure's order). The coefficients of :meth:`offline` (003 eqs.
        4-5 on the prior moments, eq. 11 in discrete form) enter
        :func:`~nlfilter.filters.offline_analysis.gain_error_analysis` as ``d = b0 − b1 m``,
        ``e = a0 − a1 m``. Polynomial models; ``t`` holds the step indices, ``.prior`` the prior's MSE.
        An ``order`` whose joint moment system exceeds
        :data:`~nlfilter.filters.offline_analysis.MAX_ANALYSIS_MOMENTS` moments (order > 14 for a
        scalar state) is a ``ValueError`` naming ``order``."""
        if not self.lin.polynomial:
            raise NotPolynomialError("model: the off-line accuracy analysis needs polynomial f, G and h")
        m0, P0 = _prior(self.model.n, m0, P0)
        V.positive("steps", steps, integer=True)
        rows = self.offline(m0, P0, steps)

        def coefficients(k):
            mean, a0, a1, b0, b1, Kg, _ = rows[k]
            return Kg, b1, b0 - b1 @ mean, a1, a0 - a1 @ mean

        return gain_error_analysis(self.model, coefficients, m0, P0, steps, closure=closure, order=order)
