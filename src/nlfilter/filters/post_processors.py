"""The joint (x, ẑ) moments of a bilinear system and its linear filter, and the odd-polynomial
post-processors fitted on them (seed 001 §3.3, Fig. 3.2, eqs. 3.29-3.35).

Post-processor: ``x̂ = Σ_k α_k φ_k(ẑ)`` with ``φ_k`` odd monomials of the linear estimate
(``α x̂ + β x̂³`` is eqs. 3.29-3.35); the gains solve the normal equations ``E[φ φᵀ] α = E[x φ]``
whose moments are the steady-state moments of the joint process ``(x, ẑ)`` (built by
:func:`~nlfilter.filters.offline_analysis.joint_sde`, as the QLF's error analysis) — exact, from the
closed moment system of the joint SDE (:func:`nlfilter.moments.solve.stationary_moments`,
conservation laws imposed on the circle). :class:`~nlfilter.filters.bilinear.TensorFilter` runs them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..bilinear import BilinearModel
from ..errors import SingularSystemError
from ..moments.ito import PolynomialSDE
from ..moments.solve import stationary_moments
from ..polynomials import Polynomial, monomials
from .linalg import symmetrize
from .offline_analysis import joint_sde



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
    (augmented ``(N, m)``): the linear filter in innovation form (001 §3.3, eq. 3.30)
    ``dẑ = [F ẑ + K H (z(x) − ẑ)] dt + K Σ_l M_l z(x) dw_l`` beside the base SDE, built by the one
    joint builder of the off-line analyses, :func:`~nlfilter.filters.offline_analysis.joint_sde`.
    Estimate coordinates with a zero gain row whose drift involves only such coordinates and the
    constant are deterministic: in steady state they equal their mean and are substituted as
    constants (this is why 001 eq. 5.7 carries x̂ and x̂³ but not x̂²)."""
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
    r_meas = Ms.shape[0]
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
    noise = []  # the estimate's noise columns K M_l z(x)
    for j in est:
        row = []
        for l in range(r_meas):
            acc = zero
            for i in range(model.m):
                if K[j, i] != 0 and meas_noise[l][i].terms:
                    acc = acc + meas_noise[l][i] * float(K[j, i])
            row.append(acc.clean(1e-15))
        noise.append(row)
    # 001 eq. 3.30: dẑ = [F ẑ + K H (z(x) − ẑ)] dt + K Σ_l M_l z(x) dw_l, the one joint builder
    names = list(base.names) + [f"hat({model.names[k]})" for k in est]
    sde = joint_sde(base, [zhat(k) for k in range(N)], [[float(F[j, k]) for k in range(N)] for j in est], None,
                    [[float(K[j, i]) for i in range(model.m)] for j in est], innov, noise, names=names, tol=1e-15)
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


def multistage(jp: JointProcess, first: PostProcessorFit, degree: int = 3, *, initial=None) -> PostProcessorFit:
    """A second stage of post-processing (001 Fig. 3.2): odd powers of the first stage's output
    ``x̃ = ψ(ẑ)`` (polynomials of ``ẑ`` of degree ``deg ψ · degree``), gains again by least squares
    from exact moments. Its MSE is never above the first stage's (``x̃`` itself is a feature)."""
    out = first.output_poly()
    feats = [out ** p for p in range(1, degree + 1, 2)]
    fit = fit_post_processor(jp, first.target, feats, out, initial=initial, moments=first.moments)
    fit.mse_linear = first.mse_linear
    return fit


__all__ = ["JointProcess", "joint_process", "odd_features", "PostProcessorFit", "fit_post_processor", "multistage"]
