"""Bilinear stochastic systems (seed 001, Vallot 1981, eqs. 2.19-2.20) and exact bilinear lifts of
polynomial models (001 eq. 5.5).

Continuous time (Itô)::

    dx = (F x + c) dt + Σ_i G_i x dw_i + B dw_a            E dw_i² = dt, E dw_a dw_aᵀ = Q dt
    dy = (H x + d) dt + Σ_j M_j x dv_j + dv_a              E dv_j² = dt, E dv_a dv_aᵀ = R dt

Discrete time (``discrete=True``; the thesis' first suggestion for future work)::

    x[k+1] = F x[k] + c + Σ_i G_i x[k] w_i[k] + B w_a[k],   y[k] = H x[k] + d + Σ_j M_j x[k] v_j[k] + v_a[k]

All noises are independent, standard (``w_i``, ``v_j``) or of covariance ``Q``/``R`` (``w_a``,
``v_a``), and independent of ``x0``. Additive noise and offsets are turned into the constant-state
augmentation of 001 §2.2 automatically: ``z = (x, 1)`` and every term becomes bilinear in ``z``
(:meth:`BilinearModel.augmented`). Matrices may depend on the time symbol ``time`` (SymPy).

A polynomial SDE ``dx = f dt + G dβ`` with ``f`` affine and ``G`` affine in ``x`` lifts *exactly*
to a bilinear system on the vector of all monomials up to a degree (the Itô rule maps monomials of
degree ≤ p to degree ≤ p); with ``h`` polynomial of degree ≤ p the measurement becomes linear.
:meth:`BilinearModel.from_polynomial` detects this and builds the lift, e.g. the cubic sensor's
``(x, x², x³)`` (001 eq. 5.5).

>>> import sympy as sp
>>> import numpy as np
>>> from nlfilter.models import SDEModel
>>> x = sp.Symbol("x")
>>> cubic = SDEModel([x], [-x], [x**3], Q=2.0, R=1.0)
>>> lift = BilinearModel.from_polynomial(cubic)
>>> lift.coords, np.round(lift.augmented(0).F, 12).tolist()       # 001 eq. 5.5 with q = 2
([(1,), (2,), (3,)], [[-1.0, 0.0, 0.0, 0.0], [0.0, -2.0, 0.0, 2.0], [6.0, 0.0, -3.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import sympy as sp

from . import _validate as V
from .codegen import lambdify_numpy
from .errors import NotPolynomialError
from .model_expressions import check_expressions
from .moments.closed import bilinear_lift
from .moments.ito import PolynomialSDE
from .polynomials import Polynomial, monomial_name, monomials


class Augmented(NamedTuple):
    """Bilinear matrices of ``z = (x, 1)`` (or ``z = x`` when nothing is additive):
    ``dz = F z dt + Σ G_i z dw_i``, ``dy = H z dt + Σ M_j z dv_j`` with standard noises."""

    F: np.ndarray   # (N, N)
    G: np.ndarray   # (q, N, N)
    H: np.ndarray   # (m, N)
    M: np.ndarray   # (r, m, N)


def _mat(name, value, shape, time):
    """A constant float array, or a SymPy matrix in ``time`` compiled to a function of t."""
    if value is None:
        return np.zeros(shape)
    if isinstance(value, sp.MatrixBase) or (isinstance(value, (list, tuple)) and any(
            isinstance(v, sp.Basic) for v in np.ravel(np.array(value, dtype=object)))):
        M = sp.Matrix(value)
        if M.shape != shape:
            raise ValueError(f"{name}: expected shape {shape}, got {M.shape}")
        check_expressions(name, M, True)
        extra = M.free_symbols - ({time} if time is not None else set())
        if extra:
            raise ValueError(f"{name}: uses symbol(s) {sorted(map(str, extra))} other than the time symbol {time}")
        if not M.free_symbols:
            return np.array(M.tolist(), dtype=float)
        fn = lambdify_numpy([time], M)
        return lambda t: np.asarray(fn(t), dtype=float)
    arr = V.as_float_array(name, value)
    if arr.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    V.finite(name, arr)
    return arr


def _column(name, value, k):
    """A vector of ``k`` entries (numbers or SymPy expressions) as a ``(k, 1)`` column."""
    if isinstance(value, sp.MatrixBase):
        if 1 not in value.shape or value.shape[0] * value.shape[1] != k:
            raise ValueError(f"{name}: expected a vector of {k} entries, got shape {value.shape}")
        return value.reshape(k, 1)
    if np.size(value) != k or np.ndim(value) > 2 or (np.ndim(value) == 2 and 1 not in np.shape(value)):
        raise ValueError(f"{name}: expected a vector of {k} entries, got shape {np.shape(value)}")
    return np.reshape(np.array(value, dtype=object), (k, 1)).tolist()


def _at(M, t):
    return M(t) if callable(M) else M


class BilinearModel:
    """A bilinear system (see the module docstring).

    Parameters
    ----------
    F : (n, n)
    H : (m, n)
    G : sequence of (n, n) — multiplicative process noise, standard Brownian motions (001 eq. 2.19)
    M : sequence of (m, n) — multiplicative measurement noise (001 eq. 2.20)
    B, Q : (n, p) and (p, p) — additive process noise ``B dw_a``, ``E dw_a dw_aᵀ = Q dt`` (Q = I if omitted)
    R : (m, m) — additive measurement noise intensity
    c, d : (n,), (m,) — constant drift and measurement offsets
    time : SymPy symbol the matrices may depend on
    discrete : bool — the discrete-time model instead of the Itô SDE
    names : state names

    Attributes
    ----------
    n, m : dimensions of x and y;  N : dimension of the augmented state (n or n + 1)
    coords : for a lift, the monomial (in ``base_states``) of each coordinate of x; else unit vectors
    base_states : SymPy symbols of the underlying variables
    """

    kind = "bilinear"

    def __init__(self, F, H, *, G=(), M=(), B=None, Q=None, R=None, c=None, d=None, time=None,
                 discrete: bool = False, names=None):
        shape = lambda M: tuple(M.shape) if isinstance(M, sp.MatrixBase) else np.shape(M)  # noqa: E731
        Fs = shape(F)
        if len(Fs) != 2 or Fs[0] != Fs[1] or Fs[0] == 0:
            raise ValueError(f"F: expected a square (n, n) matrix, got shape {Fs}")
        n = Fs[0]
        Hs = shape(H)
        if len(Hs) != 2 or Hs[1] != n:
            raise ValueError(f"H: expected shape (m, {n}), got {Hs}")
        m = Hs[0]
        self.n, self.m, self.time, self.discrete = n, m, time, bool(discrete)
        self.F = _mat("F", F, (n, n), time)
        self.H = _mat("H", H, (m, n), time)
        self.G = [_mat(f"G[{i}]", g, (n, n), time) for i, g in enumerate(G)]
        self.M = [_mat(f"M[{j}]", mm, (m, n), time) for j, mm in enumerate(M)]
        if B is None and Q is not None:
            raise ValueError("Q: given without B (the additive process noise gain)")
        if B is not None:
            Bs = B.shape if isinstance(B, sp.MatrixBase) else np.shape(B)
            if len(Bs) != 2 or Bs[0] != n:
                raise ValueError(f"B: expected shape ({n}, p), got {Bs}")
            self.B = _mat("B", B, tuple(Bs), time)
            self.Q = V.covariance("Q", np.eye(Bs[1]) if Q is None else Q, Bs[1])
        else:
            self.B, self.Q = None, None
        self.R = None if R is None else V.covariance("R", R, m)
        self.c = None if c is None else _mat("c", _column("c", c, n), (n, 1), time)
        self.d = None if d is None else _mat("d", _column("d", d, m), (m, 1), time)
        self.augment = any(v is not None for v in (self.B, self.R, self.c, self.d))
        self.N = n + 1 if self.augment else n
        self.names = list(names) if names is not None else [f"x{i + 1}" for i in range(n)]
        if len(self.names) != n:
            raise ValueError(f"names: expected {n} names, got {len(self.names)}")
        self.base_states = [sp.Symbol(s) for s in self.names]
        self.coords = [tuple(int(i == j) for j in range(n)) for i in range(n)]
        self.source = None  # the polynomial model a lift came from
        self.time_varying = any(callable(v) for v in [self.F, self.H, self.B, self.c, self.d, *self.G, *self.M])
        if not self.G and self.B is None:
            pass  # deterministic state: allowed (e.g. a constant to be estimated)
        if not self.M and self.R is None:
            raise ValueError("M, R: the measurement has no noise; give R (additive) or M (multiplicative)")

    # -- matrices -------------------------------------------------------------------------------
    def augmented(self, t=0.0) -> Augmented:
        """The bilinear matrices of ``z = (x, 1)`` at time ``t`` (001 §2.2 augmentation)."""
        n, m, N = self.n, self.m, self.N
        F = np.zeros((N, N))
        F[:n, :n] = _at(self.F, t)
        if self.c is not None:
            F[:n, n] = _at(self.c, t)[:, 0]
        if self.augment and self.discrete:
            F[n, n] = 1.0  # the constant state: 1[k+1] = 1[k] (in continuous time d1 = 0)
        Gs = []
        for g, g0 in self._noises(t):
            Gz = np.zeros((N, N))
            Gz[:n, :n] = g
            if g0 is not None:
                Gz[:n, n] = g0
            Gs.append(Gz)
        H = np.zeros((m, N))
        H[:, :n] = _at(self.H, t)
        if self.d is not None:
            H[:, n] = _at(self.d, t)[:, 0]
        Ms = []
        for mm in self.M:
            Mz = np.zeros((m, N))
            Mz[:, :n] = _at(mm, t)
            Ms.append(Mz)
        if self.R is not None:
            Rh = _sqrt_psd(self.R)
            for a in range(m):
                Mz = np.zeros((m, N))
                Mz[:, n] = Rh[:, a]
                Ms.append(Mz)
        return Augmented(F, np.array(Gs).reshape(len(Gs), N, N), H, np.array(Ms).reshape(len(Ms), m, N))

    def _noises(self, t=0.0):
        """The standard process noises as pairs ``(G_i, g_i)``: ``(G_i x + g_i) dw_i``."""
        if self._affine is not None:
            return self._affine
        out = [(_at(g, t), None) for g in self.G]
        if self.B is not None:
            Bq = _at(self.B, t) @ _sqrt_psd(self.Q)
            out += [(np.zeros((self.n, self.n)), Bq[:, a]) for a in range(Bq.shape[1])]
        return out

    _affine = None

    @property
    def constant_index(self):
        """Index of the constant coordinate ``1`` in the augmented state, or None."""
        return self.n if self.augment else None

    # -- other views -----------------------------------------------------------------------------
    def to_sde(self):
        """The same problem as an :class:`~nlfilter.models.SDEModel` in ``base_states`` (so every
        other nlfilter filter runs on it). Needs additive-only measurement noise."""
        from .models import SDEModel
        if self.discrete:
            raise ValueError("to_sde: the model is discrete-time; use to_discrete()")
        return self._to_model(SDEModel)

    def to_discrete(self):
        """The same problem as a :class:`~nlfilter.models.DiscreteModel` (discrete models only)."""
        from .models import DiscreteModel
        if not self.discrete:
            raise ValueError("to_discrete: the model is continuous-time; use to_sde()")
        return self._to_model(DiscreteModel)

    def _to_model(self, cls):
        if self.source is not None:
            return self.source
        if self.M:
            raise ValueError("M: SDEModel/DiscreteModel take additive measurement noise only; this model has "
                             f"{len(self.M)} multiplicative measurement noise term(s)")
        if self.time_varying:
            raise ValueError("to_sde: time-varying bilinear models are not converted (give a SymPy SDEModel)")
        x = sp.Matrix(self.base_states)
        f = sp.Matrix(self.F.tolist()) * x
        if self.c is not None:
            f += sp.Matrix(self.c.tolist())
        h = sp.Matrix(self.H.tolist()) * x
        if self.d is not None:
            h += sp.Matrix(self.d.tolist())
        cols = []
        for g, g0 in self._noises():
            col = sp.Matrix(g.tolist()) * x
            if g0 is not None:
                col += sp.Matrix(g0.tolist())
            cols.append(col)
        Qf = np.eye(len(cols))
        if not cols:
            raise ValueError("to_sde: the state has no noise at all")
        Gm = sp.Matrix.hstack(*cols)
        return cls(self.base_states, f, h, Gm, Qf, self.R, time=self.time)

    def poly_sde(self) -> PolynomialSDE:
        """The state equation in ``base_states`` as a :class:`~nlfilter.moments.ito.PolynomialSDE`
        with its noise columns, standard noises (multiplicative ones first, then the columns of
        ``B Q^{1/2}``); constant-time models only."""
        if self._base is not None:
            return self._base
        if self.time_varying:
            raise ValueError("poly_sde: time-varying models have no stationary moment system")
        aug = self.augmented(0)
        n, N = self.n, self.N
        zero = (0,) * n
        unit = [tuple(int(i == j) for j in range(n)) for i in range(n)]
        z = unit + ([zero] if self.augment else [])  # augmented coordinate k as a monomial of x

        def row(M, i):
            return Polynomial({z[k]: float(M[i, k]) for k in range(N) if M[i, k] != 0}, n)

        drift = [row(aug.F, i) for i in range(n)]
        diff = [[row(G, i) for G in aug.G] or [Polynomial({}, n)] for i in range(n)]
        r = max(len(aug.G), 1)
        self._base = PolynomialSDE.from_noise(drift, diff, np.eye(r), names=list(self.names))
        return self._base

    _base = None

    def coord_polys(self) -> list:
        """Each augmented coordinate as a :class:`~nlfilter.polynomials.Polynomial` in ``base_states``."""
        nb = len(self.base_states)
        out = [Polynomial({e: 1.0}, nb) for e in self.coords]
        if self.augment:
            out.append(Polynomial.constant(1.0, nb))
        return out

    # -- lifting -------------------------------------------------------------------------------------
    @classmethod
    def from_polynomial(cls, model, degree: int | None = None):
        """Exact bilinear lift of a polynomial :class:`~nlfilter.models.SDEModel` whose drift and
        noise gain are affine in the state (then the monomials of degree ≤ ``degree`` are closed
        under the Itô rule). ``degree`` defaults to the measurement's degree.

        The lifted state is every monomial of degree 1 to ``degree`` (ordered by degree, ``coords``),
        augmented with 1 (001 eq. 5.5 for the cubic sensor). Raises :class:`NotPolynomialError`
        when the model does not lift exactly (drift or noise gain of degree > 1, or a
        non-polynomial term), naming the offending term.
        """
        if getattr(model, "kind", None) != "sde" or model.sym is None:
            raise TypeError(f"model: expected a SymPy-built SDEModel, got {type(model).__name__}")
        if model.time is not None:
            raise ValueError("model: time-varying polynomial models are not lifted")
        xs = model.states
        nb = len(xs)
        for name, M in (("f", model.sym["f"]), ("G", model.sym["G"])):
            for e in M:
                deg = Polynomial.from_sympy(e, xs, name=f"model.{name}", numeric=True).degree
                if deg > 1:
                    raise NotPolynomialError(
                        f"model.{name}: term {e} has degree {deg} in the state; only affine drift and noise "
                        "gain lift exactly to a bilinear system (the Itô rule then preserves the degree)")
        hpolys = [Polynomial.from_sympy(e, xs, name="model.h", numeric=True) for e in model.sym["h"]]
        hdeg = max((sum(k) for p in hpolys for k in p.terms), default=1)
        degree = hdeg if degree is None else V.positive("degree", degree, integer=True)
        if degree < hdeg:
            raise ValueError(f"degree: {degree} is below the measurement's degree {hdeg}")
        coords = monomials(nb, degree, min_degree=1)
        idx = {e: k for k, e in enumerate(coords)}
        N = len(coords)
        Lq = _sqrt_psd(model.Q)
        G = model.sym["G"] * sp.Matrix(Lq.tolist())  # standard noises
        sde = PolynomialSDE.from_sympy(xs, model.sym["f"], G=G, Q=np.eye(G.shape[1]))
        zero = (0,) * nb
        A, Bs = bilinear_lift(sde, coords + [zero])  # z = (coords, 1): split off the constant column
        F, c = A[:N, :N], A[:N, N]
        Gs = np.array([B[:N, :N] for B in Bs])
        Bc = np.array([B[:N, N] for B in Bs]).T
        m = model.m
        H = np.zeros((m, N))
        d = np.zeros(m)
        for i, p in enumerate(hpolys):
            for mon, v in p.terms.items():
                if mon == zero:
                    d[i] += v
                else:
                    H[i, idx[mon]] += v
        # noise a enters the lift as (G_a z + g_a) dw_a: one standard noise with a multiplicative
        # part and a constant column (the cubic sensor's d(x²) = ... + 2x dw, dx = ... + dw)
        names = [monomial_name(e, [str(s) for s in xs]) for e in coords]
        self = cls(F, H, G=[Gs[a] for a in range(sde.r)], R=model.R, c=c, d=d if np.any(d) else None,
                   names=names)
        self._affine = [(Gs[a], Bc[:, a]) for a in range(sde.r)]
        self.coords = coords
        self.base_states = list(xs)
        self.source = model
        self._base = sde
        return self

    def __repr__(self):
        kind = "discrete" if self.discrete else "continuous"
        return f"BilinearModel(n={self.n}, m={self.m}, {kind}, q={len(self.G)}, r={len(self.M)}, augmented={self.augment})"


def _sqrt_psd(S):
    """A square root ``L`` with ``L Lᵀ = S`` for a PSD ``S`` (eigen-decomposition)."""
    S = np.asarray(S, dtype=float)
    w, U = np.linalg.eigh(0.5 * (S + S.T))
    return U * np.sqrt(np.clip(w, 0.0, None))


class PhaseModel(BilinearModel):
    """The phase-tracking problem (001 eqs. 4.1-4.6, 4.11-4.14) as a :class:`BilinearModel` in
    rectangular coordinates ``x = (sin θ, cos θ)``, carrying its parameters: ``q`` the intensity of
    the Brownian phase θ, ``r`` the baseband noise parameter (``E dn dnᵀ = 2 r I dt``), and
    ``P = √(2 r q)`` the noise-to-signal parameter (001 eq. 4.9). ``kind = "phase"``: the phase
    filters (:mod:`nlfilter.filters.phase`) take this model; every bilinear filter takes it too."""

    kind = "phase"

    def __init__(self, q: float, r: float):
        self.q, self.r = float(V.positive("q", q)), float(V.positive("r", r))
        J = np.array([[0.0, 1.0], [-1.0, 0.0]])
        super().__init__(-self.q / 2 * np.eye(2), np.eye(2), G=[np.sqrt(self.q) * J], R=2 * self.r * np.eye(2),
                         names=["x1", "x2"])

    @property
    def P(self) -> float:
        """``P_θℓ = √(2 r q)`` (001 eq. 4.9)."""
        return float(np.sqrt(2 * self.r * self.q))

    def __repr__(self):
        return f"PhaseModel(q={self.q:g}, r={self.r:g})"


def phase_model(q: float, r: float) -> PhaseModel:
    """Phase tracking in rectangular coordinates (001 eqs. 4.12-4.14): ``x = (sin θ, cos θ)``,
    ``dθ`` of intensity ``q``, baseband measurement ``dz = x dt + dn``, ``E dn dnᵀ = 2 r I dt``
    (a :class:`PhaseModel`).

    >>> phase_model(1.0, 0.5).augmented(0).G[0][:2, :2].tolist()   # dx = J x dθ, q = 1
    [[0.0, 1.0], [-1.0, 0.0]]
    """
    return PhaseModel(q, r)


__all__ = ["BilinearModel", "Augmented", "PhaseModel", "phase_model"]
