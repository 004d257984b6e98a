"""The off-line accuracy of ANY filter with precomputed gains: the moments of the joint process
(x, x̂) of the signal and the filter's affine recursion (seed 003 Fig. 2; the library's extension
to discrete time), for the quasilinear filters (:mod:`.quasilinear`, ``error_analysis``) and any
other schedule of gains (e.g. the optimal linear filter of a bilinear system written as an
:class:`~nlfilter.models.SDEModel`: see tests/filters/test_offline.py, which checks it against the
stationary moments of :func:`~nlfilter.filters.bilinear.joint_process`).

Length convention: the continuous analysis reports the times ``t`` it is given (the quasilinear
filters pass the grid ``t0 .. t0 + T dt``, T + 1 rows: the prior row first, then the T times of
``run``'s estimates); the discrete one reports the T steps of ``run`` (k = 0 .. T − 1, no prior row).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from .. import _validate as V
from ..moments.closures import Closure, EdgeworthClosure, gaussian_moments, kept_order
from ..moments.discrete import PolynomialMap, discrete_moment_equations, gaussian_noise_moments
from ..moments.ito import PolynomialSDE, moment_equations
from ..moments.solve import MomentSolution, iterate, propagate
from ..noise import Gaussian
from ..polynomials import Polynomial, monomials

__all__ = ["ErrorAnalysis", "gain_error_analysis", "discrete_gain_error_analysis"]


def _unit(n, i, k=1):
    e = [0] * n
    e[i] = k
    return tuple(e)


def _prior(n, m0, P0, *, definite: bool = True):
    """One prior ``(m0 (n,), P0 (n, n))`` for all paths (the off-line gains depend on it); P0
    positive definite when ``definite`` (the statistical linearization inverts it)."""
    given = np.shape(m0)
    m0 = V.as_float_array("m0", m0).reshape(-1) if np.ndim(m0) else np.full(n, float(m0))
    if m0.shape != (n,):
        raise ValueError(f"m0: the off-line gains need one prior mean of shape ({n},) for all paths, "
                         f"got shape {given}")
    V.finite("m0", m0)
    P0 = V.covariance("P0", P0, n)
    low = float(np.linalg.eigvalsh(P0)[0])
    if definite and not low > 0:  # a1 = E[f (x − m)ᵀ] K⁻¹ (003 eqs. 4-5) needs K(t0) = P0 invertible
        raise ValueError(f"P0: the statistical linearization (003 eqs. 4-5) needs a positive definite prior "
                         f"covariance, got smallest eigenvalue {low:.3g}")
    return m0, P0


def _symbols(name, rows, cols=None):
    """A SymPy matrix of coefficient symbols ``name_i_j`` (a column ``name_i`` when ``cols`` is None)."""
    if cols is None:
        return sp.Matrix(rows, 1, lambda i, j: sp.Symbol(f"{name}_{i}"))
    return sp.Matrix(rows, cols, lambda i, j: sp.Symbol(f"{name}_{i}_{j}"))


def _tabulated(table, shapes):
    """``values`` for :meth:`MomentEquations.at`: every entry ``name_i(_j)`` of the arrays
    ``table(t) -> {name: array}`` (``shapes``: {name: shape}) as a callable of t, ``table``
    evaluated once per t."""
    memo = {}

    def at(t, name, i):
        if memo.get("t") != t:
            memo.clear()
            memo.update(table(t), t=t)
        return memo[name][i]

    values = {}
    for name, shape in shapes.items():
        for i in np.ndindex(*shape):
            values["_".join([name, *map(str, i)])] = (lambda t, name=name, i=i: at(t, name, i))
    return values


def _mse(sol, n):
    """``E(x − x̂)² (T, n) = E x² − 2 E x x̂ + E x̂²`` from the joint moments of ``(x, x̂)`` (2n states)."""
    mse = np.empty((sol.t.size, n))
    for i in range(n):
        xi, hi = _unit(2 * n, i), _unit(2 * n, n + i)
        mse[:, i] = (sol.moment(_unit(2 * n, i, 2)) - 2 * sol.moment(tuple(a + b for a, b in zip(xi, hi)))
                     + sol.moment(_unit(2 * n, n + i, 2)))
    return mse



@dataclass
class ErrorAnalysis:
    """Off-line accuracy: ``t (T+1,)``, ``mse (T+1, n)`` = E(x − x̂)², the joint moments (discrete:
    ``t`` = the step indices 0 .. T − 1 of ``run``'s estimates)."""

    t: np.ndarray
    mse: np.ndarray
    solution: object



def _closure_and_order(closure, order):
    """The error analyses' pair: Edgeworth of ``order`` (default 4) when no closure is given, else
    ``closure`` with :func:`~nlfilter.moments.closures.kept_order` (its own order by default)."""
    if closure is None:
        if order is None:
            order = 4
        if isinstance(order, bool) or not isinstance(order, int) or order < 2:
            raise ValueError(f"order: expected an integer ≥ 2 (the MSE needs second moments), got {order!r}")
        return EdgeworthClosure(order), order
    return closure, kept_order(closure, order)


def gain_error_analysis(model, coefficients, m0, P0, t, *, xhat0=None, closure: Closure | None = None,
                        order: int | None = None) -> ErrorAnalysis:
    """Off-line accuracy of ANY filter with precomputed gains of the form
    ``dx̂ = [F(t) x̂ + u(t)] dt + Kg(t) dy`` on a polynomial :class:`SDEModel`: the moments of the
    joint polynomial SDE (x, x̂) (``dx̂ = [F x̂ + u + Kg h(x)] dt + Kg dη``) up to ``order``, closed by
    ``closure`` (default Edgeworth of that order), give ``E(x − x̂)²`` on the times ``t``. With a
    closure and no ``order`` the order is the closure's (an ``order`` below it is a ``ValueError``);
    neither given: Edgeworth of order 4.

    ``coefficients(t) -> (F (n, n), u (n,), Kg (n, m))``; ``x̂(t[0]) = xhat0`` (default m0), ``x(t[0]) ~
    N(m0, P0)``. For linear models and a Kalman-Bucy gain this is the Riccati solution (exact).
    """
    closure, order = _closure_and_order(closure, order)
    n, mm = model.n, model.m
    m0, P0 = _prior(n, m0, P0, definite=False)
    xh0 = m0 if xhat0 is None else V.as_float_array("xhat0", xhat0, shape_tail=(n,)).reshape(n)
    st = list(model.states)
    xh = [sp.Symbol(f"xhat_{i}") for i in range(n)]
    Fs, us, Ks = _symbols("F", n, n), _symbols("u", n), _symbols("Kg", n, mm)
    Ss = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"S_{min(i, j)}_{max(i, j)}"))
    G = model.sym["G"]
    sig = sp.expand(G * sp.Matrix(model.Q.tolist()) * G.T)
    drift = list(model.sym["f"]) + list(Fs * sp.Matrix(xh) + us + Ks * model.sym["h"])
    diff = sp.zeros(2 * n, 2 * n)
    diff[:n, :n] = sig
    diff[n:, n:] = Ss  # Kg R Kgᵀ: the filter's own noise, independent of β
    joint = PolynomialSDE.from_sympy(st + xh, drift, diff)
    idx = monomials(2 * n, order, min_degree=1)
    eqs = moment_equations(joint, idx)
    R = model.R

    def table(tt):
        F, u, Kg = coefficients(tt)
        return {"F": F, "u": u, "Kg": Kg, "S": Kg @ R @ Kg.T}

    values = _tabulated(table, {"F": (n, n), "u": (n,), "Kg": (n, mm), "S": (n, n)})
    cov0 = np.zeros((2 * n, 2 * n))
    cov0[:n, :n] = P0  # x̂(t0) is known exactly
    mu0 = gaussian_moments(np.concatenate([m0, xh0]), cov0, idx)
    sol = propagate(eqs, mu0, np.asarray(t, dtype=float), closure=closure, values=values, rtol=1e-8, atol=1e-11)
    mse = _mse(sol, n)
    return ErrorAnalysis(sol.t, mse, sol)


def discrete_gain_error_analysis(model, coefficients, m0, P0, steps: int, *, xhat0=None,
                                 closure: Closure | None = None, order: int | None = None,
                                 noise_moment=None) -> ErrorAnalysis:
    """Off-line accuracy of ANY discrete filter with precomputed coefficients on a polynomial
    :class:`~nlfilter.models.DiscreteModel` ``x[k+1] = f(x[k]) + G(x[k]) w[k]``,
    ``y[k] = h(x[k]) + v[k]`` (the discrete counterpart of :func:`gain_error_analysis`, an
    extension of the library: seed 003 is continuous). The filter, update then predict
    (``start="update"``, :meth:`DiscreteQuasilinearFilter.run`)::

        x̂⁺[k]   = x̂⁻[k] + Kg[k] (y[k] − b1[k] x̂⁻[k] − d[k])
        x̂⁻[k+1] = a1[k] x̂⁺[k] + e[k],          x̂⁻[0] = xhat0 (default m0),  x[0] ~ N(m0, P0)

    With ``M = I − Kg b1`` the prior pair ``z[k] = (x[k], x̂⁻[k])`` is a polynomial map with
    time-varying coefficients driven by the independent noises ``(w[k], v[k])``::

        x[k+1]   = f(x) + G(x) w
        x̂⁻[k+1] = a1 M x̂⁻ + a1 Kg h(x) + e − a1 Kg d + a1 Kg v

    whose raw moments up to ``order`` follow from :func:`~nlfilter.moments.ito.discrete_moment_equations`
    (003 eq. 11 in discrete form), closed by ``closure`` (default Edgeworth of ``order`` 4, as the
    paper's Fig. 2; :class:`GaussianClosure` is an option; ``order`` defaults to the closure's). The estimate ``x̂⁺[k] = M x̂⁻ + Kg h(x)
    − Kg d + Kg v`` is one more polynomial map of ``z[k]`` and ``v[k]``: its moments give
    ``E(x[k] − x̂⁺[k])²`` (per component) at k = 0 .. steps − 1, the steps of ``run``.

    ``coefficients(k) -> (Kg (n, m), b1 (m, n), d (m,), a1 (n, n), e (n,))``. The noises are
    Gaussian with covariances ``model.Q``, ``model.R`` unless ``noise_moment`` gives
    ``E[w^α v^β]`` on ``(r + m)``-multi-indices. For a linear Gaussian model every moment set is
    closed, so the result is exact (the Kalman filter's Riccati P⁺[k] for its gains).
    ``solution`` holds the moments of ``(x[k], x̂⁺[k])``.
    """
    if getattr(model, "kind", None) != "discrete" or getattr(model, "sym", None) is None:
        raise TypeError(f"model: expected a DiscreteModel stated in SymPy, got {type(model).__name__}")
    closure, order = _closure_and_order(closure, order)
    V.positive("steps", steps, integer=True)
    n, mm, r = model.n, model.m, model.r
    m0, P0 = _prior(n, m0, P0, definite=False)  # no linearization here: a known x[0] is fine
    xh0 = m0 if xhat0 is None else V.as_float_array("xhat0", xhat0, shape_tail=(n,)).reshape(n)
    if noise_moment is None:
        for nm in ("process_noise", "measurement_noise"):
            law = getattr(model, nm)
            if not isinstance(law, Gaussian):
                raise ValueError(f"model: its {nm} is {type(law).__name__}, not Gaussian; pass noise_moment "
                                 "(E[w^α v^β]) for the off-line analysis")
        QR = np.zeros((r + mm, r + mm))
        QR[:r, :r], QR[r:, r:] = model.Q, model.R
        noise_moment = gaussian_noise_moments(QR)
    elif not callable(noise_moment):
        raise TypeError(f"noise_moment: expected a callable β -> E[w^α v^β], got {type(noise_moment).__name__}")
    st = list(model.states)
    xh = sp.Matrix([sp.Symbol(f"xhat_{i}") for i in range(n)])
    z = st + list(xh)
    h = sp.Matrix(model.sym["h"])
    poly = lambda e: Polynomial.from_sympy(e, z)  # noqa: E731

    def pmap(f, G, moment):
        return PolynomialMap(tuple(poly(e) for e in f), tuple(tuple(poly(G[i, a]) for a in range(G.shape[1]))
                                                              for i in range(2 * n)), moment, time=model.time,
                             states=tuple(z))

    idx = monomials(2 * n, order, min_degree=1)
    # the prior pair, k -> k + 1: F = a1 M, L = a1 Kg, u = e − a1 Kg d
    Fs, Ls, us = _symbols("F", n, n), _symbols("L", n, mm), _symbols("u", n)
    Gz = sp.zeros(2 * n, r + mm)
    Gz[:n, :r], Gz[n:, r:] = model.sym["G"], Ls
    prior = discrete_moment_equations(pmap(list(model.sym["f"]) + list(Fs * xh + Ls * h + us), Gz, noise_moment),
                                      idx)
    # the estimate at k: (x, x̂⁻) -> (x, x̂⁺), x̂⁺ = M x̂⁻ + Kg h(x) + c + Kg v, c = −Kg d
    Ms, Ks, cs = _symbols("M", n, n), _symbols("Kg", n, mm), _symbols("c", n)
    Gv = sp.zeros(2 * n, mm)
    Gv[n:, :] = Ks
    post = discrete_moment_equations(pmap(st + list(Ms * xh + Ks * h + cs), Gv,
                                          lambda b: noise_moment((0,) * r + tuple(b))), idx)

    def table(k):
        Kg, b1, d, a1, e = (np.asarray(c, dtype=float) for c in coefficients(int(k)))
        M = np.eye(n) - Kg @ b1
        return {"F": a1 @ M, "L": a1 @ Kg, "u": e - a1 @ Kg @ d, "M": M, "Kg": Kg, "c": -Kg @ d}

    values = _tabulated(table, {"F": (n, n), "L": (n, mm), "u": (n,), "M": (n, n), "Kg": (n, mm), "c": (n,)})
    cov0 = np.zeros((2 * n, 2 * n))
    cov0[:n, :n] = P0  # x̂⁻[0] is known exactly
    mu = iterate(prior, gaussian_moments(np.concatenate([m0, xh0]), cov0, idx), steps - 1,
                 closure=closure if prior.missing else None, values=values).values
    nu = closure(idx, mu, post.missing) if post.missing else None
    out = np.stack([post.rhs(mu[k], None if nu is None else nu[k], k, values) for k in range(steps)])
    sol = MomentSolution(np.arange(steps, dtype=float), out, post, closure)
    return ErrorAnalysis(sol.t, _mse(sol, n), sol)
