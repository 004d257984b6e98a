"""Solutions of moment equations: transient (``solve_ivp``), discrete iteration, steady states.

* :func:`propagate` — ``dμ/dt = A(t) μ + B(t) ν(μ) + c(t)`` by :func:`scipy.integrate.solve_ivp`
  (stiff-capable ``LSODA`` by default; the sparse ``A`` is the Jacobian of a closed constant
  system). A variance that turns negative or a moment that blows up raises
  :class:`~nlfilter.errors.ClosureDivergedError` naming the time and the moment.
* :func:`iterate` — ``μ[k+1] = A μ[k] + B ν[k] + c`` (discrete time).
* :func:`steady_state` — the stationary moments by a *direct* sparse solve of ``A μ + c = 0``
  (continuous) or ``(A − I) μ + c = 0`` (discrete) with the constant moment ``E[1] = 1``; with a
  closure, damped Newton on ``A μ + B ν(μ) + c = 0`` with the exact
  Jacobian ``A + B ∂ν/∂μ`` (forward-mode derivative of the compiled closure). Never by integrating to t = ∞.
  Given ``initial`` or ``scale`` (or when the direct solve is singular), it uses
  :func:`~nlfilter.moments.stationary.linear_steady_state`.

The exact steady state of closed linear systems with conservation laws (:func:`linear_steady_state`,
:func:`gaussian_scale`, :func:`stationary_moments`) lives in :mod:`nlfilter.moments.stationary`
and is still importable from here.

>>> import sympy as sp
>>> from nlfilter.moments import PolynomialSDE, moment_equations, monomials
>>> x = sp.Symbol("x")
>>> eq = moment_equations(PolynomialSDE.from_sympy([x], f=[-x], sigma=[[2]]), monomials(1, 4, min_degree=1))
>>> steady_state(eq).round(12).tolist()       # stationary N(0, 1): 0, 1, 0, 3
[0.0, 1.0, 0.0, 3.0]
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
from scipy.integrate import solve_ivp

from .. import _validate as V
from ..errors import ClosureDivergedError, NoStationaryLawError, SingularSystemError
from ..polynomials import add_exp, monomial_name, unit_exp
from .closures import Closure
from .equations import MomentEquations
from .stationary import (describe_mode, gaussian_scale, linear_steady_state, moment_space_violation,
                         nondecaying_modes, stationary_moments)

__all__ = ["propagate", "iterate", "steady_state", "linear_steady_state", "stationary_moments", "gaussian_scale",
           "MomentSolution", "variance_positions"]


BLOWUP = 1e12


def variance_positions(eqs: MomentEquations):
    """``[(i, pos of E x_i, pos of E x_i²)]`` for every state whose first two moments are kept."""
    n = len(eqs.indices[0])
    out = []
    for i in range(n):
        a, b = unit_exp(n, i), unit_exp(n, i, 2)
        if a in eqs.index and b in eqs.index:
            out.append((i, eqs.index[a], eqs.index[b]))
    return out


def _check_closure(eqs, closure):
    if eqs.missing and closure is None:
        raise ValueError(f"closure: the moment system is not closed ({len(eqs.missing)} missing moments, "
                         f"first {eqs.missing[:3]}); pass a closure (GaussianClosure(), EdgeworthClosure(4) ...)")
    if closure is not None and not isinstance(closure, Closure):
        raise TypeError(f"closure: expected a Closure instance, got {type(closure).__name__}")


@dataclass
class MomentSolution:
    """Moments over time: ``t (T,)``, ``values (..., T, K)`` in the order of ``eqs.indices``."""

    t: np.ndarray
    values: np.ndarray
    eqs: MomentEquations
    closure: Closure | None = None

    def moment(self, gamma) -> np.ndarray:
        """``E[x^γ]`` over time, kept or (through the closure) missing: ``(..., T)``."""
        gamma = tuple(gamma)
        if gamma in self.eqs.index:
            return self.values[..., self.eqs.index[gamma]]
        if self.closure is None:
            raise ValueError(f"gamma: {gamma} is not a kept moment and no closure was used")
        return self.closure(self.eqs.indices, self.values, [gamma])[..., 0]

    def mean(self) -> np.ndarray:
        n = len(self.eqs.indices[0])
        return np.stack([self.moment(unit_exp(n, i)) for i in range(n)], axis=-1)

    def cov(self) -> np.ndarray:
        n = len(self.eqs.indices[0])
        m = self.mean()
        out = np.empty((*m.shape, n))
        for i in range(n):
            for j in range(n):
                e = add_exp(unit_exp(n, i), unit_exp(n, j))
                out[..., i, j] = self.moment(e) - m[..., i] * m[..., j]
        return out


def _nu(eqs, closure, mu):
    if not eqs.missing:
        return None
    return closure(eqs.indices, mu, eqs.missing)


def _diagnose(eqs, mu, t):
    """Raise ClosureDivergedError when μ is non-finite, huge, or a variance is negative."""
    mu = np.asarray(mu)
    bad = ~np.isfinite(mu) | (np.abs(mu) > BLOWUP)
    if bad.any():
        k = int(np.flatnonzero(bad.reshape(-1, mu.shape[-1]).any(axis=0))[0])
        raise ClosureDivergedError(f"moments: E[x^{eqs.indices[k]}] blew up (|value| > {BLOWUP:g} or "
                                   f"non-finite) at t = {t:.6g}", time=float(t), moment=eqs.indices[k])
    for i, p1, p2 in variance_positions(eqs):
        var = mu[..., p2] - mu[..., p1] ** 2
        scale = np.maximum(1.0, np.abs(mu[..., p2]))
        if np.any(var < -1e-9 * scale):
            raise ClosureDivergedError(f"moments: the variance of x_{i + 1} turned negative "
                                       f"({float(np.min(var)):.3g}) at t = {t:.6g}", time=float(t),
                                       moment=eqs.indices[p2])


def propagate(eqs: MomentEquations, mu0, t_eval, *, closure: Closure | None = None, t0: float | None = None,
              values=None, method: str = "LSODA", rtol: float = 1e-8, atol: float = 1e-10) -> MomentSolution:
    """Integrate the moment equations from ``mu0 (K,)`` at ``t0`` (default ``t_eval[0]``) and
    return the moments at ``t_eval``.

    ``values``: the coefficient symbols other than time ({symbol or name: number or callable of t}).
    Raises :class:`ClosureDivergedError` when a variance turns negative or a moment blows up, and
    ``ValueError`` up front for non-finite ``t_eval``, ``t0`` or ``mu0`` (a NaN time would send
    the integrator on an endless run) or ``t0 > t_eval[0]``.
    """
    if eqs.kind != "continuous":
        raise ValueError(f"eqs: expected continuous-time moment equations, got {eqs.kind}; use iterate()")
    _check_closure(eqs, closure)
    V.positive("rtol", rtol)
    V.positive("atol", atol)
    t_eval = V.as_float_array("t_eval", t_eval, ndim=1)
    V.finite("t_eval", t_eval)
    if t_eval.size == 0 or np.any(np.diff(t_eval) < 0):
        raise ValueError("t_eval: expected a non-empty non-decreasing array of times")
    mu0 = V.as_float_array("mu0", mu0, shape_tail=(len(eqs.indices),))
    if mu0.ndim != 1:
        raise ValueError(f"mu0: expected shape ({len(eqs.indices)},), got {mu0.shape}")
    V.finite("mu0", mu0)
    if t0 is not None:
        if isinstance(t0, bool) or not isinstance(t0, numbers.Real) or not np.isfinite(t0):
            raise ValueError(f"t0: expected a finite start time, got {t0!r}")
        if t0 > t_eval[0]:
            raise ValueError(f"t0: expected a start time ≤ t_eval[0] = {t_eval[0]:.6g}, got {t0!r}")
    t0 = float(t_eval[0]) if t0 is None else float(t0)

    def rhs(t, mu):
        return eqs.rhs(mu, _nu(eqs, closure, mu), t, values)

    events = []
    for i, p1, p2 in variance_positions(eqs):
        def ev(t, mu, p1=p1, p2=p2):
            return mu[p2] - mu[p1] ** 2 + 1e-12 * max(1.0, abs(mu[p2]))
        ev.terminal, ev.direction = True, -1
        events.append(ev)

    def blow(t, mu):
        return BLOWUP - np.max(np.abs(mu))
    blow.terminal, blow.direction = True, -1
    events.append(blow)
    kw = {}
    if eqs.constant and eqs.closed and method in ("BDF", "Radau"):
        kw["jac"] = eqs.A
    elif eqs.constant and eqs.closed and method == "LSODA" and len(eqs.indices) <= 2000:
        Ad = eqs.A.toarray()
        kw["jac"] = lambda t, mu: Ad  # LSODA takes a dense Jacobian, as a callable
    span = (t0, float(t_eval[-1]))
    if span[1] == span[0]:
        return MomentSolution(t_eval.copy(), np.repeat(mu0[None], t_eval.size, 0), eqs, closure)
    try:
        sol = solve_ivp(rhs, span, mu0, t_eval=t_eval, method=method, rtol=rtol, atol=atol, events=events, **kw)
    except (FloatingPointError, OverflowError) as exc:
        raise ClosureDivergedError(f"moments: integration failed ({exc})", time=None) from exc
    if sol.status == 1:
        vp = variance_positions(eqs)
        which = next(i for i, e in enumerate(sol.t_events) if len(e))
        te, ye = float(sol.t_events[which][0]), sol.y_events[which][0]
        if which < len(vp):  # a variance event: name E[x_i²]
            i, p1, p2 = vp[which]
            raise ClosureDivergedError(f"moments: the variance of x_{i + 1} reached zero (E[x^{eqs.indices[p2]}] = "
                                       f"{ye[p2]:.6g}, mean {ye[p1]:.6g}) at t = {te:.6g}; the closure failed",
                                       time=te, moment=eqs.indices[p2])
        k = int(np.argmax(np.abs(ye)))
        raise ClosureDivergedError(f"moments: E[x^{eqs.indices[k]}] blew up (|value| > {BLOWUP:g}) at t = {te:.6g}",
                                   time=te, moment=eqs.indices[k])
    if sol.status != 0:
        raise ClosureDivergedError(f"moments: integration failed at t = {sol.t[-1] if sol.t.size else t0:.6g}: "
                                   f"{sol.message}", time=float(sol.t[-1]) if sol.t.size else t0)
    vals = sol.y.T
    for k, t in enumerate(sol.t):
        _diagnose(eqs, vals[k], t)
    return MomentSolution(sol.t, vals, eqs, closure)


def iterate(eqs: MomentEquations, mu0, steps: int, *, closure: Closure | None = None, k0: int = 0,
            values=None) -> MomentSolution:
    """Discrete moment recursion ``μ[k+1] = A μ[k] + B ν[k] + c`` for ``steps`` steps from
    ``mu0 (..., K)``; returns ``values (..., steps + 1, K)``."""
    if eqs.kind != "discrete":
        raise ValueError(f"eqs: expected discrete-time moment equations, got {eqs.kind}; use propagate()")
    _check_closure(eqs, closure)
    V.positive("steps", steps, integer=True, strict=False)
    mu = V.as_float_array("mu0", mu0, shape_tail=(len(eqs.indices),))
    out = [mu]
    for k in range(steps):
        mu = eqs.rhs(mu, _nu(eqs, closure, mu), k0 + k, values)
        _diagnose(eqs, mu, k0 + k + 1)
        out.append(mu)
    return MomentSolution(np.arange(k0, k0 + steps + 1, dtype=float), np.stack(out, axis=-2), eqs, closure)


def _rank_message(M):
    dense = M.toarray() if sps.issparse(M) else np.asarray(M)
    if dense.shape[0] <= 3000:
        return f"rank {np.linalg.matrix_rank(dense)} of {dense.shape[0]}"
    return f"size {dense.shape[0]}"


def steady_state(eqs: MomentEquations, *, closure: Closure | None = None, guess=None, t=None, values=None,
                 tol: float = 1e-12, maxfev: int = 200, initial=None, scale=None) -> np.ndarray:
    """Stationary moments ``μ (K,)`` (order of ``eqs.indices``).

    Closed system: a direct sparse LU solve of ``A μ = −c`` (continuous) or ``(A − I) μ = −c``
    (discrete); the row of the constant monomial, if kept, becomes ``E[1] = 1``. A singular system
    raises :class:`~nlfilter.errors.SingularSystemError` with its rank. With ``initial`` (moments
    at t = 0, ``γ -> E[x^γ]``) or ``scale`` (typical magnitudes), a closed continuous system
    without the constant monomial is solved by :func:`linear_steady_state` instead: rescaled, and
    with the conserved combinations of moments fixed from ``initial``. With a closure: damped
    Newton from ``guess`` (default: the moments of N(0, I)) with the exact Jacobian.

    No moments of a law that does not exist: :class:`~nlfilter.errors.NoStationaryLawError` (a
    ``ValueError``) when

    * the closed moment equations have a mode that does not decay (continuous: an eigenvalue of
      ``A`` with real part ≥ 0 other than an exactly conserved 0; discrete: of modulus ≥ 1 other
      than 1), checked before solving and naming the eigenvalue and its moments — ``dx = x dt + dβ``
      has "eigenvalue +1 on E[x1] (the drift's linear part)"; with a closure, when the Jacobian
      ``A + B ∂ν/∂μ`` at the solution has such a mode (the fixed point repels);
    * the solution is not a moment sequence: a negative even moment, a covariance or moment
      (Hankel) matrix that is not positive semi-definite
      (:func:`~nlfilter.moments.stationary.moment_space_violation`).
    """
    _check_closure(eqs, closure)
    A, B, c = eqs.at(t, values)
    K = len(eqs.indices)
    zero = (0,) * len(eqs.indices[0])
    names = [f"x{i + 1}" for i in range(len(zero))]
    if eqs.closed:
        _check_stable(eqs, A, names)
    if (initial is not None or scale is not None) and eqs.closed and eqs.kind == "continuous":
        if zero in eqs.index:
            raise ValueError("initial, scale: only for systems without the constant monomial in eqs.indices")
        mu = linear_steady_state(A, c, indices=eqs.indices, initial=initial, scale=scale)
        return _check_result(eqs, mu, names, "eqs")
    M = sps.csr_matrix(A, dtype=float)
    if eqs.kind == "discrete":
        M = M - sps.identity(K, format="csr")
    rhs = -np.asarray(c, dtype=float)
    if zero in eqs.index:
        r = eqs.index[zero]
        M = M.tolil()
        M[r, :] = 0.0
        M[r, r] = 1.0
        M = M.tocsr()
        rhs[r] = 1.0
        cvec_scale = np.ones(K)
        cvec_scale[r] = 0.0
    else:
        cvec_scale = np.ones(K)
    if eqs.closed:
        try:
            lu = spla.splu(M.tocsc())
        except RuntimeError as exc:
            why = ("the stationary moments are not unique (no stationary law, or a conserved quantity: "
                   "pass initial=<moments at t = 0>)")
            if eqs.kind == "continuous" and zero not in eqs.index:  # name the conserved or drifting combination
                names = [f"x{i + 1}" for i in range(len(zero))]
                try:
                    mu = linear_steady_state(A, c, indices=eqs.indices,
                                             labels=[monomial_name(g, names) for g in eqs.indices])
                except SingularSystemError as diag:
                    why = str(diag)
                else:
                    return _check_result(eqs, mu, names, "eqs")
            raise SingularSystemError(f"eqs: the steady-state system is singular ({_rank_message(M)}); {why}") from exc
        mu = lu.solve(rhs)
        if not np.all(np.isfinite(mu)) or np.linalg.norm(M @ mu - rhs) > 1e-8 * max(1.0, np.linalg.norm(rhs)):
            raise SingularSystemError(f"eqs: the steady-state system is singular or ill-conditioned "
                                      f"({_rank_message(M)})")
        return _check_result(eqs, mu, names, "eqs")
    Bd = B.tocsr()
    Bd = sps.diags(cvec_scale) @ Bd
    if guess is None:
        from .closures import gaussian_moments
        n = len(zero)
        guess = gaussian_moments(np.zeros(n), np.eye(n), eqs.indices)
    x0 = V.as_float_array("guess", guess, shape_tail=(K,))

    def F(mu):
        nu = closure(eqs.indices, mu, eqs.missing)
        return M @ mu + Bd @ nu - rhs

    def J(mu):  # A + B ∂ν/∂μ (sparse), the closure's Jacobian exact by forward mode
        return (M + Bd @ closure.jacobian(eqs.indices, mu, eqs.missing, sparse=True)).tocsc()

    mu, res = _newton(F, J, x0.copy(), tol=tol, maxfev=maxfev)
    if not res < 1e-8 * max(1.0, np.max(np.abs(mu))):
        raise ClosureDivergedError(f"closure: the closed steady-state equations have no solution near the "
                                   f"guess (Newton stopped with residual {res:.3g})", time=np.inf)
    mu = _check_result(eqs, mu, names, "closure")
    # the fixed point must attract: the closed dynamics' Jacobian A + B ∂ν/∂μ has no non-decaying mode
    Jc = sps.csr_matrix(A, dtype=float) + sps.csr_matrix(B) @ closure.jacobian(eqs.indices, mu, eqs.missing,
                                                                              sparse=True)
    _check_stable(eqs, Jc, names, closure=closure)
    return mu


def _check_stable(eqs, A, names, closure=None):
    """Raise NoStationaryLawError when the moment dynamics (``A`` without the constant monomial)
    have a mode that does not decay (exactly conserved modes are left to the singular-system
    diagnosis; with a closure, ``A`` is the Jacobian at the fixed point and none are left out)."""
    zero = (0,) * len(names)
    keep = [i for i, g in enumerate(eqs.indices) if g != zero]
    Ak = sps.csr_matrix(A, dtype=float)[keep][:, keep]
    modes = nondecaying_modes(Ak, [eqs.indices[i] for i in keep], kind=eqs.kind, conserved=closure is None)
    if not modes:
        return
    lam, block = modes[0]
    what = describe_mode(lam, block, names, eqs.kind, linear_part=closure is None)
    if closure is None:
        raise NoStationaryLawError(f"eqs: no stationary law: the {eqs.kind} moment equations have {what}, so "
                                   f"these moments grow (or oscillate) without bound", time=np.inf, moment=block[0])
    raise NoStationaryLawError(f"closure: the steady state of the {closure.name}-closed moment equations is "
                               f"unstable ({what} of their Jacobian): the closed moments do not settle there",
                               time=np.inf, moment=block[0])


def _check_result(eqs, mu, names, who):
    """``mu`` when it is a moment sequence (finite, not blown up, see
    :func:`~nlfilter.moments.stationary.moment_space_violation`), else raise."""
    why = moment_space_violation(eqs.indices, mu, names)
    if why is not None:
        raise NoStationaryLawError(f"{who}: the steady-state solution is not the moments of any law: {why}"
                                   + ("; the closure failed" if who == "closure" else ""), time=np.inf)
    _diagnose(eqs, mu, np.inf)
    return mu


def _newton(F, J, x, *, tol, maxfev):
    """Damped Newton with a reused sparse LU factorisation (refactored when the contraction is slow)."""

    def factor(x):
        try:
            return spla.splu(J(x)).solve
        except RuntimeError as exc:
            raise SingularSystemError(f"closure: the Jacobian of the closed steady-state equations is singular "
                                      f"({exc})") from exc

    f = F(x)
    nrm = np.linalg.norm(f)
    solve, fresh, nfev = factor(x), True, 1
    while nfev < maxfev:
        if not np.isfinite(nrm):
            return x, np.inf
        if nrm <= tol * max(1.0, np.linalg.norm(x)):
            break
        step = solve(f)
        lam = 1.0
        while lam > 1e-6:
            xn = x - lam * step
            fn = F(xn)
            nfev += 1
            nn = np.linalg.norm(fn)
            if np.isfinite(nn) and nn < (1 - 1e-4 * lam) * nrm:
                break
            lam *= 0.5
        else:
            if fresh:
                return x, np.max(np.abs(f))
            solve, fresh = factor(x), True
            continue
        slow = nn > 0.5 * nrm
        x, f, nrm = xn, fn, nn
        if slow:
            solve, fresh = factor(x), True
        else:
            fresh = False
    return x, np.max(np.abs(F(x)))
