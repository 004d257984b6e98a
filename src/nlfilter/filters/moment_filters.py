"""Conditional-moment filters: the moment equations of the *conditional* law, closed by a closure.

These are the on-line counterparts of the QLF/MQLF (:mod:`.quasilinear`): instead of the prior
moments of x(t), they propagate the moments of x(t) given the measurements, for every path.

Continuous time (Kushner-Stratonovich, Itô form) for a polynomial :class:`~nlfilter.models.SDEModel`: for every
kept monomial φ = x^γ (all of degree 1..N)::

    dE[φ | Y] = E[L φ | Y] dt + Cov(φ, hᵀ | Y) R⁻¹ (dy − E[h | Y] dt)

``E[L φ]`` is the row of the engine's ``A μ + B ν + c`` (seed 003 eq. 11 applied to the
conditional law); ``E[φ h_j]`` and ``E[h]`` are exact linear functionals of the moments; the
moments not kept come from the closure. The Gaussian closure (N = 2) is the Gaussian
assumed-density filter with *exact* polynomial moments; ``EdgeworthClosure(4)`` or
``CumulantClosure(4)`` (N = 4) keep skewness and kurtosis.

One measurement step = update, then the ``dt`` term (``A μ + B ν + c``, RK4, ``substeps``):

* ``update="bayes"`` (default): the exact Bayes update over the step of the assumed density
  ``p*(x) = N(x; m, K) g(x)`` — ``g`` the degree-N polynomial matching every kept moment (the
  Gram-Charlier/Edgeworth density of 003 eq. 12; g = 1 for the Gaussian closure) — by the
  likelihood ``exp(hᵀR⁻¹dy − ½ hᵀR⁻¹h dt)``, with Gauss-Hermite quadrature (``points`` per axis).
  Where the truncated series ``g`` is negative (003, after eq. 15) it is clipped to 0, so the update
  is always that of a proper density (its moments then differ slightly from the kept ones).
  As dt → 0 this is the KS innovation term above; unlike an Euler step on it, it cannot push
  a variance negative for the Gaussian closure (the Itô correction −Cov(x,h)R⁻¹Cov(h,x) dt of the
  variance is taken exactly, not as the random square of the mean's increment).
* ``update="ito"``: the KS innovation term as one Euler-Maruyama increment. Consistent, but on
  strongly nonlinear sensors (the cubic sensor at dt = 0.01) variances often turn negative.

Discrete time (:class:`DiscreteConditionalMomentFilter`): predict with the discrete moment
equations (+ closure), update by the Bayes rule applied to the assumed density (as
``update="bayes"`` below, with the measurement noise's density). For a linear Gaussian model with
the Gaussian closure this is the Kalman filter (up to quadrature error).

Failures (variance ≤ 0, non-finite moments) are divergences of the path (``on_divergence``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import _validate as V
from ..moments.closures import Closure, GaussianClosure, gaussian_moments, kept_order
from ..moments.expect import PolynomialExpectations
from ..moments.quadrature import gaussian_rule
from ..moments.discrete import PolynomialMap, discrete_moment_equations
from ..moments.ito import PolynomialSDE, moment_equations
from ..polynomials import Polynomial, add_exp, monomials, unit_exp
from .base import ContinuousFilter, DiscreteFilter, GaussianState, continuous_precision, ode_step
from .linalg import innovation_info, measurement_loglik, observed_precision, sqrt_psd

__all__ = ["ConditionalMomentFilter", "DiscreteConditionalMomentFilter", "MomentBelief"]


class MomentBelief(NamedTuple):
    """The kept conditional moments ``mu (..., K)`` of a batch (order of ``filter.set.indices``)."""

    mu: np.ndarray


class _MomentFilter:
    """What the continuous and discrete conditional-moment filters share: the moment belief."""

    family = "conditional moments"
    needs = ("polynomial",)

    def init(self, m0, P0, batch, *, initial=None, rng=None):
        """The moments of order ≤ N of the Gaussian prior N(m0, P0)."""
        g = super().init(m0, P0, batch, initial=initial)
        return MomentBelief(gaussian_moments(g.mean, g.cov, self.set.indices))

    def summary(self, belief):
        return tuple(self.set.gaussian_state(belief.mu))


class _MomentSet:
    """Kept monomials, their equations, and the expectations a conditional-moment filter needs."""

    def __init__(self, eqs, h, closure, n):
        self.eqs, self.closure, self.n = eqs, closure, n
        self.indices = eqs.indices
        K, m = len(self.indices), len(h)
        self.m = m
        polys = list(h) + [Polynomial({g: 1.0}, n) * hj for g in self.indices for hj in h]
        polys += [Polynomial({g: 1.0}, n) for g in eqs.missing]
        self.pe = PolynomialExpectations(self.indices, polys, closure)
        self.K = K
        idx = eqs.index
        self.pos1 = [idx[unit_exp(n, i)] for i in range(n)]
        self.pos2 = [[idx[add_exp(unit_exp(n, i), unit_exp(n, j))] for j in range(n)] for i in range(n)]

    def split(self, mu):
        E = self.pe(mu)
        K, m = self.K, self.m
        Eh = E[..., :m]
        o = m
        Ephih = E[..., o:o + K * m].reshape(*E.shape[:-1], K, m)
        o += K * m
        nu = E[..., o:]
        return Eh, Ephih, nu

    def quadrature(self, points: int, N: int):
        V.positive("points", points, integer=True)
        if 2 * points - 1 < 2 * N:
            raise ValueError(f"points: expected ≥ {N + 1} Gauss-Hermite points for order {N}, got {points}")
        self._nodes = gaussian_rule(self.n, "auto", points)
        z = self._nodes[0]
        self._Z = (np.stack([np.prod(z ** np.array(g), axis=-1) for g in [(0,) * self.n] + self.indices], axis=-1)
                   if N > 2 else None)

    def _mono(self, x):
        out = [np.ones(x.shape[:-1])]
        for g in self.indices:
            v = 1.0
            for i, k in enumerate(g):
                if k:
                    v = v * x[..., i] ** k
            out.append(np.broadcast_to(v, x.shape[:-1]))
        return np.stack(out, axis=-1)

    def bayes(self, mu, loglik, evidence=None):
        """Posterior kept moments of p*(x) ∝ N(x; m, K) g(x) exp(loglik(x)), g the degree-N polynomial
        matching the kept moments (clipped at 0), by Gauss-Hermite quadrature; ``loglik`` maps nodes
        ``(..., P, n)`` to ``(..., P)``. With ``evidence`` (a function ``h`` of the nodes), also
        ``(log ∫ p* exp(loglik) / ∫ p*, E*[h], Cov*[h])``: the log-evidence of the measurement and
        the predictive moments of h under the assumed density (the filter's likelihood output)."""
        gs = self.gaussian_state(mu)
        z, w = self._nodes
        L, bad = sqrt_psd(gs.cov)  # a path whose covariance is not PSD comes back NaN (run flags it)
        x = gs.mean[..., None, :] + np.einsum("...ij,pj->...pi", L, z)  # (..., P, n)
        X = self._mono(x)  # (..., P, 1 + K): [1, x^γ]
        if self._Z is not None:  # g(z) = Σ a_ν z^ν with Σ_p w_p g(z_p) x_p^γ = E x^γ, |γ| ≤ N
            M = np.einsum("p,pa,...pg->...ga", w, self._Z, X)
            full = np.concatenate([np.ones((*mu.shape[:-1], 1)), mu], axis=-1)
            try:
                a = np.linalg.solve(M, full[..., None])[..., 0]
            except np.linalg.LinAlgError:  # a degenerate law (P = 0 in a direction: the nodes coincide) has
                sign, _ = np.linalg.slogdet(np.where(np.isfinite(M), M, 0.0))  # no series: those paths fail
                sing = ~(np.abs(sign) > 0) | ~np.all(np.isfinite(M), axis=(-1, -2))
                a = np.linalg.solve(np.where(sing[..., None, None], np.eye(M.shape[-1]), M), full[..., None])[..., 0]
                bad = bad | sing
            # the truncated series is negative in places (003, after eq. 15): clip it, so the update is
            # the Bayes update of a proper (positive) density with nearly the kept moments
            omega = w * np.maximum(a @ self._Z.T, 0.0)
        else:
            omega = np.broadcast_to(w, x.shape[:-1])
        ll = loglik(x)
        mx = ll.max(axis=-1, keepdims=True)
        lw = np.exp(ll - mx) * omega
        out = np.einsum("...p,...pg->...g", lw, X[..., 1:]) / lw.sum(axis=-1)[..., None]
        out = np.where(bad[..., None], np.nan, out)
        if evidence is None:
            return out
        om = np.broadcast_to(omega, x.shape[:-1])
        tot = om.sum(axis=-1)
        lev = mx[..., 0] + np.log(lw.sum(axis=-1)) - np.log(tot)  # log E*[exp(loglik)]
        hx = evidence(x)  # (..., P, m)
        Eh = np.einsum("...p,...pi->...i", om, hx) / tot[..., None]
        d = hx - Eh[..., None, :]
        Ch = np.einsum("...p,...pi,...pj->...ij", om, d, d) / tot[..., None, None]
        return out, np.where(bad, np.nan, lev), Eh, Ch

    def gaussian_state(self, mu):
        mean = mu[..., self.pos1]
        n = self.n
        cov = np.empty((*mu.shape[:-1], n, n))
        for i in range(n):
            for j in range(n):
                cov[..., i, j] = mu[..., self.pos2[i][j]] - mean[..., i] * mean[..., j]
        return GaussianState(mean, cov)


def _unless_missing(obs, mu, post):
    """The updated moments ``post``, except on the paths whose measurement is missing entirely
    (``obs (..., m)`` all False): those keep ``mu`` (a flat likelihood would still move the kept
    moments of order > 2 where the clipped Edgeworth density differs from them)."""
    none = ~obs.any(axis=-1)
    return np.where(none[..., None], mu, post) if none.any() else post


def _model_polys(model, who):
    if getattr(model, "sym", None) is None:
        raise TypeError(f"model: {who} needs a model stated in SymPy")
    st = model.states
    return [Polynomial.from_sympy(e, st, name=f"h[{i}]") for i, e in enumerate(model.sym["h"])]


class ConditionalMomentFilter(_MomentFilter, ContinuousFilter):
    """Kushner-Stratonovich conditional-moment filter for a polynomial :class:`~nlfilter.models.SDEModel`.

    Parameters
    ----------
    model : SDEModel with polynomial f, GQGᵀ, h (else :class:`~nlfilter.errors.NotPolynomialError`
        naming the term)
    dt : measurement step of the increments ``dy``
    closure : default :class:`GaussianClosure` (the Gaussian assumed-density filter)
    order : order N of the kept moments (default: the closure's order)
    substeps : RK4 substeps of the ``dt`` term per measurement step
    name : the filter's label (default from the closure)

    Examples
    --------
    >>> import sympy as sp; from nlfilter import SDEModel
    >>> x = sp.Symbol("x")
    >>> f = ConditionalMomentFilter(SDEModel([x], [-x], [x], Q=1.0, R=1.0), 0.01)
    >>> est = f.run(np.zeros((2, 3, 1)), [0.0], [[0.5]])
    >>> est.means.shape, est.covs.shape
    ((2, 3, 1), (2, 3, 1, 1))
    """

    source = "seed 003 eqs. 11-12 (conditional law), Kushner-Stratonovich"

    def __init__(self, model, dt, *, closure: Closure | None = None, order: int | None = None,
                 substeps: int = 1, update: str = "bayes", points: int = 24, name: str | None = None):
        ContinuousFilter.__init__(self, model, dt, scheme="rk4", substeps=substeps)
        self.update_rule = V.choice("update", update, {"bayes", "ito"})
        if self.update_rule == "ito":
            self.likelihood = None
        closure = GaussianClosure() if closure is None else closure
        N = kept_order(closure, order)
        h = _model_polys(model, "ConditionalMomentFilter")
        sde = PolynomialSDE.from_model(model)
        if sde.symbols:
            raise ValueError("model: time-varying coefficients are not supported by ConditionalMomentFilter yet")
        eqs = moment_equations(sde, monomials(model.n, N, min_degree=1))
        self.closure = closure
        self.set = _MomentSet(eqs, h, closure, model.n)
        self._Rinv = continuous_precision(model)
        self.name = name or (f"{closure.name}-closure" if N == closure.order else f"{closure.name}{N}-closure")
        if self.update_rule == "bayes":
            self.set.quadrature(points, N)

    def init_moments(self, m0, P0):
        return gaussian_moments(m0, P0, self.set.indices)

    def _drift(self, mu):
        *_, nu = self.set.split(mu)
        return self.set.eqs.rhs(mu, nu if self.set.eqs.missing else None)

    def _update_ito(self, mu, dy):
        """KS innovation term as one Euler-Maruyama increment (gain at the start of the step)."""
        Eh, Ephih, _ = self.set.split(mu)
        C = Ephih - mu[..., :, None] * Eh[..., None, :]  # Cov(φ, hᵀ)
        obs = ~np.isnan(dy)
        innov = np.where(obs, dy - Eh * self.dt, 0.0)
        Rinv = observed_precision(self.model.R, self._Rinv, obs)
        return mu + np.einsum("...km,...mn,...n->...k", C, Rinv, innov)

    # the log-evidence of each increment under the closure's assumed density, by the Bayes
    # update's quadrature (an instance with the Itô update has none: set in __init__)
    likelihood = "assumed-density"

    def _step_info(self, belief, dy, t):
        """``run(..., loglik=True)``: the step and ``log E*[N(dy; h(x) dt, R dt)]`` under the
        assumed density p* of the kept moments (the Kallianpur–Striebel ratio of the Bayes update
        times the density of dy under pure noise), the innovation ``dy − E*[h] dt`` and
        ``(Cov*[h] dt + R) dt``."""
        if self.likelihood is None:
            return super()._step_info(belief, dy, t)
        dy = np.asarray(dy, dtype=float)
        mu, (lev, Eh, Ch) = self._update_bayes(belief.mu, dy, t, info=True)
        mu = ode_step(lambda v, s: self._drift(v), mu, t, self.dt, substeps=self.substeps)
        md, dt = self.model, self.dt
        info = innovation_info(dy / dt, Eh, Ch + md.R / dt, scale=dt)
        obs = ~np.isnan(dy)
        lev = lev + innovation_info(dy, np.zeros_like(dy), md.R * dt)["loglik"]
        info["loglik"] = np.where(obs.any(axis=-1), lev, 0.0)
        return MomentBelief(mu), None, info

    def _update_bayes(self, mu, dy, t, info: bool = False):
        """Bayes update over the step by the likelihood exp(hᵀR⁻¹dy − ½hᵀR⁻¹h dt) (see module docstring)."""
        obs = ~np.isnan(dy)
        dyz = np.where(obs, dy, 0.0)[..., None, :]
        dt, md = self.dt, self.model
        Rinv = observed_precision(md.R, self._Rinv, obs)  # zero in the missing rows and columns

        def loglik(x):
            hx = md.h(x, t + dt)
            Rh = np.einsum("...mn,...pn->...pm", Rinv, hx)
            return np.einsum("...pm,...pm->...p", Rh, dyz) - 0.5 * dt * np.einsum("...pm,...pm->...p", Rh, hx)

        if info:
            post, *ev = self.set.bayes(mu, loglik, evidence=lambda x: md.h(x, t + dt))
            return _unless_missing(obs, mu, post), ev
        return _unless_missing(obs, mu, self.set.bayes(mu, loglik))

    def step_moments(self, mu, dy, t):
        """One measurement step of the conditional moments ``mu (..., K)`` with increments ``dy (..., m)``:
        the update (``"bayes"`` or ``"ito"``), then the ``dt`` term of the moment equations by RK4."""
        mu = self._update_bayes(mu, dy, t) if self.update_rule == "bayes" else self._update_ito(mu, dy)
        return ode_step(lambda v, s: self._drift(v), mu, t, self.dt, substeps=self.substeps)

    def step(self, belief, dy, t):
        return MomentBelief(self.step_moments(belief.mu, dy, t))


class DiscreteConditionalMomentFilter(_MomentFilter, DiscreteFilter):
    """Discrete-time conditional-moment filter (predict: discrete moment equations + closure;
    update: Bayes rule on the assumed density, Gauss-Hermite quadrature with ``points`` per axis). The belief passed between ``predict``
    and ``update`` is a :class:`MomentBelief` (all kept moments; ``init`` makes it from N(m0, P0),
    ``summary`` gives its mean and covariance).

    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> x = sp.Symbol("x")
    >>> est = DiscreteConditionalMomentFilter(DiscreteModel([x], [0.5 * x], [x], Q=1.0, R=1.0)).run(
    ...     np.array([[[1.0], [0.0]]]), [0.0], [[1.0]])
    >>> est.means[0, :, 0].round(6).tolist()       # = Kalman filter on a linear model
    [0.5, 0.117647]
    """

    source = "seed 003 eqs. 11-12 (discrete moment equations), Bayes update of the assumed density"

    def __init__(self, model, *, closure: Closure | None = None, order: int | None = None,
                 start: str | None = None, points: int = 24, name: str | None = None):
        DiscreteFilter.__init__(self, model, start=start)
        if getattr(model, "R_constant", True) and not model.measurement_noise.has_density:
            raise ValueError(f"measurement_noise: the discrete conditional-moment filter's Bayes update needs a law "
                             f"with a density; got {model.measurement_noise!r} (a Gaussian has none when its "
                             "covariance R is singular)")
        closure = GaussianClosure() if closure is None else closure
        N = kept_order(closure, order)
        h = _model_polys(model, "DiscreteConditionalMomentFilter")
        pm = PolynomialMap.from_model(model)
        eqs = discrete_moment_equations(pm, monomials(model.n, N, min_degree=1))
        if eqs.symbols:
            raise ValueError("model: time-varying coefficients are not supported by DiscreteConditionalMomentFilter yet")
        self.closure = closure
        self.set = _MomentSet(eqs, h, closure, model.n)
        self.set.quadrature(points, N)
        self.name = name or (f"{closure.name}-closure" if N == closure.order else f"{closure.name}{N}-closure")

    def predict_moments(self, mu, k):
        *_, nu = self.set.split(mu)
        return self.set.eqs.rhs(mu, nu if self.set.eqs.missing else None, k)

    def update_moments(self, mu, y, k):
        """Bayes update of the assumed density by the measurement likelihood p_v(y − h(x))."""
        y = np.asarray(y, dtype=float)
        obs = ~np.isnan(y)
        return _unless_missing(obs, mu, self.set.bayes(mu, self._loglik(y, obs, k)))

    def _loglik(self, y, obs, k):
        """``x -> log p_v(y − h(x, k))`` at quadrature nodes; partly missing: the marginal law of
        the observed components."""
        md = self.model
        return lambda x: measurement_loglik(md.measurement_noise,
                                            np.where(obs[..., None, :], y[..., None, :] - md.h(x, k), 0.0), obs)

    likelihood = "assumed-density"

    def _update_info(self, belief, y, k):
        """``run(..., loglik=True)``: the update and ``log E*[p_v(y − h(x))]`` under the assumed
        density p* of the kept moments (the Bayes update's quadrature), the innovation
        ``y − E*[h]`` and ``Cov*[h] + R``."""
        y = np.asarray(y, dtype=float)
        obs = ~np.isnan(y)
        md = self.model
        post, lev, Eh, Ch = self.set.bayes(belief.mu, self._loglik(y, obs, k), evidence=lambda x: md.h(x, k))
        info = innovation_info(y, Eh, Ch + md.R)
        info["loglik"] = np.where(obs.any(axis=-1), lev, 0.0)
        return MomentBelief(_unless_missing(obs, belief.mu, post)), None, info

    def predict(self, belief, k):
        return MomentBelief(self.predict_moments(belief.mu, k))

    def update(self, belief, y, k):
        return MomentBelief(self.update_moments(belief.mu, y, k))
