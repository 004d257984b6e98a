"""Models stated once, in SymPy, with batched numeric functions generated at construction.

Two kinds of model (the forms of Henriksen (1979), eqs. 1-2 and 24-25; docs/guide/conventions.rst):

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
(``G_k Q_k^{1/2}``, ``model.Q`` the identity); a time-varying ``R`` is ``R_k`` (:meth:`Model.R_of`).
``Q``, ``R`` may also be given per step, ``(T, d, d)`` or ``(B, T, d, d)`` (:mod:`~nlfilter.model_noise`).

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

Angular components (``angles={"states": [...], "measurements": [...]}``): wrapped residuals and
circular means in every filter, :mod:`nlfilter.angles`.

Functions (checked at construction, :data:`~nlfilter.model_expressions.SUPPORTED_FUNCTIONS`): f, h,
G and symbolic Q, R are real, finite expressions (no ``I``, ``oo``, ``zoo``, ``nan``; a ``ValueError`` names the field
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
from types import MappingProxyType

import numpy as np
import sympy as sp

from . import _validate as V
from .codegen import jacobian
from .model_builders import from_functions, linear
from .model_expressions import (SUPPORTED_FUNCTIONS, check_expressions, check_free_symbols, code_matrix, matrix,
                                model_symbols, noise_symbols, vector)
from .model_functions import bind_functions, build_functions
from .model_noise import STATE_R, STEP_R, LazyGaussian, R_at, bind_noise, cross_noise_matrix, new_noise, noise_covariances
from .angles import NO_ANGLES, declare
from .model_values import NO_VALUES, Broadcast, Values, param_value, rows_of
from .noise import Gaussian, NoiseLaw

__all__ = ["Model", "DiscreteModel", "SDEModel", "SUPPORTED_FUNCTIONS"]

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
    angles : ``{"states": [...], "measurements": [...]}``: the components that are angles (states
        by symbol, name or index; measurements by index into h): :mod:`nlfilter.angles`.
    """

    kind = "model"
    time_name = "t"
    angles = NO_ANGLES  # the angular components, :class:`~nlfilter.angles.Angles` (``angles=``)

    def __init__(self, states, f, h, G=None, Q=None, R=None, *, params=None, inputs=None, time=None,
                 process_noise: NoiseLaw | None = None, measurement_noise: NoiseLaw | None = None,
                 name: str = "", cross_noise=None, noise=None, meas_noise=None, angles=None):
        states, params, inputs = model_symbols(states, time, params, inputs)
        self.states, self.time, self.name, self.inputs = states, time, name, inputs
        self._psyms = tuple(params) + inputs  # every argument beyond states and time
        n = len(states)
        fM, hM = vector("f", f, n), vector("h", h)
        check_expressions("f", fM)
        check_expressions("h", hM)
        # non-additive noise: x[k+1] = f(x[k], w[k]), y[k] = h(x[k], v[k]) with the noise symbols in f, h
        noise, meas_noise = noise_symbols(noise, meas_noise, states, time, self._psyms)
        f_aug, h_aug = (fM if noise else None), (hM if meas_noise else None)
        if meas_noise:
            hM = hM.subs({v: 0 for v in meas_noise})  # the nominal measurement h(x, 0)
        if noise:
            if G is not None:
                raise ValueError("G: a model with non-additive noise (noise=[...]) states the noise in f; expected "
                                 f"G=None, got {G!r}")
            GM = jacobian(code_matrix(fM), noise).subs({w: 0 for w in noise})  # the noise gain at w = 0
        else:
            GM = sp.eye(n) if G is None else matrix("G", G, n, None)
            check_expressions("G", GM, True)
        check_free_symbols(fM, h_aug if meas_noise else hM, GM, states, time, self._psyms, noise, meas_noise)
        if noise:
            fM = fM.subs({w: 0 for w in noise})
        self.additive, self.additive_measurement = not noise, not meas_noise
        self.noise_symbols, self.meas_noise_symbols = noise, meas_noise
        self.n, self.m, self.r = n, hM.shape[0], GM.shape[1]
        self.mv = len(meas_noise) if meas_noise else self.m  # the dimension of v (R is mv x mv)
        self._sym = {"f": fM, "h": hM, "G": GM}  # parameters as symbols; .sym substitutes them
        noise_covariances(self, Q, R, process_noise, measurement_noise)
        build_functions(self, fM, hM, GM, f_aug, h_aug)
        self.cross_noise = cross_noise_matrix(self, cross_noise)
        self.angles = declare(angles, n, self.m, states)  # angular components (nlfilter.angles)
        self._uses.update({k: set(kn.params) for k, kn in self._QR.items()})
        values = {p: param_value(str(p), v) for p, v in params.items()}
        values.update({u: None for u in inputs})
        self._bind(Values(values, inputs, None, 0.0))

    def _bind(self, values: Values) -> None:
        """Bind the generated functions, Q, R, the noise laws and the flags to one set of values
        (no SymPy: this is all :meth:`with_params` costs)."""
        if self.kind == "sde" and values.arrays and values.dt is None:
            raise ValueError(f"dt: the parameter(s) {sorted(map(str, values.arrays))} are arrays over time; an "
                             "SDEModel needs their grid: model.with_params(..., dt=, t0=)")
        bind_functions(self, values)
        tv = {k for k, used in self._uses.items() if used & (values.arrays | values.unset)} | set(self._steps)
        bind_noise(self, values, tv)
        self._per_path_G = bool(self._uses["G"] & values.per_path) or self._per_path_Q  # G Q_k^{1/2} per path
        fixed = self._G_fixed and "G" not in tv and not self._fold
        self._GQG0 = (Broadcast(self.G(np.zeros(self.n)) @ self.Q @ self.G(np.zeros(self.n)).T)
                      if fixed else None)  # fixed G Q Gᵀ, computed once
        # f, h, G (and Q) do not depend on the time: filters may compute time-fixed quantities once
        self.time_invariant = not self._timed and not tv
        self._sym_cache = None

    @property
    def structure(self) -> frozenset:
        """What the model has beyond additive, uncorrelated noise with one constant R:
        ``"state-dependent R"`` (:meth:`R_of`), ``"time-varying R"`` (R per step: :meth:`R_of` at
        the step; a filter that takes R(x) takes it), ``"cross noise"`` (``cross_noise``),
        ``"non-additive noise"``, ``"angles"`` (:mod:`nlfilter.angles`); a filter refuses a structure
        it does not handle (its ``structures``, :func:`~nlfilter.filters.base.check_structure`)."""
        out = set()
        if not getattr(self, "R_constant", True):
            out.add("time-varying R" if getattr(self, "_R_kind", None) == "time" else "state-dependent R")
        if getattr(self, "cross_noise", None) is not None:
            out.add("cross noise")
        if not getattr(self, "additive", True):
            out.add("non-additive noise")
        if not getattr(self, "additive_measurement", True):
            out.add("non-additive measurement noise")
        if self.angles:
            out.add("angles")
        return frozenset(out)

    # -- the measurement noise covariance: one matrix, or R(x, k) --------------------------------
    @property
    def R(self) -> np.ndarray:
        """The measurement noise covariance ``(m, m)`` when it is constant (``R_constant``); a model
        whose R depends on the state has none: :meth:`R_of` evaluates it."""
        if self._R is None:
            raise ValueError(STEP_R if self._R_kind == "time" else STATE_R)
        return self._R

    @R.setter
    def R(self, value):
        self._R = value

    @property
    def measurement_noise(self) -> NoiseLaw:
        """The law of ``v`` (for simulation and the reference filters' likelihood); a model with
        a state-dependent R has the Gaussian ``N(0, R(x))`` at each state instead (:meth:`R_of`)."""
        if self._measurement_noise is None:
            raise ValueError((STEP_R if self._R_kind == "time" else STATE_R).replace("model.R", "model.measurement_noise", 1))
        if self._measurement_noise is LazyGaussian:
            self._measurement_noise = Gaussian(self.R)
        return self._measurement_noise

    @measurement_noise.setter
    def measurement_noise(self, value):
        self._measurement_noise = value

    @property
    def process_noise(self) -> NoiseLaw:
        """The law of ``w`` (for simulation and the reference filters; Gaussian ``N(0, Q)`` by default)."""
        if self._process_noise is LazyGaussian:
            self._process_noise = Gaussian(self.Q)
        return self._process_noise

    @process_noise.setter
    def process_noise(self, value):
        self._process_noise = value

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
        return R_at(self, x, t)

    # -- parameters and inputs ------------------------------------------------------------------
    @property
    def params(self):
        """The parameter values, ``{name: value}`` (read-only; inputs not included)."""
        vals = getattr(self, "_values", NO_VALUES)
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
        names = self.__dict__.get("_names")
        if names is None:  # by name, computed once (SymPy's str costs microseconds a symbol)
            names = self._names = {str(p): p for p in self._psyms}
        if isinstance(key, str) and key in names:
            return names[key]
        for p in self._psyms:
            if str(p) == key:
                return p
        raise ValueError(f"with_params: unknown parameter {key!r}; the model's parameters are "
                         f"{[str(p) for p in self._psyms if p not in self.inputs]}"
                         + (f" and inputs {[str(u) for u in self.inputs]}" if self.inputs else ""))

    def with_params(self, values=None, /, *, dt: float | None = None, t0: float = 0.0, R=None, Q=None, **named):
        """A copy of the model with new parameter values, sharing the generated code (no SymPy).

        ``values``: a dict keyed by symbol or name, and/or keywords by name (a parameter named
        ``dt``, ``t0``, ``R`` or ``Q`` goes in the dict). A value is a number, an array ``(T,)`` over time shared
        by all paths, or ``(..., T)`` per path (leading axes those of the filtered batch). A
        discrete model reads entry ``k`` at step ``k``; an :class:`SDEModel` reads the array as
        piecewise constant on the grid ``t0 + i dt`` (``i = floor((t - t0)/dt + 1e-9)``, clipped
        to the array): ``dt`` is then required (kept from the model when not given). An array
        makes the model time-varying (``time_invariant = False``).

        ``R``, ``Q`` (discrete models whose R, Q are numbers, not expressions): new noise
        covariances, one matrix or one per step as the constructor takes them — ``(T, m, m)``
        shared by the paths or ``(B, T, m, m)`` per path (Q: ``(T, r, r)``, ``(B, T, r, r)``),
        entry ``k`` read at step ``k`` (:mod:`nlfilter.model_noise`).

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
            new[p] = param_value(key if isinstance(key, str) else str(p), v)
        if self.kind == "discrete":
            if dt is not None:
                raise ValueError(f"dt: a DiscreteModel reads array entry k at step k; expected None, got {dt!r}")
            grid = (None, 0.0)
        else:
            grid = ((float(V.positive("dt", dt)), float(t0)) if dt is not None
                    else (self._values.dt, self._values.t0 if t0 == 0.0 else float(t0)))
        out = copy.copy(self)
        if R is not None or Q is not None:
            new_noise(out, R, Q)
        out._bind(Values(new, self.inputs, *grid))
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

    _rows = rows_of  # the model for a range of paths (nlfilter.model_values.rows_of)

    # -- construction without SymPy text (nlfilter.model_builders) -----------------------------
    from_functions = classmethod(from_functions)
    linear = classmethod(linear)

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
            return self._GQG0((x.shape if type(x) is np.ndarray else np.shape(x))[:-1])
        Gx = self.G(x, t)
        return np.einsum("...ia,ab,...jb->...ij", Gx, self.Q, Gx)

    def __repr__(self):
        return f"{type(self).__name__}(n={self.n}, m={self.m}, r={self.r}{', ' + self.name if self.name else ''})"


class DiscreteModel(Model):
    """``x[k+1] = f(x[k], k) + G(x[k], k) w[k]``, ``y[k] = h(x[k], k) + v[k]`` (see module docstring).

    Parameters
    ----------
    states : list of sympy.Symbol, length n
    f : n expressions
    h : m expressions
    G : n x r matrix (identity if omitted)
    Q : (r, r) covariance of w
    R : (m, m) covariance of v
    params : {Symbol: value}, kept as symbols of the generated functions (:meth:`Model.with_params`)
    inputs : control-input symbols, fed by :meth:`Model.with_inputs` an array ``u (..., T, p)``
    time : the step-index symbol, if f, h or G depend on it
    process_noise, measurement_noise : laws used to *simulate* w and v (Gaussian by default)
    cross_noise : ``(r, m)`` ``E[w_k v_kᵀ]``, correlated process and measurement noise (module docstring)
    noise : the process-noise symbols when they enter ``f`` non-additively (module docstring)
    meas_noise : the measurement-noise symbols when they enter ``h`` non-additively
    angles : the angular states and measurements (:class:`Model`; :mod:`nlfilter.angles`)

    Examples
    --------
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
                 name: str = "", cross_noise=None, noise=None, meas_noise=None, angles=None):
        for nm, val in (("cross_noise", cross_noise), ("noise", noise), ("meas_noise", meas_noise)):
            if val is not None:
                raise ValueError(f"{nm}: correlated (cross_noise) or non-additive (noise, meas_noise) noise is supported for "
                                 f"DiscreteModel only; an SDEModel is dx = f dt + G dβ, dy = h dt + dη with "
                                 f"independent β and η; expected None, got {val!r}")
        super().__init__(states, f, h, G, Q, R, params=params, inputs=inputs, time=time,
                         process_noise=process_noise, measurement_noise=measurement_noise, name=name, angles=angles)
        if not self.R_constant:
            raise ValueError("R: an SDEModel's measurement intensity (E dη dηᵀ = R dt) must not depend on the "
                             "state: a state-dependent R(x) is supported for DiscreteModel only (a "
                             "continuous-discrete model's discrete measurements: give them as a DiscreteModel)")
        for nm in ("process_noise", "measurement_noise"):
            if not isinstance(getattr(self, nm), Gaussian):
                raise ValueError(f"{nm}: an SDEModel is driven by Brownian motion; expected None or "
                                 f"Gaussian, got {type(getattr(self, nm)).__name__}")
