"""Filters for bilinear systems (seed 001, Vallot 1981): the optimal linear filter, nonlinear
post-processors of its estimate (the "tensor filter"), multi-stage post-processing, the
updated-innovations filter and the pseudo-observables filter.

Optimal linear filter (001 eqs. 2.31-2.47), in the augmented coordinates ``z = (x, 1)`` of
:meth:`~nlfilter.bilinear.BilinearModel.augmented`::

    dẑ = F ẑ dt + K (dy − H ẑ dt),      K = P Hᵀ Σ_v⁻¹                         (2.31, 2.32)
    Σ_v = Σ_j M_j X M_jᵀ                                                        (2.47)
    dX/dt = F X + X Fᵀ + Σ_i G_i X G_iᵀ                                         (2.37)
    dP/dt = F P + P Fᵀ + Σ_i G_i X G_iᵀ − K Σ_v Kᵀ                              (2.43)

Its gains do not depend on the data: they are computed once, off-line (time-varying along the
measurement grid, or the steady state of the algebraic equations (2.54) solved directly).

Post-processor (001 §3.3): ``x̂ = Σ_k α_k φ_k(ẑ)`` with ``φ_k`` odd monomials of the linear
estimate (``α x̂ + β x̂³`` is eqs. 3.29-3.35); the gains solve the normal equations
``E[φ φᵀ] α = E[x φ]`` whose moments are the steady-state moments of the joint process
``(x, ẑ)`` — exact, from the closed moment system of the joint SDE
(:func:`nlfilter.moments.solve.stationary_moments`, conservation laws imposed on the circle).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sps

from .. import _validate as V
from ..bilinear import BilinearModel
from ..errors import SingularSystemError
from ..moments.ito import PolynomialSDE, bilinear_lift, closed_hull
from ..moments.solve import linear_steady_state, stationary_moments
from ..polynomials import Polynomial, monomials
from .base import Estimates, _Runner, screen_outputs, screened, symmetrize


# ================================================ the optimal linear filters (moved: linear_bilinear)
from .linear_bilinear import (DiscreteOptimalLinearFilter, LinearSteadyState, OptimalLinearFilter,  # noqa: E402,F401
                              WonhamReport, _affine_step, _kron_operator, _pinv_psd, _start_run,
                              augmented_second_moment, state_second_moments, wonham_condition)


# ====================================================================== joint moments (x, ẑ)
@dataclass
class JointProcess:
    """The joint SDE of the base variables and the linear filter's random estimates, as a
    :class:`~nlfilter.moments.ito.PolynomialSDE` with its noise columns (001 eqs. 3.30, 4.26-4.27, 5.7).

    ``estimate_vars``: augmented coordinate index of each estimate variable; ``fixed``: the
    coordinates whose estimate is deterministic in steady state (zero gain row, e.g. the cubic
    sensor's x̂² = E[x²]) with their values; ``coord_poly(k)`` / ``estimate_poly(k)``: coordinate k
    of z and of ẑ as polynomials in the joint variables.
    """

    sde: PolynomialSDE
    nb: int
    estimate_vars: list
    fixed: dict
    coords: list
    K: np.ndarray

    def coord_poly(self, k: int) -> Polynomial:
        return self.coords[k].pad(self.sde.n)

    def estimate_poly(self, k: int) -> Polynomial:
        nv = self.sde.n
        if k in self.estimate_vars:
            return Polynomial.variable(self.nb + self.estimate_vars.index(k), nv)
        return Polynomial.constant(float(self.fixed[k]), nv)

    def initial(self, base_initial: Callable, z0) -> Callable:
        """Moments of the joint variables at t = 0, the estimates starting at ``z0`` (deterministic)."""
        zr = np.array([z0[k] for k in self.estimate_vars])

        def f(mon):
            b = base_initial(tuple(mon[:self.nb]))
            return b * float(np.prod(zr ** np.array(mon[self.nb:])))
        return f


def joint_process(model: BilinearModel, K: np.ndarray, *, tol: float = 1e-12) -> JointProcess:
    """Joint SDE of ``(base variables, random linear estimates)`` for a constant gain ``K``
    (augmented ``(N, m)``). Estimate coordinates with a zero gain row whose drift involves only
    such coordinates and the constant are deterministic: in steady state they equal their mean
    and are substituted as constants (this is why 001 eq. 5.7 carries x̂ and x̂³ but not x̂²)."""
    aug = model.augmented(0)
    F, H, Ms = aug.F, aug.H, aug.M
    N, ci = model.N, model.constant_index
    base = model.poly_sde()
    nb = base.n
    cp = model.coord_polys()
    # deterministic estimate coordinates
    kscale = max(1e-300, float(np.max(np.abs(K)))) if K.size else 1.0
    D = {k for k in range(N) if k != ci and np.all(np.abs(K[k]) <= tol * kscale)}
    changed = True
    while changed:
        changed = False
        for k in sorted(D):
            others = [j for j in range(N) if abs(F[k, j]) > 0 and j not in D and j != ci]
            if others:
                D.discard(k)
                changed = True
    Dl = sorted(D)
    fixed = {}
    if Dl:
        FD = F[np.ix_(Dl, Dl)]
        rhs = -F[Dl, ci] if ci is not None else np.zeros(len(Dl))
        try:
            vals = np.linalg.solve(FD, rhs)
        except np.linalg.LinAlgError:
            raise SingularSystemError("joint_process: deterministic estimate coordinates without a rest point") from None
        if np.max(np.linalg.eigvals(FD).real, initial=-1.0) >= 0:
            raise SingularSystemError("joint_process: deterministic estimate coordinates do not settle")
        fixed = dict(zip(Dl, vals))
    if ci is not None:
        fixed[ci] = 1.0
    est = [k for k in range(N) if k not in fixed]
    nr = len(est)
    nv = nb + nr
    zero = Polynomial({}, nv)

    def zhat(k):
        if k in fixed:
            return Polynomial.constant(float(fixed[k]), nv)
        return Polynomial.variable(nb + est.index(k), nv)

    zx = [p.pad(nv) for p in cp]
    drift = [p.pad(nv) for p in base.drift]
    q_proc = base.r
    r_meas = Ms.shape[0]
    diff = [[base.noise[i][a].pad(nv) for a in range(q_proc)] + [zero] * r_meas for i in range(nb)]
    innov = [zero] * model.m  # H (z(x) − ẑ)
    for i in range(model.m):
        acc = zero
        for k in range(N):
            if H[i, k] != 0:
                acc = acc + zx[k] * float(H[i, k])
                acc = acc + zhat(k) * float(-H[i, k])
        innov[i] = acc.clean(1e-15)
    meas_noise = []  # for each measurement noise l: the m-vector M_l z(x)
    for l in range(r_meas):
        rows = []
        for i in range(model.m):
            acc = zero
            for k in range(N):
                if Ms[l, i, k] != 0:
                    acc = acc + zx[k] * float(Ms[l, i, k])
            rows.append(acc)
        meas_noise.append(rows)
    for j in est:
        acc = zero
        for k in range(N):
            if F[j, k] != 0:
                acc = acc + zhat(k) * float(F[j, k])
        for i in range(model.m):
            if K[j, i] != 0:
                acc = acc + innov[i] * float(K[j, i])
        drift.append(acc.clean(1e-15))
        row = [zero] * q_proc
        for l in range(r_meas):
            acc = zero
            for i in range(model.m):
                if K[j, i] != 0 and meas_noise[l][i].terms:
                    acc = acc + meas_noise[l][i] * float(K[j, i])
            row.append(acc.clean(1e-15))
        diff.append(row)
    names = list(base.names) + [f"hat({model.names[k]})" for k in est]
    sde = PolynomialSDE.from_noise(drift, diff, np.eye(q_proc + r_meas), names=names)
    return JointProcess(sde, nb, est, fixed, cp, K)


# ====================================================================== post-processing
def odd_features(vars_: Sequence[int], degree: int, nv: int, *, cross: bool = False) -> list:
    """Odd monomials of degree 1, 3, ..., ``degree`` in the joint variables ``vars_``: powers of
    each variable alone (001 eq. 3.29, 5.11), or every odd-degree product if ``cross``."""
    out = []
    if cross:
        for e in monomials(len(vars_), degree, min_degree=1):
            if sum(e) % 2 == 1:
                full = [0] * nv
                for v, a in zip(vars_, e):
                    full[v] = a
                out.append(Polynomial({tuple(full): 1.0}, nv))
        return out
    for v in vars_:
        for p in range(1, degree + 1, 2):
            full = [0] * nv
            full[v] = p
            out.append(Polynomial({tuple(full): 1.0}, nv))
    return out


@dataclass
class PostProcessorFit:
    """Least-squares post-processor ``ψ = Σ_k α_k φ_k`` of a target (001 eqs. 3.32-3.35):
    ``gains`` α, ``features`` φ (polys in the joint variables), ``mse`` its MSE, ``mse_linear``
    the linear estimate's MSE, ``moments`` the steady-state moments used."""

    gains: np.ndarray
    features: list
    mse: float
    mse_linear: float
    target: Polynomial
    moments: dict = field(repr=False)

    @property
    def reduction(self) -> float:
        """Relative MSE reduction over the linear estimate, in percent (001 Fig. 4.3)."""
        return 100.0 * (1.0 - self.mse / self.mse_linear)

    def output_poly(self) -> Polynomial:
        acc = Polynomial({}, self.target.nvars)
        for a, f in zip(self.gains, self.features):
            acc = acc + f * float(a)
        return acc


def fit_post_processor(jp: JointProcess, target: Polynomial, features: list, linear: Polynomial, *,
                       initial: Callable | None = None, moments: dict | None = None) -> PostProcessorFit:
    """Gains of the post-processor minimizing ``E[(target − Σ α_k φ_k)²]`` from the exact
    steady-state joint moments (001 eqs. 3.33-3.35 generalised to a least-squares solve):
    ``E[φ φᵀ] α = E[target φ]``. ``linear`` is the linear estimate of the target (for the
    reference MSE). ``initial``: moments at t = 0 of the joint variables, needed when the dynamics
    conserve moments (see :func:`~nlfilter.moments.solve.linear_steady_state`)."""
    Phi_p = [[a * b for b in features] for a in features]
    g_p = [target * f for f in features]
    extra = [target * target, target * linear, linear * linear]
    wanted = set()
    for p in [q for row in Phi_p for q in row] + g_p + extra:
        wanted.update(p.terms)
    mom = dict(moments or {})
    missing = [m for m in wanted if m not in mom]
    if missing:
        mom.update(stationary_moments(jp.sde, missing, initial=initial))
    E = lambda p: float(p.expect(mom))  # noqa: E731
    Phi = np.array([[E(p) for p in row] for row in Phi_p])
    g = np.array([E(p) for p in g_p])
    dn = np.sqrt(np.maximum(np.diag(Phi), 1e-300))  # normalise the features to unit RMS
    Phin = symmetrize(Phi / np.outer(dn, dn))
    w = np.linalg.eigvalsh(Phin)
    if w[0] <= 1e-12 * w[-1]:
        raise SingularSystemError(f"fit_post_processor: the features are linearly dependent "
                                  f"(normalised E[φφᵀ] condition {w[-1] / max(w[0], 1e-300):.3g})")
    alpha = np.linalg.solve(Phin, g / dn) / dn
    mse = E(extra[0]) - float(g @ alpha)
    mse_lin = E(extra[0]) - 2 * E(extra[1]) + E(extra[2])
    return PostProcessorFit(alpha, list(features), mse, mse_lin, target, mom)


class TensorFilter:
    """Optimal linear filter followed by memoryless polynomial post-processors (001 Fig. 3.3,
    §3.3; "tensor filter", 001 §4.3 and ch. 5). All gains are computed off-line from the steady
    state.

    Parameters
    ----------
    model : BilinearModel;  dt : measurement step
    targets : augmented coordinates to estimate (default: all of x)
    degree : odd degree of the post-processor (3 = ``α x̂ + β x̂³``; 5, 7 ... also)
    inputs : "own" (each target from powers of its own linear estimate, as 001 eqs. 4.20, 5.11-5.12)
        or "cross" (odd monomials of all random estimates, with cross terms)
    initial : callable ``base monomial -> E[.]`` at t = 0 (needed on conservative state spaces)
    """

    name = "tensor"

    def __init__(self, model: BilinearModel, dt: float, *, targets=None, degree: int = 3, inputs: str = "own",
                 initial: Callable | None = None, X0=None, scheme: str = "rk4"):
        if degree < 1 or degree % 2 == 0:
            raise ValueError(f"degree: expected an odd positive integer, got {degree!r}")
        self.linear = OptimalLinearFilter(model, dt, gains="steady", X0=X0, scheme=scheme)
        self.model, self.dt, self.degree = model, dt, degree
        self.inputs = V.choice("inputs", inputs, {"own", "cross"})
        self.targets = list(range(model.n)) if targets is None else list(targets)
        self.initial = initial
        self._fits = None

    def fit(self) -> list:
        """Off-line: steady gains, the joint process, and one post-processor per target."""
        if self._fits is not None:
            return self._fits
        ss = self.linear.steady_state()
        jp = joint_process(self.model, ss.K)
        self.joint = jp
        z0 = np.zeros(self.model.N)
        if self.model.constant_index is not None:
            z0[self.model.constant_index] = 1.0
        init = None if self.initial is None else jp.initial(self.initial, z0)
        nv = jp.sde.n
        fits, mom = [], {}
        for k in self.targets:
            if k not in jp.estimate_vars:
                raise ValueError(f"targets: coordinate {k} has a deterministic linear estimate; nothing to post-process")
            v = jp.nb + jp.estimate_vars.index(k)
            if self.inputs == "own":
                feats = odd_features([v], self.degree, nv)
            else:
                feats = odd_features(list(range(jp.nb, nv)), self.degree, nv, cross=True)
            fit = fit_post_processor(jp, jp.coord_poly(k), feats, jp.estimate_poly(k), initial=init, moments=mom)
            mom = fit.moments
            fits.append(fit)
        self._fits = fits
        return fits

    def with_dt(self, dt: float) -> "TensorFilter":
        """The same filter (same off-line gains, computed once) for increments of step ``dt``."""
        other = type(self).__new__(type(self))
        other.__dict__.update(self.__dict__)
        other.linear = OptimalLinearFilter(self.model, dt, gains="steady", X0=self.linear.X0, scheme=self.linear.scheme)
        other.linear._steady = self.linear._steady
        other.dt = float(dt)
        return other

    def post_process(self, zhat: np.ndarray) -> np.ndarray:
        """Apply the post-processors to linear estimates ``(..., N)`` (augmented) -> ``(..., len(targets))``."""
        fits = self.fit()
        jp = self.joint
        vals = np.zeros((*zhat.shape[:-1], jp.sde.n))
        for i, k in enumerate(jp.estimate_vars):
            vals[..., jp.nb + i] = zhat[..., k]
        return np.stack([f.output_poly()(vals) for f in fits], axis=-1)

    @screened
    def run(self, dys, m0, P0, *, on_divergence: str = "raise") -> Estimates:
        """Linear estimates (augmented) then post-processing; ``means`` are the targets'
        estimates ``(..., T, len(targets))``; ``covs`` hold the off-line post-processor MSEs
        on the diagonal (cross terms not computed: NaN)."""
        self.fit()
        est = self.linear.run(dys, m0, P0, on_divergence=on_divergence, return_augmented=True)
        means = self.post_process(est.means)
        # the linear run checked ẑ; its post-processed value may still overflow (x̂³ of a huge ẑ)
        means, diverged, step = screen_outputs(self.name, means, est.diverged, est.diverged_step, on_divergence)
        nt = len(self.targets)
        cov = np.full((nt, nt), np.nan)
        np.fill_diagonal(cov, [f.mse for f in self._fits])
        covs = np.broadcast_to(cov, (*means.shape, nt)).copy()
        covs[diverged[..., None] & (np.arange(means.shape[-2]) >= step[..., None])] = np.nan  # as _Runner
        return Estimates(means, covs, diverged, step)


def multistage(jp: JointProcess, first: PostProcessorFit, degree: int = 3, *, initial=None) -> PostProcessorFit:
    """A second stage of post-processing (001 Fig. 3.2): odd powers of the first stage's output
    ``x̃ = ψ(ẑ)`` (polynomials of ``ẑ`` of degree ``deg ψ · degree``), gains again by least squares
    from exact moments. Its MSE is never above the first stage's (``x̃`` itself is a feature)."""
    out = first.output_poly()
    feats = [out ** p for p in range(1, degree + 1, 2)]
    fit = fit_post_processor(jp, first.target, feats, out, initial=initial, moments=first.moments)
    fit.mse_linear = first.mse_linear
    return fit


# ====================================================================== updated innovations
class UpdatedInnovationsFilter(TensorFilter):
    """The linear filter's recursion driven by innovations formed with the post-processed
    estimate (001 Fig. 3.4; "not evaluated in this research": evaluated here by Monte Carlo)::

        dẑ = F ẑ dt + K (dy − H ẑ' dt),   ẑ' = ẑ with its post-processed coordinates replaced

    Gains ``K`` and post-processor gains are those of :class:`TensorFilter` (off-line). The
    recursion is nonlinear, so its error has no closed moment system: it is evaluated by
    simulation. Integration: explicit RK4 (or Euler) with ``dy/dt`` held constant over a step.
    """

    name = "updated-innovations"

    @classmethod
    def from_tensor(cls, tf: TensorFilter, dt: float | None = None) -> "UpdatedInnovationsFilter":
        """Reuse a fitted :class:`TensorFilter`'s off-line gains (and optionally a new step)."""
        other = cls.__new__(cls)
        other.__dict__.update((tf if dt is None else tf.with_dt(dt)).__dict__)
        return other

    @screened
    def run(self, dys, m0, P0, *, on_divergence: str = "raise") -> Estimates:
        """Estimates of the targets for increments ``dys (..., T, m)``. ``covs`` are NaN on every
        path: the nonlinear recursion has no error covariance (its error is measured by
        simulation); a path whose estimate overflows is raised or marked in ``diverged``."""
        from .base import GaussianState
        self.fit()
        model = self.model
        dys, (z0, _, Pa), zs = _start_run(model, "dys", dys, m0, P0)
        ss = self.linear.steady_state()
        aug = model.augmented(0)
        F, H, K = aug.F, aug.H, ss.K
        batch, T_ = dys.shape[:-2], dys.shape[-2]
        nt = len(self.targets)
        out = _Runner(batch, T_, nt, on_divergence, self.name)
        h = self.dt
        tg = self.targets

        def rhs(z, y):
            zp = z.copy()
            zp[..., tg] = self.post_process(z)
            return z @ F.T + (y - zp @ H.T) @ K.T

        eye = np.broadcast_to(np.eye(nt), (*batch, nt, nt))  # placeholder: the divergence screen checks means
        reset = GaussianState(np.broadcast_to(z0[tg], (*batch, nt)), eye)
        for k in range(T_):
            y = dys[..., k, :] / h
            if self.linear.scheme == "euler":
                zs = zs + h * rhs(zs, y)
            else:
                k1 = rhs(zs, y)
                k2 = rhs(zs + h / 2 * k1, y)
                k3 = rhs(zs + h / 2 * k2, y)
                k4 = rhs(zs + h * k3, y)
                zs = zs + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            out.record(k, GaussianState(self.post_process(zs), eye), reset)
            if out.diverged.any():  # diverged paths restart harmlessly; their outputs are NaN
                zs = np.where(out.diverged[..., None], z0, zs)
        res = out.result()
        cov = np.full((nt, nt), np.nan)  # no error covariance for this nonlinear recursion
        return Estimates(res.means, np.broadcast_to(cov, res.covs.shape).copy(), res.diverged, res.diverged_step)


# ====================================================================== pseudo-observables
class PseudoObservablesFilter:
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
    dt : measurement step;  x_moment : callable ``base monomial -> E[x0^α]`` (initial law of x)
    """

    name = "pseudo-observables"

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

        def rhs(X, P):
            Pi = np.einsum("aij,jk,alk->il", Bs, X, Bs)
            C = np.einsum("aij,jk,alk->il", Bs, X, Ms)
            Sv = np.einsum("aij,jk,alk->il", Ms, X, Ms)
            K = (P @ H.T + C) @ _pinv_psd(Sv, tol=1e-10)
            return A @ X + X @ A.T + Pi, A @ P + P @ A.T + Pi - K @ Sv @ K.T, K

        Xs, Ps, Ks = [X], [P], []
        for _ in range(2 * T_):
            k1 = rhs(X, P)
            Ks.append(k1[2])
            k2 = rhs(X + h / 2 * k1[0], P + h / 2 * k1[1])
            k3 = rhs(X + h / 2 * k2[0], P + h / 2 * k2[1])
            k4 = rhs(X + h * k3[0], P + h * k3[1])
            X = symmetrize(X + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]))
            P = symmetrize(P + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))
            Xs.append(X)
            Ps.append(P)
        Ks.append(rhs(X, P)[2])
        return np.array(Xs), np.array(Ps), np.array(Ks)

    def error_variance(self, T_: int) -> np.ndarray:
        """Off-line ``E[(x_i − x̂_i)²]`` at ``t_k = k dt``, k = 0..T, shape ``(T+1, n_base)``."""
        _, Ps, _ = self.covariance_path(T_)
        ix = [self.index[tuple(int(j == v) for j in range(self.nb + self.m))] for v in range(self.nb)]
        return np.stack([Ps[::2, i, i] for i in ix], axis=-1)

    @screened
    def run(self, dys, *, on_divergence: str = "raise") -> Estimates:
        """Filter increments ``dys (..., T, m)`` (y0 = 0): pseudo-observable increments are formed
        from the running ``y``; returns estimates of the base variables."""
        from .base import GaussianState
        dys = V.as_float_array("dys", dys, ndim_min=2, shape_tail=(None, self.m))
        V.finite("dys", dys)
        batch, T_ = dys.shape[:-2], dys.shape[-2]
        z0, _ = self.initial_moments()
        _, Ps, Ks = self.covariance_path(T_)
        y = np.concatenate([np.zeros((*batch, 1, self.m)), np.cumsum(dys, axis=-2)], axis=-2)
        Y = np.stack([y[..., i] ** p for i, p in self.obs_meta], axis=-1)  # pseudo-observables y_i^p
        dY = np.diff(Y, axis=-2)
        zs = np.broadcast_to(z0, (*batch, len(z0))).copy()
        ix = [self.index[tuple(int(j == v) for j in range(self.nb + self.m))] for v in range(self.nb)]
        out = _Runner(batch, T_, self.nb, on_divergence, self.name)
        h = self.dt
        for k in range(T_):
            K0, K1, K2 = Ks[2 * k], Ks[2 * k + 1], Ks[2 * k + 2]
            Phi, Gam = _affine_step(self.A - K0 @ self.H, self.A - K1 @ self.H, self.A - K2 @ self.H,
                                    K0, K1, K2, h, self.scheme)
            zs = zs @ Phi.T + (dY[..., k, :] / h) @ Gam.T
            Pk = Ps[2 * k + 2][np.ix_(ix, ix)]
            st = GaussianState(zs[..., ix], np.broadcast_to(Pk, (*batch, self.nb, self.nb)))
            out.record(k, st, st)
        return out.result()


__all__ = ["PseudoObservablesFilter", "OptimalLinearFilter", "DiscreteOptimalLinearFilter", "LinearSteadyState", "WonhamReport",
           "wonham_condition", "state_second_moments", "augmented_second_moment", "JointProcess",
           "joint_process", "odd_features", "fit_post_processor", "PostProcessorFit", "TensorFilter",
           "multistage", "UpdatedInnovationsFilter"]
