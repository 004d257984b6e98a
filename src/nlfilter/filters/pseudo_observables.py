"""The pseudo-observables filter of seed 001 §3.2 (eq. 3.14): the optimal linear filter using the
tensored observables ``y, y^p, ...``, ``x̂ = P[x | H^y ⊕ H^{y³} ⊕ ...]``, on the off-line-gain
runner of :mod:`.offline` (its time-varying gain schedule, convention ``"held"``, the
pseudo-observables' increments as the schedule's input map).
"""

from __future__ import annotations

import numpy as np

from .. import _validate as V
from ..bilinear import BilinearModel
from ..moments.closed import bilinear_lift, closed_hull
from ..moments.ito import PolynomialSDE
from ..polynomials import Polynomial
from ..sde_step import HELD
from .linear_bilinear import _affine_step, _pinv_psd, _riccati_path
from .offline import ContinuousSchedule, OfflineGainFilter


class _PseudoSchedule(ContinuousSchedule):
    """The gains of :class:`PseudoObservablesFilter` (its :meth:`~PseudoObservablesFilter.covariance_path`,
    extended lazily), its input map (the increments ``d(y_i^p)`` from the running ``y``) and the
    affine step maps (``dy/dt`` held, 001 §4.3). Every path reports the schedule's covariance
    (``own_cov = False``): after a gap the higher powers' increments are formed from an estimated
    ``y``, so the affine recursion's own covariance would not be the error's either."""

    convention = "held"
    own_cov = False

    def __init__(self, flt):
        self.flt, self.dt, self.scheme = flt, flt.dt, flt.scheme
        self.comp = np.array([i for i, _ in flt.obs_meta])
        self.iy = [flt.index[tuple(int(j == flt.nb + i) for j in range(flt.nb + flt.m))] for i in range(flt.m)]

    def cov(self, k):
        return self.flt._schedule(max(k - 1, 0))[0][2 * k]

    def step_map(self, k, obs):
        flt = self.flt
        Ks = flt._schedule(k)[1]
        K0, K1, K2 = Ks[2 * k], Ks[2 * k + 1], Ks[2 * k + 2]
        if obs is not None:  # the observables of a missing component: no innovation
            K0, K1, K2 = K0 * obs, K1 * obs, K2 * obs
        A, H = flt.A, flt.H
        return _affine_step(A - K0 @ H, A - K1 @ H, A - K2 @ H, K0, K1, K2, self.dt, self.scheme)

    def drive(self, y, dy):
        """``d(y_i^p) = (y_i + dy_i)^p − y_i^p`` (NaN where ``dy_i`` is missing)."""
        miss = np.isnan(dy)
        y_new = y + (np.where(miss, 0.0, dy) if miss.any() else dy)
        dY = np.stack([y_new[..., i] ** p - y[..., i] ** p for i, p in self.flt.obs_meta], axis=-1)
        return np.where(miss[:, self.comp], np.nan, dY) if miss.any() else dY

    def carry(self, y, dy, z):
        """The running ``y``; an unobserved ``y_i`` goes on from its estimate (a coordinate of z)."""
        miss = np.isnan(dy)
        if not miss.any():
            return y + dy
        return np.where(miss, z[:, self.iy], y + np.where(miss, 0.0, dy))



class PseudoObservablesFilter(OfflineGainFilter):
    """Optimal linear filter using tensored observables ``y, y^p, ...`` (001 §3.2, eq. 3.14):
    ``x̂ = P[x | H^y ⊕ H^{y³} ⊕ ...]``.

    The observation ``y`` (with ``y0`` known, 001: "y0 assumed to be equal to zero") joins the
    state; the vector ``z`` of monomials of ``(x, y)`` closed under the Itô rule and its noise
    coefficients is bilinear (001 eqs. 3.11-3.13), and each pseudo-observable ``y_i^p`` is
    observed through its increment ``d(y_i^p) = H_o z dt + Σ_a M_o,a z dβ_a`` (001 eq. 3.16),
    driven by the *same* noises as the state (``y`` is a state): the linear filter then has the
    cross term ``C = Σ_a B_a X M_aᵀ``::

        dẑ = A ẑ dt + K (dY − H ẑ dt),   K = (P Hᵀ + C) Σ_v⁺,   Σ_v = Σ_a M_a X M_aᵀ
        dX/dt = A X + X Aᵀ + Σ_a B_a X B_aᵀ,   dP/dt = A P + P Aᵀ + Σ_a B_a X B_aᵀ − K Σ_v Kᵀ

    At t = 0 the innovation intensity of ``y³`` is ``9 E[y0⁴] = 0``: Σ_v is singular and the
    gain uses its pseudo-inverse (the Liptser-Shiryaev treatment of a singular observation, 001
    §3.2). The moments of ``y`` grow without bound, so there is no steady state: gains are
    time-varying (and, as the thesis observed, the y³ information fades).

    Parameters
    ----------
    model : BilinearModel with additive measurement noise only (``R``; no ``M``)
    powers : the powers of each measurement component used as observables (``(1, 3)``: y and y³)
    dt : measurement step
    x_moment : callable ``base monomial -> E[x0^α]`` (initial law of x)

    Notes
    -----
    ``run(ys)`` (``ys`` the increments ``dy``, y0 = 0): the off-line-gain runner of :mod:`.offline`
    over an :class:`~nlfilter.filters.offline.OfflineState` (``carried``: the running ``y``);
    ``means`` the estimates of the base variables, ``covs`` the off-line error covariance of the
    gain schedule (on every path, missing data or not).
    The prior is the law of x0 whose moments ``x_moment`` gives (every moment enters the
    pseudo-observables' gains), so ``m0``/``P0`` must be None (refused naming ``m0``). A missing
    increment component: its observables give no innovation (see :meth:`step`).
    """

    name = "pseudo-observables"
    own_prior = True  # the law of x0 comes from x_moment: run takes m0 = P0 = None

    @classmethod
    def for_model(cls, model, *, dt=None, start=None):
        """No default instance: the initial law's moments ``x_moment`` are the user's to give."""
        raise ValueError("x_moment: PseudoObservablesFilter needs the initial law's moments of x (no default); "
                         "build it with PseudoObservablesFilter(model, dt, x_moment=...)")
    family = "off-line gains"
    source = "seed 001 §3.2, eqs. 3.11-3.16"
    accepts = ("bilinear",)
    needs = ("additive measurement noise", "time-invariant model", "moments of x0 (x_moment)")
    time = "continuous"
    measurement_convention = HELD

    def __init__(self, model: BilinearModel, dt: float, *, powers=(1, 3), x_moment=None, scheme: str = "rk4"):
        if model.M:
            raise ValueError("model: pseudo-observables need additive measurement noise (R), not M")
        if model.R is None:
            raise ValueError("model: R (additive measurement noise) is required")
        if model.time_varying:
            raise ValueError("model: time-varying models are not supported here")
        self.model, self.dt = model, float(V.positive("dt", dt))
        self.scheme = V.choice("scheme", scheme, {"rk4", "euler"})
        self.powers = tuple(int(p) for p in powers)
        if 1 not in self.powers or any(p < 1 for p in self.powers):
            raise ValueError(f"powers: expected positive integers including 1, got {powers!r}")
        self.x_moment = x_moment
        self._build()
        self._path = None
        self._ix = [self.index[tuple(int(j == v) for j in range(self.nb + self.m))] for v in range(self.nb)]

    def _build(self):
        model = self.model
        base = model.poly_sde()
        nb, m = base.n, model.m
        nv = nb + m
        aug = model.augmented(0)
        Lr = np.linalg.cholesky(model.R + 1e-300 * np.eye(m)) if np.all(np.linalg.eigvalsh(model.R) > 0) else None
        if Lr is None:
            raise ValueError("model.R: expected positive definite")
        q = base.r
        zero = Polynomial({}, nv)
        drift = [p.pad(nv) for p in base.drift]
        diff = [[base.noise[i][a].pad(nv) for a in range(q)] + [zero] * m for i in range(nb)]
        cp = model.coord_polys()
        for i in range(m):  # dy_i = (H z(x) + d)_i dt + (R^½ dv)_i
            acc = zero
            for k in range(model.N):
                if aug.H[i, k] != 0:
                    acc = acc + cp[k].pad(nv) * float(aug.H[i, k])
            drift.append(acc)
            diff.append([zero] * q + [Polynomial.constant(float(Lr[i, j]), nv) for j in range(m)])
        names = list(base.names) + [f"y{i + 1}" for i in range(m)]
        sde = PolynomialSDE.from_noise(drift, diff, np.eye(q + m), names=names)
        obs, meta = [], []
        for i in range(m):
            for p in self.powers:
                e = [0] * nv
                e[nb + i] = p
                obs.append(tuple(e))
                meta.append((i, p))
        self.obs_meta = meta
        seeds = [tuple(int(j == v) for j in range(nv)) for v in range(nb)] + obs
        mons = closed_hull(sde, seeds, with_noise=True)
        coords = mons + [(0,) * nv]
        A, Bs = bilinear_lift(sde, coords)
        idx = {c: k for k, c in enumerate(coords)}
        rows = [idx[o] for o in obs]  # the pseudo-observables are coordinates: their rows of the lift
        H, Ms = A[rows], np.array([B[rows] for B in Bs])
        self.sde, self.coords, self.index, self.obs = sde, coords, idx, obs
        self.A, self.B, self.H, self.M = A, np.array(Bs), H, Ms
        self.nb, self.m = nb, m

    def initial_moments(self):
        """``(ẑ0, X0)``: x0 from ``x_moment``, y0 = 0."""
        if self.x_moment is None:
            raise ValueError("x_moment: the initial law's moments of x are needed (callable monomial -> E)")
        nb = self.nb

        def E(e):
            return 0.0 if any(e[nb:]) else float(self.x_moment(tuple(e[:nb])))
        N = len(self.coords)
        z0 = np.array([E(c) for c in self.coords])
        X0 = np.array([[E(tuple(a + b for a, b in zip(self.coords[i], self.coords[j]))) for j in range(N)]
                       for i in range(N)])
        return z0, X0

    def covariance_path(self, T_: int):
        """``(X, P, K)`` on the half-step grid ``j dt/2``, j = 0..2T (RK4 with step dt/2)."""
        z0, X = self.initial_moments()
        P = X - np.outer(z0, z0)
        A, Bs, H, Ms = self.A, self.B, self.H, self.M
        h = self.dt / 2

        def rhs(X, P, t):  # time-invariant
            Pi = np.einsum("aij,jk,alk->il", Bs, X, Bs)
            C = np.einsum("aij,jk,alk->il", Bs, X, Ms)
            Sv = np.einsum("aij,jk,alk->il", Ms, X, Ms)
            K = (P @ H.T + C) @ _pinv_psd(Sv, tol=1e-10)
            return A @ X + X @ A.T + Pi, A @ P + P @ A.T + Pi - K @ Sv @ K.T, K

        return _riccati_path(rhs, X, P, 0.0, h, 2 * T_)

    def error_variance(self, T_: int) -> np.ndarray:
        """Off-line ``E[(x_i − x̂_i)²]`` at ``t_k = k dt``, k = 0..T, shape ``(T+1, n_base)``."""
        _, Ps, _ = self.covariance_path(T_)
        ix = [self.index[tuple(int(j == v) for j in range(self.nb + self.m))] for v in range(self.nb)]
        return np.stack([Ps[::2, i, i] for i in ix], axis=-1)

    # -- the belief functions (Filter) ---------------------------------------------------------
    @property
    def state_dim(self) -> int:
        return self.nb

    @property
    def data_dim(self) -> int:
        return self.m

    def _schedule(self, k: int):
        """``(Ps, Ks)`` of :meth:`covariance_path` covering step ``k`` (computed once and extended
        by doubling; the path is one sequential RK4 run, so a longer one has the same prefix)."""
        if self._path is None or len(self._path[1]) < 2 * k + 3:
            T_ = max(k + 1, 2 * (len(self._path[1]) // 2) if self._path is not None else 0, 16)
            self._path = self.covariance_path(T_)
        return self._path[1], self._path[2]

    def schedule(self, m0, P0, batch, steps, t0):
        """The start ``ẑ0`` of :meth:`initial_moments` (x0 from ``x_moment``, all its moments, and
        y0 = 0): this filter refuses a Gaussian prior (m0, P0), which would not give the moments
        of the pseudo-observables. The gains are a schedule from the model's t = 0."""
        if m0 is not None or P0 is not None:
            raise ValueError(f"{'m0' if m0 is not None else 'P0'}: {type(self).__name__} starts from the law of x0 "
                             "given by x_moment (and y0 = 0); "
                             f"expected m0=None, P0=None, got m0={m0!r}, P0={P0!r}")
        B = int(np.prod(batch))
        z0, _ = self.initial_moments()
        sch = _PseudoSchedule(self)
        return sch, z0, sch.cov(0), np.zeros((B, self.m))

    def init(self, m0=None, P0=None, batch=(), *, initial=None, rng=None, **kw):
        if initial is not None:
            raise ValueError(f"initial: the initial law is x_moment's; expected None, got {type(initial).__name__}")
        return super().init(m0, P0, batch, **kw)

    def summary(self, belief):
        """``(x̂ (B, n_base), the off-line error covariance at that step)``."""
        ix = self._ix
        return belief.mean[:, ix], belief.cov[(slice(None), *np.ix_(ix, ix))]


__all__ = ["PseudoObservablesFilter"]
