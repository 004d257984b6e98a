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
* :func:`linear_steady_state` — the exact steady state of a closed linear system, rescaled, with
  the conservation laws of the dynamics (left null vectors of ``A``) fixed from initial moments
  (seed 001's tensor systems on the circle); :func:`steady_state` uses it when given ``initial``
  or ``scale``;
* :func:`stationary_moments` — ``E[x^γ]`` at rest for given monomials of an SDE whose moment
  hierarchy closes (the closed hull, its equations, then :func:`linear_steady_state`).

>>> import sympy as sp
>>> from nlfilter.moments import PolynomialSDE, moment_equations, monomials
>>> x = sp.Symbol("x")
>>> eq = moment_equations(PolynomialSDE.from_sympy([x], f=[-x], sigma=[[2]]), monomials(1, 4, min_degree=1))
>>> steady_state(eq).round(12).tolist()       # stationary N(0, 1): 0, 1, 0, 3
[0.0, 1.0, 0.0, 3.0]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
from scipy.integrate import solve_ivp
from scipy.sparse.csgraph import connected_components

from .. import _validate as V
from ..errors import ClosureDivergedError, SingularSystemError
from ..polynomials import monomial_name
from .closures import Closure
from .ito import MomentEquations, as_polynomial_sde, closed_hull, moment_equations

__all__ = ["propagate", "iterate", "steady_state", "linear_steady_state", "stationary_moments", "gaussian_scale",
           "MomentSolution", "variance_positions"]

BLOWUP = 1e12


def _unit(n, i, k=1):
    e = [0] * n
    e[i] = k
    return tuple(e)


def variance_positions(eqs: MomentEquations):
    """``[(i, pos of E x_i, pos of E x_i²)]`` for every state whose first two moments are kept."""
    n = len(eqs.indices[0])
    out = []
    for i in range(n):
        a, b = _unit(n, i), _unit(n, i, 2)
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
        return np.stack([self.moment(_unit(n, i)) for i in range(n)], axis=-1)

    def cov(self) -> np.ndarray:
        n = len(self.eqs.indices[0])
        m = self.mean()
        out = np.empty((*m.shape, n))
        for i in range(n):
            for j in range(n):
                e = tuple(a + b for a, b in zip(_unit(n, i), _unit(n, j)))
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
    Raises :class:`ClosureDivergedError` when a variance turns negative or a moment blows up.
    """
    if eqs.kind != "continuous":
        raise ValueError(f"eqs: expected continuous-time moment equations, got {eqs.kind}; use iterate()")
    _check_closure(eqs, closure)
    t_eval = V.as_float_array("t_eval", t_eval, ndim=1)
    if t_eval.size == 0 or np.any(np.diff(t_eval) < 0):
        raise ValueError("t_eval: expected a non-empty non-decreasing array of times")
    mu0 = V.as_float_array("mu0", mu0, shape_tail=(len(eqs.indices),))
    if mu0.ndim != 1:
        raise ValueError(f"mu0: expected shape ({len(eqs.indices)},), got {mu0.shape}")
    V.finite("mu0", mu0)
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
    """
    _check_closure(eqs, closure)
    A, B, c = eqs.at(t, values)
    K = len(eqs.indices)
    zero = (0,) * len(eqs.indices[0])
    if (initial is not None or scale is not None) and eqs.closed and eqs.kind == "continuous":
        if zero in eqs.index:
            raise ValueError("initial, scale: only for systems without the constant monomial in eqs.indices")
        mu = linear_steady_state(A, c, indices=eqs.indices, initial=initial, scale=scale)
        _diagnose(eqs, mu, np.inf)
        return mu
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
                    _diagnose(eqs, mu, np.inf)
                    return mu
            raise SingularSystemError(f"eqs: the steady-state system is singular ({_rank_message(M)}); {why}") from exc
        mu = lu.solve(rhs)
        if not np.all(np.isfinite(mu)) or np.linalg.norm(M @ mu - rhs) > 1e-8 * max(1.0, np.linalg.norm(rhs)):
            raise SingularSystemError(f"eqs: the steady-state system is singular or ill-conditioned "
                                      f"({_rank_message(M)})")
        _diagnose(eqs, mu, np.inf)
        return mu
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


# ---------------------------------------------------------------------------------------------
# closed linear systems: rescaled, conservation-aware exact steady state (seed 001)
# ---------------------------------------------------------------------------------------------
def _equilibrate(A, passes: int = 6):
    """Row and column scalings (powers of two) giving ``Dr A Dc`` entries of max-norm ~1."""
    N = A.shape[0]
    dense = N <= 3000
    absA = np.abs(A.toarray()) if dense else abs(sps.csr_matrix(A))
    dr, dc = np.ones(N), np.ones(N)

    def p2(v):
        return np.where(v > 0, 2.0 ** np.round(np.log2(np.where(v > 0, v, 1.0))), 1.0)

    for _ in range(passes):
        if dense:
            M = absA * dr[:, None] * dc[None, :]
            dr = dr / p2(M.max(axis=1))
            M = absA * dr[:, None] * dc[None, :]
            dc = dc / p2(M.max(axis=0))
        else:
            M = sps.diags(dr) @ absA @ sps.diags(dc)
            dr = dr / p2(M.max(axis=1).toarray().ravel())
            M = sps.diags(dr) @ absA @ sps.diags(dc)
            dc = dc / p2(M.max(axis=0).toarray().ravel())
    return dr, dc


def gaussian_scale(indices, sigma) -> np.ndarray:
    """Typical magnitudes of monomial moments: ``Π_v √((2γ_v − 1)!!) σ_v^{γ_v}`` (the root of
    ``E[(x^γ)²]`` for independent centred Gaussians of standard deviations ``σ``)."""
    sig = np.asarray(sigma, dtype=float)
    out = np.empty(len(indices))
    for k, m in enumerate(indices):
        v = 1.0
        for a, sv in zip(m, sig):
            if a:
                v *= np.sqrt(float(np.prod(np.arange(2 * a - 1, 0, -2, dtype=float)))) * sv ** a
        out[k] = v
    return out


def _eigvals_blockwise(M) -> np.ndarray:
    """Eigenvalues of a sparse ``M`` from the diagonal blocks of its strongly connected
    components: permuted to block-triangular form, its spectrum is the union of theirs (moment
    matrices split by degree, so the blocks are small)."""
    if M.shape[0] <= 64:
        return np.linalg.eigvals(M.toarray())
    ncomp, lab = connected_components(M, directed=True, connection="strong")
    if ncomp == 1:
        return np.linalg.eigvals(M.toarray())
    M = sps.csr_matrix(M)
    order = np.argsort(lab, kind="stable")
    bounds = np.flatnonzero(np.diff(lab[order])) + 1
    out = []
    for idx in np.split(order, bounds):
        out.append(np.linalg.eigvals(M[idx][:, idx].toarray()))
    return np.concatenate(out)


def _describe(vec, labels, k=6):
    order = np.argsort(-np.abs(vec))[:k]
    v = vec / vec[order[0]]
    return " + ".join(f"{v[i]:.3g}·E[{labels[i]}]" for i in order if abs(v[i]) > 1e-8)


def linear_steady_state(A, c, *, indices, initial=None, scale=None, labels=None, tol: float = 1e-9,
                        check_stable: bool = True) -> np.ndarray:
    """Steady state ``μ∞`` of a closed linear moment system ``dμ/dt = A μ + c`` by a direct solve,
    with the conservation laws of the dynamics imposed (seed 001 eqs. 3.8-3.9, 3.13 at rest).

    ``indices``: the moment of each row (a monomial γ, or any hashable key ``initial`` accepts);
    ``labels``: their names for messages (default ``E[x^γ]`` written from ``indices``).

    The moments are first rescaled, ``μ = S ν`` with ``S`` = ``scale`` (typical magnitudes, e.g.
    :func:`gaussian_scale`) or an equilibration, so that the similar matrix ``S⁻¹ A S`` has
    entries of comparable size: moments of high degree differ by many orders of magnitude. Its
    eigenvalues (computed block by block on its strongly connected components) decide: any with
    non-negative real part other than exact zeros -> no finite steady state; ``k`` zero
    eigenvalues -> ``k`` conserved functionals. Nonsingular: LU with row equilibration and
    iterative refinement in extended precision, then a residual check.

    Singular (on the circle ``x1² + x2² = 1`` every ``E[|x|^{2k}]`` is constant, so ``A`` is
    singular and a least-squares or sparse solver may return a finite but wrong answer): the
    conserved functionals ``ℓ_i`` (left null vectors of ``A``, ``d/dt ℓ_iᵀμ = ℓ_iᵀ c``) must satisfy
    ``ℓ_iᵀ c = 0`` (else moments drift linearly) and their values are taken from ``initial``
    (dict or callable ``index -> E[·] at t = 0``); the solution is unique iff ``[A; ℓᵀ]`` has
    full column rank.

    Raises :class:`~nlfilter.errors.SingularSystemError` when there is no steady state or it is
    not unique.

    >>> import scipy.sparse as sps
    >>> linear_steady_state(sps.csr_matrix([[-2.0]]), [2.0], indices=[(2,)]).tolist()   # OU: E x² = 1
    [1.0]
    """
    A0 = sps.csr_matrix(A, dtype=float)
    b0 = np.asarray(c, dtype=float)
    N = A0.shape[0]
    indices = list(indices)
    if A0.shape != (N, N) or b0.shape != (N,) or len(indices) != N:
        raise ValueError(f"A, c, indices: expected shapes (N, N), (N,) and N keys, got {A0.shape}, "
                         f"{b0.shape} and {len(indices)}")
    if labels is None:
        labels = [str(m) for m in indices]
    if N == 0:
        return np.zeros(0)
    if scale is None:
        _, s = _equilibrate(A0)
    else:
        s = np.asarray(scale, dtype=float)
    As = sps.csr_matrix(sps.diags(1.0 / s) @ A0 @ sps.diags(s))  # similar to A
    bs = b0 / s
    rmax = abs(As).max(axis=1).toarray().ravel()
    dr = 1.0 / np.where(rmax > 0, rmax, 1.0)
    Ar = sps.csr_matrix(sps.diags(dr) @ As)
    br = dr * bs
    dense = N <= 3000
    k0 = 0
    if dense:
        ev = _eigvals_blockwise(As)
        escale = max(float(np.max(np.abs(ev))), 1e-300)
        zero = np.abs(ev) <= 1e-8 * escale
        k0 = int(zero.sum())
        if check_stable and np.any(ev.real[~zero] > -tol * escale):
            raise SingularSystemError(
                f"steady_state: the moments grow without bound (eigenvalue {ev.real[~zero].max():.3g} "
                "of the moment matrix has non-negative real part): no finite steady state")
        Ard = Ar.toarray()
    if k0 == 0:
        try:  # sparse LU: the moment matrices are sparse, and small dense LAPACK calls pay for threads
            solve = spla.splu(sps.csc_matrix(Ar)).solve
        except (RuntimeError, np.linalg.LinAlgError, ValueError):
            raise SingularSystemError("steady_state: the moment matrix is singular") from None
        nu = solve(-br)
        Al, bl = (Ard if dense else Ar.toarray()).astype(np.longdouble), br.astype(np.longdouble)
        for _ in range(2):  # iterative refinement, residual in extended precision
            r = -bl - Al @ nu.astype(np.longdouble)
            nu = nu + solve(np.asarray(r, dtype=float))
        res = float(np.linalg.norm(np.asarray(-bl - Al @ nu.astype(np.longdouble), float))) / max(np.linalg.norm(br), 1e-300)
        if not np.all(np.isfinite(nu)) or res > 1e-8:
            raise SingularSystemError(f"steady_state: direct solve inaccurate (relative residual {res:.2g})")
        return s * nu
    U, sv, Vt = np.linalg.svd(Ard)
    Lr = U[:, N - k0:].T  # left null space of Dr S⁻¹ A S
    W = Lr * dr            # conserved functionals of ν = S⁻¹ μ
    rank = N - k0
    drift = Lr @ br
    if np.max(np.abs(drift), initial=0.0) > 1e-8 * max(1.0, np.max(np.abs(br))):
        i = int(np.argmax(np.abs(drift)))
        raise SingularSystemError(
            f"steady_state: no steady state; the combination {_describe(W[i] / s, labels)} grows "
            f"linearly in time (rate {drift[i]:.3g})")
    if initial is None:
        desc = "; ".join(_describe(w / s, labels) for w in W[:4])
        raise SingularSystemError(
            f"steady_state: the moment system is singular (rank {rank} of {N}): the dynamics "
            f"conserve {k0} combination(s) of moments, e.g. {desc}; the steady state depends "
            "on their initial values: pass initial=<callable or dict monomial -> E[monomial] at t=0> "
            "(or impose the invariants of the state space)")
    get = initial if callable(initial) else (lambda m: initial[m])
    support = np.max(np.abs(W), axis=0) > 1e-12 * np.max(np.abs(W))  # moments the laws involve
    nu0 = np.array([float(get(m)) if s_ else 0.0 for m, s_ in zip(indices, support)]) / s
    M = np.vstack([Ard, Lr * dr])
    rhs = np.concatenate([-br, W @ nu0])
    sol, _, rk, svm = np.linalg.lstsq(M, rhs, rcond=None)
    if rk < N or svm[-1] <= 1e-12 * svm[0]:
        raise SingularSystemError(
            f"steady_state: not unique even with the {k0} conservation law(s) imposed "
            f"(rank {rk} of {N}): the zero eigenvalue of the moment matrix is not semisimple")
    res = np.linalg.norm(M @ sol - rhs) / max(np.linalg.norm(rhs), 1e-300)
    if res > 1e-8:
        raise SingularSystemError(f"steady_state: inconsistent conservation laws (residual {res:.2g})")
    return s * sol


def stationary_moments(sde, wanted, *, initial=None, max_size: int = 20000, rescale: bool = True) -> dict:
    """Steady-state ``E[x^γ]`` for each monomial γ in ``wanted`` (and every monomial of the closed
    hull it needs), as a dict ``{γ: value}`` (the constant monomial maps to 1).

    ``initial``: moments at t = 0 (callable or dict), needed when the dynamics conserve moments
    (see :func:`linear_steady_state`). ``rescale``: for degrees above 4 the moments are scaled by
    the Gaussian magnitudes (:func:`gaussian_scale`) of the stationary second moments, computed
    first. Raises :class:`~nlfilter.errors.MomentsNotClosedError` when the hierarchy does not close
    within ``max_size`` monomials, :class:`~nlfilter.errors.SingularSystemError` when there is no
    unique steady state.
    """
    sde = as_polynomial_sde(sde)  # once: the generator's cache serves the hull and the equations
    n = sde.n
    zero = (0,) * n
    start = list(dict.fromkeys(tuple(int(a) for a in m) for m in wanted if any(m)))
    out = {zero: 1.0}
    if not start:
        return out
    eqs = moment_equations(sde, closed_hull(sde, start, max_size=max_size))
    scale = None
    if rescale and max(sum(m) for m in eqs.indices) > 4:  # typical magnitudes from the second moments first
        sq = [_unit(n, v, 2) for v in range(n)]
        m2 = stationary_moments(sde, sq, initial=initial, max_size=max_size, rescale=False)
        sigma = np.sqrt(np.maximum([m2[e] for e in sq], 1e-300))
        sigma = np.where(sigma > 1e-150, sigma, 1.0)
        scale = gaussian_scale(eqs.indices, sigma)
    labels = [monomial_name(m, sde.names) for m in eqs.indices]
    mu = linear_steady_state(eqs.A, eqs.c, indices=eqs.indices, labels=labels, initial=initial, scale=scale)
    out.update((m, float(v)) for m, v in zip(eqs.indices, mu))
    return out
