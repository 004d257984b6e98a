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

from ..errors import NoStationaryLawError, SingularSystemError
from ..polynomials import monomial_name, unit_exp
from .closed import closed_hull
from .ito import as_polynomial_sde, moment_equations

__all__ = ["linear_steady_state", "gaussian_scale", "stationary_moments", "nondecaying_modes",
           "moment_space_violation"]


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


def _spectrum_blocks(M, max_block: int = 3000):
    """``[(idx, eigenvalues)]`` of the diagonal blocks of ``M`` on its strongly connected
    components (the spectrum is their union), or None when a block exceeds ``max_block``."""
    M = sps.csr_matrix(M)
    ncomp, lab = connected_components(M, directed=True, connection="strong")
    order = np.argsort(lab, kind="stable")
    blocks = np.split(order, np.flatnonzero(np.diff(lab[order])) + 1)
    if max(len(b) for b in blocks) > max_block:
        return None
    return [(idx, np.linalg.eigvals(M[idx][:, idx].toarray())) for idx in blocks]


def nondecaying_modes(A, indices, *, kind: str = "continuous", tol: float = 1e-9, conserved: bool = True,
                      max_block: int = 3000):
    """The modes of the moment dynamics ``dμ/dt = A μ`` (``kind="continuous"``) or
    ``μ' = A μ`` (``"discrete"``) that do not decay: ``[(λ, monomials of its block)]``, lowest
    degree first (within a block the least stable eigenvalue). Exactly conserved modes (``λ = 0``,
    discrete ``λ = 1``) are left out when ``conserved`` (they make the system singular, which the
    callers diagnose). Returns None when the spectrum is too large to compute (a block over
    ``max_block``). ``indices``: the monomial of each row of ``A`` (the constant one excluded).

    The eigenvalues are those of a diagonally rescaled (similar) matrix, block by block on the
    strongly connected components of ``A`` (moment matrices split by degree).
    """
    A = sps.csr_matrix(A, dtype=float)
    if A.shape[0] == 0:
        return []
    _, s = _equilibrate(A)
    blocks = _spectrum_blocks(sps.diags(1.0 / s) @ A @ sps.diags(s), max_block)
    if blocks is None:
        return None
    allev = np.concatenate([ev for _, ev in blocks])
    escale = max(float(np.max(np.abs(allev))), 1e-300) if kind == "continuous" else 1.0
    out = []
    for idx, ev in blocks:
        if kind == "continuous":
            keep = np.abs(ev) > 1e-8 * escale if conserved else np.ones(ev.shape, bool)
            bad = keep & (ev.real > -tol * escale)
            key = ev.real
        else:
            keep = np.abs(ev - 1.0) > 1e-8 if conserved else np.ones(ev.shape, bool)
            bad = keep & (np.abs(ev) > 1.0 - tol)
            key = np.abs(ev)
        if bad.any():
            k = np.flatnonzero(bad)[np.argmax(key[bad])]
            out.append((complex(ev[k]), [indices[i] for i in sorted(idx)]))
    out.sort(key=lambda m: min(sum(g) for g in m[1]))
    return out


def describe_mode(lam: complex, block, names, kind: str = "continuous", *, linear_part: bool = True) -> str:
    """``"eigenvalue +1 (real part ≥ 0) on E[x1] (the drift's linear part)"``: a mode of
    :func:`nondecaying_modes` in words (the last remark when ``linear_part`` and the block is of
    the means)."""
    lam_s = f"{lam.real:+.4g}" if abs(lam.imag) <= 1e-12 * max(1.0, abs(lam)) else f"{lam:.4g}"
    cond = "real part ≥ 0" if kind == "continuous" else "modulus ≥ 1"
    mons = ", ".join(f"E[{monomial_name(g, names)}]" for g in block[:4]) + (", ..." if len(block) > 4 else "")
    part = " (the drift's linear part)" if kind == "continuous" else " (the map's linear part)"
    return f"eigenvalue {lam_s} ({cond}) on {mons}" + (part if linear_part and all(sum(g) == 1 for g in block)
                                                       else "")


def moment_space_violation(indices, mu, names, *, tol: float = 1e-7, max_matrix: int = 300) -> str | None:
    """Why the values ``mu`` of the monomials ``indices`` are not the moments of any law, or None.

    Checks what is cheap and necessary: every even moment ``E[x^{2α}] ≥ 0``; the covariance
    (raw second-moment matrix when the means are not kept) positive semi-definite; the moment
    matrix ``[E x^{α+β}]`` over the monomials up to half the top degree positive semi-definite when
    all its entries are kept (at most ``max_matrix`` rows), else each coordinate's Hankel matrix
    ``[E x_i^(p+q)]`` over the powers whose products are kept.
    Matrices are normalized by their diagonals; ``tol`` bounds their negative eigenvalues.
    """
    mu = np.asarray(mu, dtype=float)
    if not np.all(np.isfinite(mu)):
        return None  # non-finite values are a blow-up, reported as such
    n = len(indices[0]) if len(indices) else 0
    zero = (0,) * n
    val = {tuple(g): float(v) for g, v in zip(indices, mu)}
    val[zero] = 1.0
    deg_scale: dict = {}
    for g, v in val.items():
        deg_scale[sum(g)] = max(deg_scale.get(sum(g), 1.0), abs(v))
    for g, v in val.items():
        if any(g) and all(a % 2 == 0 for a in g) and v < -tol * deg_scale[sum(g)]:
            return f"the even moment E[{monomial_name(g, names)}] = {v:.4g} is negative"

    def units(i, k=1):
        e = [0] * n
        e[i] = k
        return tuple(e)

    def psd(basis, what):
        M = np.array([[val[tuple(a + b for a, b in zip(p, q))] for q in basis] for p in basis])
        d = np.sqrt(np.where(np.diag(M) > 0, np.diag(M), 1.0))
        w = np.linalg.eigvalsh(M / d[:, None] / d[None, :])
        return None if w[0] >= -tol else f"{what} is not positive semi-definite (eigenvalue {w[0]:.3g} after " \
                                            f"normalization by its diagonal)"

    second = [tuple(a + b for a, b in zip(units(i), units(j))) for i in range(n) for j in range(n)]
    if all(e in val for e in second):
        if all(units(i) in val for i in range(n)):
            m = np.array([val[units(i)] for i in range(n)])
            C = np.array([[val[tuple(a + b for a, b in zip(units(i), units(j)))] for j in range(n)]
                          for i in range(n)]) - np.outer(m, m)
            dg = np.diag(C)
            neg = np.flatnonzero(dg < -tol * np.maximum(1.0, np.abs([val[units(i, 2)] for i in range(n)])))
            if neg.size:
                i = int(neg[0])
                return f"the variance of {names[i]} is {dg[i]:.4g} < 0"
            dd = np.sqrt(np.where(dg > 0, dg, 1.0))
            w = np.linalg.eigvalsh(C / dd[:, None] / dd[None, :])
            if w[0] < -tol:
                return f"the covariance is not positive semi-definite (eigenvalue {w[0]:.3g} of the correlation matrix)"
        else:
            why = psd([units(i) for i in range(n)], "the second-moment matrix E[x xᵀ]")
            if why:
                return why
    top = max((sum(g) for g in val), default=0)
    half = top // 2
    if half >= 1:
        from ..polynomials import monomials
        basis = monomials(n, half)
        if len(basis) <= max_matrix and all(tuple(a + b for a, b in zip(p, q)) in val for p in basis for q in basis):
            return psd(basis, f"the moment matrix [E x^(α+β)] over the monomials of degree ≤ {half}")
        for i in range(n):  # the powers p of x_i whose products E[x_i^(p+q)] are all kept (x², x⁴ alone: 1, x²)
            pw = [0]
            for p in range(1, half + 1):
                if all(units(i, p + q) in val for q in pw + [p]):
                    pw.append(p)
            if len(pw) > 1:
                why = psd([units(i, p) for p in pw], f"the Hankel matrix of the moments of {names[i]}")
                if why:
                    return why
    return None


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

    Raises :class:`~nlfilter.errors.NoStationaryLawError` (a
    :class:`~nlfilter.errors.SingularSystemError`) when a mode grows or oscillates (no finite
    steady state), :class:`~nlfilter.errors.SingularSystemError` when it is not unique.

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
            raise NoStationaryLawError(
                f"steady_state: the moments grow without bound (eigenvalue {ev.real[~zero].max():.3g} "
                "of the moment matrix has non-negative real part): no finite steady state", time=np.inf)
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
    wanted = [tuple(m.tolist()) if isinstance(m, np.ndarray) else m for m in wanted]
    for m in wanted:
        if (not isinstance(m, (tuple, list)) or len(m) != n
                or not all(isinstance(a, (int, np.integer)) and not isinstance(a, bool) and a >= 0 for a in m)):
            raise ValueError(f"wanted: expected multi-indices of {n} non-negative integers (one per state), got {m!r}")
    start = list(dict.fromkeys(tuple(int(a) for a in m) for m in wanted if any(m)))
    out = {zero: 1.0}
    if not start:
        return out
    eqs = moment_equations(sde, closed_hull(sde, start, max_size=max_size))
    scale = None
    if rescale and max(sum(m) for m in eqs.indices) > 4:  # typical magnitudes from the second moments first
        sq = [unit_exp(n, v, 2) for v in range(n)]
        m2 = stationary_moments(sde, sq, initial=initial, max_size=max_size, rescale=False)
        sigma = np.sqrt(np.maximum([m2[e] for e in sq], 1e-300))
        sigma = np.where(sigma > 1e-150, sigma, 1.0)
        scale = gaussian_scale(eqs.indices, sigma)
    labels = [monomial_name(m, sde.names) for m in eqs.indices]
    mu = linear_steady_state(eqs.A, eqs.c, indices=eqs.indices, labels=labels, initial=initial, scale=scale)
    out.update((m, float(v)) for m, v in zip(eqs.indices, mu))
    return out
