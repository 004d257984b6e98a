"""Analysis of a bilinear model (seed 001 §2.3): the existence of a finite steady state (the
Wonham-type condition, 001 eq. 2.52), the steady-state second moments of the augmented state
(001 eq. 2.37 at rest), and the augmented prior of a mean and covariance of x0.

These are properties of :class:`~nlfilter.bilinear.BilinearModel` alone (no filter): the optimal
linear filter, the tensor filter and the phase filters use them off-line.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sps

from . import _validate as V
from .bilinear import BilinearModel
from .errors import SingularSystemError
from .moments.stationary import linear_steady_state


def symmetrize(P: np.ndarray) -> np.ndarray:  # as filters.linalg.symmetrize (no import of the filters here)
    if P.shape[-1] == 1:
        return P
    return 0.5 * (P + np.swapaxes(P, -1, -2))


# =========================================================================== second moments
def _kron_operator(F, Gs):
    """Matrix of ``X ↦ F X + X Fᵀ + Σ G_i X G_iᵀ`` on ``vec X`` (column-major)."""
    N = F.shape[0]
    I = np.eye(N)
    A = np.kron(I, F) + np.kron(F, I)
    for G in Gs:
        A += np.kron(G, G)
    return A


class WonhamReport(NamedTuple):
    """Existence of a finite steady state of the optimal linear filter (001 §2.3).

    ``rho``: spectral radius of ``Y ↦ ∫₀^∞ e^{Ft} Σ_i G_i Y G_iᵀ e^{Fᵀt} dt`` on the non-constant
    block (the operator form of the Wonham-type condition 2.52; NaN when ``F`` is not Hurwitz);
    ``abscissa``: largest real part of the second-moment operator's eigenvalues (the scalar case
    is ``2a + b²`` of 001 §2.3); ``detectable``: (F, H) detectable; ``finite``: a finite
    steady-state ``X∞`` and ``P∞`` exist; ``message``: a sentence saying why not."""

    rho: float
    abscissa: float
    detectable: bool
    finite: bool
    message: str


def wonham_condition(model: BilinearModel, t: float = 0.0) -> WonhamReport:
    """Evaluate the Wonham-type condition (001 eq. 2.52) for a constant bilinear model.

    (2.52) as printed bounds a matrix norm of one integral, which is not scale-invariant; we use the
    operator form of Wonham (1968): the state-multiplicative noise operator composed with the
    Lyapunov solution operator must have spectral radius < 1, equivalently the second moments
    ``X`` converge (001 §2.3 gives the scalar case ``2a + b² < 0``). Radius exactly 1 with a
    semisimple zero mode is a conservation law (the circle): ``X∞`` is then finite but depends on
    ``X(0)``. Detectability of ``(F, H)`` is checked on the modes the filter must estimate.

    >>> from nlfilter.bilinear import BilinearModel
    >>> rep = wonham_condition(BilinearModel([[-1.0]], [[1.0]], G=[[[1.0]]], B=[[1.0]], R=[[1.0]]))
    >>> round(rep.rho, 6), rep.abscissa, rep.finite                 # b²/(−2a) = 1/2;  2a + b² = −1
    (0.5, -1.0, True)
    """
    aug = model.augmented(t)
    n = model.n
    F, Gs, H = aug.F[:n, :n], aug.G[:, :n, :n], aug.H[:, :n]
    I = np.eye(n)
    L0 = np.kron(I, F) + np.kron(F, I)
    Pi = sum((np.kron(G, G) for G in Gs), np.zeros((n * n, n * n)))
    ev = np.linalg.eigvals(L0 + Pi)
    absc = float(np.max(ev.real))
    if np.max(np.linalg.eigvals(F).real) < 0:
        rho = float(np.max(np.abs(np.linalg.eigvals(np.linalg.solve(-L0, Pi))))) if Gs.size else 0.0
    else:
        rho = float("nan")
    # detectability: every unstable mode of F is seen by H (PBH test)
    w, Vr = np.linalg.eig(F)
    detectable = all(np.linalg.norm(H @ Vr[:, k]) > 1e-10 * max(1.0, np.linalg.norm(H)) or w[k].real < 0
                     for k in range(n))
    scale = max(1.0, float(np.max(np.abs(ev))))
    if absc > 1e-9 * scale:
        msg = (f"the state's second moments grow without bound (largest eigenvalue {absc:.4g} of "
               f"F⊕F + ΣG⊗G; Wonham radius {rho:.4g} ≥ 1): too much state-multiplicative noise")
        finite = False
    elif not detectable:
        msg = "(F, H) is not detectable: the error covariance of an unstable, unobserved mode grows"
        finite = False
    else:
        msg = "finite steady state" + (" (conserved second moments: X∞ depends on X(0))" if absc > -1e-9 * scale else "")
        finite = True
    return WonhamReport(rho, absc, detectable, finite, msg)


def state_second_moments(model: BilinearModel, X0=None, t: float = 0.0) -> np.ndarray:
    """Steady-state ``X∞ = E[z zᵀ]`` of the augmented state (001 eq. 2.37 at rest), by a direct
    solve with the conserved quantities fixed by ``X0`` (augmented ``(N, N)``, or the original
    ``(n, n)`` second moment when the model is augmented only by the constant, which is then 1).
    Raises :class:`~nlfilter.errors.SingularSystemError` when there is no finite or unique steady state."""
    aug = model.augmented(t)
    N, ci = model.N, model.constant_index
    A = _kron_operator(aug.F, aug.G)
    pairs = [(i, j) for j in range(N) for i in range(N)]  # column-major vec
    if X0 is not None:
        X0 = np.asarray(X0, dtype=float)
        if X0.shape == (model.n, model.n) and ci is not None:
            raise ValueError("X0: the model is augmented with the constant state; give the (N, N) second "
                             "moment of z = (x, 1), e.g. from m0, P0 via augmented_second_moment()")
        if X0.shape != (N, N):
            raise ValueError(f"X0: expected shape ({N}, {N}), got {X0.shape}")

    def initial(pair):
        i, j = pair
        if X0 is not None:
            return X0[i, j]
        if ci is not None and i == ci and j == ci:
            return 1.0
        raise _NeedX0()

    try:
        mu = linear_steady_state(sps.csr_matrix(A), np.zeros(N * N), indices=pairs, initial=initial,
                                 labels=[f"z{i}z{j}" for i, j in pairs])
    except _NeedX0:
        raise SingularSystemError("state_second_moments: the dynamics conserve second moments other than "
                                  "the constant (e.g. |x|² on a sphere); pass X0 (or m0, P0) to fix them") from None
    except SingularSystemError as exc:
        rep = wonham_condition(model, t)
        raise SingularSystemError(f"state_second_moments: no finite steady state: {rep.message} ({exc})") from None
    X = mu.reshape(N, N, order="F")
    return symmetrize(X)


class _NeedX0(Exception):
    pass


def augmented_second_moment(model: BilinearModel, m0, P0) -> tuple:
    """``(ẑ0, X0, P0_aug)`` of the augmented state from the mean ``m0`` and covariance ``P0`` of x0."""
    n, N = model.n, model.N
    m0 = V.as_float_array("m0", m0, ndim=1, shape_tail=(n,))
    P0 = V.covariance("P0", P0, n)
    z0 = np.append(m0, 1.0) if N > n else m0.copy()
    X0 = np.zeros((N, N))
    X0[:n, :n] = P0 + np.outer(m0, m0)
    if N > n:
        X0[:n, n] = X0[n, :n] = m0
        X0[n, n] = 1.0
    Pa = np.zeros((N, N))
    Pa[:n, :n] = P0
    return z0, X0, Pa


__all__ = ["WonhamReport", "wonham_condition", "state_second_moments", "augmented_second_moment"]
