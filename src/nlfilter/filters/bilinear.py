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

from .. import _validate as V
from ..bilinear import BilinearModel
from ..errors import SingularSystemError
from ..moments.closed import bilinear_lift, closed_hull
from ..moments.ito import PolynomialSDE
from ..moments.solve import stationary_moments
from ..polynomials import Polynomial, monomials
from .base import Filter, gaussian_prior, ode_step
from .linalg import symmetrize


# the model analysis lives beside BilinearModel (nlfilter.bilinear_analysis); re-exported here
from ..bilinear_analysis import (WonhamReport, augmented_second_moment,  # noqa: E402,F401
                                 state_second_moments, wonham_condition)


# ================================================ the optimal linear filters (moved: linear_bilinear)
from .linear_bilinear import (DiscreteOptimalLinearFilter, LinearSteadyState, OptimalLinearFilter,  # noqa: E402,F401
                              _affine_step, _pinv_psd)


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


class AugmentedEstimate(NamedTuple):
    """Belief of the steady-gain filters of this module: the linear filter's estimate ``z (B, N)``
    of the augmented state ``z = (x, 1)`` (the constant coordinate included)."""

    z: np.ndarray


class _SteadyLinearRecursion(Filter):
    """The optimal linear filter's steady-gain recursion ``dẑ = F ẑ dt + K (dy − H ẑ dt)``
    (001 eqs. 2.31-2.32, gains of eq. 2.54) over an :class:`AugmentedEstimate`, as a
    continuous-time :class:`~nlfilter.filters.base.Filter`: one RK4 (or Euler) step with
    ``dy/dt`` held constant is the affine map ``ẑ ↦ Φ ẑ + Γ dy/dt``, computed once.

    Missing data: a NaN component of ``dy`` contributes no innovation (its gain column is
    dropped for that step; the off-line gains are not re-optimised). Prior: ``ẑ0 = (m0, 1)``,
    per path allowed; the gains are the steady state's from t = 0 and do not depend on the prior,
    so ``P0`` is checked but does not enter."""

    family = "off-line gains"
    accepts = ("bilinear", "phase")
    needs = ("time-invariant model", "finite steady state (Wonham condition)")
    time = "continuous"

    def _linear(self, model, dt, scheme, X0):
        self.linear = OptimalLinearFilter(model, dt, gains="steady", X0=X0, scheme=scheme)
        self.model, self.dt = model, self.linear.dt
        self._maps = {}

    @property
    def data_dim(self) -> int:
        return self.model.m

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        """``ẑ0 = (m0, 1)`` on every path (``m0`` common or per path); ``P0`` checked only."""
        if initial is not None:
            raise ValueError(f"initial: {type(self).__name__} starts from the prior mean m0 (ẑ0 = (m0, 1)); "
                             f"expected None, got {type(initial).__name__}")
        g = gaussian_prior(m0, P0, self.model.n, batch)
        z = g.mean if self.model.N == self.model.n else np.concatenate([g.mean, np.ones((len(g.mean), 1))], axis=1)
        return AugmentedEstimate(z)

    def _affine(self, observed: tuple):
        """``(Φ, Γ)`` of one step with the components ``observed`` (a tuple of bools) measured."""
        maps = self._maps.get(observed)
        if maps is None:
            K = self.linear.steady_state().K
            if not all(observed):
                K = K * np.asarray(observed, float)  # no innovation from a missing component
            a = self.model.augmented(0)
            A = a.F - K @ a.H
            maps = self._maps[observed] = _affine_step(A, A, A, K, K, K, self.dt, self.linear.scheme)
        return maps

    def step(self, belief, dy, t):
        """``ẑ`` at ``t + dt`` after the increment ``dy (B, m)`` (NaN components: no innovation)."""
        z = belief.z
        miss = np.isnan(dy)
        if not miss.any():
            Phi, Gam = self._affine((True,) * dy.shape[-1])
            return AugmentedEstimate(z @ Phi.T + (dy / self.dt) @ Gam.T)
        y = np.where(miss, 0.0, dy) / self.dt
        out = np.empty_like(z)
        patterns, which = np.unique(~miss, axis=0, return_inverse=True)
        for j, obs in enumerate(patterns):  # one affine map per missing pattern (not per path)
            sel = which.ravel() == j
            Phi, Gam = self._affine(tuple(bool(o) for o in obs))
            out[sel] = z[sel] @ Phi.T + y[sel] @ Gam.T
        return AugmentedEstimate(out)


class TensorFilter(_SteadyLinearRecursion):
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

    ``run(ys, m0, P0)`` (``ys`` the increments ``dy``): the belief is the linear filter's augmented
    estimate ``ẑ`` (:class:`_SteadyLinearRecursion`: prior ``ẑ0 = (m0, 1)``, missing components
    give no innovation); the post-processor is the map from ``ẑ`` to the reported estimate,
    applied at every step (``summary``) so that the run loop screens its overflow too (``x̂³``
    of a huge but finite ``ẑ``). ``means`` are the targets' estimates ``(..., T, len(targets))``;
    ``covs`` the off-line steady-state error covariance of the post-processed estimates
    (:meth:`error_covariance`), the same at every step.
    """

    name = "tensor"
    source = "seed 001 §3.3, Fig. 3.3, eqs. 3.29-3.35 (ch. 4-5)"

    def __init__(self, model: BilinearModel, dt: float, *, targets=None, degree: int = 3, inputs: str = "own",
                 initial: Callable | None = None, X0=None, scheme: str = "rk4"):
        if degree < 1 or degree % 2 == 0:
            raise ValueError(f"degree: expected an odd positive integer, got {degree!r}")
        self._linear(model, dt, scheme, X0)
        self.degree = degree
        self.inputs = V.choice("inputs", inputs, {"own", "cross"})
        self.targets = list(range(model.n)) if targets is None else list(targets)
        self.initial = initial
        self._fits = None
        self._cov = None

    @classmethod
    def for_model(cls, model, *, dt=None, start="update"):
        """Default instance: the targets are the coordinates of the base state (for a lift, the
        degree-1 monomials), the estimates a comparison reads."""
        nb = len(model.coords[0])
        units = [tuple(int(i == j) for i in range(nb)) for j in range(nb)]
        return cls(model, dt, targets=[model.coords.index(u) for u in units if u in model.coords])

    @property
    def state_dim(self) -> int:
        return len(self.targets)

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
        self._joint_initial = init
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
        self._outputs = [f.output_poly() for f in fits]
        return fits

    def error_covariance(self) -> np.ndarray:
        """Off-line steady-state ``E[(t − ψ)(t − ψ)ᵀ]`` of the targets ``t`` and their
        post-processed estimates ``ψ``: the diagonal is each fit's ``mse``; the cross terms come
        from the same exact joint moments (a few more monomials)."""
        if self._cov is None:
            fits = self.fit()
            nt = len(fits)
            errs = [f.target - f.output_poly() for f in fits]
            cov = np.diag([f.mse for f in fits])
            pairs = [(i, j) for i in range(nt) for j in range(i + 1, nt)]
            if pairs:
                mom = dict(fits[-1].moments)
                prods = {(i, j): errs[i] * errs[j] for i, j in pairs}
                missing = sorted({e for p in prods.values() for e in p.terms if e not in mom})
                if missing:
                    mom.update(stationary_moments(self.joint.sde, missing, initial=self._joint_initial))
                for (i, j), p in prods.items():
                    cov[i, j] = cov[j, i] = float(p.expect(mom))
            self._cov = cov
        return self._cov

    def with_dt(self, dt: float) -> "TensorFilter":
        """The same filter (same off-line gains, computed once) for increments of step ``dt``."""
        other = type(self).__new__(type(self))
        other.__dict__.update(self.__dict__)
        other.linear = OptimalLinearFilter(self.model, dt, gains="steady", X0=self.linear.X0, scheme=self.linear.scheme)
        other.linear._steady = self.linear._steady
        other.dt = float(dt)
        other._maps = {}  # the step maps depend on dt
        return other

    def post_process(self, zhat: np.ndarray) -> np.ndarray:
        """Apply the post-processors to linear estimates ``(..., N)`` (augmented) -> ``(..., len(targets))``."""
        self.fit()
        jp = self.joint
        vals = np.zeros((*zhat.shape[:-1], jp.sde.n))
        for i, k in enumerate(jp.estimate_vars):
            vals[..., jp.nb + i] = zhat[..., k]
        return np.stack([out(vals) for out in self._outputs], axis=-1)

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        self.fit()
        return super().init(m0, P0, batch, initial=initial, rng=rng)

    def summary(self, belief):
        """``(ψ(ẑ) (B, len(targets)), the off-line error covariance)``."""
        cov = self.error_covariance()
        return self.post_process(belief.z), np.broadcast_to(cov, (len(belief.z), *cov.shape))


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
    simulation, and ``covs`` are NaN on every path (no error covariance; a path whose estimate
    overflows is raised or marked in ``diverged``). Integration: explicit RK4 (or Euler) with
    ``dy/dt`` held constant over a step; a missing component of ``dy`` gives no innovation
    (skipped in the recursion). Prior as :class:`TensorFilter`: ``ẑ0 = (m0, 1)``.
    """

    name = "updated-innovations"
    source = "seed 001 §3.4, Fig. 3.4"

    @classmethod
    def from_tensor(cls, tf: TensorFilter, dt: float | None = None) -> "UpdatedInnovationsFilter":
        """Reuse a fitted :class:`TensorFilter`'s off-line gains (and optionally a new step)."""
        other = cls.__new__(cls)
        other.__dict__.update((tf if dt is None else tf.with_dt(dt)).__dict__)
        return other

    def step(self, belief, dy, t):
        """``ẑ`` at ``t + dt`` after ``dy (B, m)``: RK4 (or Euler) of the updated-innovations SDE."""
        aug = self.model.augmented(0)
        F, H, K = aug.F, aug.H, self.linear.steady_state().K
        tg = self.targets
        miss = np.isnan(dy)
        y = (np.where(miss, 0.0, dy) if miss.any() else dy) / self.dt

        def rhs(z):
            zp = z.copy()
            zp[..., tg] = self.post_process(z)
            innov = y - zp @ H.T
            if miss.any():
                innov = np.where(miss, 0.0, innov)  # a missing component: no innovation
            return z @ F.T + innov @ K.T

        return AugmentedEstimate(ode_step(lambda z, s: rhs(z), belief.z, t, self.dt, scheme=self.linear.scheme))

    def summary(self, belief):
        """``(ψ(ẑ), None)``: no error covariance for this nonlinear recursion (``covs`` NaN)."""
        return self.post_process(belief.z), None


# ====================================================================== pseudo-observables
class PseudoObservablesFilter(Filter):
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

    ``run(ys)`` (``ys`` the increments ``dy``, y0 = 0): a continuous-time
    :class:`~nlfilter.filters.base.Filter` over a :class:`PseudoObservablesState`; ``means`` the
    estimates of the base variables, ``covs`` the off-line error covariance of the gain schedule.
    The prior is the law of x0 whose moments ``x_moment`` gives (every moment enters the
    pseudo-observables' gains), so ``m0``/``P0`` must be None (refused naming ``m0``). A missing
    increment component: its observables give no innovation (see :meth:`step`).
    """

    name = "pseudo-observables"
    own_prior = True  # the law of x0 comes from x_moment: run takes m0 = P0 = None

    @classmethod
    def for_model(cls, model, *, dt=None, start="update"):
        """No default instance: the initial law's moments ``x_moment`` are the user's to give."""
        raise ValueError("x_moment: PseudoObservablesFilter needs the initial law's moments of x (no default); "
                         "build it with PseudoObservablesFilter(model, dt, x_moment=...)")
    family = "off-line gains"
    source = "seed 001 §3.2, eqs. 3.11-3.16"
    accepts = ("bilinear",)
    needs = ("additive measurement noise", "time-invariant model", "moments of x0 (x_moment)")
    time = "continuous"

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

    def init(self, m0=None, P0=None, batch=(), *, initial=None, rng=None):
        """The start ``ẑ0`` of :meth:`initial_moments` (x0 from ``x_moment``, all its moments, and
        y0 = 0): this filter refuses a Gaussian prior (m0, P0), which would not give the moments
        of the pseudo-observables."""
        if m0 is not None or P0 is not None:
            raise ValueError(f"{'m0' if m0 is not None else 'P0'}: {type(self).__name__} starts from the law of x0 "
                             "given by x_moment (and y0 = 0); "
                             f"expected m0=None, P0=None, got m0={m0!r}, P0={P0!r}")
        if initial is not None:
            raise ValueError(f"initial: the initial law is x_moment's; expected None, got {type(initial).__name__}")
        B = int(np.prod(batch))
        z0, _ = self.initial_moments()
        return PseudoObservablesState(np.broadcast_to(z0, (B, len(z0))).copy(), np.zeros((B, self.m)), 0)

    def step(self, belief, dy, t):
        """One increment ``dy (B, m)``: the pseudo-observables' increments ``d(y_i^p)`` are formed
        from the running ``y``. A missing component ``i``: its observables give no innovation at
        that step, and ``y_i`` goes on from its estimate ``ŷ_i`` (y is a coordinate of the lift;
        exact for the power 1, an approximation for the higher powers after a gap)."""
        k = belief.k
        Ps, Ks = self._schedule(k)
        miss = np.isnan(dy)
        A, H, h = self.A, self.H, self.dt
        y_new = belief.y + (np.where(miss, 0.0, dy) if miss.any() else dy)
        dY = np.stack([y_new[..., i] ** p - belief.y[..., i] ** p for i, p in self.obs_meta], axis=-1)
        K0, K1, K2 = Ks[2 * k], Ks[2 * k + 1], Ks[2 * k + 2]
        if not miss.any():
            Phi, Gam = _affine_step(A - K0 @ H, A - K1 @ H, A - K2 @ H, K0, K1, K2, h, self.scheme)
            z = belief.z @ Phi.T + (dY / h) @ Gam.T
            return PseudoObservablesState(z, y_new, k + 1)
        z = np.empty_like(belief.z)
        comp = np.array([i for i, _ in self.obs_meta])
        patterns, which = np.unique(~miss, axis=0, return_inverse=True)
        for j, obs in enumerate(patterns):
            sel = which.ravel() == j
            keep = obs[comp].astype(float)  # the observables of a missing component: no innovation
            k0, k1, k2 = K0 * keep, K1 * keep, K2 * keep
            Phi, Gam = _affine_step(A - k0 @ H, A - k1 @ H, A - k2 @ H, k0, k1, k2, h, self.scheme)
            z[sel] = belief.z[sel] @ Phi.T + (np.where(keep > 0, dY[sel], 0.0) / h) @ Gam.T
        iy = [self.index[tuple(int(j == self.nb + i) for j in range(self.nb + self.m))] for i in range(self.m)]
        y_new = np.where(miss, z[:, iy], y_new)  # an unobserved y_i goes on from its estimate
        return PseudoObservablesState(z, y_new, k + 1)

    def summary(self, belief):
        """``(x̂ (B, n_base), the off-line error covariance at that step)``."""
        Ps, _ = self._schedule(max(belief.k - 1, 0))
        ix = self._ix
        Pk = Ps[2 * belief.k][np.ix_(ix, ix)]
        return belief.z[:, ix], np.broadcast_to(Pk, (len(belief.z), self.nb, self.nb))


class PseudoObservablesState(NamedTuple):
    """Belief of :class:`PseudoObservablesFilter`: the estimate ``z (B, N)`` of the lifted state,
    the running observation ``y (B, m)`` (y0 = 0), and the step count ``k`` (shared by the paths:
    the gains are a schedule from t = 0)."""

    z: np.ndarray
    y: np.ndarray
    k: int

    _shared = ("k",)


__all__ = ["PseudoObservablesFilter", "OptimalLinearFilter", "DiscreteOptimalLinearFilter", "LinearSteadyState", "WonhamReport",
           "wonham_condition", "state_second_moments", "augmented_second_moment", "JointProcess",
           "joint_process", "odd_features", "fit_post_processor", "PostProcessorFit", "TensorFilter",
           "multistage", "UpdatedInnovationsFilter"]
