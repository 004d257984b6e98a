"""Densities from moments on a bounded interval or box (seed 000, Chapter II).

A density ``f`` on ``[a, b]`` is replaced by the degree-N polynomial closest to it in the
least-squares sense (000 eq. 2.14).  On the scaled variable ``t = (2x - a - b)/(b - a)`` in
``[-1, 1]`` this polynomial is the truncated Legendre series (000 eqs. 2.13, 2.17)::

    g(t) = sum_{i<=N} A_i P_i(t),    A_i = (2i+1)/2 * E[P_i(t)],

so its coefficients are linear in the moments ``m_1 .. m_N`` of ``x`` and nothing has to be
solved: the normal equations 2.26 of the power basis (a Hilbert matrix, which the paper warns is
ill-conditioned) are never formed.  Everything here stays in the Legendre basis:

* :class:`LegendreDensity` — batched polynomial densities on batched intervals, with exact
  integrals ``int_l^u x^p f(x) dx`` over sub-intervals (Bonnet recurrence, antiderivative
  ``(P_{i+1} - P_{i-1})/(2i+1)``), the power-basis coefficients ``a_i`` of eq. 2.19 on request.
* :class:`LegendreDensity2D` — the same on a box with the tensor Legendre basis of total
  degree ``<= N`` (the least-squares projection onto that space; mixed moments in, exact
  integrals over the box, and over the part of the box inside a slab ``l <= c.x <= u``).
* :func:`sum_moments`, :func:`difference_moments` — moments of a sum of independent variables
  by binomial expansion and its inversion (000 eqs. 3.12-3.14); :func:`affine_moments`,
  :func:`moments_to_cumulants`, :func:`cumulants_to_moments`, :func:`uniform_moments`,
  :func:`is_moment_sequence` (Hankel test on an interval).

Moment arrays are ``(..., N)`` holding ``m_1 .. m_N`` (``m_0 = 1`` implied), batch axes first.

>>> import numpy as np
>>> d = LegendreDensity.from_moments(uniform_moments(4, -1.0, 1.0))   # U(-1, 1): exactly 1/2
>>> float(d.pdf(0.3))
0.5
>>> float(d.integral(0.0, 1.0, power=1))                               # int_0^1 x/2 dx
0.25
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.polynomial import legendre as npleg

from .. import _validate as V

__all__ = ["LegendreDensity", "LegendreDensity2D", "legendre_values", "legendre_antiderivative",
           "sum_moments", "difference_moments", "affine_moments", "uniform_moments",
           "power_density_moments", "moments_to_cumulants", "cumulants_to_moments",
           "is_moment_sequence", "series_times_x", "MAX_DEGREE"]

#: Highest degree accepted (the experiments use N <= 12; the Legendre basis itself is stable far
#: beyond, but moments estimated from data carry no information at such orders).
MAX_DEGREE = 40


# ---------------------------------------------------------------- Legendre basics (batched)

def legendre_values(t, K: int) -> np.ndarray:
    """``P_0(t) .. P_K(t)`` by Bonnet's recurrence, shape ``(*t.shape, K+1)`` (000 eq. 2.10)."""
    t = np.asarray(t, dtype=float)
    out = np.empty((*t.shape, K + 1))
    out[..., 0] = 1.0
    if K >= 1:
        out[..., 1] = t
    for i in range(1, K):  # (i+1) P_{i+1} = (2i+1) t P_i - i P_{i-1}
        out[..., i + 1] = ((2 * i + 1) * t * out[..., i] - i * out[..., i - 1]) / (i + 1)
    return out


def legendre_antiderivative(c, t, *, values=None) -> np.ndarray:
    """``F(t) = int_{-1}^t sum_i c_i P_i(s) ds`` for a batch of series ``c`` (..., K+1).

    Uses ``int P_0 = t + 1`` and ``int_{-1}^t P_i = (P_{i+1}(t) - P_{i-1}(t))/(2i+1)`` (i >= 1).
    ``values``: ``legendre_values(t, K')`` with ``K' >= K + 1``, when already computed (one table
    serves several series at the same points).
    """
    c = np.asarray(c, dtype=float)
    K = c.shape[-1] - 1
    P = legendre_values(t, K + 1) if values is None else values
    F = c[..., 0] * (P[..., 1] + 1.0)
    if K >= 1:
        i = np.arange(1, K + 1)
        F = F + np.sum(c[..., 1:] * (P[..., 2:K + 2] - P[..., :K]) / (2 * i + 1), axis=-1)
    return F


def _legmulx(c: np.ndarray) -> np.ndarray:
    """Series of ``t * g(t)`` from that of ``g`` (last axis): t P_i = ((i+1)P_{i+1} + i P_{i-1})/(2i+1)."""
    K = c.shape[-1]
    i = np.arange(K)
    out = np.zeros((*c.shape[:-1], K + 1))
    out[..., 1:] += c * (i + 1) / (2 * i + 1)
    if K > 1:
        out[..., : K - 1] += c[..., 1:] * i[1:] / (2 * i[1:] + 1)
    return out


def series_times_x(c, alpha, center) -> np.ndarray:
    """Legendre series (in t) of ``x g(t)`` from that of ``g`` (last axis), ``x = center + t / alpha``
    (``alpha``, ``center`` broadcast over the batch)."""
    center, alpha = np.asarray(center, dtype=float), np.asarray(alpha, dtype=float)
    return center[..., None] * np.concatenate([c, np.zeros((*c.shape[:-1], 1))], axis=-1) + _legmulx(c) / alpha[..., None]


@functools.lru_cache(maxsize=None)
def _poly_to_leg_matrix(K: int) -> np.ndarray:
    """``L`` (K+1, K+1) with ``P_i(t) = sum_k L[i, k] t^k`` (exact rationals rounded once; computed
    once per K and shared, read-only)."""
    L = np.zeros((K + 1, K + 1))
    for i in range(K + 1):
        e = np.zeros(i + 1)
        e[i] = 1.0
        L[i, : i + 1] = npleg.leg2poly(e)
    L.flags.writeable = False
    return L


# ---------------------------------------------------------------- moment algebra

def _moments(name: str, m) -> np.ndarray:
    arr = V.as_float_array(name, m, ndim_min=1)
    V.finite(name, arr)
    if arr.shape[-1] > MAX_DEGREE:
        raise ValueError(f"{name}: expected at most {MAX_DEGREE} moments, got {arr.shape[-1]}")
    return arr


def _with_m0(m: np.ndarray) -> np.ndarray:
    return np.concatenate([np.ones((*m.shape[:-1], 1)), m], axis=-1)


def _binom(N: int) -> np.ndarray:
    return np.array([[math.comb(i, j) for j in range(N + 1)] for i in range(N + 1)], dtype=float)


def sum_moments(mx, mv) -> np.ndarray:
    """Moments of ``z = x + v`` for independent ``x``, ``v`` (000 eq. 3.13).

    ``m_z^(i) = sum_j C(i, j) m_x^(j) m_v^(i-j)``; ``mx`` and ``mv`` are ``(..., N)`` (broadcast).

    >>> sum_moments([0.0, 1/3], [0.0, 1/3]).round(6).tolist()   # two U(-1,1): var 2/3
    [0.0, 0.666667]
    """
    mx, mv = np.broadcast_arrays(_with_m0(_moments("mx", mx)), _with_m0(_moments("mv", mv)))
    N = mx.shape[-1] - 1
    C = _binom(N)
    out = np.zeros(mx.shape[:-1] + (N,))
    for i in range(1, N + 1):
        j = np.arange(i + 1)
        out[..., i - 1] = np.sum(C[i, j] * mx[..., j] * mv[..., i - j], axis=-1)
    return out


def difference_moments(mz, mv) -> np.ndarray:
    """Moments of ``x`` from those of ``z = x + v`` and of the independent ``v`` (000 eq. 3.14).

    Solved sequentially, ``m_x^(i) = m_z^(i) - sum_{j<i} C(i, j) m_x^(j) m_v^(i-j)``.
    """
    mz = _moments("mz", mz)
    mv = _with_m0(_moments("mv", mv))
    mz, mv = np.broadcast_arrays(mz, mv[..., 1:])
    mv = _with_m0(mv)
    N = mz.shape[-1]
    C = _binom(N)
    mx = np.ones(mz.shape[:-1] + (N + 1,))
    for i in range(1, N + 1):
        j = np.arange(i)
        mx[..., i] = mz[..., i - 1] - np.sum(C[i, j] * mx[..., j] * mv[..., i - j], axis=-1)
    return mx[..., 1:]


def affine_moments(m, scale, shift) -> np.ndarray:
    """Moments of ``scale * x + shift`` (binomial expansion; scale/shift broadcast over the batch)."""
    m = _with_m0(_moments("m", m))
    s = np.asarray(scale, dtype=float)[..., None]
    c = np.asarray(shift, dtype=float)[..., None]
    N = m.shape[-1] - 1
    C = _binom(N)
    out = []
    for i in range(1, N + 1):
        j = np.arange(i + 1)
        out.append(np.sum(C[i, j] * s ** j * m[..., j] * c ** (i - j), axis=-1))
    return np.stack(out, axis=-1)


def uniform_moments(N: int, a: float = -1.0, b: float = 1.0) -> np.ndarray:
    """``m_1 .. m_N`` of the uniform law on ``(a, b)``: ``(b^{i+1} - a^{i+1}) / ((i+1)(b-a))``."""
    i = np.arange(1, N + 1)
    return (b ** (i + 1) - a ** (i + 1)) / ((i + 1) * (b - a))


def power_density_moments(N: int, J: int) -> np.ndarray:
    """Moments of ``f(x) = (J+1)/2 x^J`` on (-1, 1), J even (000 eqs. 3.18, 3.22)."""
    i = np.arange(1, N + 1)
    return np.where(i % 2 == 0, (J + 1) / (J + i + 1), 0.0)


def moments_to_cumulants(m) -> np.ndarray:
    """Cumulants ``k_1 .. k_N`` from raw moments (recursion k_n = m_n - sum C(n-1,j-1) k_j m_{n-j})."""
    m = _with_m0(_moments("m", m))
    N = m.shape[-1] - 1
    k = np.zeros_like(m)
    for n in range(1, N + 1):
        k[..., n] = m[..., n] - sum(math.comb(n - 1, j - 1) * k[..., j] * m[..., n - j] for j in range(1, n))
    return k[..., 1:]


def cumulants_to_moments(k) -> np.ndarray:
    """Raw moments from cumulants (inverse of :func:`moments_to_cumulants`)."""
    k = _with_m0(_moments("k", k))
    N = k.shape[-1] - 1
    m = np.ones_like(k)
    for n in range(1, N + 1):
        m[..., n] = sum(math.comb(n - 1, j - 1) * k[..., j] * m[..., n - j] for j in range(1, n + 1))
    return m[..., 1:]


def is_moment_sequence(m, a: float = -1.0, b: float = 1.0, *, tol: float = 1e-12) -> np.ndarray:
    """Whether ``m_1 .. m_N`` can be the moments of a probability law on ``[a, b]`` (batched).

    The truncated Hausdorff moment problem (Krein & Nudelman 1977, ch. III; Curto & Fialkow 1991,
    Houston J. Math. 17, sec. 4): with ``m_0 = 1``, a law on the compact ``[a, b]`` with these
    moments exists iff, for ``N = 2r``, the Hankel matrix ``[m_{i+j}]_{i,j<=r}`` and the localizing
    matrix of ``(b - x)(x - a)``, ``[(a + b) m_{i+j+1} - m_{i+j+2} - a b m_{i+j}]_{i,j<r}``, are
    positive semi-definite; for ``N = 2r + 1``, those of ``x - a`` and ``b - x``,
    ``[m_{i+j+1} - a m_{i+j}]`` and ``[b m_{i+j} - m_{i+j+1}]`` (``i, j <= r``).  The moments are
    first scaled to those of ``x / max(|a|, |b|)`` (entries within [-1, 1]; a shift to the centre
    would cancel digits in the binomial sums, 1e-5 relative at N = 16 on [0, 1]);
    ``tol`` is the most negative eigenvalue allowed, relative to the largest eigenvalue of the
    matrices (a law on few points, on the boundary of the moment space, has singular matrices whose
    zero eigenvalues round to about ±1e-16 of that scale; those of a law on the two ends vanish).
    Returns a boolean array ``(...)``.

    >>> bool(is_moment_sequence(uniform_moments(6, 0.0, 2.0), 0.0, 2.0))
    True
    >>> bool(is_moment_sequence([0.0, 1.0, 0.0, 0.5]))    # E x^4 < (E x^2)^2: no law has it
    False
    """
    m = _moments("m", m)
    a, b = float(a), float(b)
    if not (np.isfinite(a) and np.isfinite(b) and a < b):
        raise ValueError(f"a, b: expected finite a < b, got a={a!r}, b={b!r}")
    tol = float(V.positive("tol", tol, strict=False))
    s = max(abs(a), abs(b))
    if s != 1.0:  # moments of x / s, on [a/s, b/s] within [-1, 1] (a pure scaling: no cancellation)
        m = m * s ** -np.arange(1.0, m.shape[-1] + 1)
        a, b = a / s, b / s
    m = _with_m0(m)
    N = m.shape[-1] - 1
    mats = []
    if N % 2 == 0:
        r = N // 2
        idx = np.add.outer(np.arange(r + 1), np.arange(r + 1))
        mats.append(m[..., idx])
        if r >= 1:
            i2 = np.add.outer(np.arange(r), np.arange(r))
            mats.append(-m[..., i2 + 2] + (a + b) * m[..., i2 + 1] - a * b * m[..., i2])  # (b - x)(x - a)
    else:
        r = (N - 1) // 2
        i2 = np.add.outer(np.arange(r + 1), np.arange(r + 1))
        mats.append(m[..., i2 + 1] - a * m[..., i2])  # x - a
        mats.append(b * m[..., i2] - m[..., i2 + 1])  # b - x
    w = [np.linalg.eigvalsh(M) for M in mats]
    scale = np.max([np.max(np.abs(x), axis=-1) for x in w], axis=0)
    return np.all([x[..., 0] >= -tol * scale for x in w], axis=0)


# ---------------------------------------------------------------- 1-D polynomial densities

class LegendreDensity:
    """Batched polynomial densities ``f(x) = alpha * sum_i A_i P_i(alpha (x - c))`` on ``[lo, hi]``.

    Parameters
    ----------
    coef : array (..., N+1)
        Legendre coefficients ``A_i`` of the density of the scaled variable ``t`` (000 eq. 2.17).
    lo, hi : array (...)
        Interval ends (broadcast against the batch shape ``coef.shape[:-1]``).

    Notes
    -----
    The polynomial is the least-squares approximation; it may be negative somewhere and need not
    integrate a sub-interval to a positive number (the filters check this, 000 Fig. 7 step 9).
    """

    def __init__(self, coef, lo=-1.0, hi=1.0):
        self.coef = V.as_float_array("coef", coef, ndim_min=1)
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        if np.any(~(hi > lo)):
            raise ValueError(f"lo, hi: expected lo < hi everywhere, got lo={lo!r}, hi={hi!r}")
        shape = np.broadcast_shapes(self.coef.shape[:-1], lo.shape, hi.shape)
        self.coef = np.broadcast_to(self.coef, (*shape, self.coef.shape[-1]))
        self.lo = np.broadcast_to(lo, shape)
        self.hi = np.broadcast_to(hi, shape)

    @property
    def degree(self) -> int:
        return self.coef.shape[-1] - 1

    @property
    def alpha(self) -> np.ndarray:
        return 2.0 / (self.hi - self.lo)

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (self.hi + self.lo)

    @classmethod
    def from_moments(cls, moments, lo=-1.0, hi=1.0) -> "LegendreDensity":
        """Degree-N least-squares density from ``m_1 .. m_N`` of ``x`` on ``[lo, hi]`` (000 eq. 2.17-2.18).

        >>> d = LegendreDensity.from_moments([0.0, 0.6], -1, 1)   # eq. 2.20 with m2 = 0.6
        >>> d.power_coefficients().round(6).tolist()              # a0, a1, a2
        [0.0, 0.0, 1.5]
        """
        m = _moments("moments", moments)
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        if np.any(~(hi > lo)):
            raise ValueError(f"lo, hi: expected lo < hi, got lo={lo!r}, hi={hi!r}")
        N = m.shape[-1]
        alpha = 2.0 / (hi - lo)
        mt = _with_m0(affine_moments(m, alpha, -alpha * 0.5 * (hi + lo)))  # moments of t
        L = _poly_to_leg_matrix(N)
        EP = np.einsum("ik,...k->...i", L, mt)  # E[P_i(t)]
        A = (2 * np.arange(N + 1) + 1) / 2.0 * EP  # 000 eq. 2.17
        return cls(A, lo, hi)

    def _t(self, x):
        return self.alpha * (np.asarray(x, dtype=float) - self.center)

    def pdf(self, x) -> np.ndarray:
        """The polynomial (zero outside ``[lo, hi]``); ``x`` broadcast against the batch shape."""
        t = self._t(x)
        val = self.alpha * np.sum(self.coef * legendre_values(t, self.degree), axis=-1)
        return np.where((t >= -1.0) & (t <= 1.0), val, 0.0)

    def _series_times_x_power(self, p: int) -> np.ndarray:
        """Legendre series (in t) of ``x^p g(t)``, with ``x = c + t / alpha``."""
        out = self.coef
        for _ in range(p):
            out = series_times_x(out, self.alpha, self.center)
        return out

    def integral(self, l, u, power: int = 0) -> np.ndarray:
        """``int_l^u x^power f(x) dx`` exactly, ``[l, u]`` clipped to ``[lo, hi]`` (batched)."""
        if isinstance(power, bool) or not isinstance(power, (int, np.integer)) or power < 0:
            raise ValueError(f"power: expected a non-negative integer, got {power!r}")
        tl = np.clip(self._t(l), -1.0, 1.0)
        tu = np.clip(self._t(u), -1.0, 1.0)
        s = self._series_times_x_power(int(power))
        return legendre_antiderivative(s, tu) - legendre_antiderivative(s, tl)

    def integrals(self, l, u, powers) -> np.ndarray:
        """``int_l^u x^p f`` for each ``p`` in ``powers``, stacked on a last axis."""
        return np.stack([self.integral(l, u, int(p)) for p in powers], axis=-1)

    def moments(self, N: int | None = None) -> np.ndarray:
        """Moments ``m_1 .. m_N`` of the polynomial over its interval (``N`` = degree by default)."""
        N = self.degree if N is None else N
        return self.integrals(self.lo, self.hi, range(1, N + 1))

    def power_coefficients(self) -> np.ndarray:
        """Coefficients ``a_i`` of ``f(x) = sum a_i x^i`` (000 eq. 2.19); ill-conditioned for large N."""
        N = self.degree
        L = _poly_to_leg_matrix(N)
        b = self.alpha[..., None] * np.einsum("...i,ik->...k", self.coef, L)  # in powers of t
        # t = alpha (x - c): expand sum b_k alpha^k (x - c)^k in powers of x.
        out = np.zeros_like(b)
        for k in range(N + 1):
            for j in range(k + 1):
                out[..., j] += b[..., k] * self.alpha ** k * math.comb(k, j) * (-self.center) ** (k - j)
        return out


# ---------------------------------------------------------------- 2-D polynomial densities

class LegendreDensity2D:
    """Batched polynomial densities on boxes ``[lo0, hi0] x [lo1, hi1]``, tensor Legendre basis.

    ``coef[..., i, j]`` multiplies ``P_i(t0) P_j(t1)``; entries with ``i + j > N`` are zero (total
    degree N), so N-th order (mixed) moments determine the density: the least-squares projection
    onto polynomials of total degree ``<= N`` has ``A_ij = (2i+1)(2j+1)/4 E[P_i(t0) P_j(t1)]``.
    """

    def __init__(self, coef, lo, hi):
        self.coef = V.as_float_array("coef", coef, ndim_min=2)
        lo = V.as_float_array("lo", lo, shape_tail=(2,))
        hi = V.as_float_array("hi", hi, shape_tail=(2,))
        if np.any(~(hi > lo)):
            raise ValueError("lo, hi: expected lo < hi componentwise")
        shape = np.broadcast_shapes(self.coef.shape[:-2], lo.shape[:-1], hi.shape[:-1])
        self.coef = np.broadcast_to(self.coef, (*shape, *self.coef.shape[-2:]))
        self.lo = np.broadcast_to(lo, (*shape, 2))
        self.hi = np.broadcast_to(hi, (*shape, 2))

    @property
    def degree(self) -> int:
        return self.coef.shape[-1] - 1

    @property
    def alpha(self):
        return 2.0 / (self.hi - self.lo)

    @property
    def center(self):
        return 0.5 * (self.hi + self.lo)

    @classmethod
    def from_moments(cls, M, lo, hi) -> "LegendreDensity2D":
        """From mixed moments ``M[..., i, j] = E[x0^i x1^j]`` (i + j <= N used; ``M[...,0,0] = 1``)."""
        M = V.as_float_array("M", M, ndim_min=2)
        N = M.shape[-1] - 1
        if M.shape[-2] != N + 1:
            raise ValueError(f"M: expected trailing shape (N+1, N+1), got {M.shape}")
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        alpha = 2.0 / (hi - lo)
        c = 0.5 * (hi + lo)
        # moments of t = alpha (x - c), per component, by a double binomial expansion
        Bt0 = _affine_matrix(N, alpha[..., 0], -alpha[..., 0] * c[..., 0])  # (..., N+1, N+1): t^i = sum_k B[i,k] x^k
        Bt1 = _affine_matrix(N, alpha[..., 1], -alpha[..., 1] * c[..., 1])
        mask = np.add.outer(np.arange(N + 1), np.arange(N + 1)) <= N
        Mm = np.where(mask, M, 0.0)
        Mt = np.einsum("...ik,...kl,...jl->...ij", Bt0, Mm, Bt1)
        L = _poly_to_leg_matrix(N)
        EP = np.einsum("ik,...kl,jl->...ij", L, Mt, L)
        w = (2 * np.arange(N + 1) + 1) / 2.0
        A = np.where(mask, w[:, None] * w[None, :] * EP, 0.0)
        return cls(A, lo, hi)

    def pdf(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        t = self.alpha * (x - self.center)
        P0 = legendre_values(t[..., 0], self.degree)
        P1 = legendre_values(t[..., 1], self.degree)
        val = np.prod(self.alpha, axis=-1) * np.einsum("...ij,...i,...j->...", self.coef, P0, P1)
        inside = np.all((t >= -1) & (t <= 1), axis=-1)
        return np.where(inside, val, 0.0)

    def box_moments(self, N: int | None = None) -> np.ndarray:
        """Mixed moments ``E[x0^i x1^j]`` (i, j <= N) over the whole box, exactly."""
        N = self.degree if N is None else N
        out = np.zeros((*self.coef.shape[:-2], N + 1, N + 1))
        # int over t of t^k P_i(t) dt: closed form via series; use Gauss-Legendre (exact, degree <= N+deg)
        nodes, weights = np.polynomial.legendre.leggauss(N + self.degree + 2)
        P = legendre_values(nodes, self.degree)  # (q, K+1)
        x0 = self.center[..., 0, None] + nodes / self.alpha[..., 0, None]  # (..., q)
        x1 = self.center[..., 1, None] + nodes / self.alpha[..., 1, None]
        pw0 = x0[..., None, :] ** np.arange(N + 1)[:, None]  # (..., N+1, q)
        pw1 = x1[..., None, :] ** np.arange(N + 1)[:, None]
        # int int x0^i x1^j alpha0 alpha1 sum A_kl P_k(t0) P_l(t1) dx0 dx1 = sum_kl A_kl G0[i,k] G1[j,l]
        G0 = np.einsum("...iq,q,qk->...ik", pw0, weights, P)
        G1 = np.einsum("...jq,q,ql->...jl", pw1, weights, P)
        out = np.einsum("...kl,...ik,...jl->...ij", self.coef, G0, G1)
        return out


def _affine_matrix(N: int, s, c) -> np.ndarray:
    """``B[..., i, k]`` with ``(s x + c)^i = sum_k B[i, k] x^k`` (batched s, c)."""
    s = np.asarray(s, dtype=float)
    c = np.asarray(c, dtype=float)
    shape = np.broadcast_shapes(s.shape, c.shape)
    B = np.zeros((*shape, N + 1, N + 1))
    for i in range(N + 1):
        for k in range(i + 1):
            B[..., i, k] = math.comb(i, k) * s ** k * c ** (i - k)
    return B


def pdf_batched_1d(d: LegendreDensity, x) -> np.ndarray:
    """Values ``(..., Q)`` at points ``x (..., Q)`` of a batch of 1-D densities ``d`` of shape ``(...)``."""
    t = d.alpha[..., None] * (x - d.center[..., None])
    P = legendre_values(t, d.degree)
    return d.alpha[..., None] * np.einsum("...i,...qi->...q", d.coef, P)


def pdf_batched_2d(d: LegendreDensity2D, X) -> np.ndarray:
    """Values ``(..., Q)`` at points ``X (..., Q, 2)`` of a batch of 2-D densities ``d`` of shape ``(...)``."""
    t = d.alpha[..., None, :] * (X - d.center[..., None, :])
    P0 = legendre_values(t[..., 0], d.degree)
    P1 = legendre_values(t[..., 1], d.degree)
    return np.prod(d.alpha, axis=-1)[..., None] * np.einsum("...ij,...qi,...qj->...q", d.coef, P0, P1)
