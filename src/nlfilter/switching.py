"""A jump-Markov (switching) model: ``M`` discrete models (modes) over one state and one
measurement, switched by a Markov chain — what the IMM filter (:class:`~nlfilter.filters.IMM`)
assumes, stated once so that it can be simulated
(:func:`~nlfilter.simulate_switching.simulate_switching`), filtered optimally
(:class:`~nlfilter.filters.reference.JumpParticleFilter`) and compared
(``compare(switching_model, ...)``).

The model (Bar-Shalom, Li & Kirubarajan 2001, §11.6.1): the mode ``r_k ∈ {0..M−1}`` is a Markov
chain with ``P(r_0 = j) = μ0_j`` and ``P(r_{k+1} = j | r_k = i) = Π_ij``; given the modes, the
state moves and is measured by the mode's model::

    x_{k+1} = f_{r_{k+1}}(x_k, k) + G_{r_{k+1}}(x_k, k) w_k,   y_k = h_{r_k}(x_k, k) + v_k,  v_k ~ R_{r_k}

(the mode of a step drives the transition into it and the measurement of it: the IMM's
convention, whose mode-matched filter j predicts and updates with model j).

>>> import sympy as sp; from nlfilter import DiscreteModel
>>> x = sp.Symbol("x")
>>> slow = DiscreteModel([x], [0.9 * x], [x], Q=0.01, R=0.5)
>>> fast = DiscreteModel([x], [0.9 * x], [x], Q=4.0, R=0.5)
>>> sw = SwitchingModel([slow, fast], [[0.95, 0.05], [0.1, 0.9]])
>>> sw.modes, sw.n, sw.m, sw.mode_probs0.tolist()
(2, 1, 1, [0.5, 0.5])
"""

from __future__ import annotations

import numpy as np

from . import _validate as V

__all__ = ["SwitchingModel", "probability_rows", "markov_chain"]


def probability_rows(name, value, M=None):
    """``value`` as a float array whose last axis is a probability vector (rows summing to 1 to
    1e-9, non-negative), of length ``M`` when given; a ValueError naming ``name`` otherwise."""
    a = V.finite(name, V.as_float_array(name, value))
    if a.ndim == 0 or (M is not None and a.shape[-1] != M):
        raise ValueError(f"{name}: expected {'a vector' if M is None else f'{M} entries'} of probabilities, "
                         f"got shape {a.shape}")
    if (a < 0).any():
        raise ValueError(f"{name}: expected non-negative probabilities, got {V.shown(a.tolist())}")
    s = a.sum(axis=-1)
    bad = np.flatnonzero(np.abs(np.atleast_1d(s) - 1.0) > 1e-9)
    if bad.size:
        rows = f" (row(s) {bad.tolist()})" if a.ndim > 1 else ""
        raise ValueError(f"{name}: expected probabilities summing to 1 (to 1e-9){' in every row' if a.ndim > 1 else ''}"
                         f", got sums {V.shown(np.atleast_1d(s).tolist())}{rows}")
    return a


def markov_chain(transition, mode_probs0, M: int, per: str):
    """``(Π, μ0)``: the ``(M, M)`` Markov matrix ``transition`` and the initial mode probabilities
    ``mode_probs0`` (None: uniform) checked by :func:`probability_rows`; ``per`` says what a row
    and column stand for in the message (``"mode: 2 models"``, ``"filter"``)."""
    Pi = probability_rows("transition", transition)
    if Pi.shape != (M, M):
        raise ValueError(f"transition: expected a ({M}, {M}) Markov matrix (one row and column per {per}), "
                         f"got shape {Pi.shape}")
    mu0 = np.full(M, 1.0 / M) if mode_probs0 is None else probability_rows("mode_probs0", mode_probs0, M)
    if mu0.ndim != 1:
        raise ValueError(f"mode_probs0: expected a vector of {M} probabilities, got shape {mu0.shape}")
    return Pi, mu0


class SwitchingModel:
    """A jump-Markov model (module docstring).

    Parameters
    ----------
    models : a list of ``M ≥ 1`` DiscreteModels (one per mode) over the same state and
        measurement dimensions
    transition : ``(M, M)`` Markov matrix ``Π``, ``transition[i, j] = P(mode j at k+1 | mode i at k)``
        (non-negative, rows summing to 1 to 1e-9)
    mode_probs0 : the initial mode probabilities ``μ0`` (default uniform)
    name : a label (tables, figures)

    Notes
    -----
    :meth:`from_params`: the modes as parameter values of one model (as
    :meth:`nlfilter.filters.IMM.from_params`). The attributes the comparison reads (``kind``,
    ``n``, ``m``, ``states``) are the first mode's.
    """

    kind = "discrete"

    def __init__(self, models, transition, mode_probs0=None, *, name: str = ""):
        if not isinstance(models, (list, tuple)) or not models:
            raise TypeError(f"models: expected a non-empty list of DiscreteModels (one per mode), got {V.shown(models)}")
        for j, md in enumerate(models):
            if getattr(md, "kind", None) != "discrete" or not callable(getattr(md, "transition", None)):
                raise TypeError(f"models: expected DiscreteModels, got {type(md).__name__} at position {j}")
        first = models[0]
        for j, md in enumerate(models[1:], 1):
            if (md.n, md.m) != (first.n, first.m):
                raise ValueError(f"models: every mode must have the same state and measurement dimensions; model {j} "
                                 f"has (n, m) = {(md.n, md.m)}, model 0 {(first.n, first.m)}")
        M = len(models)
        Pi, mu0 = markov_chain(transition, mode_probs0, M, f"mode: {M} models")
        if not isinstance(name, str):
            raise TypeError(f"name: expected a string, got {V.shown(name)}")
        self.models, self.transition, self.mode_probs0 = tuple(models), Pi, mu0
        self.name = name

    @classmethod
    def from_params(cls, model, modes, transition, mode_probs0=None, *, name: str = ""):
        """The switching model of one ``model`` whose modes are values of its parameters: mode j is
        ``model.with_params(modes[j])`` (e.g. ``[{"omega": 0.0}, {"omega": 0.3}]``)."""
        if not isinstance(modes, (list, tuple)) or not modes or not all(isinstance(v, dict) for v in modes):
            raise TypeError(f"modes: expected a non-empty list of dicts of parameter values (one per mode), "
                            f"got {V.shown(modes)}")
        if not callable(getattr(model, "with_params", None)):
            raise TypeError(f"model: expected a model with parameters (params=), got {type(model).__name__}")
        return cls([model.with_params(v) for v in modes], transition, mode_probs0, name=name)

    @property
    def modes(self) -> int:
        return len(self.models)

    @property
    def n(self) -> int:
        return self.models[0].n

    @property
    def m(self) -> int:
        return self.models[0].m

    @property
    def states(self):
        return getattr(self.models[0], "states", None)

    def __repr__(self):
        return (f"SwitchingModel({list(self.models)!r}, transition={self.transition.tolist()!r}, "
                f"mode_probs0={self.mode_probs0.tolist()!r}{f', name={self.name!r}' if self.name else ''})")
