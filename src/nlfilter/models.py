"""Models stated once, in SymPy, with batched numeric functions generated at construction.

Two kinds of model (the forms of seed 004, eqs. 1-2 and 24-25; README, "Conventions"):

* :class:`DiscreteModel` — ``x[k+1] = f(x[k], k) + G(x[k], k) w[k]``,
  ``y[k] = h(x[k], k) + v[k]``, ``w ~ (0, Q)``, ``v ~ (0, R)``;
* :class:`SDEModel` (Itô) — ``dx = f(x, t) dt + G(x, t) dβ``, ``E dβ dβᵀ = Q dt``;
  ``dy = h(x, t) dt + dη``, ``E dη dηᵀ = R dt``.

Every numeric function takes a batch of states ``x`` of shape ``(..., n)`` and a scalar time
(``k`` or ``t``) and returns, in one call:

=========  =====================  ==============================================
name       shape                  meaning
=========  =====================  ==============================================
f          (..., n)               drift / transition
f_x        (..., n, n)            [i, j] = ∂f_i/∂x_j
f_xx       (..., n, n, n)         [i, j, k] = ∂²f_i/∂x_j∂x_k
h          (..., m)               measurement
h_x        (..., m, n)            [i, j] = ∂h_i/∂x_j
h_xx       (..., m, n, n)         [i, j, k] = ∂²h_i/∂x_j∂x_k
G          (..., n, r)            noise gain
G_x        (..., n, r, n)         [i, a, j] = ∂G_ia/∂x_j
G_xx       (..., n, r, n, n)      [i, a, j, k] = ∂²G_ia/∂x_j∂x_k
=========  =====================  ==============================================

A model may also be given as plain Python callables (:meth:`DiscreteModel.from_functions`); a
derivative that was not given is ``None`` and a filter that needs it fails at construction
(:meth:`Model.require`).

Example
-------
>>> import sympy as sp
>>> x = sp.symbols("x")
>>> m = DiscreteModel([x], f=[0.9 * x], h=[x**3], Q=0.1, R=0.2)
>>> m.h_x(np.array([[1.0], [2.0]]), 0)[:, 0, 0].tolist()
[3.0, 12.0]
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import sympy as sp
from sympy.printing.numpy import NumPyPrinter
from sympy.printing.precedence import precedence

from . import _validate as V
from .noise import NoiseLaw, as_law

_DERIVS = ("f", "f_x", "f_xx", "h", "h_x", "h_xx", "G", "G_x", "G_xx")


class FullPrecisionPrinter(NumPyPrinter):
    """NumPy code whose float constants carry full double precision: ``repr(float(c))``, the
    shortest text that reads back to the same double (up to 17 significant digits). SymPy's own
    printer writes 15 (``0.1 + 2**-50`` would become ``0.100000000000001``)."""

    def _print_Float(self, expr):
        value = float(expr)
        if np.isfinite(value):
            return repr(value)
        return super()._print_Float(expr)


def lambdify_numpy(args, exprs, **kw):
    """``sympy.lambdify`` to NumPy with :class:`FullPrecisionPrinter` (the one code generator of
    the library; ``kw`` such as ``cse=True`` pass through)."""
    return sp.lambdify(args, exprs, modules="numpy",
                       printer=FullPrecisionPrinter({"fully_qualified_modules": False, "inline": True,
                                                     "allow_unknown_functions": True}), **kw)


class _Printer(FullPrecisionPrinter):
    """NumPy code with small integer powers written as products (``x*x*x`` is several times
    faster than ``x**3`` on arrays), float constants in full precision."""

    def _print_Pow(self, expr, rational=False):
        if expr.exp.is_Integer and 2 <= int(expr.exp) <= 4:
            base = self.parenthesize(expr.base, precedence(expr))
            return "(" + "*".join([base] * int(expr.exp)) + ")"  # parenthesized: a product, not a power
        return super()._print_Pow(expr, rational=rational)


class _Broadcast:
    """A constant array viewed over a batch shape, the last view kept (filters ask for the same
    batch at every step, and ``np.broadcast_to`` costs microseconds)."""

    def __init__(self, value: np.ndarray):
        self.value = value
        self._batch, self._view = None, None

    def __call__(self, batch: tuple) -> np.ndarray:
        if batch != self._batch:
            self._batch, self._view = batch, np.broadcast_to(self.value, (*batch, *self.value.shape))
        return self._view


class _Batched:
    """A SymPy array expression compiled once (``lambdify`` with ``cse=True``) into a function
    of a state batch ``(..., n)`` and a scalar time, returning ``(..., *shape)``.

    Constant entries are broadcast over the batch (raw ``lambdify`` on matrices does not:
    sympy issues #5642, #19259).
    """

    def __init__(self, exprs, states, time, shape):
        self.shape = tuple(shape)
        flat = [sp.sympify(e) for e in exprs]
        self._const = all(not (e.free_symbols & (set(states) | ({time} if time is not None else set())))
                          for e in flat)
        args = list(states) + ([time] if time is not None else [sp.Symbol("_t_unused")])
        if self._const:
            self._value = _Broadcast(np.array([float(e) for e in flat], dtype=float).reshape(self.shape))
        else:
            self._fn = sp.lambdify(args, flat, modules="numpy", cse=True,
                                   printer=_Printer({"fully_qualified_modules": False, "inline": True,
                                                     "allow_unknown_functions": True}))
        self._n = len(states)

    def __call__(self, x, t=0.0):
        x = np.asarray(x, dtype=float)
        batch = x.shape[:-1]
        if self._const:
            return self._value(batch)
        vals = self._fn(*(x[..., i] for i in range(self._n)), t)
        if len(vals) == 1 and np.shape(vals[0]) == batch:  # one entry: a reshape, no copy
            return np.asarray(vals[0], dtype=float).reshape(*batch, *self.shape)
        out = np.empty((*batch, len(vals)))
        for j, v in enumerate(vals):
            out[..., j] = v
        return out.reshape(*batch, *self.shape)


def _matrix(name, value, rows=None, cols=None) -> sp.Matrix:
    try:
        M = sp.Matrix(value)
    except (TypeError, ValueError, sp.SympifyError) as exc:
        raise TypeError(f"{name}: expected a list or SymPy Matrix of expressions, got {type(value).__name__}") from exc
    if rows is not None and M.shape[0] != rows:
        raise ValueError(f"{name}: expected {rows} row(s), got shape {M.shape}")
    if cols is not None and M.shape[1] != cols:
        raise ValueError(f"{name}: expected {cols} column(s), got shape {M.shape}")
    return M


def _vector(name, value, n=None) -> sp.Matrix:
    """A column of expressions from a list, a row or a column (``n`` entries when given)."""
    M = _matrix(name, value)
    if 1 not in M.shape or (n is not None and M.shape[0] * M.shape[1] != n):
        want = f"{n} expressions" if n is not None else "a list of expressions"
        raise ValueError(f"{name}: expected {want} (a vector), got shape {M.shape}")
    return M.reshape(M.shape[0] * M.shape[1], 1)


class Model:
    """Common part of :class:`DiscreteModel` and :class:`SDEModel` (see the module docstring)."""

    kind = "model"
    time_name = "t"

    def __init__(self, states, f, h, G=None, Q=None, R=None, *, params=None, time=None,
                 process_noise: NoiseLaw | None = None, measurement_noise: NoiseLaw | None = None,
                 name: str = ""):
        if isinstance(states, sp.Symbol):
            states = [states]
        states = list(states)
        if not states or not all(isinstance(s, sp.Symbol) for s in states):
            raise TypeError(f"states: expected a non-empty list of SymPy symbols, got {states!r}")
        if len(set(states)) != len(states):
            raise ValueError(f"states: expected distinct symbols, got {states!r}")
        if time is not None and not isinstance(time, sp.Symbol):
            raise TypeError(f"time: expected a SymPy symbol or None, got {type(time).__name__}")
        self.states = states
        self.time = time
        self.name = name
        n = len(states)
        params = dict(params or {})
        for p in params:
            if not isinstance(p, sp.Symbol):
                raise TypeError(f"params: expected SymPy symbols as keys, got {p!r}")

        fM = _vector("f", f, n)
        hM = _vector("h", h)
        GM = sp.eye(n) if G is None else _matrix("G", G, n, None)
        fM, hM, GM = (M.subs(params) for M in (fM, hM, GM))
        allowed = set(states) | ({time} if time is not None else set())
        for nm, M in (("f", fM), ("h", hM), ("G", GM)):
            extra = M.free_symbols - allowed
            if extra:
                raise ValueError(f"{nm}: uses symbol(s) {sorted(map(str, extra))} that are neither states "
                                 f"{[str(s) for s in states]}, the time symbol, nor given in params")
        self.n, self.m, self.r = n, hM.shape[0], GM.shape[1]
        self.sym = {"f": fM, "h": hM, "G": GM}  # for the moment engine and second-order filters
        self.Q = V.covariance("Q", np.eye(self.r) if Q is None and process_noise is None
                              else (process_noise.cov if Q is None else Q), self.r)
        if R is None and measurement_noise is None:
            raise ValueError("R: expected the measurement noise covariance (m x m), got None")
        self.R = V.covariance("R", measurement_noise.cov if R is None else R, self.m)
        self.process_noise = as_law("process_noise", process_noise, self.Q)
        self.measurement_noise = as_law("measurement_noise", measurement_noise, self.R)
        for nm, law, cov in (("process_noise", self.process_noise, self.Q),
                             ("measurement_noise", self.measurement_noise, self.R)):
            if law.cov.shape != cov.shape or not np.allclose(law.cov, cov, rtol=1e-8, atol=1e-12):
                raise ValueError(f"{nm}: its covariance {law.cov.tolist()} differs from the given "
                                 f"{'Q' if nm.startswith('p') else 'R'} {cov.tolist()}")

        x = sp.Matrix(states)
        fx = fM.jacobian(x)
        hx = hM.jacobian(x)
        fxx = [[[sp.diff(fx[i, j], s) for s in states] for j in range(n)] for i in range(n)]
        hxx = [[[sp.diff(hx[i, j], s) for s in states] for j in range(n)] for i in range(self.m)]
        Gx = [[[sp.diff(GM[i, a], s) for s in states] for a in range(self.r)] for i in range(n)]
        Gxx = [[[[sp.diff(GM[i, a], s, u) for u in states] for s in states] for a in range(self.r)]
               for i in range(n)]
        flat = lambda nested: list(np.array(nested, dtype=object).ravel())  # noqa: E731
        specs = {"f": (list(fM), (n,)), "f_x": (list(fx), (n, n)), "f_xx": (flat(fxx), (n, n, n)),
                 "h": (list(hM), (self.m,)), "h_x": (list(hx), (self.m, n)),
                 "h_xx": (flat(hxx), (self.m, n, n)),
                 "G": (list(GM), (n, self.r)), "G_x": (flat(Gx), (n, self.r, n)),
                 "G_xx": (flat(Gxx), (n, self.r, n, n))}
        for key, (exprs, shape) in specs.items():
            setattr(self, key, _Batched(exprs, states, time, shape))
        self.given = set(_DERIVS)
        # structure flags, read by filters that can exploit them
        self.G_constant = all(e.free_symbols.isdisjoint(states) for e in GM)
        self._GQG0 = (_Broadcast(self.G(np.zeros(n)) @ self.Q @ self.G(np.zeros(n)).T)
                      if all(not e.free_symbols for e in GM) else None)  # fixed G Q Gᵀ, computed once
        self.is_linear = self.G_constant and all(  # f and h affine in the state
            e.is_polynomial(*states) and sp.Poly(e, *states).total_degree() <= 1 for e in list(fM) + list(hM))
        # f, h and G do not depend on the time: filters may compute time-fixed quantities once
        self.time_invariant = time is None or not any(M.has(time) for M in (fM, hM, GM))

    # -- construction from plain callables -----------------------------------------------------
    @classmethod
    def from_functions(cls, n: int, m: int, f: Callable, h: Callable, *, Q, R, G: Callable | None = None,
                       r: int | None = None, f_x=None, f_xx=None, h_x=None, h_xx=None, G_x=None, G_xx=None,
                       process_noise=None, measurement_noise=None, name: str = "", is_linear: bool = False,
                       time_invariant: bool = False):
        """A model from callables ``f(x, t)``, ``h(x, t)`` (and ``G(x, t)``, derivatives) that take a
        batch ``(..., n)``. Derivatives not given are ``None``; filters that need them say so.

        The callables receive the time (``k`` or ``t``) at every call, so the model is taken to
        vary with it unless ``time_invariant=True`` promises that none of them reads it (filters
        then compute time-fixed quantities, such as the Kalman filter's matrices, once)."""
        self = cls.__new__(cls)
        V.positive("n", n, integer=True)
        V.positive("m", m, integer=True)
        self.n, self.m, self.name, self.time, self.states, self.sym = n, m, name, None, None, None
        Qa = V.covariance("Q", Q)
        self.r = Qa.shape[0] if r is None else r
        self.Q = V.covariance("Q", Q, self.r)
        self.R = V.covariance("R", R, m)
        self.process_noise = as_law("process_noise", process_noise, self.Q)
        self.measurement_noise = as_law("measurement_noise", measurement_noise, self.R)
        for key, fn in (("f", f), ("h", h)):
            if not callable(fn):
                raise TypeError(f"{key}: expected a callable {key}(x, t), got {type(fn).__name__}")
        if G is None:
            if self.r != n:
                raise ValueError(f"G: expected a callable when Q is {self.r}x{self.r} and n = {n}, got None")
            eye = np.eye(n)
            G = lambda x, t=0.0: np.broadcast_to(eye, (*np.shape(x)[:-1], n, n))  # noqa: E731
            zero = np.zeros((n, n, n))
            G_x = G_x or (lambda x, t=0.0: np.broadcast_to(zero, (*np.shape(x)[:-1], n, n, n)))  # noqa: E731
            zero2 = np.zeros((n, n, n, n))
            G_xx = G_xx or (lambda x, t=0.0: np.broadcast_to(zero2, (*np.shape(x)[:-1], n, n, n, n)))  # noqa: E731
            self.G_constant = True
            self._GQG0 = _Broadcast(self.Q)
        else:
            self._GQG0 = None
            self.G_constant = False
        fns = {"f": f, "h": h, "G": G, "f_x": f_x, "f_xx": f_xx, "h_x": h_x, "h_xx": h_xx, "G_x": G_x, "G_xx": G_xx}
        for key, fn in fns.items():
            if fn is not None and not callable(fn):
                raise TypeError(f"{key}: expected a callable or None, got {type(fn).__name__}")
            setattr(self, key, fn)
        self.given = {k for k, v in fns.items() if v is not None}
        self.is_linear = bool(is_linear)
        if not isinstance(time_invariant, bool):
            raise TypeError(f"time_invariant: expected True or False, got {type(time_invariant).__name__}")
        self.time_invariant = time_invariant
        return self

    @classmethod
    def linear(cls, F, H, Q, R, G=None, *, process_noise: NoiseLaw | None = None,
               measurement_noise: NoiseLaw | None = None, name: str = ""):
        """A linear model ``f = F x``, ``h = H x`` (``G`` constant, identity by default)."""
        F = V.as_float_array("F", F, ndim=2)
        H = V.as_float_array("H", H, ndim=2)
        if F.shape[0] != F.shape[1]:
            raise ValueError(f"F: expected a square matrix, got shape {F.shape}")
        if H.shape[1] != F.shape[0]:
            raise ValueError(f"H: expected {F.shape[0]} columns, got shape {H.shape}")
        xs = sp.symbols(f"x1:{F.shape[0] + 1}")
        X = sp.Matrix(xs)
        Fm = sp.Matrix(F.tolist()) * X
        Hm = sp.Matrix(H.tolist()) * X
        return cls(list(xs), Fm, Hm, None if G is None else sp.Matrix(np.asarray(G, float).tolist()), Q, R,
                   process_noise=process_noise, measurement_noise=measurement_noise, name=name)

    def require(self, *names: str, by: str = "this filter") -> None:
        """Raise ``ValueError`` naming each derivative in ``names`` that the model lacks."""
        missing = [k for k in names if k not in self.given or getattr(self, k, None) is None]
        if missing:
            raise ValueError(f"model: {by} needs {', '.join(missing)}, which the model does not give; "
                             "state the model in SymPy or pass these callables to from_functions")

    def Gw(self, x, w, t=0.0) -> np.ndarray:
        """``G(x) w`` for a batch of states ``(..., n)`` and noises ``(..., r)`` (matmul when G is constant)."""
        if self.G_constant:
            return w @ self.G(np.zeros(self.n), t).T
        return np.einsum("...ia,...a->...i", self.G(x, t), w)

    def GQGT(self, x, t=0.0) -> np.ndarray:
        """G Q Gᵀ at a batch of states, shape (..., n, n)."""
        if self._GQG0 is not None:
            return self._GQG0(np.shape(x)[:-1])
        Gx = self.G(x, t)
        return np.einsum("...ia,ab,...jb->...ij", Gx, self.Q, Gx)

    def __repr__(self):
        return f"{type(self).__name__}(n={self.n}, m={self.m}, r={self.r}{', ' + self.name if self.name else ''})"


class DiscreteModel(Model):
    """``x[k+1] = f(x[k], k) + G(x[k], k) w[k]``, ``y[k] = h(x[k], k) + v[k]`` (see module docstring).

    Parameters
    ----------
    states : list of sympy.Symbol, length n
    f : n expressions;  h : m expressions;  G : n x r matrix (identity if omitted)
    Q : (r, r) covariance of w;  R : (m, m) covariance of v
    params : {Symbol: value} substituted at construction
    time : the step-index symbol, if f, h or G depend on it
    process_noise, measurement_noise : laws used to *simulate* w and v (Gaussian by default)
    """

    kind = "discrete"
    time_name = "k"


class SDEModel(Model):
    """Itô SDE ``dx = f(x, t) dt + G(x, t) dβ``, ``dy = h(x, t) dt + dη`` (see module docstring).

    ``Q`` and ``R`` are the intensities: ``E dβ dβᵀ = Q dt``, ``E dη dηᵀ = R dt``. Simulation uses
    Gaussian increments (``process_noise``/``measurement_noise`` laws other than Gaussian are
    rejected).
    """

    kind = "sde"
    time_name = "t"

    def __init__(self, states, f, h, G=None, Q=None, R=None, *, params=None, time=None,
                 process_noise: NoiseLaw | None = None, measurement_noise: NoiseLaw | None = None,
                 name: str = ""):
        super().__init__(states, f, h, G, Q, R, params=params, time=time, process_noise=process_noise,
                         measurement_noise=measurement_noise, name=name)
        from .noise import Gaussian
        for nm in ("process_noise", "measurement_noise"):
            if not isinstance(getattr(self, nm), Gaussian):
                raise ValueError(f"{nm}: an SDEModel is driven by Brownian motion; expected None or "
                                 f"Gaussian, got {type(getattr(self, nm)).__name__}")
