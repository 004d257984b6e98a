"""Models built without SymPy text: from plain callables (:func:`from_functions`) and linear models
from matrices (:func:`linear`); the classmethods ``from_functions`` and ``linear`` of
:class:`~nlfilter.models.Model` (``cls`` the model class).

>>> import numpy as np
>>> from nlfilter.models import DiscreteModel
>>> m = DiscreteModel.linear([[0.9]], [[1.0]], Q=0.1, R=0.2)
>>> m.is_linear, m.f(np.array([2.0]), 0).tolist()
(True, [1.8])
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import sympy as sp

from . import _validate as V
from .model_values import NO_VALUES, Broadcast
from .noise import NoiseLaw, as_law


def from_functions(cls, n: int, m: int, f: Callable, h: Callable, *, Q, R, G: Callable | None = None,
                   r: int | None = None, f_x=None, f_xx=None, h_x=None, h_xx=None, G_x=None, G_xx=None,
                   process_noise=None, measurement_noise=None, name: str = "", is_linear: bool = False,
                   time_invariant: bool = False):
    """A model from callables ``f(x, t)``, ``h(x, t)`` (and ``G(x, t)``, derivatives) that take a
    batch ``(..., n)``. Derivatives not given are ``None``; filters that need them say so.

    The callables receive the time (``k`` or ``t``) at every call, so the model is taken to
    vary with it unless ``time_invariant=True`` promises that none of them reads it (filters
    then compute time-fixed quantities, such as the Kalman filter's matrices, once)."""
    model = cls.__new__(cls)
    V.positive("n", n, integer=True)
    V.positive("m", m, integer=True)
    model.n, model.m, model.name, model.time, model.states, model._sym = n, m, name, None, None, None
    model.inputs, model._psyms, model._values, model._per_path_G, model._sym_cache = (), (), NO_VALUES, False, None
    Qa = V.covariance("Q", Q)
    model.r = Qa.shape[0] if r is None else r
    model.Q = V.covariance("Q", Q, model.r)
    model.R = V.covariance("R", R, m)
    model.R_constant, model.cross_noise, model.additive, model.noise_symbols = True, None, True, ()
    model.additive_measurement, model.meas_noise_symbols, model.mv = True, (), m
    model.piecewise = frozenset()
    model.process_noise = as_law("process_noise", process_noise, model.Q)
    model.measurement_noise = as_law("measurement_noise", measurement_noise, model.R)
    for key, fn in (("f", f), ("h", h)):
        if not callable(fn):
            raise TypeError(f"{key}: expected a callable {key}(x, t), got {type(fn).__name__}")
    if G is None:
        if model.r != n:
            raise ValueError(f"G: expected a callable when Q is {model.r}x{model.r} and n = {n}, got None")
        eye = np.eye(n)
        G = lambda x, t=0.0: np.broadcast_to(eye, (*np.shape(x)[:-1], n, n))  # noqa: E731
        zero = np.zeros((n, n, n))
        G_x = G_x or (lambda x, t=0.0: np.broadcast_to(zero, (*np.shape(x)[:-1], n, n, n)))  # noqa: E731
        zero2 = np.zeros((n, n, n, n))
        G_xx = G_xx or (lambda x, t=0.0: np.broadcast_to(zero2, (*np.shape(x)[:-1], n, n, n, n)))  # noqa: E731
        model.G_constant = True
        model._GQG0 = Broadcast(model.Q)
    else:
        model._GQG0 = None
        model.G_constant = False
    fns = {"f": f, "h": h, "G": G, "f_x": f_x, "f_xx": f_xx, "h_x": h_x, "h_xx": h_xx, "G_x": G_x, "G_xx": G_xx}
    for key, fn in fns.items():
        if fn is not None and not callable(fn):
            raise TypeError(f"{key}: expected a callable or None, got {type(fn).__name__}")
        setattr(model, key, fn)
    model.given = {k for k, v in fns.items() if v is not None}
    model.is_linear = bool(is_linear)
    if not isinstance(time_invariant, bool):
        raise TypeError(f"time_invariant: expected True or False, got {type(time_invariant).__name__}")
    model.time_invariant = time_invariant
    return model


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
