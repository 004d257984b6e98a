"""Statistical linearization about the prior law of ``x`` (seed 003, Oh & Shin, eqs. 3-5, 11):
the linearization coefficients and the moment system of the prior that the quasilinear filters
(:mod:`nlfilter.filters.quasilinear`: QLF, MQLF, the discrete QLF) compute before the data.

``f(x) ≈ a0 + a1 (x − m)``, ``a0 = E f``, ``a1 = E[f (x − m)ᵀ] K⁻¹`` (same for h: b0, b1), the
expectations from the moment engine: the exact moment equations of a polynomial model closed by a
closure, or Gauss-Hermite expectations under the Gaussian closure.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from ..errors import NotPolynomialError
from ..moments.closures import Closure, GaussianClosure, gaussian_moments, kept_order
from ..moments.discrete import PolynomialMap, discrete_moment_equations, gaussian_noise_moments
from ..moments.expect import PolynomialExpectations, statistical_linearization_polys
from ..moments.ito import PolynomialSDE, moment_equations
from ..moments.quadrature import expect_gaussian, gaussian_rule
from ..polynomials import Polynomial, add_exp, monomials, unit_exp
from .linalg import symmetrize

__all__ = ["statistical_linearization"]


def statistical_linearization(mean, cov, Ef, Efx):
    """``(a0, a1)`` of 003 eqs. 4-5 from ``E f (..., k)`` and ``E[f xᵀ] (..., k, n)`` under a law
    with mean ``(..., n)`` and covariance ``(..., n, n)``: ``a1 = (E[f xᵀ] − E f mᵀ) K⁻¹``.

    >>> m, K = np.array([1.0]), np.array([[0.5]])
    >>> a0, a1 = statistical_linearization(m, K, np.array([-(1 + 3 * 0.5)]), np.array([[-(3 * 0.25 + 6 * 0.5 + 1)]]))
    >>> a0.tolist(), a1.round(12).tolist()     # −x³ under N(1, 0.5): a1 = −3 E x² = −4.5
    ([-2.5], [[-4.5]])
    """
    mean, cov = np.asarray(mean), np.asarray(cov)
    C = Efx - Ef[..., :, None] * mean[..., None, :]  # E[f (x − m)ᵀ]
    a1 = np.swapaxes(np.linalg.solve(cov, np.swapaxes(C, -1, -2)), -1, -2)  # C K⁻¹ (K symmetric)
    return Ef, a1


class _Linearizer:
    """The prior law of x as a moment vector, its evolution, and the linearization coefficients.

    Polynomial model: raw moments up to ``order`` (exact equations + closure). Otherwise (Gaussian
    closure only): ``[m, vec K]`` with Gauss-Hermite expectations."""

    def __init__(self, model, closure: Closure, order: int | None, kind: str, points: int = 9):
        self.model, self.closure, self.kind = model, closure, kind
        n, m = model.n, model.m
        self.n, self.m = n, m
        N = kept_order(closure, order)
        if getattr(model, "sym", None) is None:
            raise TypeError("model: quasilinear filters need a model stated in SymPy")
        if model.time is not None and (model.sym["f"].has(model.time) or model.sym["h"].has(model.time)
                                       or model.sym["G"].has(model.time)):
            raise ValueError("model: time-varying models are not supported by the quasilinear filters yet")
        st = model.states
        try:
            f = [Polynomial.from_sympy(e, st, name=f"f[{i}]") for i, e in enumerate(model.sym["f"])]
            h = [Polynomial.from_sympy(e, st, name=f"h[{i}]") for i, e in enumerate(model.sym["h"])]
            G = model.sym["G"]
            S = sp.expand(G * sp.Matrix(model.Q.tolist()) * G.T)
            sig = [Polynomial.from_sympy(S[i, j], st, name=f"GQGᵀ[{i},{j}]") for i in range(n) for j in range(n)]
            self.polynomial = True
        except NotPolynomialError as exc:
            if not isinstance(closure, GaussianClosure):
                raise NotPolynomialError(f"closure: the {closure.name} closure needs exact polynomial moments, "
                                         f"but {exc}") from None
            self.polynomial = False
            self.order = 2
            self.nodes = gaussian_rule(n, "auto", points)
            return
        self.order = N
        self.indices = monomials(n, N, min_degree=1)
        if kind == "continuous":
            self.eqs = moment_equations(PolynomialSDE(tuple(f), tuple(tuple(sig[i * n:(i + 1) * n]) for i in range(n)),
                                                      states=tuple(st)), self.indices)
        else:
            Gp = [[Polynomial.from_sympy(G[i, a], st) for a in range(G.shape[1])] for i in range(n)]
            self.eqs = discrete_moment_equations(
                PolynomialMap(tuple(f), tuple(map(tuple, Gp)), gaussian_noise_moments(model.Q), states=tuple(st)),
                self.indices)
        polys = statistical_linearization_polys(f, n) + statistical_linearization_polys(h, n) + sig
        self.pe = PolynomialExpectations(self.indices, polys, closure)
        self.pe_next = PolynomialExpectations(self.indices, [], closure)
        self._miss = (PolynomialExpectations(self.indices, [Polynomial({g: 1.0}, n) for g in self.eqs.missing],
                                             closure) if self.eqs.missing else None)
        self.pos1 = [self.eqs.index[unit_exp(n, i)] for i in range(n)]

    @property
    def size(self):
        return len(self.indices) if self.polynomial else self.n + self.n * self.n

    def init(self, m0, P0):
        if self.polynomial:
            return gaussian_moments(m0, P0, self.indices)
        return np.concatenate([m0, P0.ravel()])

    def mean_cov(self, mu):
        n = self.n
        if not self.polynomial:
            return mu[..., :n], mu[..., n:].reshape(*mu.shape[:-1], n, n)
        idx = self.eqs.index
        m = mu[..., self.pos1]
        K = np.empty((*mu.shape[:-1], n, n))
        for i in range(n):
            for j in range(n):
                K[..., i, j] = mu[..., idx[add_exp(unit_exp(n, i), unit_exp(n, j))]] - m[..., i] * m[..., j]
        return m, K

    def coeffs(self, mu, t=0.0):
        """(m, K, a0, a1, b0, b1, σ̄) for moment vectors ``mu (..., size)``."""
        n, m_ = self.n, self.m
        mean, K = self.mean_cov(mu)
        if self.polynomial:
            E = self.pe(mu)
        else:
            md = self.model

            def fx(x):
                f, h = md.f(x, t), md.h(x, t)
                return np.concatenate([f, (f[..., :, None] * x[..., None, :]).reshape(*x.shape[:-1], -1), h,
                                       (h[..., :, None] * x[..., None, :]).reshape(*x.shape[:-1], -1),
                                       md.GQGT(x, t).reshape(*x.shape[:-1], -1)], axis=-1)
            E = expect_gaussian(fx, mean, K, nodes=self.nodes, check=False)
        # E = [E f (n), E f xᵀ (n·n), E h (m), E h xᵀ (m·n), E G Q Gᵀ (n·n)] in that order
        b = E.shape[:-1]
        cuts = np.cumsum([n, n * n, m_, m_ * n])
        Ef, Efx, Eh, Ehx, sig = np.split(E, cuts, axis=-1)
        Efx, Ehx, sig = Efx.reshape(*b, n, n), Ehx.reshape(*b, m_, n), sig.reshape(*b, n, n)
        a0, a1 = statistical_linearization(mean, K, Ef, Efx)  # 003 eq. 4
        b0, b1 = statistical_linearization(mean, K, Eh, Ehx)  # 003 eq. 5
        return mean, K, a0, a1, b0, b1, sig

    def deriv(self, mu, t, c=None):
        """d(moment vector)/dt (continuous)."""
        if self.polynomial:
            nu = self._miss(mu) if self._miss is not None else None
            return self.eqs.rhs(mu, nu, t)
        mean, K, a0, a1, b0, b1, sig = c if c is not None else self.coeffs(mu, t)
        dK = a1 @ K + K @ np.swapaxes(a1, -1, -2) + sig  # Gaussian closure: exact for stat.-lin. f
        return np.concatenate([a0, dK.reshape(*dK.shape[:-2], -1)], axis=-1)

    def step(self, mu, k):
        """Prior moments of x[k+1] from those of x[k] (discrete)."""
        if self.polynomial:
            nu = self._miss(mu) if self._miss is not None else None
            return self.eqs.rhs(mu, nu, k)
        md, n = self.model, self.n
        mean, K = self.mean_cov(mu)

        def g(x):
            f = md.f(x, k)
            return np.concatenate([f, (f[..., :, None] * f[..., None, :]).reshape(*x.shape[:-1], -1),
                                   md.GQGT(x, k).reshape(*x.shape[:-1], -1)], axis=-1)
        E = expect_gaussian(g, mean, K, nodes=self.nodes, check=False)
        m1 = E[..., :n]
        K1 = E[..., n:n + n * n].reshape(n, n) - np.outer(m1, m1) + E[..., n + n * n:].reshape(n, n)
        return np.concatenate([m1, symmetrize(K1).ravel()])
