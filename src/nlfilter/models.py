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

``f``, ``h``, ``G`` and the Jacobians ``f_x``, ``h_x`` are generated at construction; the second
derivatives ``f_xx``, ``h_xx`` and G's derivatives ``G_x``, ``G_xx`` on their first call (a filter
that never uses them never pays for them), once for the model and all its :meth:`Model.with_params`
copies; a ``G`` free of the states has ``G_x = G_xx = 0`` without any SymPy.

Parameters (``params={a: 0.9, q: 0.1}``) stay symbols of the generated functions: a model
with other values is :meth:`Model.with_params` (no code generated again; what a fit needs), and
``Q``/``R`` may be expressions in them (``Q=[[q]]``). A value may be an array over time ``(T,)``
or per path ``(B, T)`` (``B`` the filtered batch), read at entry ``k`` at step ``k`` (SDE models:
piecewise constant on a grid ``dt``); control inputs (``inputs=[u]``) are such arrays, given by
:meth:`Model.with_inputs` ``u (..., T, p)``. A time-varying ``Q`` is carried by ``G``
(``G_k Q_k^{1/2}``, ``model.Q`` the identity); a ``R`` varying with parameter arrays is not
supported.

Structure beyond additive, uncorrelated noise with one constant R (:attr:`Model.structure`;
each filter lists in ``structures`` what it handles and refuses the rest at construction):

* ``R`` in the states (and the time symbol): ``v_k ~ N(0, R(x_k, k))``, evaluated by
  :meth:`Model.R_of` (``R_constant`` False; ``model.R`` then raises, naming the filters that take
  R(x)). Discrete models only.
* ``cross_noise=S`` ``(r, m)``: ``E[w_k v_kᵀ] = S`` (w_k drives x_{k+1}, v_k corrupts y_k);
  constant G and R, the joint covariance checked positive semi-definite.
* ``noise=[w1, ..., wr]``: non-additive process noise, ``x[k+1] = f(x[k], w[k], k)`` with the
  noise symbols in ``f`` (``G`` not given, ``Q`` their covariance); :meth:`Model.transition`
  evaluates it (``f_aug`` on the augmented vector ``(x, w)``), ``model.f`` is ``f(x, 0)`` and
  ``model.G`` is ``∂f/∂w`` at ``w = 0``.
* ``meas_noise=[v1, ..., vp]``: non-additive measurement noise, ``y[k] = h(x[k], v[k], k)``
  (``R`` the ``p x p`` covariance of v); :meth:`Model.measurement` evaluates it (``h_aug``),
  ``model.h`` is ``h(x, 0)``.

Functions (checked at construction, :data:`SUPPORTED_FUNCTIONS`): f, h, G and symbolic Q, R are
real, finite expressions (no ``I``, ``oo``, ``zoo``, ``nan``; a ``ValueError`` names the field
and the entry) of ``+ * **`` (``sqrt`` included), ``pi``, ``E`` and ``exp log sin cos tan cot
sec csc asin acos atan atan2 sinh cosh tanh asinh acosh atanh erf erfc`` (smooth: SymPy's
derivatives), and the piecewise-smooth ``Abs sign floor ceiling Heaviside Max Min``, evaluated as
NumPy does, whose derivatives (EKF Jacobians, second-order Hessians) follow one convention, the
derivative almost everywhere: ``Abs' = sign``; ``sign' = floor' = ceiling' = Heaviside' = 0``
(no Dirac delta); ``∂Max(a, b)/∂a = Heaviside(a - b)`` and ``∂Min(a, b)/∂a = Heaviside(b - a)``
(1/2 each at a tie; more arguments fold pairwise). ``Heaviside(0)`` is SymPy's ``H0`` (1/2 by
default). Any other function (``DiracDelta``, ``Piecewise``, an undefined ``Function("g")``) is
refused naming it. The compiled backend (``backend="numba"``) does not take the piecewise
functions. Scalars reach the generated code as NumPy floats, so a singularity (``x/t`` at
``t = 0``) gives ``inf``/``nan`` with NumPy's warning, which the filters' divergence screening
then reports, never a ``ZeroDivisionError``.

>>> import sympy as sp
>>> x, u = sp.symbols("x u")
>>> m = DiscreteModel([x], [0.5 * x + u], [x], Q=1.0, R=1.0, inputs=[u]).with_inputs([[1.0], [2.0]])
>>> m.f(np.array([2.0]), 1).tolist(), m.time_invariant
([3.0], False)

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

import copy
import weakref
from types import MappingProxyType
from typing import Callable

import numpy as np
import sympy as sp
from sympy.core.function import AppliedUndef

from . import _validate as V
from .codegen import first_derivatives, is_affine, jacobian, lambdify_arrays
from .noise import Gaussian, NoiseLaw, as_law

_DERIVS = ("f", "f_x", "f_xx", "h", "h_x", "h_xx", "G", "G_x", "G_xx")

_STATE_R = ("model.R: this model's measurement noise covariance depends on the state (R(x)), so it has no "
            "single matrix R; a filter that needs one (off-line gains, QLF/MQLF, moment filters, the Kalman "
            "filter, continuous-time filters) cannot take it. Use a Gaussian filter (EKF, UKF, CKF, GHKF, "
            "second-order: R at the predicted mean), GridFilter or ParticleFilter (R(x) exactly); "
            "model.R_of(x, k) evaluates it")


class _PiecewiseFn(sp.Function):
    """A piecewise-smooth function in the generated code, with the derivative convention of the
    module docstring ("Functions"): derivatives taken almost everywhere (``fdiff``; zero, that of a
    step function, unless a subclass says otherwise), printed as the NumPy ufunc ``ufunc``. Used
    only for code generation (:func:`_code_form`); the model's own expressions keep SymPy's
    ``Abs``, ``sign``, ..."""

    ufunc = ""

    @classmethod
    def eval(cls, *args):
        if all(a.is_Number for a in args):  # numbers: SymPy's own function evaluates them
            return cls.sympy(*args)

    def fdiff(self, argindex=1):
        return sp.S.Zero

    def _numpycode(self, printer):
        return f"{self.ufunc}({', '.join(printer._print(a) for a in self.args)})"


def _piecewise_fn(name, nargs, ufunc, sympy_fn, base=_PiecewiseFn, **attrs):
    return type(name, (base,), {"nargs": nargs, "ufunc": ufunc, "sympy": sympy_fn, **attrs})


_Sign = _piecewise_fn("_Sign", 1, "sign", sp.sign)
_Floor = _piecewise_fn("_Floor", 1, "floor", sp.floor)
_Ceiling = _piecewise_fn("_Ceiling", 1, "ceil", sp.ceiling)
_Step = _piecewise_fn("_Step", 2, "heaviside", sp.Heaviside)  # Heaviside(u, H0): H0 at u = 0


class _Abs(_PiecewiseFn):
    nargs, ufunc, sympy = 1, "absolute", sp.Abs

    def fdiff(self, argindex=1):
        return _Sign(self.args[0])


class _Extremum(_PiecewiseFn):
    """max(a, b) (``side`` 1) or min(a, b) (``side`` -1): the derivative 1 in the argument that
    wins, 0 in the other, 1/2 in each at a tie."""

    def fdiff(self, argindex=1):
        a, b = self.args
        return _Step(self.side * (a - b if argindex == 1 else b - a), sp.S.Half)


_Max = _piecewise_fn("_Max", 2, "maximum", sp.Max, _Extremum, side=1)
_Min = _piecewise_fn("_Min", 2, "minimum", sp.Min, _Extremum, side=-1)


def _pairwise(cls, args):
    out = args[0]
    for a in args[1:]:
        out = cls(out, a)
    return out


_PIECEWISE = {sp.Abs: _Abs, sp.sign: _Sign, sp.floor: _Floor, sp.ceiling: _Ceiling,
              sp.Heaviside: lambda u, h0=sp.S.Half: _Step(u, sp.S.Half if h0 is None else h0),
              sp.Max: lambda *a: _pairwise(_Max, a), sp.Min: lambda *a: _pairwise(_Min, a)}
_SMOOTH = (sp.exp, sp.log, sp.sin, sp.cos, sp.tan, sp.cot, sp.sec, sp.csc, sp.asin, sp.acos, sp.atan,
           sp.atan2, sp.sinh, sp.cosh, sp.tanh, sp.asinh, sp.acosh, sp.atanh, sp.erf, sp.erfc)
SUPPORTED_FUNCTIONS = tuple(f.__name__ for f in _SMOOTH + tuple(_PIECEWISE))
"""The SymPy functions a model's f, h, G (and symbolic Q, R) may use (module docstring,
"Functions"); powers, ``sqrt`` included, and the constants ``pi``, ``E`` too."""


def _code_form(e):
    """``e`` with SymPy's piecewise functions replaced by their code-generation forms
    (:class:`_PiecewiseFn`: derivatives by the stated convention); ``e`` itself when it has none."""
    if not e.has(*_PIECEWISE):
        return e
    return e.replace(lambda a: type(a) in _PIECEWISE, lambda a: _PIECEWISE[type(a)](*a.args))


def _code_matrix(M):
    """:func:`_code_form` of every entry of the matrix ``M`` (``M`` itself when none changes)."""
    return M.applyfunc(_code_form) if any(e.has(*_PIECEWISE) for e in M) else M


def _check_expressions(name: str, M, shape_index: bool = False) -> None:
    """Refuse, naming ``name`` and the entry, an entry of ``M`` that is not a real, finite
    expression of supported functions (:data:`SUPPORTED_FUNCTIONS`)."""
    allowed = set(_SMOOTH) | set(_PIECEWISE)
    for k, e in enumerate(M):
        where = f"{name}[{k}]" if not shape_index else f"{name}[{k // M.shape[1]}, {k % M.shape[1]}]"
        if not isinstance(e, sp.Expr):
            raise TypeError(f"{name}: expected real expressions, got {e!r} ({type(e).__name__}) in {where}")
        for a in sp.preorder_traversal(e):
            if a.is_Symbol or a.is_NumberSymbol:
                continue
            if a.is_Number or a is sp.I or a in (sp.zoo, sp.oo, -sp.oo, sp.nan):
                if not (a.is_extended_real and a.is_finite):
                    raise ValueError(f"{name}: {where} = {e} is not real/finite (it contains {a}); expected "
                                     "real, finite expressions")
                continue
            if isinstance(a, (sp.Add, sp.Mul, sp.Pow)):
                continue
            if isinstance(a, AppliedUndef):
                raise ValueError(f"{name}: undefined function {a} in {where}; a model's functions must be "
                                 f"SymPy's, one of {', '.join(SUPPORTED_FUNCTIONS)}")
            if type(a) in allowed:
                continue
            raise ValueError(f"{name}: unsupported {'function' if isinstance(a, sp.Function) else 'expression'} "
                             f"{a} in {where}; supported: {', '.join(SUPPORTED_FUNCTIONS)} (and +, *, powers, "
                             "sqrt, pi, E)")


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


class _Values:
    """The parameter values of one model: ``{Symbol: float | array | None}`` and the grid that
    maps a time to an array entry (shared by every generated function of the model).

    A scalar is used as is. An array ``(T,)`` (shared by all paths) or ``(..., T)`` (one row per
    path) is read at entry ``k`` at step ``k`` (discrete models: the time argument *is* the
    integer step), or for SDE models piecewise constant on the grid ``t0 + i dt``:
    ``i = floor((t - t0) / dt + 1e-9)``, clipped to ``0..T-1``. ``None`` is an input that was
    declared and not given.
    """

    def __init__(self, values: dict, inputs: tuple, dt, t0):
        self.values, self.inputs, self.dt, self.t0 = values, inputs, dt, t0
        self.arrays = {p for p, v in values.items() if isinstance(v, np.ndarray)}
        self.per_path = {p for p in self.arrays if values[p].ndim > 1}
        self.unset = {p for p, v in values.items() if v is None}
        # scalars as NumPy floats: the generated code then follows NumPy's semantics (1/0 is inf,
        # with a RuntimeWarning, for the filters' divergence screening), not Python's ZeroDivisionError
        self._np = {p: np.float64(v) for p, v in values.items() if isinstance(v, float)}

    def scalar(self, syms) -> bool:
        return not any(p in self.arrays or p in self.unset for p in syms)

    def index(self, p, t, T: int) -> int:
        if self.dt is None:  # a discrete model: the step index itself
            k = float(t)
            if k != int(k) or k < 0 or k >= T:
                raise ValueError(f"{p}: its value is an array over {T} step(s); step k = {t!r} is outside "
                                 f"0..{T - 1} (give at least as many entries as steps)")
            return int(k)
        return min(max(int(np.floor((float(t) - self.t0) / self.dt + 1e-9)), 0), T - 1)

    def at(self, p, t, batch: tuple):
        v = self.values[p]
        if v is None:
            raise ValueError(f"inputs: the model declares input(s) {[str(u) for u in self.inputs]} and none "
                             "were given; evaluate model.with_inputs(u) with u of shape (..., T, p)")
        if p not in self.arrays:
            return self._np.get(p, v)
        k = self.index(p, t, v.shape[-1])
        if v.ndim == 1:
            return v[k]
        lead = v.shape[:-1]
        if tuple(batch[:len(lead)]) != lead:
            raise ValueError(f"{p}: a per-path parameter array of shape {v.shape} needs states whose leading "
                             f"axes are the paths {lead}, got a state batch {tuple(batch)}: per-path values "
                             "need a filter that evaluates per path (not a grid filter's points, nor "
                             "Filter.run(chunk=...)); give a (T,) array shared by all paths instead")
        return v[..., k].reshape(*lead, *(1,) * (len(batch) - len(lead)))


_NO_VALUES = _Values({}, (), None, 0.0)


class _Kernel:
    """A SymPy array expression compiled once (``lambdify`` with ``cse=True``) into a function of
    the state components, the time and the parameters it uses; shared by every
    :meth:`Model.with_params` copy of a model."""

    @classmethod
    def zeros(cls, shape, n: int) -> "_Kernel":
        """The kernel of an all-zero array (G's derivatives when G is free of the states), no SymPy."""
        self = cls.__new__(cls)
        self.shape, self.params, self.varies, self.const, self.n = tuple(shape), (), False, True, n
        self.value = np.zeros(self.shape)
        return self

    def __init__(self, exprs, states, time, shape, params=()):
        self.shape = tuple(shape)
        flat = [sp.sympify(e) for e in exprs]
        free = set().union(*(e.free_symbols for e in flat)) if flat else set()
        self.params = tuple(p for p in params if p in free)
        self.varies = bool(free & (set(states) | ({time} if time is not None else set())))
        self.const = not self.varies and not self.params
        self.n = len(states)
        if self.const:
            self.value = np.array([float(e) for e in flat], dtype=float).reshape(self.shape)
        else:
            args = list(states) + ([time] if time is not None else [sp.Symbol("_t_unused")]) + list(self.params)
            flat = [_code_form(e) for e in flat]
            self.fn = lambdify_arrays(args, flat)


# the derivatives of the generated code (:mod:`nlfilter.codegen`); the private names are kept for the
# compiled loop (filters/compiled.py), which imports them from here
_jacobian, _first = jacobian, first_derivatives


class _LazyKernels:
    """Kernels generated on first use (the second derivatives, G's derivatives), shared by every
    :meth:`Model.with_params` copy of a model: whichever copy calls first generates the code once,
    and every copy, made before or after, uses it."""

    def __init__(self, makers: dict):
        self.shapes = {k: shape for k, (shape, _) in makers.items()}
        self._makers = {k: make for k, (_, make) in makers.items()}
        self.built = {}

    def kernel(self, key) -> "_Kernel":
        kn = self.built.get(key)
        if kn is None:
            kn = self.built[key] = self._makers[key]()
            del self._makers[key]  # the SymPy expressions it held are no longer needed
        return kn

    def bind(self, key, values, model):
        if key in self.built:
            return _Batched(self.built[key], values)
        return _Lazy(self, key, values, model)


def _no_model():
    return None


class _Lazy:
    """Stands for a model's ``_Batched`` function until its first call, which generates the kernel
    (:class:`_LazyKernels`), binds it to the model's values and puts it in the model's place."""

    def __init__(self, store: _LazyKernels, key: str, values, model):
        self.store, self.key, self.values, self.shape = store, key, values, store.shapes[key]
        self._model, self._fn = weakref.ref(model), None

    @property
    def kernel(self) -> "_Kernel":
        return self.store.kernel(self.key)

    def __getstate__(self):  # pickled (e.g. to a Dask worker) without the weak back-reference
        return {**self.__dict__, "_model": None}

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self._model is None:
            self._model = _no_model

    def __call__(self, x, t=0.0):
        fn = self._fn
        if fn is None:
            fn = self._fn = _Batched(self.store.kernel(self.key), self.values)
            model = self._model()
            if model is not None and model.__dict__.get(self.key) is self:
                setattr(model, self.key, fn)  # later look-ups go straight to the function
        return fn(x, t)


class _Batched:
    """A compiled :class:`_Kernel` bound to a model's parameter values: a function of a state batch
    ``(..., n)`` and a scalar time, returning ``(..., *shape)``.

    Constant entries are broadcast over the batch (raw ``lambdify`` on matrices does not:
    sympy issues #5642, #19259); so is a function that depends on scalar parameters only.
    """

    def __init__(self, kernel: _Kernel, values: _Values = _NO_VALUES):
        self.kernel, self.values, self.shape = kernel, values, kernel.shape
        self._fixed = None
        if kernel.const:
            self._fixed = _Broadcast(kernel.value)
        elif not kernel.varies and values.scalar(kernel.params):
            self._fixed = _Broadcast(self._eval(np.zeros(kernel.n), 0.0))

    def __call__(self, x, t=0.0):
        x = np.asarray(x, dtype=float)
        if self._fixed is not None:
            return self._fixed(x.shape[:-1])
        return self._eval(x, t)

    def _eval(self, x, t):
        batch = x.shape[:-1]
        kn = self.kernel
        extra = [self.values.at(p, t, batch) for p in kn.params]
        vals = kn.fn(*(x[..., i] for i in range(kn.n)), np.float64(t), *extra)
        if len(vals) == 1 and np.shape(vals[0]) == batch:  # one entry: a reshape, no copy
            return np.asarray(vals[0], dtype=float).reshape(*batch, *self.shape)
        out = np.empty((*batch, len(vals)))
        for j, v in enumerate(vals):
            out[..., j] = v
        return out.reshape(*batch, *self.shape)


class _Folded:
    """``G`` (or ``G_x``, ``G_xx``: the noise axis is the second) times ``Q_t^{1/2}`` when ``Q``
    varies with time: the filters and the simulator then see ``Q = I`` and the same ``G Q Gᵀ``."""

    def __init__(self, inner: _Batched, Qfn: _Batched, per_path: int):
        self.inner, self.Qfn, self.per_path, self.shape = inner, Qfn, per_path, inner.shape

    def __call__(self, x, t=0.0):
        x = np.asarray(x, dtype=float)
        batch = x.shape[:-1]
        lead = batch[:self.per_path]
        Qt = self.Qfn(np.zeros((*lead, x.shape[-1])), t)  # (*lead, r, r)
        w, U = np.linalg.eigh(Qt)
        L = U * np.sqrt(np.clip(w, 0.0, None))[..., None, :]  # Q = L Lᵀ
        L = L.reshape(*lead, *(1,) * (len(batch) - len(lead)), *L.shape[-2:])
        G = self.inner(x, t)
        if G.ndim == len(batch) + 2:
            return G @ L
        G = np.moveaxis(G, len(batch) + 1, -1)  # noise axis last
        L = L.reshape(*L.shape[:-2], *(1,) * (G.ndim - len(batch) - 1), *L.shape[-2:])
        return np.moveaxis(np.einsum("...a,...ab->...b", G, L), -1, len(batch) + 1)


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


def _is_symbolic(value) -> bool:
    """Whether a Q or R argument holds SymPy expressions with free symbols."""
    if isinstance(value, (sp.Basic, sp.MatrixBase)):
        return bool(value.free_symbols)
    if isinstance(value, (list, tuple)):
        return any(_is_symbolic(v) for v in value)
    if isinstance(value, np.ndarray) and value.dtype == object:
        return any(_is_symbolic(v) for v in value.ravel())
    return False


def _param_value(name, value):
    """A parameter value: a finite float, or a float array ``(T,)`` / ``(..., T)`` (read-only)."""
    if np.ndim(value) == 0:
        try:
            v = float(value)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{name}: expected a number or an array over time, got {type(value).__name__}") from exc
        V.finite(name, v)
        return v
    arr = V.as_float_array(name, value).copy()
    if arr.shape[-1] == 0:
        raise ValueError(f"{name}: expected an array over at least one step, got shape {arr.shape}")
    V.finite(name, arr)
    arr.setflags(write=False)
    return arr


class Model:
    """Common part of :class:`DiscreteModel` and :class:`SDEModel` (see the module docstring).

    Parameters
    ----------
    params : ``{Symbol: value}``: symbols of f, h, G, Q and R kept as arguments of the generated
        functions (values changed by :meth:`with_params` without generating code again). A value
        is a number, or an array over time ``(T,)`` or per path ``(..., T)`` (see
        :meth:`with_params`).
    inputs : control-input symbols ``[u1, ..., up]`` fed by :meth:`with_inputs`.
    Q, R : numbers or matrices, or SymPy expressions in the parameters (``[[q]]``, ``[[r**2]]``).
    """

    kind = "model"
    time_name = "t"

    def __init__(self, states, f, h, G=None, Q=None, R=None, *, params=None, inputs=None, time=None,
                 process_noise: NoiseLaw | None = None, measurement_noise: NoiseLaw | None = None,
                 name: str = "", cross_noise=None, noise=None, meas_noise=None):
        if isinstance(states, sp.Symbol):
            states = [states]
        states = list(states)
        if not states or not all(isinstance(s, sp.Symbol) for s in states):
            raise TypeError(f"states: expected a non-empty list of SymPy symbols, got {states!r}")
        if len(set(states)) != len(states):
            raise ValueError(f"states: expected distinct symbols, got {states!r}")
        if time is not None and not isinstance(time, sp.Symbol):
            raise TypeError(f"time: expected a SymPy symbol or None, got {type(time).__name__}")
        if time is not None and time in states:
            raise ValueError(f"time: the time symbol {time} is also a state (states {[str(s) for s in states]}); "
                             "expected a symbol distinct from the states")
        self.states = states
        self.time = time
        self.name = name
        n = len(states)
        params = dict(params or {})
        for p in params:
            if not isinstance(p, sp.Symbol):
                raise TypeError(f"params: expected SymPy symbols as keys, got {p!r}")
        if isinstance(inputs, sp.Symbol):
            inputs = [inputs]
        inputs = tuple(inputs or ())
        if not all(isinstance(u, sp.Symbol) for u in inputs) or len(set(inputs)) != len(inputs):
            raise TypeError(f"inputs: expected a list of distinct SymPy symbols, got {list(inputs)!r}")
        clash = (set(inputs) & set(params)) | ((set(inputs) | set(params)) & (set(states) | {time}))
        if clash:
            roles = {s: [nm for nm, group in (("a state", states), ("the time", [time]), ("a parameter", params),
                                              ("an input", inputs)) if s in group] for s in clash}
            raise ValueError(f"params/inputs: symbol(s) {sorted(map(str, clash))} are used twice ("
                             + "; ".join(f"{s} is {' and '.join(r)}" for s, r in sorted(roles.items(), key=str))
                             + "); expected states, the time, parameters and inputs disjoint")
        names = [str(p) for p in list(params) + list(inputs)]
        if len(set(names)) != len(names):
            raise ValueError(f"params/inputs: expected distinct names, got {names}")
        self.inputs = inputs
        self._psyms = tuple(params) + inputs  # every argument beyond states and time

        fM = _vector("f", f, n)
        hM = _vector("h", h)
        _check_expressions("f", fM)
        _check_expressions("h", hM)
        # non-additive noise: x[k+1] = f(x[k], w[k]), y[k] = h(x[k], v[k]) with the noise symbols in f, h
        noise, meas_noise = (tuple([a] if isinstance(a, sp.Symbol) else (a or ())) for a in (noise, meas_noise))
        for nm, syms, other in (("noise", noise, meas_noise), ("meas_noise", meas_noise, noise)):
            if not syms:
                continue
            if not all(isinstance(w, sp.Symbol) for w in syms) or len(set(syms)) != len(syms):
                raise TypeError(f"{nm}: expected a list of distinct SymPy symbols (the "
                                f"{'process noise in f' if nm == 'noise' else 'measurement noise in h'}), got {list(syms)!r}")
            used = set(syms) & (set(states) | set(self._psyms) | {time} | set(other))
            if used:
                raise ValueError(f"{nm}: symbol(s) {sorted(map(str, used))} are already states, the time, parameters, "
                                 "inputs or the other noise")
        if meas_noise:
            h_aug = hM
            hM = hM.subs({v: 0 for v in meas_noise})  # the nominal measurement h(x, 0)
        if noise:
            if G is not None:
                raise ValueError("G: a model with non-additive noise (noise=[...]) states the noise in f; expected "
                                 f"G=None, got {G!r}")
            fw0 = fM.subs({w: 0 for w in noise})
            GM = jacobian(_code_matrix(fM), noise).subs({w: 0 for w in noise})  # the noise gain at w = 0
        else:
            GM = sp.eye(n) if G is None else _matrix("G", G, n, None)
            _check_expressions("G", GM, True)
        self.additive, self.additive_measurement = not noise, not meas_noise
        self.noise_symbols, self.meas_noise_symbols = noise, meas_noise
        allowed = set(states) | ({time} if time is not None else set()) | set(self._psyms)
        for nm, M in (("f", fM), ("h", h_aug if meas_noise else hM), ("G", GM)):
            own = set(noise) if nm == "f" else set(meas_noise) if nm == "h" else set()
            extra = M.free_symbols - allowed - own
            if extra:
                raise ValueError(f"{nm}: uses symbol(s) {sorted(map(str, extra))} that are neither states "
                                 f"{[str(s) for s in states]}, the time symbol, nor given in params or inputs"
                                 + (" (nor noise)" if nm == "f" and noise else "")
                                 + (" (nor meas_noise)" if nm == "h" and meas_noise else ""))
        if noise:
            f_aug = fM
            fM = fw0
        self.n, self.m, self.r = n, hM.shape[0], GM.shape[1]
        self.mv = len(meas_noise) if meas_noise else self.m  # the dimension of v (R is mv x mv)
        self._sym = {"f": fM, "h": hM, "G": GM}  # parameters as symbols; .sym substitutes them
        self._given_laws = (process_noise, measurement_noise)
        # Q and R: numbers, checked once as before, or SymPy matrices in the parameters
        self._QR = {}
        for nm, val, dim in (("Q", Q, self.r), ("R", R, self.mv)):
            if not _is_symbolic(val):
                continue
            M = _matrix(nm, [[val]] if isinstance(val, sp.Basic) and not isinstance(val, sp.MatrixBase) else val,
                        dim, dim)
            _check_expressions(nm, M, True)
            # R may depend on the state (and the time): R(x, k), evaluated by R_of
            ok = set(self._psyms) | (set(states) | ({time} if time is not None else set()) if nm == "R" else set())
            extra = M.free_symbols - ok
            if extra:
                raise ValueError(f"{nm}: uses symbol(s) {sorted(map(str, extra))} that are not given in params"
                                 + (" (nor states or the time symbol)" if nm == "R" else ""))
            if self._given_laws[nm == "R"] is not None:
                raise ValueError(f"{'process_noise' if nm == 'Q' else 'measurement_noise'}: a noise law cannot "
                                 f"be given with a {nm} that depends on parameters or states; drop the law (Gaussian)")
            if nm == "R" and any(sp.simplify(M[i, j] - M[j, i]) != 0 for i in range(dim) for j in range(i)):
                raise ValueError(f"{nm}: expected a symmetric matrix, got {M.tolist()}")
            self._QR[nm] = _Kernel(list(M), states, time if nm == "R" else None, (dim, dim), self._psyms)
        if "Q" not in self._QR:
            self._Q0 = V.covariance("Q", np.eye(self.r) if Q is None and process_noise is None
                                    else (process_noise.cov if Q is None else Q), self.r)
        if "R" not in self._QR:
            if R is None and measurement_noise is None:
                raise ValueError("R: expected the measurement noise covariance (m x m), got None")
            self._R0 = V.covariance("R", measurement_noise.cov if R is None else R, self.mv)
            self._R_law = as_law("measurement_noise", measurement_noise, self._R0)
        if "Q" not in self._QR:
            self._Q_law = as_law("process_noise", process_noise, self._Q0)
        for nm, key in (("process_noise", "Q"), ("measurement_noise", "R")):
            if key in self._QR:
                continue
            law, cov = getattr(self, f"_{key}_law"), getattr(self, f"_{key}0")
            if law.cov.shape != cov.shape or not np.allclose(law.cov, cov, rtol=1e-8, atol=1e-12):
                raise ValueError(f"{nm}: its covariance {law.cov.tolist()} differs from the given "
                                 f"{key} {cov.tolist()}")

        # derivatives of the code forms (Abs, sign, Max, ...: the convention of the module docstring)
        self.piecewise = frozenset(type(a).__name__ for M in (fM, hM, GM) for e in M if e.has(*_PIECEWISE)
                                   for a in sp.preorder_traversal(e) if type(a) in _PIECEWISE)
        fM, hM, GM = _code_matrix(fM), _code_matrix(hM), _code_matrix(GM)
        fx = jacobian(fM, states)
        hx = jacobian(hM, states)
        # the G-constant flag first: a G free of the states has G_x = G_xx = 0 (no SymPy)
        sset = frozenset(states)  # (one set: n² entries are tested against it)
        self.G_constant = all(e.free_symbols.isdisjoint(sset) for e in GM)
        specs = {"f": (list(fM), (n,)), "f_x": (list(fx), (n, n)),
                 "h": (list(hM), (self.m,)), "h_x": (list(hx), (self.m, n)),
                 "G": (list(GM), (n, self.r))}
        self._kernels = {key: _Kernel(exprs, states, time, shape, self._psyms) for key, (exprs, shape) in specs.items()}
        # second derivatives (and G's derivatives) are generated on first call, once for every copy
        r, m, Gc, ps = self.r, self.m, self.G_constant, self._psyms
        self._lazy = _LazyKernels({
            "f_xx": ((n, n, n), lambda: _Kernel(first_derivatives(list(fx), states), states, time, (n, n, n), ps)),
            "h_xx": ((m, n, n), lambda: _Kernel(first_derivatives(list(hx), states), states, time, (m, n, n), ps)),
            "G_x": ((n, r, n), lambda: _Kernel.zeros((n, r, n), n) if Gc else
                    _Kernel(first_derivatives(GM, states), states, time, (n, r, n), ps)),
            "G_xx": ((n, r, n, n), lambda: _Kernel.zeros((n, r, n, n), n) if Gc else
                     _Kernel(first_derivatives(first_derivatives(GM, states), states), states, time, (n, r, n, n), ps)),
        })
        if noise:  # f(x, w) on the augmented vector (x, w) (..., n + r)
            self._kernels["f_aug"] = _Kernel(list(f_aug), states + list(noise), time, (n,), self._psyms)
        if meas_noise:  # h(x, v) on (x, v) (..., n + mv)
            self._kernels["h_aug"] = _Kernel(list(h_aug), states + list(meas_noise), time, (self.m,), self._psyms)
        self.given = set(_DERIVS)
        # structure flags (for every parameter value), read by filters that can exploit them
        self._G_fixed = all(e.free_symbols.isdisjoint(sset | {time}) for e in GM)
        self.is_linear = self.additive and self.additive_measurement and self.G_constant and all(  # f and h affine in the state
            is_affine(e, row, states) for e, row in zip(list(fM) + list(hM), fx.tolist() + hx.tolist()))
        self._timed = time is not None and any(M.has(time) for M in (fM, hM, GM) + ((f_aug,) if noise else ())
                                               + ((h_aug,) if meas_noise else ()))
        self._uses = {k: set(self._kernels[k].params) for k in ("f", "h", "G")}
        if noise:
            self._uses["f"] |= set(self._kernels["f_aug"].params)
        if meas_noise:
            self._uses["h"] |= set(self._kernels["h_aug"].params)
            if "R" in self._QR and self._QR["R"].varies:
                raise ValueError("R: a state-dependent R with non-additive measurement noise (meas_noise=) is not "
                                 "supported; state the dependence in h(x, v)")
        self.cross_noise = None
        if cross_noise is not None:  # E[w vᵀ] = S (r x m), Anderson & Moore 1979 §5.5
            if noise or meas_noise:
                raise ValueError("cross_noise: correlated noise with non-additive noise (noise=, meas_noise=) is not "
                                 "supported")
            if not self.G_constant:
                raise ValueError("cross_noise: correlated process and measurement noise needs a G that does not "
                                 "depend on the state")
            if any(law is not None and not isinstance(law, Gaussian) for law in self._given_laws):
                raise ValueError("cross_noise: correlated noise is drawn jointly Gaussian; expected no (or Gaussian) "
                                 "process_noise and measurement_noise laws")
            Sc = V.as_float_array("cross_noise", cross_noise, ndim=2)
            if Sc.shape != (self.r, self.m):
                raise ValueError(f"cross_noise: expected E[w vᵀ] of shape (r, m) = ({self.r}, {self.m}), got {Sc.shape}")
            V.finite("cross_noise", Sc)
            Sc = Sc.copy()
            Sc.setflags(write=False)
            self.cross_noise = Sc
        self._uses.update({k: set(kn.params) for k, kn in self._QR.items()})
        values = {p: _param_value(str(p), v) for p, v in params.items()}
        values.update({u: None for u in inputs})
        self._bind(_Values(values, inputs, None, 0.0))

    def _bind(self, values: _Values) -> None:
        """Bind the generated functions, Q, R, the noise laws and the flags to one set of values
        (no SymPy: this is all :meth:`with_params` costs)."""
        if self.kind == "sde" and values.arrays and values.dt is None:
            raise ValueError(f"dt: the parameter(s) {sorted(map(str, values.arrays))} are arrays over time; an "
                             "SDEModel needs their grid: model.with_params(..., dt=, t0=)")
        self._values = values
        for key, kn in self._kernels.items():
            setattr(self, key, _Batched(kn, values))
        for key in self._lazy.shapes:  # built on first call (or now, if another copy built the code)
            setattr(self, key, self._lazy.bind(key, values, self))
        tv = {k for k, used in self._uses.items() if used & (values.arrays | values.unset)}
        Qlaw, Rlaw = self._given_laws
        self.R_constant = True
        if "R" in self._QR:
            if "R" in tv:
                raise ValueError(f"R: depends on time-varying parameter(s) {sorted(map(str, self._uses['R'] & values.arrays))}; "
                                 "a time-varying R is not supported (filters read model.R as one matrix)")
            if self._QR["R"].varies:  # R(x, k): a function of the state (and time), R_of
                self.R_constant = False
                self._R, self._measurement_noise = None, None
                self._R_fn = _Batched(self._QR["R"], values)
            else:
                self.R = self._covariance("R", self.mv, values)
                self.measurement_noise = Gaussian(self.R)
        else:
            self.R, self.measurement_noise = self._R0, self._R_law
        self._fold = "Q" in tv
        if self._fold and (self.cross_noise is not None or not self.additive):
            raise ValueError("Q: a time-varying Q with correlated (cross_noise) or non-additive noise is not supported")
        if self._fold:  # Q_t = L_t L_tᵀ moved into G: the filters see Q = I and the same G Q Gᵀ
            per = max((values.values[p].ndim - 1 for p in self._uses["Q"] & values.per_path), default=0)
            Qfn = _Batched(self._QR["Q"], values)
            for key in ("G", "G_x", "G_xx"):
                setattr(self, key, _Folded(getattr(self, key), Qfn, per))
            self.Q = np.eye(self.r)
            self.process_noise = Gaussian(self.Q)
        elif "Q" in self._QR:
            self.Q = self._covariance("Q", self.r, values)
            self.process_noise = Gaussian(self.Q)
        else:
            self.Q, self.process_noise = self._Q0, self._Q_law
        if self.cross_noise is not None:
            if not self.R_constant:
                raise ValueError("cross_noise: correlated noise with a state-dependent R is not supported")
            J = np.block([[self.Q, self.cross_noise], [self.cross_noise.T, self.R]])
            low = np.linalg.eigvalsh(J)[0]
            if low < -1e-12 * max(1.0, np.abs(J).max()):
                raise ValueError(f"cross_noise: the joint covariance [[Q, S], [Sᵀ, R]] of (w, v) is not positive "
                                 f"semi-definite (smallest eigenvalue {low:.3g}); got S = {self.cross_noise.tolist()}")
            self._joint_noise = Gaussian(J)
        self._per_path_G = bool(self._uses["G"] & values.per_path) or (self._fold and bool(self._uses["Q"] & values.per_path))
        fixed = self._G_fixed and "G" not in tv and not self._fold
        self._GQG0 = (_Broadcast(self.G(np.zeros(self.n)) @ self.Q @ self.G(np.zeros(self.n)).T)
                      if fixed else None)  # fixed G Q Gᵀ, computed once
        # f, h, G (and Q) do not depend on the time: filters may compute time-fixed quantities once
        self.time_invariant = not self._timed and not tv
        self._sym_cache = None

    @property
    def structure(self) -> frozenset:
        """What the model has beyond additive, uncorrelated noise with one constant R:
        ``"state-dependent R"`` (:meth:`R_of`), ``"cross noise"`` (:attr:`cross_noise`),
        ``"non-additive noise"``; a filter refuses a structure it does not handle (its
        ``structures``, :func:`~nlfilter.filters.base.check_structure`)."""
        out = set()
        if not getattr(self, "R_constant", True):
            out.add("state-dependent R")
        if getattr(self, "cross_noise", None) is not None:
            out.add("cross noise")
        if not getattr(self, "additive", True):
            out.add("non-additive noise")
        if not getattr(self, "additive_measurement", True):
            out.add("non-additive measurement noise")
        return frozenset(out)

    # -- the measurement noise covariance: one matrix, or R(x, k) --------------------------------
    @property
    def R(self) -> np.ndarray:
        """The measurement noise covariance ``(m, m)`` when it is constant (``R_constant``); a model
        whose R depends on the state has none: :meth:`R_of` evaluates it."""
        if self._R is None:
            raise ValueError(_STATE_R)
        return self._R

    @R.setter
    def R(self, value):
        self._R = value

    @property
    def measurement_noise(self) -> NoiseLaw:
        """The law of ``v`` (for simulation and the reference filters' likelihood); a model with
        a state-dependent R has the Gaussian ``N(0, R(x))`` at each state instead (:meth:`R_of`)."""
        if self._measurement_noise is None:
            raise ValueError(_STATE_R.replace("model.R", "model.measurement_noise", 1))
        return self._measurement_noise

    @measurement_noise.setter
    def measurement_noise(self, value):
        self._measurement_noise = value

    def R_of(self, x, t=0.0) -> np.ndarray:
        """``R(x, t) (..., m, m)`` at a batch of states ``x (..., n)`` (the constant ``R``
        broadcast when ``R_constant``). A state-dependent R is checked at every call: where it is
        not positive definite a ``ValueError`` names the first such state (never silent).

        >>> import sympy as sp
        >>> x = sp.Symbol("x")
        >>> m = DiscreteModel([x], [x], [x], Q=1.0, R=[[0.1 + x**2]])
        >>> m.R_constant, m.R_of(np.array([[1.0], [2.0]]), 0)[:, 0, 0].tolist()
        (False, [1.1, 4.1])
        """
        x = np.asarray(x, dtype=float)
        if self.R_constant:
            return np.broadcast_to(self._R, (*x.shape[:-1], *self._R.shape))
        R = self._R_fn(x, t)
        if self.m == 1:
            bad = ~(R[..., 0, 0] > 0)
        else:
            bad = ~np.all(np.linalg.eigvalsh(np.where(np.isfinite(R), R, 0.0)) > 0, axis=-1) | \
                ~np.all(np.isfinite(R), axis=(-1, -2))
        if bad.any():
            idx = np.argwhere(bad)[0]
            raise ValueError(f"R: the state-dependent measurement noise covariance is not positive definite at "
                             f"state x = {x[tuple(idx)].tolist()} ({self.time_name} = {t!r}): R = "
                             f"{R[tuple(idx)].tolist()}; expected R(x) positive definite wherever it is evaluated")
        return R

    def _covariance(self, nm, dim, values):
        C = _Batched(self._QR[nm], values)(np.zeros(self.n))
        try:
            return V.covariance(nm, C, dim)
        except ValueError as exc:
            used = {str(p): values.values[p] for p in self._QR[nm].params}
            raise ValueError(f"{exc} (at parameter values {used})") from None

    # -- parameters and inputs ------------------------------------------------------------------
    @property
    def params(self):
        """The parameter values, ``{name: value}`` (read-only; inputs not included)."""
        vals = getattr(self, "_values", _NO_VALUES)
        return MappingProxyType({str(p): v for p, v in vals.values.items() if p not in vals.inputs})

    @property
    def expressions(self):
        """``{"f", "h", "G"}`` as SymPy matrices with the parameters and inputs kept as symbols (their
        structure in the states holds for every value); ``None`` for a model from callables."""
        return self._sym

    @property
    def sym(self):
        """``{"f", "h", "G"}`` as SymPy matrices with the current parameter values substituted
        (for the moment engine and the symbolic filters); ``None`` for a model from callables."""
        if self._sym is None:
            return None
        if not (self.additive and self.additive_measurement):
            raise ValueError("model.sym: the model's noise enters f or h non-additively (noise=, meas_noise=); "
                             "symbolic methods (moment engine, quasilinear and conditional-moment filters) take "
                             "x[k+1] = f(x) + G w, y = h(x) + v")
        if self._sym_cache is None:
            vals = self._values
            bad = set().union(*(M.free_symbols for M in self._sym.values())) & (vals.arrays | vals.unset)
            if bad:
                raise ValueError(f"model.sym: parameter(s)/input(s) {sorted(map(str, bad))} have no single value "
                                 "(arrays over time, or inputs not given); symbolic methods need numbers")
            sub = {p: v for p, v in vals.values.items() if p not in vals.arrays and v is not None}
            self._sym_cache = {k: (M.subs(sub) if sub else M) for k, M in self._sym.items()}
        return self._sym_cache

    def symbol(self, name):
        """The SymPy symbol of the parameter ``name`` (a name or the symbol itself; its
        assumptions, e.g. ``positive=True``, say how :func:`nlfilter.fit` may move it)."""
        return self._lookup(name)

    def _lookup(self, key):
        if isinstance(key, sp.Symbol) and key in self._psyms:
            return key
        for p in self._psyms:
            if str(p) == key:
                return p
        raise ValueError(f"with_params: unknown parameter {key!r}; the model's parameters are "
                         f"{[str(p) for p in self._psyms if p not in self.inputs]}"
                         + (f" and inputs {[str(u) for u in self.inputs]}" if self.inputs else ""))

    def with_params(self, values=None, /, *, dt: float | None = None, t0: float = 0.0, **named):
        """A copy of the model with new parameter values, sharing the generated code (no SymPy).

        ``values``: a dict keyed by symbol or name, and/or keywords by name (a parameter named
        ``dt`` or ``t0`` goes in the dict). A value is a number, an array ``(T,)`` over time shared
        by all paths, or ``(..., T)`` per path (leading axes those of the filtered batch). A
        discrete model reads entry ``k`` at step ``k``; an :class:`SDEModel` reads the array as
        piecewise constant on the grid ``t0 + i dt`` (``i = floor((t - t0)/dt + 1e-9)``, clipped
        to the array): ``dt`` is then required (kept from the model when not given). An array
        makes the model time-varying (``time_invariant = False``).

        >>> import sympy as sp
        >>> x, a = sp.symbols("x a")
        >>> m = DiscreteModel([x], [a * x], [x], Q=1.0, R=1.0, params={a: 0.9})
        >>> m2 = m.with_params(a=0.5)
        >>> m2.params["a"], m2.f(np.array([2.0]), 0).tolist(), m.f(np.array([2.0]), 0).tolist()
        (0.5, [1.0], [1.8])
        """
        if self._sym is None:
            raise ValueError("with_params: a model built from_functions has no parameters; give their values "
                             "to your callables (a closure) or state the model in SymPy with params=")
        new = dict(self._values.values)
        given = dict(values or {})
        if not isinstance(given, dict):
            raise TypeError(f"values: expected a dict keyed by symbol or name, got {type(values).__name__}")
        given.update(named)
        for key, v in given.items():
            p = self._lookup(key)
            new[p] = _param_value(str(p), v)
        if self.kind == "discrete":
            if dt is not None:
                raise ValueError(f"dt: a DiscreteModel reads array entry k at step k; expected None, got {dt!r}")
            grid = (None, 0.0)
        else:
            grid = ((float(V.positive("dt", dt)), float(t0)) if dt is not None
                    else (self._values.dt, self._values.t0 if t0 == 0.0 else float(t0)))
        out = copy.copy(self)
        out._bind(_Values(new, self.inputs, *grid))
        return out

    def with_inputs(self, u, *, dt: float | None = None, t0: float = 0.0):
        """A copy of the model fed by the control inputs ``u (..., T, p)`` (``p`` the declared
        inputs; ``(T, p)`` shared by all paths, ``(B, T, p)`` per path): each input is a
        time-varying parameter (:meth:`with_params`), read at entry ``k`` at step ``k``."""
        if not self.inputs:
            raise ValueError("with_inputs: the model declares no inputs; build it with inputs=[u1, ...]")
        p = len(self.inputs)
        u = V.as_float_array("u", u)
        if u.ndim < 2 or u.shape[-1] != p:
            raise ValueError(f"u: expected shape (..., T, {p}) for input(s) {[str(s) for s in self.inputs]}, "
                             f"got {u.shape}")
        return self.with_params({s: u[..., j] for j, s in enumerate(self.inputs)}, dt=dt, t0=t0)

    def _rows(self, paths: range):
        """The model for the paths ``paths`` (rows of every per-path parameter array), or itself."""
        vals = getattr(self, "_values", _NO_VALUES)
        if not vals.per_path:
            return self
        new = {}
        for p in vals.per_path:
            v = vals.values[p]
            if v.ndim != 2 or v.shape[0] < paths.stop:
                raise ValueError(f"{p}: a per-path array of shape {v.shape} for paths {paths!r}; expected "
                                 f"(P, T) with P >= {paths.stop}")
            new[p] = v[paths.start:paths.stop]
        return self.with_params(new)

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
        self.n, self.m, self.name, self.time, self.states, self._sym = n, m, name, None, None, None
        self.inputs, self._psyms, self._values, self._per_path_G, self._sym_cache = (), (), _NO_VALUES, False, None
        Qa = V.covariance("Q", Q)
        self.r = Qa.shape[0] if r is None else r
        self.Q = V.covariance("Q", Q, self.r)
        self.R = V.covariance("R", R, m)
        self.R_constant, self.cross_noise, self.additive, self.noise_symbols = True, None, True, ()
        self.additive_measurement, self.meas_noise_symbols, self.mv = True, (), m
        self.piecewise = frozenset()
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

    def transition(self, x, w, t=0.0) -> np.ndarray:
        """``x[k+1]`` from states ``(..., n)`` and process noises ``(..., r)``: ``f(x) + G(x) w``, or
        ``f(x, w)`` for a model with non-additive noise (``noise=``; evaluated as ``f_aug`` on the
        augmented vector ``(x, w)``)."""
        if getattr(self, "additive", True):
            return self.f(x, t) + self.Gw(x, w, t)
        x, w = np.asarray(x, dtype=float), np.asarray(w, dtype=float)
        lead = np.broadcast_shapes(x.shape[:-1], w.shape[:-1])
        z = np.concatenate([np.broadcast_to(x, (*lead, self.n)), np.broadcast_to(w, (*lead, self.r))], axis=-1)
        return self.f_aug(z, t)

    def measurement(self, x, v, t=0.0) -> np.ndarray:
        """``y`` from states ``(..., n)`` and measurement noises ``(..., mv)``: ``h(x) + v``, or
        ``h(x, v)`` for non-additive measurement noise (``meas_noise=``; ``h_aug`` on ``(x, v)``)."""
        if getattr(self, "additive_measurement", True):
            return self.h(x, t) + v
        x, v = np.asarray(x, dtype=float), np.asarray(v, dtype=float)
        lead = np.broadcast_shapes(x.shape[:-1], v.shape[:-1])
        z = np.concatenate([np.broadcast_to(x, (*lead, self.n)), np.broadcast_to(v, (*lead, self.mv))], axis=-1)
        return self.h_aug(z, t)

    def Gw(self, x, w, t=0.0) -> np.ndarray:
        """``G(x) w`` for a batch of states ``(..., n)`` and noises ``(..., r)`` (matmul when G is constant)."""
        if self.G_constant and not self._per_path_G:
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
    params : {Symbol: value}, kept as symbols of the generated functions (:meth:`Model.with_params`)
    inputs : control-input symbols, fed by :meth:`Model.with_inputs` an array ``u (..., T, p)``
    time : the step-index symbol, if f, h or G depend on it
    process_noise, measurement_noise : laws used to *simulate* w and v (Gaussian by default)
    cross_noise : ``(r, m)`` ``E[w_k v_kᵀ]``, correlated process and measurement noise (module docstring)
    noise : the process-noise symbols when they enter ``f`` non-additively (module docstring)
    meas_noise : the measurement-noise symbols when they enter ``h`` non-additively

    ``R`` may depend on the states (``R_of``): the radar of filterpy's EKF test, whose range
    noise grows with the range:

    >>> import sympy as sp
    >>> px, v, alt = sp.symbols("px v alt")
    >>> rng_ = sp.sqrt(px**2 + alt**2)
    >>> radar = DiscreteModel([px, v, alt], [px + 0.05 * v, v, alt], [rng_], Q=np.diag([0, 1e-3, 1e-3]),
    ...                       R=[[0.05 * rng_]])
    >>> sorted(radar.structure), radar.R_of(np.array([300.0, 90.0, 400.0]), 0).tolist()
    (['state-dependent R'], [[25.0]])
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

    def __init__(self, states, f, h, G=None, Q=None, R=None, *, params=None, inputs=None, time=None,
                 process_noise: NoiseLaw | None = None, measurement_noise: NoiseLaw | None = None,
                 name: str = "", cross_noise=None, noise=None, meas_noise=None):
        for nm, val in (("cross_noise", cross_noise), ("noise", noise), ("meas_noise", meas_noise)):
            if val is not None:
                raise ValueError(f"{nm}: correlated (cross_noise) or non-additive (noise, meas_noise) noise is supported for "
                                 f"DiscreteModel only; an SDEModel is dx = f dt + G dβ, dy = h dt + dη with "
                                 f"independent β and η; expected None, got {val!r}")
        super().__init__(states, f, h, G, Q, R, params=params, inputs=inputs, time=time,
                         process_noise=process_noise, measurement_noise=measurement_noise, name=name)
        if not self.R_constant:
            raise ValueError("R: an SDEModel's measurement intensity (E dη dηᵀ = R dt) must not depend on the "
                             "state: a state-dependent R(x) is supported for DiscreteModel only (a "
                             "continuous-discrete model's discrete measurements: give them as a DiscreteModel)")
        for nm in ("process_noise", "measurement_noise"):
            if not isinstance(getattr(self, nm), Gaussian):
                raise ValueError(f"{nm}: an SDEModel is driven by Brownian motion; expected None or "
                                 f"Gaussian, got {type(getattr(self, nm)).__name__}")
