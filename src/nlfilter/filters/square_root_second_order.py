"""The square-root second-order filters (``sr-second-order``): seed 004's discrete second-order
filters (Henriksen 1979; :class:`~nlfilter.filters.second_order.SecondOrderFilter`) in every
``form`` of :data:`~nlfilter.filters.rules.FORMS`, on a lower-triangular factor ``S`` of the
covariance (``P = S Sᵀ``), in the array form of :mod:`nlfilter.filters.square_root`.

Every second-order term is a set of columns of the QR pre-array (``tria``) or a rank-one Cholesky
downdate (:func:`~nlfilter.filters.triangular.downdate`), so P is never formed. With the
congruences ``B_i = Sᵀ A_i S`` of the Hessians ``A_i = ∂²g_i/∂x²`` at the mean,
``(P A)_i = Σ_jl P_jl A_ijl = tr B_i`` and
``½ tr(A_i P A_j P) = ½ Σ_cd B_i,cd B_j,cd`` (the Gaussian fourth-moment term: the columns
``B_i,cc/√2`` and ``B_i,cd``, c < d). Prediction (004 eqs. 18-19)::

    m⁻ = f(m) + ½ (tr B_i)_i
    S⁻ = tria([F S,  N,  [Gaussian fourth moments: the columns of B]])       F = f_x(m)
         then, "-quarter" forms (004 eq. 11): a downdate by ½ (tr B_i)_i

with ``N`` the columns of ``E[G V Gᵀ]`` (004 eqs. 13-14, 19; :func:`noise_columns`). Update
(004 eqs. 20-23): the joint array of :func:`~nlfilter.filters.square_root.sqrt_condition` with
``H S⁻`` over ``S⁻``, the Gaussian fourth-moment columns of ``h`` over zeros, and for the
``"-quarter"`` innovation term the downdate by ``[½ tr B_h; 0]`` (only the innovation block loses
it: ``S = H P⁻ Hᵀ + R − ¼ (P h_xx)(P h_xx)ᵀ``); ``ŷ = h(m⁻) + ½ (tr B_h,i)_i``. The forcing term of
the forms that have one (004 eq. 33 as :meth:`~nlfilter.filters.rules.Taylor2.forcing`),
``P⁺ += Σ_k M_k v_k`` with ``v = S⁻¹ (y − ŷ) = S_y⁻ᵀ u``, is ``S⁻ W S⁻ᵀ`` with the symmetric
``W = −½ (tr B_h · v) I`` (truncated-Jazwinski: ``M_k = −½ P (P h_xx)_k``) or
``W = Σ_k v_k B_h,k`` (Gaussian: ``M_k = P h_xx⁽ᵏ⁾ P``): by the eigenvectors of ``W``
(``W = U Λ Uᵀ``), the columns ``S⁻ U_i √λ_i`` of the positive eigenvalues join ``S⁺`` in a
``tria``, those of the negative ones are downdates. A downdate that fails (the standard filter's
covariance would have lost definiteness there) poisons its path: ``run`` raises or marks it.

The same estimates as :class:`~nlfilter.filters.second_order.SecondOrderFilter` of the same form
in exact arithmetic (``tests/filters/test_square_root_second_order.py``: 1e-10 on every form,
log-likelihood included); ``smooth`` is the square-root RTS smoother of the module above (the
joint factor's lower block ``S`` under ``F S``: ``Cov[x_{k+1}, x_k] = F P``, third moments
neglected, as the standard filter's smoother reads it), except for the ``"-quarter"`` prediction
(truncated-Jazwinski), whose joint law of ``(x_{k+1}, x_k)`` is indefinite (its Schur complement
``P⁻ − F P Fᵀ = N − ¼ (P f_xx)(P f_xx)ᵀ`` need not be PSD though P⁻ is) and so has no factor:
there the moment-form RTS smoother from the reported moments, as the standard filter's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _validate as V
from .gaussian import GaussianFilter
from .linalg import mm
from .rules import FORM_TABLE, FORMS, Taylor2
from .square_root import SquareRootFilter, _broadcast_concat, _poison
from .triangular import downdate, tria

__all__ = ["SqrtTaylor2", "SquareRootSecondOrderFilter", "congruence", "quartic_columns", "noise_columns",
           "add_symmetric"]


def congruence(S, A):
    """``B_i = Sᵀ A_i S`` ``(..., p, n, n)`` for a factor ``S (..., n, n)`` and Hessians ``A (..., p, n, n)``:
    ``tr B_i = (P A)_i`` (004 eq. 9) and ``Σ_cd B_i,cd B_j,cd = tr(A_i P A_j P)``."""
    St = S.swapaxes(-1, -2)[..., None, :, :]
    return St @ A @ S[..., None, :, :]


def quartic_columns(B):
    """``(..., p, n(n+1)/2)``: columns ``Q`` with ``Q Qᵀ = ½ tr(A_i P A_j P)`` (the Gaussian
    fourth-moment term, :func:`~nlfilter.filters.contractions.gaussian_quartic`) from the
    congruences ``B`` (:func:`congruence`): ``B_i,cc/√2`` and ``B_i,cd`` for c < d."""
    n = B.shape[-1]
    r, c = np.triu_indices(n)
    return B[..., r, c] * np.where(r == c, np.sqrt(0.5), 1.0)


def _trace(B):
    return np.trace(B, axis1=-2, axis2=-1)


def noise_columns(model, m, S, t, Lq, *, second: bool = True, gaussian: bool = False):
    """The factor columns of ``E[G(x) V G(x)ᵀ]`` to second order (004 eqs. 13-14, 19;
    :func:`~nlfilter.filters.contractions.noise_covariance`) and the downdates it needs, from the
    factor ``S`` and ``Lq`` (``V = Lq Lqᵀ``). With ``Ḡ_ia = Σ_pt P_pt ∂²G_ia/∂x_p∂x_t``::

        G V Gᵀ + ½ Ḡ V Gᵀ + ½ G V Ḡᵀ = (G + ½Ḡ) V (G + ½Ḡ)ᵀ − ¼ Ḡ V Ḡᵀ

    so the columns are ``(G + ½Ḡ) Lq``, ``Σ_pa ∂G_ia/∂x_p S_pc Lq_ad`` (the term ``(X V G_x²)``),
    and either the downdates ``½ Ḡ Lq e_d`` or, with the Gaussian fourth moments (whose ``¼ Ḡ V Ḡᵀ``
    cancels them), the columns ``Σ_a (Sᵀ G_xx,ia S)_cd Lq_ae / √2``. Constant G (or ``second``
    False): ``G(m) Lq``, no downdate."""
    G = model.G(m, t)
    if model.G_constant or not second:
        return G @ Lq, []
    Gx, Gxx = model.G_x(m, t), model.G_xx(m, t)  # (..., n, r, n), (..., n, r, n, n)
    Bg = S.swapaxes(-1, -2)[..., None, None, :, :] @ Gxx @ S[..., None, None, :, :]  # Sᵀ G_xx,ia S
    Gbar = _trace(Bg)  # (..., n, r)
    n, r = G.shape[-2:]
    lead = Gbar.shape[:-2]
    cols = [(G + 0.5 * Gbar) @ Lq,
            np.einsum("...iap,...pc,ad->...icd", Gx, S, Lq).reshape(*lead, n, -1)]  # (X V G_x²)
    if gaussian:
        cols.append(np.sqrt(0.5) * np.einsum("...iacd,ae->...icde", Bg, Lq).reshape(*lead, n, -1))
        return _broadcast_concat(cols, -1), []
    half = 0.5 * Gbar @ Lq
    return _broadcast_concat(cols, -1), [half[..., :, e] for e in range(Lq.shape[-1])]


@dataclass(frozen=True)
class SqrtTaylor2(Taylor2):
    """:class:`~nlfilter.filters.rules.Taylor2` with the square-root forms of its terms (module
    docstring): :meth:`sqrt_dynamics` and :meth:`sqrt_measurement` are the columns that
    :func:`~nlfilter.filters.square_root.sqrt_predict` and
    :func:`~nlfilter.filters.square_root.sqrt_condition` stack into their arrays. Its moment form
    (``moments``, the fixed-lag smoother's and the posterior sampler's) is Taylor2's."""

    def sqrt_dynamics(self, model, m, S, t, Lq, f, f_x, f_xx, joint):
        """``(m⁻, columns of P⁻, the joint array's lower block, downdates, noise columns, noise
        downdates)`` of the prediction (004 eqs. 18-19)."""
        n = m.shape[-1]
        mean = f(m, t)
        cols, low, neg = [mm(f_x(m, t), S)], [S], []  # F S over S
        if self.second:
            B = congruence(S, (model.f_xx if f_xx is None else f_xx)(m, t))
            a = _trace(B)  # (P f_xx)
            mean = mean + 0.5 * a  # 004 eq. 18
            kind = FORM_TABLE[self.form].prediction
            if kind == "gaussian":  # ½ tr(f_xx⁽ⁱ⁾ P f_xx⁽ʲ⁾ P)
                Qc = quartic_columns(B)
                cols.append(Qc)
                low.append(np.zeros((*Qc.shape[:-2], n, Qc.shape[-1])))
            elif kind == "-quarter":  # −¼ (P f_xx)(P f_xx)ᵀ (004 eq. 11)
                v = 0.5 * a
                neg.append(np.concatenate([v, np.zeros(v.shape)], axis=-1) if joint else v)
        noise, nneg = noise_columns(model, m, S, t, Lq, second=self.second,
                                    gaussian=FORM_TABLE[self.form].gaussian_noise)
        return mean, _broadcast_concat(cols, -1), _broadcast_concat(low, -1), neg, noise, nneg

    def sqrt_measurement(self, model, m, S, t):
        """``(ŷ, H S⁻ and the fourth-moment columns, S⁻ over zeros, downdates)`` of the update's
        joint array (004 eqs. 20-23)."""
        n = m.shape[-1]
        yhat = model.h(m, t)
        Y, Xc, neg = [mm(model.h_x(m, t), S)], [S], []
        if self.second:
            a = _trace(B := congruence(S, model.h_xx(m, t)))
            yhat = yhat + 0.5 * a  # 004 eq. 20
            kind = FORM_TABLE[self.form].innovation
            if kind == "gaussian":
                Qc = quartic_columns(B)
                Y.append(Qc)
                Xc.append(np.zeros((*Qc.shape[:-2], n, Qc.shape[-1])))
            elif kind == "-quarter":  # −¼ (P h_xx)(P h_xx)ᵀ in S only (004 text after eq. 23)
                neg.append(np.concatenate([0.5 * a, np.zeros((*a.shape[:-1], n))], axis=-1))
        return yhat, _broadcast_concat(Y, -1), _broadcast_concat(Xc, -1), neg

    def sqrt_forcing(self, model, m, S, t, v):
        """``W (..., n, n)`` with the forcing term ``Σ_k M_k v_k = S W Sᵀ`` (module docstring), or None."""
        kind = FORM_TABLE[self.form].forcing
        if kind == "none" or not self.second:
            return None
        B = congruence(S, model.h_xx(m, t))
        if kind == "truncated":  # M_k = −½ P (P h_xx)_k
            c = -0.5 * np.sum(_trace(B) * v, axis=-1)
            return c[..., None, None] * np.eye(m.shape[-1])
        return np.einsum("...k,...kab->...ab", v, B)  # M_k = P h_xx⁽ᵏ⁾ P


def add_symmetric(L, S, W):
    """``(L', failed)``: ``L' L'ᵀ = L Lᵀ + S W Sᵀ`` for a symmetric ``W`` (batched), by its
    eigenvectors: the columns of its positive eigenvalues in a ``tria``, the negative ones downdates."""
    finite = np.isfinite(W).all(axis=(-2, -1))
    lam, U = np.linalg.eigh(np.where(finite[..., None, None], W, 0.0))
    Z = S @ U
    up = Z * np.sqrt(np.maximum(lam, 0.0))[..., None, :]
    dn = Z * np.sqrt(np.maximum(-lam, 0.0))[..., None, :]
    return downdate(tria(_broadcast_concat([L, up], -1)), [dn[..., :, i] for i in range(W.shape[-1])])


class SquareRootSecondOrderFilter(SquareRootFilter):
    """Square-root second-order filter (seed 004, Henriksen 1979) for a
    :class:`~nlfilter.models.DiscreteModel`: the steps of the module docstring, the same estimates
    as :class:`~nlfilter.filters.second_order.SecondOrderFilter` of the same ``form`` in exact
    arithmetic, ``covs = S Sᵀ`` symmetric PSD by construction.

    Parameters
    ----------
    model : DiscreteModel with ``f_xx``, ``h_xx`` (and ``G_x``, ``G_xx`` when G depends on x)
    form : one of :data:`~nlfilter.filters.rules.FORMS` (default ``"truncated"``, the paper's
        correct form; ``"first-order"``: the square-root EKF)
    start : ``"update"`` or ``"predict"``

    Notes
    -----
    A path whose downdate fails (a ``"-quarter"`` term or a forcing term larger than the
    covariance it is removed from) is poisoned, as every square-root filter's: ``run`` raises or,
    with ``on_divergence="mark"``, marks it (the standard filter raises there).

    Examples
    --------
    >>> import sympy as sp; from nlfilter import DiscreteModel
    >>> from nlfilter.filters.second_order import SecondOrderFilter
    >>> x = sp.Symbol("x")
    >>> model = DiscreteModel([x], [0.9 * x + 0.1 * x**2], [x + 0.5 * x**2], Q=0.1, R=0.1)
    >>> ys = np.array([[[0.5], [0.2], [0.9]]])
    >>> a = SquareRootSecondOrderFilter(model, form="gaussian").run(ys, [0.5], [[0.3]])
    >>> b = SecondOrderFilter(model, form="gaussian").run(ys, [0.5], [[0.3]])
    >>> float(np.abs(a.means - b.means).max()) < 1e-12, float(np.abs(a.covs - b.covs).max()) < 1e-12
    (True, True)
    """

    name = "sr-second-order"
    family = "second-order"
    source = ("seed 004 eqs. 18-23 (Henriksen 1979) in the array form of Morf & Kailath 1975, IEEE TAC 20(4); "
              "Bierman 1977 (Cholesky up- and downdates)")
    needs = ("f_x", "f_xx", "h_x", "h_xx")
    compiled = False
    compiled_refusal = "its second-order square-root columns have no compiled kernel; it runs on the NumPy loop"

    def __init__(self, model, *, form: str = "truncated", start: str | None = None):
        form = V.choice("form", form, set(FORMS))
        super().__init__(model, SqrtTaylor2(form), start=start)
        self.form = form

    def _smooth(self, est, beliefs, ys, t0):
        """The square-root RTS smoother; the ``"-quarter"`` prediction forms (truncated-Jazwinski) the
        moment-form RTS from the reported moments, as the standard filter's: their joint law of
        ``(x_{k+1}, x_k)`` is indefinite (its Schur complement ``P⁻ − F P Fᵀ = N − ¼ (P f_xx)(P f_xx)ᵀ``
        need not be PSD though P⁻ is), so it has no factor."""
        if FORM_TABLE[self.form].prediction == "-quarter":
            return GaussianFilter._smooth(self, est, beliefs, ys, t0)
        return super()._smooth(est, beliefs, ys, t0)

    def _conditioned(self, state, y, k, full: bool = False):
        """The array update (the rule's columns), then the forcing term of the form (module docstring)."""
        new, bad, info = super()._conditioned(state, y, k, full=full)
        yhat, Sy, u, _ = info
        if FORM_TABLE[self.form].forcing == "none":
            return new, bad, info
        sing = ~np.all(np.diagonal(Sy, axis1=-2, axis2=-1) > 0, axis=-1)
        safe = np.where(sing[..., None, None], np.eye(Sy.shape[-1]), Sy)
        v = np.linalg.solve(safe.swapaxes(-1, -2), u[..., None])[..., 0]  # S⁻¹ (y − ŷ) = S_y⁻ᵀ u
        m, Sp = state[0], state[1]
        W = self.rule.sqrt_forcing(self.model, m, Sp, self._time(k), v)
        L, failed = add_symmetric(new.factor, Sp, W)
        new = _poison(new._replace(factor=L), failed)
        if failed is not None and failed.any():
            bad = failed if bad is None else bad | failed
        return new, bad, info
