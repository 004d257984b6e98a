"""The off-line accuracy of ANY filter with precomputed gains: the moments of the joint process
(x, x̂) of the signal and the filter's affine recursion (seed 003 Fig. 2; the library's extension
to discrete time), for the quasilinear filters (:mod:`.quasilinear`, ``error_analysis``) and any
other schedule of gains (e.g. the optimal linear filter of a bilinear system written as an
:class:`~nlfilter.models.SDEModel`: see tests/filters/test_offline.py, which checks it against the
stationary moments of :func:`~nlfilter.filters.bilinear.joint_process`).

:func:`joint_sde` builds the joint SDE of a signal and an affine filter (here, and for the bilinear
post-processors' :func:`~nlfilter.filters.post_processors.joint_process`, seed 001 §3.3).
One function, :func:`gain_error_analysis`, for both time kinds (the model's), with ``run``'s
length convention: T rows, row k ↔ ``Estimates.means[..., k, :]`` (continuous: the state at
``t0 + (k + 1) dt``; discrete: the state measured by ``ys[k]``); the prior row (the MSE of the
filter's initial estimate) is the separate field ``ErrorAnalysis.prior``, the same for both kinds.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np
import sympy as sp

from .. import _validate as V
from ..moments.closures import Closure, EdgeworthClosure, gaussian_moments, kept_order
from ..moments.discrete import PolynomialMap, discrete_moment_equations, gaussian_noise_moments
from ..moments.ito import PolynomialSDE, _symbolic, moment_equations
from ..moments.solve import MomentSolution, iterate, propagate
from ..noise import Gaussian
from ..polynomials import Polynomial, add_exp, monomials, unit_exp

__all__ = ["ErrorAnalysis", "gain_error_analysis", "joint_sde", "MAX_ANALYSIS_MOMENTS"]

#: Most moments of the joint process (x, x̂) an error analysis keeps: ``C(2n + order, order) − 1``
#: for the monomials of degree 1..order in 2n variables. The equations are expanded symbolically
#: in the gains (``Kg_i_j`` ...), a cost that grows steeply with the order: for a scalar cubic
#: model order 10 (65 moments) takes ~5 s, order 14 (119) ~30 s. 120 allows order 14 for n = 1,
#: 4 for n = 2, 3 for n = 3.
MAX_ANALYSIS_MOMENTS = 120


_DEFINITE = 1e-12  # relative floor of the prior's smallest variance (_prior)


def _prior(n, m0, P0, *, definite: bool = True):
    """One prior ``(m0 (n,), P0 (n, n))`` for all paths (the off-line gains depend on it); P0
    positive definite when ``definite`` (the statistical linearization inverts it)."""
    given = np.shape(m0)
    m0 = V.as_float_array("m0", m0).reshape(-1) if np.ndim(m0) else V.mean("m0", m0, n)
    if m0.shape != (n,):
        raise ValueError(f"m0: the off-line gains need one prior mean of shape ({n},) for all paths, "
                         f"got shape {given}")
    V.finite("m0", m0)
    P0 = V.covariance("P0", P0, n)
    w = np.linalg.eigvalsh(P0)
    low = float(w[0])
    # a1 = E[f (x − m)ᵀ] K⁻¹ (003 eqs. 4-5) needs K(t0) = P0 invertible, and K is recomputed from the
    # raw moments (K = E xxᵀ − m mᵀ): below 1e-12 of E|x|² it is lost to cancellation
    floor = _DEFINITE * float(m0 @ m0 + w[-1])
    if definite and not low > floor:
        raise ValueError(f"P0: the statistical linearization (003 eqs. 4-5) needs a positive definite prior "
                         f"covariance (smallest eigenvalue > {_DEFINITE:g} · (|m0|² + largest) = {floor:.3g}), "
                         f"got smallest eigenvalue {low:.3g}")
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
        xi, hi = unit_exp(2 * n, i), unit_exp(2 * n, n + i)
        mse[:, i] = (sol.moment(unit_exp(2 * n, i, 2)) - 2 * sol.moment(add_exp(xi, hi))
                     + sol.moment(unit_exp(2 * n, n + i, 2)))
    return mse



@dataclass
class ErrorAnalysis:
    """Off-line accuracy, with ``run``'s length convention for both time kinds: T rows, row k ↔
    ``Estimates.means[..., k, :]`` (continuous: the state at ``t0 + (k + 1) dt``; discrete: the
    state measured by ``ys[k]``, ``start="update"``).

    ``t (T,)`` the times (discrete: the step indices 0 .. T − 1); ``mse (T, n)`` = E(x − x̂)² per
    component; ``prior (n,)`` the MSE of the filter's initial estimate ``xhat0`` (continuous: x̂(t0);
    discrete: x̂⁻[0]), ``diag P0 + (m0 − xhat0)²``, the row before the first (the same for both
    kinds); ``solution`` the joint moments of ``(x, x̂)`` on the T rows."""

    t: np.ndarray
    mse: np.ndarray
    prior: np.ndarray
    solution: object


def _is_num_zero(c) -> bool:
    return not isinstance(c, sp.Basic) and float(c) == 0.0


def joint_sde(base: PolynomialSDE, xhat, F, u, Kg, innovation, noise, noise_cov=None, *, names=None,
              tol: float = 0.0) -> PolynomialSDE:
    """The joint Itô SDE of a signal and an affine filter of its measurements, the one builder of
    the off-line analyses (seed 003 Fig. 2: the QLF's (x, x̂); seed 001 §3.3, eq. 3.30: a bilinear
    system and its linear filter, :func:`~nlfilter.filters.post_processors.joint_process`)::

        dx   = f(x) dt + G(x) dβ                                        (``base``, with noise columns)
        dx̂_j = [Σ_k F_jk x̂_k + u_j + Σ_i Kg_ji ι_i] dt + Σ_l N_jl dw_l,  E dw dwᵀ = noise_cov dt

    in the variables (base variables, then one per row of ``F``), w independent of β.
    ``xhat``: the K estimate coordinates x̂_k as polynomials in the joint variables (a variable, or a
    constant for a deterministic coordinate); ``F (J, K)``, ``u (J,)`` (or None), ``Kg (J, m)``:
    numbers or SymPy symbols (coefficients tabulated over time); ``innovation``: the m polynomials
    ι_i whose Kg-combination drives x̂ (h(x) for ``Kg dy``; H (z(x) − ẑ) in innovation form);
    ``noise (J, r_e)``: the polynomial columns N of the estimate's noise, ``noise_cov`` their
    covariance (default I). Numeric zero coefficients are skipped; ``tol`` cleans each drift row."""
    nb = base.n
    J = len(F)
    nv = nb + J
    if base.noise is None:
        raise ValueError("base: the joint SDE needs the signal's noise columns (PolynomialSDE.from_noise)")
    zero = Polynomial({}, nv)
    drift = [p.pad(nv) for p in base.drift]
    for j in range(J):
        acc = zero
        for k, xk in enumerate(xhat):
            if not _is_num_zero(F[j][k]):
                acc = acc + xk * F[j][k]
        if u is not None and not _is_num_zero(u[j]):
            acc = acc + u[j]
        for i, io in enumerate(innovation):
            if not _is_num_zero(Kg[j][i]):
                acc = acc + io * Kg[j][i]
        drift.append(acc.clean(tol))
    rb, re = base.r, len(noise[0]) if J else 0
    G = [[base.noise[i][a].pad(nv) for a in range(rb)] + [zero] * re for i in range(nb)]
    G += [[zero] * rb + [noise[j][l] for l in range(re)] for j in range(J)]
    Qb = base.noise_cov
    Qe = np.eye(re) if noise_cov is None else noise_cov
    if isinstance(Qe, sp.MatrixBase) or _symbolic(Qe):
        Q = sp.diag(sp.Matrix(np.asarray(Qb).tolist()), sp.Matrix(Qe))
    else:
        Q = np.zeros((rb + re, rb + re))
        Q[:rb, :rb], Q[rb:, rb:] = Qb, Qe
    return PolynomialSDE.from_noise(drift, G, Q, time=base.time, names=names)


def _closure_and_order(closure, order):
    """The error analyses' pair: Edgeworth of ``order`` (default 4) when no closure is given, else
    ``closure`` with :func:`~nlfilter.moments.closures.kept_order` (its own order by default)."""
    if closure is None:
        if order is None:
            order = 4
        if isinstance(order, bool) or not isinstance(order, int) or order < 2:
            raise ValueError(f"order: expected an integer ≥ 2 (the MSE needs second moments), got {V.shown(order)}")
        return EdgeworthClosure(order), order
    return closure, kept_order(closure, order)


def gain_error_analysis(model, coefficients, m0, P0, steps: int, *, dt: float | None = None, t0: float = 0.0,
                        xhat0=None, closure: Closure | None = None, order: int | None = None,
                        noise_moment=None) -> ErrorAnalysis:
    """Off-line accuracy of ANY filter with precomputed gains on a polynomial model: the raw
    moments of the joint process ``(x, x̂)`` of the signal and the filter's affine recursion up to
    ``order``, closed by ``closure`` (default Edgeworth of that order, as seed 003 Fig. 2; with a
    closure and no ``order`` the order is the closure's, an ``order`` below it is a ``ValueError``),
    give ``E(x − x̂)²`` on the ``steps`` rows of ``run`` (:class:`ErrorAnalysis`). The time kind is
    the model's; ``x(t0) ~ N(m0, P0)`` (discrete: ``x[0]``), the filter starts at ``xhat0``
    (default ``m0``, known exactly).

    Continuous (:class:`~nlfilter.models.SDEModel`, ``dt`` required, rows at ``t0 + (k + 1) dt``):
    the filter ``dx̂ = [F(t) x̂ + u(t)] dt + Kg(t) dy`` (003 eq. 16 for the QLF's coefficients
    ``F = a1 − Kg b1``, ``u``, ``Kg = P b1ᵀ R⁻¹`` of eqs. 4-8), ``coefficients(t) -> (F (n, n),
    u (n,), Kg (n, m))``; the joint polynomial SDE ``dx = f dt + G dβ``, ``dx̂ = [F x̂ + u + Kg h(x)]
    dt + Kg dη`` has the moment equations of 003 eq. 11 (Itô's rule on the monomials of (x, x̂)).
    For a linear model and the Kalman-Bucy gain this is the Riccati solution (exact).

    Discrete (:class:`~nlfilter.models.DiscreteModel` ``x[k+1] = f(x) + G(x) w``, ``y = h(x) + v``;
    the library's extension: seed 003 is continuous), update then predict (``start="update"``)::

        x̂⁺[k]   = x̂⁻[k] + Kg[k] (y[k] − b1[k] x̂⁻[k] − d[k])
        x̂⁻[k+1] = a1[k] x̂⁺[k] + e[k],          x̂⁻[0] = xhat0

    ``coefficients(k) -> (Kg (n, m), b1 (m, n), d (m,), a1 (n, n), e (n,))``. With ``M = I − Kg b1``
    the prior pair ``(x[k], x̂⁻[k])`` is a polynomial map driven by the independent ``(w, v)``
    (``x̂⁻' = a1 M x̂⁻ + a1 Kg h(x) + e − a1 Kg d + a1 Kg v``), whose moments follow from
    :func:`~nlfilter.moments.discrete.discrete_moment_equations` (003 eq. 11 in discrete form);
    row k is one more map, ``x̂⁺ = M x̂⁻ + Kg h(x) − Kg d + Kg v``. The noises are Gaussian with
    ``model.Q``, ``model.R`` unless ``noise_moment`` gives ``E[w^α v^β]`` on ``(r + m)``-multi-indices
    (discrete only). A linear Gaussian model closes every moment set: the Kalman filter's P⁺[k].

    An ``order`` whose joint system would exceed :data:`MAX_ANALYSIS_MOMENTS` (120) moments is a
    ``ValueError`` naming ``order``, raised before anything is built (``C(2n + order, order) − 1``
    moments: order ≤ 14 for n = 1, ≤ 4 for n = 2).
    """
    kind = getattr(model, "kind", None)
    if kind not in ("sde", "discrete") or getattr(model, "sym", None) is None:
        raise TypeError(f"model: expected an SDEModel or DiscreteModel stated in SymPy, got {type(model).__name__}")
    if not callable(coefficients):
        raise TypeError(f"coefficients: expected a callable of the time (index), got {type(coefficients).__name__}")
    closure, order = _closure_and_order(closure, order)
    V.positive("steps", steps, integer=True)
    n = model.n
    size = comb(2 * n + order, order) - 1
    if size > MAX_ANALYSIS_MOMENTS:
        raise ValueError(f"order: expected an order whose joint moment system (monomials of degree 1..order of the "
                         f"{2 * n} variables (x, x̂)) has at most {MAX_ANALYSIS_MOMENTS} moments, got order={order} "
                         f"with {size}; lower the order")
    m0, P0 = _prior(n, m0, P0, definite=False)  # no linearization here: a known x(t0) is fine
    t0 = V.real("t0", t0)
    xh0 = m0 if xhat0 is None else V.as_float_array("xhat0", xhat0, shape_tail=(n,)).reshape(n)
    V.finite("xhat0", xh0)
    idx = monomials(2 * n, order, min_degree=1)
    cov0 = np.zeros((2 * n, 2 * n))
    cov0[:n, :n] = P0  # x̂ starts known exactly
    mu0 = gaussian_moments(np.concatenate([m0, xh0]), cov0, idx)
    if kind == "sde":
        if dt is None:
            raise ValueError("dt: the continuous analysis reports run's grid t0 + (k + 1) dt; pass its step dt")
        V.positive("dt", dt)
        if isinstance(t0, bool) or not np.isfinite(t0):
            raise ValueError(f"t0: expected a finite start time, got {t0!r}")
        if noise_moment is not None:
            raise ValueError("noise_moment: only the discrete analysis takes noise moments (an SDE's noise is "
                             "Gaussian)")
        sol = _continuous(model, coefficients, mu0, idx, t0 + dt * np.arange(steps + 1), closure)
        t_prior = float(t0)
    else:
        if dt is not None or t0 != 0.0:
            raise ValueError(f"dt, t0: a discrete model is indexed by the step k = 0 .. steps − 1, got dt={dt!r}, "
                             f"t0={t0!r}")
        sol = _discrete(model, coefficients, mu0, idx, steps, closure, noise_moment)
        t_prior = -1.0
    prior = _mse(MomentSolution(np.array([t_prior]), mu0[None], sol.eqs, closure), n)[0]
    return ErrorAnalysis(sol.t, _mse(sol, n), prior, sol)


def _continuous(model, coefficients, mu0, idx, t, closure) -> MomentSolution:
    """The joint SDE (:func:`joint_sde`) of ``x`` and ``dx̂ = [F x̂ + u + Kg h(x)] dt + Kg dη``
    (coefficients as symbols ``F_i_j``, ``u_i``, ``Kg_i_j``, and ``S_i_j`` = Kg R Kgᵀ the covariance
    of the noise ``Kg dη``, tabulated from ``coefficients``), its moments over ``t`` (003 eq. 11);
    the T rows after ``t[0]``."""
    n, mm = model.n, model.m
    st = list(model.states)
    base = PolynomialSDE.from_sympy(st, model.sym["f"], G=model.sym["G"], Q=model.Q, time=model.time)
    nv = 2 * n
    xhat = [Polynomial.variable(n + i, nv) for i in range(n)]
    h = [Polynomial.from_sympy(e, st, name=f"h[{i}]").pad(nv) for i, e in enumerate(model.sym["h"])]
    Fs, us, Ks = _symbols("F", n, n), _symbols("u", n), _symbols("Kg", n, mm)
    Ss = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"S_{min(i, j)}_{max(i, j)}"))  # Kg R Kgᵀ
    unit = [[Polynomial.constant(float(i == j), nv) for j in range(n)] for i in range(n)]
    joint = joint_sde(base, xhat, Fs.tolist(), list(us), Ks.tolist(), h, unit, Ss,
                      names=[*map(str, st), *(f"xhat_{i}" for i in range(n))])
    eqs = moment_equations(joint, idx)
    R = model.R

    def table(tt):
        F, u, Kg = coefficients(tt)
        return {"F": F, "u": u, "Kg": Kg, "S": Kg @ R @ Kg.T}

    values = _tabulated(table, {"F": (n, n), "u": (n,), "Kg": (n, mm), "S": (n, n)})
    sol = propagate(eqs, mu0, t, closure=closure, values=values, rtol=1e-8, atol=1e-11)
    return MomentSolution(sol.t[1:], sol.values[..., 1:, :], sol.eqs, sol.closure)


def _discrete(model, coefficients, mu0, idx, steps, closure, noise_moment) -> MomentSolution:
    """The prior pair ``(x[k], x̂⁻[k])`` iterated over k (discrete 003 eq. 11), then the estimate
    map ``(x, x̂⁻) -> (x, x̂⁺)`` at every k: the moments of ``(x[k], x̂⁺[k])``, k = 0 .. steps − 1."""
    n, mm, r = model.n, model.m, model.r
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
    mu = iterate(prior, mu0, steps - 1, closure=closure if prior.missing else None, values=values).values
    nu = closure(idx, mu, post.missing) if post.missing else None
    out = np.stack([post.rhs(mu[k], None if nu is None else nu[k], k, values) for k in range(steps)])
    return MomentSolution(np.arange(steps, dtype=float), out, post, closure)
