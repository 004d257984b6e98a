"""The optimal linear filters of bilinear systems (seed 001, Vallot 1981), continuous and discrete
time, with their second moments, steady state and the Wonham-type existence condition; both run
on the off-line-gain runner of :mod:`.offline` (re-exported by :mod:`nlfilter.filters.bilinear`).

Optimal linear filter (001 eqs. 2.31-2.47), in the augmented coordinates ``z = (x, 1)`` of
:meth:`~nlfilter.bilinear.BilinearModel.augmented`::

    dẑ = F ẑ dt + K (dy − H ẑ dt),      K = P Hᵀ Σ_v⁻¹                         (2.31, 2.32)
    Σ_v = Σ_j M_j X M_jᵀ                                                        (2.47)
    dX/dt = F X + X Fᵀ + Σ_i G_i X G_iᵀ                                         (2.37)
    dP/dt = F P + P Fᵀ + Σ_i G_i X G_iᵀ − K Σ_v Kᵀ                              (2.43)

Its gains do not depend on the data: they are computed once, off-line (time-varying along the
measurement grid, or the steady state of the algebraic equations (2.54) solved directly).
Missing data (NaN components of ``dy`` / ``y``): the gain's columns of the missing components
are dropped, and the path's reported covariance is that of the recursion actually run
(:mod:`.offline`).
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from .. import _validate as V
from ..bilinear import BilinearModel
from ..sde_step import HELD
from ..bilinear_analysis import augmented_second_moment, state_second_moments, wonham_condition
from ..errors import SingularSystemError
from ..ode import ode_step
from .base import gaussian_prior, set_start
from .linalg import symmetrize
from .offline import ContinuousSchedule, DiscreteSchedule, OfflineGainFilter


class LinearSteadyState(NamedTuple):
    """Steady state of the optimal linear filter, augmented coordinates: ``X`` = E[z zᵀ],
    ``P`` error covariance, ``K`` gain, ``Sigma_v`` innovation intensity, ``Pi`` = Σ G_i X G_iᵀ."""

    X: np.ndarray
    P: np.ndarray
    K: np.ndarray
    Sigma_v: np.ndarray
    Pi: np.ndarray


def _pinv_psd(S, tol=1e-12):
    """Inverse of a PSD matrix, or its pseudo-inverse when singular (001 §3.2: a singular
    innovation covariance, handled as in Liptser-Shiryaev by projecting on its range)."""
    w, U = np.linalg.eigh(symmetrize(S))
    big = w > tol * max(1.0, float(np.max(np.abs(w)))) if w.size else w
    inv = np.where(big, 1.0 / np.where(big, w, 1.0), 0.0)
    return (U * inv) @ U.T


# =========================================================================== the linear filter
def _start_run(model, name, ys, m0, P0):
    """Checked measurements ``ys (..., T, m)`` (named ``name``), the augmented prior
    ``(z0, X0, Pa)`` of :func:`augmented_second_moment`, and the batch of augmented means."""
    ys = V.as_float_array(name, ys, ndim_min=2, shape_tail=(None, model.m))
    V.finite(name, ys)
    prior = augmented_second_moment(model, m0, P0)
    return ys, prior, np.broadcast_to(prior[0], (*ys.shape[:-2], model.N)).copy()


class _LinearSchedule(ContinuousSchedule):
    """Gains of :class:`OptimalLinearFilter` on the half-step grid ``t0 + i dt/2`` (steady: constant)."""

    convention = "held"

    def __init__(self, flt, t0, steady=None, path=None):
        self.flt, self.t0 = flt, t0
        self.dt, self.substeps, self.scheme = flt.dt, 1, flt.scheme
        self.steady, self.path = steady, path
        self._maps = {}
        self._aug0 = flt.model.augmented(0) if steady is not None else None

    def cov(self, k):
        return self.steady.P if self.steady is not None else self.path[1][2 * k]

    def coeffs(self, i):
        if self.steady is not None:
            a, X, K = self._aug0, self.steady.X, self.steady.K
        else:
            a = self.flt.model.augmented(self.t0 + i * self.dt / 2)
            X, K = self.path[0][i], self.path[2][i]
        Q = np.einsum("aij,jk,alk->il", a.G, X, a.G)
        S = np.einsum("aij,jk,alk->il", a.M, X, a.M)
        return a.F, np.zeros(a.F.shape[0]), a.H, np.zeros(a.H.shape[0]), K, Q, S

    def step_map(self, k, obs):
        cut = (lambda K: K) if obs is None else (lambda K: K * obs)
        if self.steady is not None:
            key = None if obs is None else tuple(obs)
            if key not in self._maps:
                K = cut(self.steady.K)
                self._maps[key] = self.flt._step_maps(K, K, K, self.t0)
            return self._maps[key]
        Ks = self.path[2]
        return self.flt._step_maps(cut(Ks[2 * k]), cut(Ks[2 * k + 1]), cut(Ks[2 * k + 2]), self.t0 + k * self.dt)


class OptimalLinearFilter(OfflineGainFilter):
    """The linear minimum-variance filter of a continuous-time bilinear system (001 eqs. 2.31-2.47).

    Parameters
    ----------
    model : BilinearModel (continuous time)
    dt : float — step of the measurement increments ``dy``
    gains : ``"steady"`` (the algebraic steady state (2.54) solved directly, from t = 0) or
        ``"time-varying"`` (eqs. 2.37, 2.43 integrated from ``(m0, P0)``)
    scheme : ``"rk4"`` (default) or ``"euler"`` — integration of the mean with ``dy/dt`` held
        constant over a step (RK4 is the thesis' choice, 001 §4.3)
    X0 : optional (N, N) initial second moment of z, needed by ``"steady"`` when the dynamics
        conserve second moments (the circle); otherwise taken from ``(m0, P0)``

    Notes
    -----
    ``run(ys, m0, P0)`` (increments ``ys``) returns :class:`~nlfilter.filters.estimates.Estimates` in the
    coordinates of x (the constant coordinate dropped; ``return_augmented=True``: all of z).
    ``m0``/``P0`` must be common to all paths (the gains are computed once for the whole batch).
    The on-line step is the affine runner of :mod:`.offline` (convention ``"held"``); NaN
    components of an increment are missing (no innovation; the path's own covariance).

    Examples
    --------
    >>> from nlfilter.bilinear import BilinearModel
    >>> model = BilinearModel([[-1.0]], [[1.0]], B=[[1.0]], R=[[1.0]])    # Ornstein-Uhlenbeck
    >>> ss = OptimalLinearFilter(model, 0.01).steady_state()
    >>> round(float(ss.P[0, 0]), 6)                                      # Kalman-Bucy: √2 − 1
    0.414214
    """

    name = "linear"
    source = "seed 001 eqs. 2.31-2.47, 2.54"
    accepts = ("bilinear",)
    time = "continuous"
    measurement_convention = HELD
    _augmented = False

    def __init__(self, model: BilinearModel, dt: float, *, gains: str = "steady", scheme: str = "rk4",
                 X0=None):
        if not isinstance(model, BilinearModel):
            raise TypeError(f"model: expected a BilinearModel, got {type(model).__name__}")
        if model.discrete:
            raise ValueError("model: discrete-time model; use DiscreteOptimalLinearFilter")
        self.model = model
        self.dt = float(V.positive("dt", dt))
        self.gains = V.choice("gains", gains, {"steady", "time-varying"})
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        if gains == "steady" and model.time_varying:
            raise ValueError("gains: 'steady' needs a time-invariant model; use gains='time-varying'")
        self.X0 = X0
        self._steady = None

    # -- off-line quantities ----------------------------------------------------------------------
    def steady_state(self, X0=None) -> LinearSteadyState:
        """Solve the algebraic equations (001 eq. 2.54) directly: ``X∞`` from the linear
        second-moment equation (with conservation laws fixed by ``X0``), then ``P∞`` from the
        algebraic Riccati equation with ``Π∞ = Σ G_i X∞ G_iᵀ``. Raises
        :class:`~nlfilter.errors.SingularSystemError` with the Wonham-type diagnosis when there is no finite one."""
        X0 = self.X0 if X0 is None else X0
        if self._steady is not None and X0 is None:
            return self._steady
        model = self.model
        rep = wonham_condition(model)
        if not rep.finite:
            raise SingularSystemError(f"OptimalLinearFilter.steady_state: no finite steady state: {rep.message}")
        aug = model.augmented(0)
        X = state_second_moments(model, X0)
        Pi = symmetrize(np.einsum("aij,jk,alk->il", aug.G, X, aug.G))
        Sv = symmetrize(np.einsum("aij,jk,alk->il", aug.M, X, aug.M))
        n, N = model.n, model.N
        try:
            Pn = sla.solve_continuous_are(aug.F[:n, :n].T, aug.H[:, :n].T, Pi[:n, :n], Sv)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise SingularSystemError(f"OptimalLinearFilter.steady_state: the algebraic Riccati equation "
                                      f"(001 eq. 2.54) has no stabilizing solution ({exc})") from None
        P = np.zeros((N, N))
        P[:n, :n] = symmetrize(Pn)
        K = P @ aug.H.T @ _pinv_psd(Sv)
        out = LinearSteadyState(X, P, K, Sv, Pi)
        if X0 is None:
            self._steady = out
        return out

    def covariance_path(self, T: int, m0, P0, *, t0: float = 0.0):
        """Time-varying ``X``, ``P`` and gains on the half-step grid ``t0 + j dt/2``, ``j = 0..2T``
        (RK4 of eqs. 2.37 and 2.43 with step ``dt/2``). Returns ``(X, P, K)`` of shapes
        ``(2T+1, N, N)``, ``(2T+1, N, N)``, ``(2T+1, N, m)``."""
        model = self.model
        t0 = V.real("t0", t0)
        _, X, P = augmented_second_moment(model, m0, P0)
        h = self.dt / 2

        def rhs(X, P, t):
            a = model.augmented(t)
            Pi = np.einsum("aij,jk,alk->il", a.G, X, a.G)
            Sv = np.einsum("aij,jk,alk->il", a.M, X, a.M)
            K = P @ a.H.T @ _pinv_psd(Sv)
            dX = a.F @ X + X @ a.F.T + Pi                       # 001 eq. 2.37
            dP = a.F @ P + P @ a.F.T + Pi - K @ Sv @ K.T        # 001 eq. 2.43
            return dX, dP, K

        return _riccati_path(rhs, X, P, t0, h, 2 * T)

    # -- on-line ------------------------------------------------------------------------------------
    def _step_maps(self, K0, K1, K2, t):
        """Affine map ``ẑ ↦ Φ ẑ + Γ z`` of one RK4/Euler step of ``dẑ/dt = F ẑ + K (z − H ẑ)``
        with gains ``K0, K1, K2`` at ``t, t + dt/2, t + dt`` (``z = dy/dt`` held constant)."""
        m = self.model
        h = self.dt
        a0, a1, a2 = m.augmented(t), m.augmented(t + h / 2), m.augmented(t + h)
        return _affine_step(a0.F - K0 @ a0.H, a1.F - K1 @ a1.H, a2.F - K2 @ a2.H, K0, K1, K2, h, self.scheme)

    @property
    def state_dim(self) -> int:
        return self.model.N if self._augmented else self.model.n

    def schedule(self, m0, P0, batch, steps, t0):
        """The gains of a run: the steady state (from t0) or the time-varying path of ``steps``."""
        prior = gaussian_prior(m0, P0, self.model.n, (1,), one=True, who=type(self).__name__)
        z0, X0, Pa = augmented_second_moment(self.model, prior.mean[0], prior.cov[0])
        if self.gains == "steady":
            ss = self.steady_state(self.X0 if self.X0 is not None else (X0 if self._conserves() else None))
            return _LinearSchedule(self, t0, steady=ss), z0, Pa
        if steps is None:
            raise ValueError("steps: time-varying gains are integrated for a horizon; pass steps= to init")
        return _LinearSchedule(self, t0, path=self.covariance_path(int(steps), prior.mean[0], prior.cov[0], t0=t0)), z0, Pa

    def run(self, ys, m0=None, P0=None, *, return_augmented: bool = False, **kw):
        """Filter a batch of increments ``ys (..., T, m)``; estimates at ``t0 + k dt``, k = 1..T
        (:meth:`~nlfilter.filters.base.Filter.run`); ``return_augmented``: means and covariances of
        all of z (the constant coordinate included)."""
        flt = self
        if return_augmented:
            flt = copy.copy(self)
            flt._augmented = True
        return OfflineGainFilter.run(flt, ys, m0, P0, **kw)

    def _conserves(self) -> bool:
        rep = wonham_condition(self.model)
        return rep.abscissa > -1e-9 * max(1.0, abs(rep.abscissa))


def _riccati_path(rhs, X, P, t0, h, steps):
    """``(X, P, K)`` on the grid ``t0 + j h``, ``j = 0..steps``: the second moment ``X`` and the
    Riccati covariance ``P`` by classical RK4 steps of ``h`` (:func:`~nlfilter.ode.ode_step`, the one
    schedule integrator; both symmetrized after each step), ``rhs(X, P, t) -> (dX, dP, K)``; the
    gain ``K`` at each grid point is the one of the step's first stage (at its start), the last
    from one more evaluation at the end."""
    Xs, Ps, Ks = [X], [P], []
    for j in range(steps):
        first = []

        def f(x, t):
            dX, dP, K = rhs(x[0], x[1], t)
            if not first:  # the first stage is at the step's start (ode_step, rk4 and euler)
                first.append(K)
            return dX, dP

        X, P = ode_step(f, (X, P), t0 + j * h, h, finish=lambda x: (symmetrize(x[0]), symmetrize(x[1])))
        Ks.append(first[0])
        Xs.append(X)
        Ps.append(P)
    Ks.append(rhs(X, P, t0 + steps * h)[2])
    return np.array(Xs), np.array(Ps), np.array(Ks)


def _affine_step(A0, A1, A2, K0, K1, K2, h, scheme):
    """One RK4 (or Euler) step of the affine ODE ``dẑ/dt = A(t) ẑ + K(t) z`` with ``z`` constant,
    as the map ``ẑ ↦ Φ ẑ + Γ z`` (stages as affine maps; ``A, K`` at t, t + h/2, t + h)."""
    I = np.eye(A0.shape[0])
    if scheme == "euler":
        return I + h * A0, h * K0
    k1 = (A0, K0)
    k2 = (A1 @ (I + h / 2 * k1[0]), A1 @ (h / 2 * k1[1]) + K1)
    k3 = (A1 @ (I + h / 2 * k2[0]), A1 @ (h / 2 * k2[1]) + K1)
    k4 = (A2 @ (I + h * k3[0]), A2 @ (h * k3[1]) + K2)
    Phi = I + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
    Gam = h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return Phi, Gam


# ====================================================================== discrete-time counterpart
class _LinearDiscreteSchedule(DiscreteSchedule):
    """Gains of :class:`DiscreteOptimalLinearFilter`: the second moments X[k] and the projection
    recursion (pseudo-inverse of the innovation covariance), extended along k."""

    def __init__(self, model, X0, Pa, start):
        super().__init__(Pa, start)
        self.bil, self.X = model, X0

    def model(self, k):
        a = self.bil.augmented(k)
        X = self.X
        Q = np.einsum("aij,jk,alk->il", a.G, X, a.G)
        S = np.einsum("aij,jk,alk->il", a.M, X, a.M)
        self.X = symmetrize(a.F @ X @ a.F.T + Q)
        return a.F, np.zeros(a.F.shape[0]), a.H, np.zeros(a.H.shape[0]), Q, S

    def gain(self, P, H, S):
        Ssum = H @ P @ H.T + S
        K = P @ H.T @ _pinv_psd(Ssum)
        return K, symmetrize(P - K @ Ssum @ K.T)


class DiscreteOptimalLinearFilter(OfflineGainFilter):
    """Linear minimum-variance filter of a discrete-time bilinear system (the thesis' first
    suggestion for future work, 001 ch. 6), derived by the same orthogonal projection::

        X[k+1] = F X Fᵀ + Σ G_i X G_iᵀ                       (state second moment)
        predict: ẑ⁻ = F ẑ,   P⁻ = F P Fᵀ + Σ G_i X[k] G_iᵀ
        update:  S = H P⁻ Hᵀ + Σ M_j X[k+1] M_jᵀ,  K = P⁻ Hᵀ S⁻¹,
                 ẑ = ẑ⁻ + K (y − H ẑ⁻),  P = P⁻ − K S Kᵀ

    (the multiplicative terms enter through the *unconditional* second moment ``X``, because
    ``E[G x wᵀ Gᵀ ...]`` factors by the independence of ``w`` from the past).
    Step convention ``start`` as :class:`~nlfilter.filters.base.DiscreteFilter` (default
    ``"update"``: ``ys[..., 0, :]`` measures ``x0 ~ (m0, P0)``). Gains off-line; ``predict`` /
    ``update`` are the affine runner of :mod:`.offline` (NaN components of ``y`` are missing).

    >>> from nlfilter.bilinear import BilinearModel
    >>> model = BilinearModel([[0.9]], [[1.0]], B=[[1.0]], R=[[1.0]], discrete=True)
    >>> est = DiscreteOptimalLinearFilter(model).run(np.zeros((1, 3, 1)), [0.0], [[1.0]])
    >>> round(float(est.covs[0, 0, 0, 0]), 6)        # Kalman: 1·1/(1+1)
    0.5
    """

    name = "linear"
    source = "seed 001 ch. 6 (discrete counterpart of eqs. 2.31-2.47)"
    accepts = ("bilinear-discrete",)
    time = "discrete"

    def __init__(self, model: BilinearModel, *, start: str | None = None):
        if not isinstance(model, BilinearModel) or not model.discrete:
            raise TypeError("model: expected a discrete-time BilinearModel (discrete=True)")
        self.model = model
        set_start(self, start)

    def schedule(self, m0, P0, batch, steps, t0):
        prior = gaussian_prior(m0, P0, self.model.n, (1,), one=True, who=type(self).__name__)
        z0, X0, Pa = augmented_second_moment(self.model, prior.mean[0], prior.cov[0])
        return _LinearDiscreteSchedule(self.model, X0, Pa, self.start), z0, Pa


__all__ = ["OptimalLinearFilter", "DiscreteOptimalLinearFilter", "LinearSteadyState"]
