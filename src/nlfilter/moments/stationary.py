"""Exact steady states of closed linear moment systems, with their conservation laws (seed 001).

* :func:`linear_steady_state` — the steady state of ``dμ/dt = A μ + c`` by a direct solve, after
  rescaling the moments (:func:`gaussian_scale` or an equilibration), with the conservation laws
  of the dynamics (left null vectors of ``A``) fixed from initial moments (seed 001's tensor
  systems on the circle); :func:`~nlfilter.moments.solve.steady_state` uses it when given
  ``initial`` or ``scale``;
* :func:`gaussian_scale` — typical magnitudes of monomial moments (Gaussian);
* :func:`stationary_moments` — ``E[x^γ]`` at rest for given monomials of an SDE whose moment
  hierarchy closes (the closed hull, its equations, then :func:`linear_steady_state`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components

from ..errors import SingularSystemError
from ..polynomials import monomial_name
from .closed import closed_hull
from .equations import _unit
from .ito import as_polynomial_sde, moment_equations

__all__ = ["linear_steady_state", "gaussian_scale", "stationary_moments"]


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
