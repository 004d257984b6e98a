"""A model's generated functions: SymPy expressions compiled once into batched NumPy functions
(:func:`nlfilter.codegen.lambdify_arrays`) and bound to one set of parameter values; the second
derivatives and G's derivatives generated on their first call, once for a model and all its
:meth:`~nlfilter.models.Model.with_params` copies (:mod:`nlfilter.models`, the table of functions).

>>> import numpy as np
>>> import sympy as sp
>>> x, a = sp.symbols("x a")
>>> kn = Kernel([a * x**2, x], [x], None, (2,), [a])
>>> Batched(kn, Values({a: 0.5}, (), None, 0.0))(np.array([[2.0], [4.0]])).tolist()
[[2.0, 2.0], [8.0, 4.0]]
"""

from __future__ import annotations

import dis
import weakref

import numpy as np
import sympy as sp

from .codegen import first_derivatives, is_affine, jacobian, lambdify_arrays
from .model_expressions import code_form, code_matrix, piecewise_names
from .model_values import NO_VALUES, Broadcast, Values

_F8 = np.dtype(float)


def _on_floats(fn, x, t, shape):
    """``fn`` (a scalar-safe kernel, :meth:`Batched._scalar_safe`) of one state ``x`` on its entries as Python
    floats, ~5x cheaper than arrays of one entry for the same numbers; where Python raises (x/0, 0/0) and NumPy
    gives inf or NaN, on NumPy scalars. The output as an array of ``shape``."""
    try:
        vals = fn(*x.ravel().tolist(), float(t))
    except ZeroDivisionError:
        vals = fn(*x.ravel(), np.float64(t))
    return np.array(vals, dtype=float).reshape(shape)


class Kernel:
    """A SymPy array expression compiled once (``lambdify`` with ``cse=True``) into a function of
    the state components, the time and the parameters it uses; shared by every
    :meth:`~nlfilter.models.Model.with_params` copy of a model."""

    @classmethod
    def zeros(cls, shape, n: int) -> Kernel:
        """The kernel of an all-zero array (G's derivatives when G is free of the states), no SymPy."""
        self = cls.__new__(cls)
        self.shape, self.params, self.varies, self.const, self.n = tuple(shape), (), False, True, n
        self.timed = False
        self.value = np.zeros(self.shape)
        self.fixed = self.moving = ()
        return self

    def __init__(self, exprs, states, time, shape, params=()):
        self.shape = tuple(shape)
        flat = [sp.sympify(e) for e in exprs]
        free = set().union(*(e.free_symbols for e in flat)) if flat else set()
        self.params = tuple(p for p in params if p in free)
        self.varies = bool(free & (set(states) | ({time} if time is not None else set())))
        self.timed = time is not None and time in free  # the function reads its time argument
        self.const = not self.varies and not self.params
        self.n = len(states)
        # the entries that are numbers (Batched._eval writes them once) and the others
        self.fixed = tuple(j for j, e in enumerate(flat) if not e.free_symbols)
        self.moving = tuple(j for j, e in enumerate(flat) if e.free_symbols)
        if self.const:
            self.value = np.array([float(e) for e in flat], dtype=float).reshape(self.shape)
        else:
            args = list(states) + ([time] if time is not None else [sp.Symbol("_t_unused")]) + list(self.params)
            flat = [code_form(e) for e in flat]
            self.fn = lambdify_arrays(args, flat)


class LazyKernels:
    """Kernels generated on first use (the second derivatives, G's derivatives), shared by every
    :meth:`~nlfilter.models.Model.with_params` copy of a model: whichever copy calls first generates the code once,
    and every copy, made before or after, uses it."""

    def __init__(self, makers: dict):
        self.shapes = {k: shape for k, (shape, _) in makers.items()}
        self._makers = {k: make for k, (_, make) in makers.items()}
        self.built = {}

    def kernel(self, key) -> Kernel:
        kn = self.built.get(key)
        if kn is None:
            kn = self.built[key] = self._makers[key]()
            del self._makers[key]  # the SymPy expressions it held are no longer needed
        return kn

    def bind(self, key, values, model):
        if key in self.built:
            return Batched(self.built[key], values)
        return Lazy(self, key, values, model)


def _no_model():
    return None


class Lazy:
    """Stands for a model's ``Batched`` function until its first call, which generates the kernel
    (:class:`LazyKernels`), binds it to the model's values and puts it in the model's place."""

    def __init__(self, store: LazyKernels, key: str, values, model):
        self.store, self.key, self.values, self.shape = store, key, values, store.shapes[key]
        self._model, self._fn = weakref.ref(model), None

    @property
    def kernel(self) -> Kernel:
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
            fn = self._fn = Batched(self.store.kernel(self.key), self.values)
            model = self._model()
            if model is not None and model.__dict__.get(self.key) is self:
                setattr(model, self.key, fn)  # later look-ups go straight to the function
        return fn(x, t)


class Batched:
    """A compiled :class:`Kernel` bound to a model's parameter values: a function of a state batch
    ``(..., n)`` and a scalar time, returning ``(..., *shape)``.

    Constant entries are broadcast over the batch (raw ``lambdify`` on matrices does not:
    sympy issues #5642, #19259); so is a function that depends on scalar parameters only.
    """

    #: the largest output (entries over the batch) whose constant entries are kept filled in a template
    TEMPLATE_MAX = 1 << 16

    def __init__(self, kernel: Kernel, values: Values = NO_VALUES):
        self.kernel, self.values, self.shape = kernel, values, kernel.shape
        self._fixed = None
        self._tmpl = None  # the output's constant entries for the last batch shape (_eval)
        self._scalar = None  # whether one state may be evaluated on NumPy scalars (_scalar_safe)
        self._one = None  # the kernel for one state on Python floats, False where not _scalar_safe (None: unknown)
        self._n, self._shape1 = kernel.n, (1, *kernel.shape)  # (the output of one state (1, n): (1, *shape))
        self._row = (1, kernel.n)  # one state as a run's single trajectory passes it
        # the kernel of a state of one component, without parameters (the common call, made without _eval),
        # and whether it reads its time argument (else the time goes as given: no NumPy float to make)
        self._column = kernel.fn if not kernel.const and kernel.n == 1 and not kernel.params else None
        self._timed = getattr(kernel, "timed", True)
        if kernel.const:
            self._fixed = Broadcast(kernel.value)
        elif not kernel.varies and values.scalar(kernel.params):
            self._fixed = Broadcast(self._eval(np.zeros(kernel.n), 0.0))

    def __call__(self, x, t=0.0):
        one = self._one
        if one and type(x) is np.ndarray and x.shape == self._row and x.dtype is _F8:  # one state (1, n), its
            return _on_floats(one, x, t, self._shape1)  # kernel known scalar-safe: the path below, in two checks
        x = np.asarray(x, dtype=float)
        if self._fixed is not None:
            return self._fixed(x.shape[:-1])
        fn = self._column
        if fn is not None and x.size > 1:  # a batch of one-component states: the kernel on the column
            batch = x.shape[:-1]
            return self._assemble(fn(x[..., 0], np.float64(t) if self._timed else t), x, batch)
        if x.size == self._n == x.shape[-1]:  # one state
            one = self._one
            if one is None:
                one = self._one = self.kernel.fn if self._scalar_safe() else False
            if one is not False:  # one state (a single trajectory): on Python floats (_on_floats)
                return _on_floats(one, x, t, self._shape1 if x.ndim == 2 else x.shape[:-1] + self.shape)
        return self._eval(x, t)

    def _scalar_safe(self) -> bool:
        """Whether the kernel gives the same numbers on Python floats (NumPy scalars where Python
        raises) as on arrays of one entry: no parameters, and no ``**`` (a scalar's power is C
        ``pow``, an array's NumPy's own loop, which differ in the last bit; the four operations,
        ``%``, ``//`` are IEEE's or NumPy's Python rule on both, and the ufunc calls, ``sin``,
        ``exp``, ..., the same loops)."""
        kn = self.kernel
        ok = kn.__dict__.get("_scalar_ok")  # (decided once per kernel: a with_params copy binds it anew)
        if ok is None:
            ok = kn._scalar_ok = not kn.params and not any(i.opname.startswith("BINARY") and "**" in i.argrepr
                                                           for i in dis.get_instructions(kn.fn))
        self._scalar = ok
        return ok

    def _eval(self, x, t):
        batch = x.shape[:-1]
        kn = self.kernel
        if kn.params:
            extra = [self.values.at(p, t, batch) for p in kn.params]
            vals = kn.fn(*(x[..., i] for i in range(kn.n)), np.float64(t), *extra)
        else:  # (a list, not a generator: star-arguments of a generator cost here)
            vals = kn.fn(*[x[..., i] for i in range(kn.n)], np.float64(t) if self._timed else t)
        return self._assemble(vals, x, batch)

    def _assemble(self, vals, x, batch):
        """The output ``(*batch, *shape)`` from the kernel's entries ``vals`` (arrays or numbers)."""
        if len(vals) == 1 and getattr(vals[0], "shape", None) == batch:  # one entry: a reshape, no copy
            return np.asarray(vals[0], dtype=float).reshape(batch + self.shape)
        kn = self.kernel
        fixed = kn.fixed
        if fixed and len(vals) * (x.size // x.shape[-1]) <= self.TEMPLATE_MAX:  # the numbers are written once
            tmpl = self._tmpl
            if tmpl is None or tmpl.shape[:-1] != batch:
                tmpl = np.empty((*batch, len(vals)))
                for j in fixed:
                    tmpl[..., j] = vals[j]
                self._tmpl = tmpl
            out = tmpl.copy()
            for j in kn.moving:
                out[..., j] = vals[j]
            return out.reshape(*batch, *self.shape)
        out = np.empty((*batch, len(vals)))
        for j, v in enumerate(vals):
            out[..., j] = v
        return out.reshape(*batch, *self.shape)


class Folded:
    """``G`` (or ``G_x``, ``G_xx``: the noise axis is the second) times ``Q_t^{1/2}`` when ``Q``
    varies with time: the filters and the simulator then see ``Q = I`` and the same ``G Q Gᵀ``."""

    def __init__(self, inner: Batched, Qfn: Batched, per_path: int):
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


DERIVS = ("f", "f_x", "f_xx", "h", "h_x", "h_xx", "G", "G_x", "G_xx")
"""The functions a SymPy model gives (the table of :mod:`nlfilter.models`)."""


def build_functions(model, fM, hM, GM, f_aug=None, h_aug=None) -> None:
    """Generate ``model``'s functions from its expressions (``f_aug``, ``h_aug``: f and h of the
    non-additive noises on the augmented vector): the kernels of f, f_x, h, h_x, G (and f_aug,
    h_aug) now, the second derivatives and G's derivatives on first call; and the structure flags
    that hold for every parameter value (``piecewise``, ``G_constant``, ``is_linear``, the symbols
    each function uses). Derivatives are those of the code forms (Abs, sign, Max, ...: the
    convention of :mod:`nlfilter.models`, "Functions")."""
    states, time, ps, n, m, r = model.states, model.time, model._psyms, model.n, model.m, model.r
    noise, meas_noise = model.noise_symbols, model.meas_noise_symbols
    model.piecewise = piecewise_names((fM, hM, GM))
    fM, hM, GM = code_matrix(fM), code_matrix(hM), code_matrix(GM)
    fx = jacobian(fM, states)
    hx = jacobian(hM, states)
    # the G-constant flag first: a G free of the states has G_x = G_xx = 0 (no SymPy)
    sset = frozenset(states)  # (one set: n² entries are tested against it)
    model.G_constant = Gc = all(e.free_symbols.isdisjoint(sset) for e in GM)
    specs = {"f": (list(fM), (n,)), "f_x": (list(fx), (n, n)), "h": (list(hM), (m,)), "h_x": (list(hx), (m, n)),
             "G": (list(GM), (n, r))}
    kernels = {key: Kernel(exprs, states, time, shape, ps) for key, (exprs, shape) in specs.items()}
    # second derivatives (and G's derivatives) are generated on first call, once for every copy
    model._lazy = LazyKernels({
        "f_xx": ((n, n, n), lambda: Kernel(first_derivatives(list(fx), states), states, time, (n, n, n), ps)),
        "h_xx": ((m, n, n), lambda: Kernel(first_derivatives(list(hx), states), states, time, (m, n, n), ps)),
        "G_x": ((n, r, n), lambda: Kernel.zeros((n, r, n), n) if Gc else
                Kernel(first_derivatives(GM, states), states, time, (n, r, n), ps)),
        "G_xx": ((n, r, n, n), lambda: Kernel.zeros((n, r, n, n), n) if Gc else
                 Kernel(first_derivatives(first_derivatives(GM, states), states), states, time, (n, r, n, n), ps)),
    })
    if noise:  # f(x, w) on the augmented vector (x, w) (..., n + r)
        kernels["f_aug"] = Kernel(list(f_aug), states + list(noise), time, (n,), ps)
    if meas_noise:  # h(x, v) on (x, v) (..., n + mv)
        kernels["h_aug"] = Kernel(list(h_aug), states + list(meas_noise), time, (m,), ps)
    model._kernels = kernels
    model.given = set(DERIVS)
    # structure flags (for every parameter value), read by filters that can exploit them
    model._G_fixed = all(e.free_symbols.isdisjoint(sset | {time}) for e in GM)
    model.is_linear = model.additive and model.additive_measurement and Gc and all(  # f and h affine in the state
        is_affine(e, row, states) for e, row in zip(list(fM) + list(hM), fx.tolist() + hx.tolist()))
    model._timed = time is not None and any(M.has(time) for M in (fM, hM, GM) + ((f_aug,) if noise else ())
                                            + ((h_aug,) if meas_noise else ()))
    model._uses = {k: set(kernels[k].params) for k in ("f", "h", "G")}
    if noise:
        model._uses["f"] |= set(kernels["f_aug"].params)
    if meas_noise:
        model._uses["h"] |= set(kernels["h_aug"].params)


def bind_functions(model, values: Values) -> None:
    """Bind ``model``'s generated functions to the parameter values ``values`` (no SymPy): a
    function not generated yet is bound on its first call (:class:`Lazy`)."""
    model._values = values
    for key, kn in model._kernels.items():
        setattr(model, key, Batched(kn, values))
    for key in model._lazy.shapes:  # built on first call (or now, if another copy built the code)
        setattr(model, key, model._lazy.bind(key, values, model))
