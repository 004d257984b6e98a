"""Seed 004's contractions (Henriksen 1979): the second-order terms shared by the Taylor-2 rule
(:class:`~nlfilter.filters.rules.Taylor2`), the second-order filters and the continuous skeleton.

>>> import numpy as np
>>> hessian_trace(np.eye(2), np.arange(8.0).reshape(2, 2, 2)).tolist()
[3.0, 11.0]
"""

from __future__ import annotations

import numpy as np

from .._npcall import einsum as _einsum

__all__ = ["hessian_trace", "quarter_outer", "gaussian_quartic", "noise_covariance"]


def hessian_trace(X: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``(X A)_i = Σ_jl X_jl A_ijl`` (004 eqs. 9, 23, 30-31): ``X (..., n, n)``, ``A (..., p, n, n)``
    → ``(..., p)``.

    >>> hessian_trace(np.eye(2), np.arange(8.0).reshape(2, 2, 2)).tolist()
    [3.0, 11.0]
    """
    return _einsum("...jl,...ijl->...i", X, A)  # i: output component, j,l: summed state indices


def quarter_outer(X: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``¼ (X A)(X A)ᵀ`` (004 eq. 11, last term), ``(..., p, p)``."""
    t = hessian_trace(X, A)
    return 0.25 * t[..., :, None] * t[..., None, :]


def gaussian_quartic(X: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``½ tr(A_i X A_j X)``: ``Cov[½δᵀA_iδ, ½δᵀA_jδ]`` for ``δ ~ N(0, X)``, ``(..., p, p)``."""
    AX = _einsum("...iab,...bc->...iac", A, X)  # (A_i X)_ac: i component, a,b,c state indices
    return 0.5 * _einsum("...iac,...jca->...ij", AX, AX)  # tr((A_i X)(A_j X)) over a, c


def noise_covariance(X, V, G, G_x=None, G_xx=None, *, gaussian: bool = False) -> np.ndarray:
    """Second-order approximation of ``E[G(x) V G(x)ᵀ]`` for ``x ~ (m, X)`` (004 eqs. 13, 14, 19).

    ``G (..., n, r)``, ``G_x (..., n, r, n)``, ``G_xx (..., n, r, n, n)`` at the mean; ``V (r, r)``.
    Returns ``G V Gᵀ + (X V G_x²) + ½(X V G_xx G) + ½(X V G_xx G)ᵀ``; with ``gaussian=True`` also the
    fourth-moment term ``¼ E[(G_xx δδ) V (G_xx δδ)ᵀ]`` of a Gaussian ``δ`` (exact for quadratic G).
    ``G_x``/``G_xx`` may be ``None`` (constant G).
    """
    out = np.einsum("...ia,ab,...qb->...iq", G, V, G)  # G V Gᵀ: i,q states, a,b noise indices
    if G_x is not None:
        GxX = np.einsum("...iap,...pt->...iat", G_x, X)  # Σ_p ∂G_ia/∂x_p X_pt
        out = out + np.einsum("...iat,ab,...qbt->...iq", GxX, V, G_x)  # 004 eq. 13: (X V G_x²)_iq
    if G_xx is not None:
        XGxx = np.einsum("...iapt,...pt->...ia", G_xx, X)  # Σ_pt X_pt ∂²G_ia/∂x_p∂x_t
        half = 0.5 * np.einsum("...ia,ab,...qb->...iq", XGxx, V, G)  # 004 eq. 14: ½(X V G_xx G)_iq
        out = out + half + np.swapaxes(half, -1, -2)
        if gaussian:  # ¼ E[δδ:G_xx V G_xxᵀ:δδ] = ¼ (XG_xx)V(XG_xx)ᵀ + ½ Σ_ab V_ab tr(G_xx,ia X G_xx,qb X)
            GxxX = np.einsum("...iapt,...tu->...iapu", G_xx, X)  # (G_xx,ia X)_pu
            out = out + 0.25 * np.einsum("...ia,ab,...qb->...iq", XGxx, V, XGxx) + 0.5 * np.einsum(
                "...iapu,ab,...qbup->...iq", GxxX, V, GxxX)  # trace over p, u
    return out
