"""Angular components: wrapped residuals and circular means for states and measurements declared
angles (``DiscreteModel(..., angles={"states": [psi], "measurements": [1]})``; a model file's
``[model] angles = {...}``).

An angle lives on the circle, represented in ``(−π, π]``: the difference of two angles is the
wrapped residual ``wrap(a − b)`` (the shortest turn from b to a) and the mean of weighted angles
is the circular weighted mean (Mardia & Jupp 2000, *Directional Statistics*, §2.2)::

    wrap(x) = π − ((π − x) mod 2π)                 ∈ (−π, π]
    θ̄ = atan2(Σ w_i sin θ_i, Σ w_i cos θ_i)        (the argument of Σ w_i e^{iθ_i})

Every filter reads the declaration from the model (``model.angles``, an
:class:`Angles` of component indices): the Gaussian rules average the angular components of f and
h at their nodes by :func:`circular_mean` and take their deviations wrapped (:func:`deviations`);
an update conditions on the wrapped innovation (:func:`near`: ``ŷ`` moved by whole turns to the
branch of ``y``) and wraps its mean (:func:`wrap_components`); the smoothers wrap
``mˢ_{k+1} − m⁻_{k+1}``; the reference filters average their particles (grid points) circularly,
the grid being periodic along an angular state axis; simulation wraps its states and
measurements; the MSE and NEES take wrapped errors (:func:`residual`). An SDEModel's measurements
read as increments ``dy = h dt + dη`` (the grid and particle references on an SDE) are not angles:
those filters refuse angular measurements there (angular states they take). A model without angles
(the default :data:`NO_ANGLES`) takes none of these paths: its arithmetic is unchanged.

>>> import numpy as np
>>> float(wrap(np.pi)), float(wrap(-np.pi)), round(float(wrap(3 * np.pi / 2)), 6)
(3.141592653589793, 3.141592653589793, -1.570796)
>>> round(float(circular_mean(np.array([[3.0], [-3.0]]), np.array([0.5, 0.5]), (0,))[0]), 12)
3.14159265359
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._npcall import einsum as _einsum

__all__ = ["Angles", "NO_ANGLES", "wrap", "wrap_components", "residual", "near", "circular_mean", "deviations", "angles_of",
           "node_moments", "mixture", "weighted_moments",
           "declare"]

TWO_PI = 2.0 * np.pi


class Angles(NamedTuple):
    """The angular components of a model: indices into the state ``(n,)`` and the measurement
    ``(m,)`` (sorted, distinct). Falsy when neither declares one."""

    states: tuple = ()
    measurements: tuple = ()

    def __bool__(self):
        return bool(self.states or self.measurements)


#: no angular component (every model's default)
NO_ANGLES = Angles()


def wrap(x):
    """``x`` wrapped to ``(−π, π]`` (elementwise; NaN stays NaN)."""
    return np.pi - np.mod(np.pi - np.asarray(x, dtype=float), TWO_PI)


def wrap_components(x, idx):
    """``x (..., d)`` with its components ``idx`` wrapped (``x`` itself when ``idx`` is empty)."""
    if not idx:
        return x
    out = np.array(x, dtype=float, copy=True)
    out[..., idx] = wrap(out[..., idx])
    return out


def residual(a, b, idx):
    """``a − b`` with the components ``idx`` wrapped: the shortest turn from b to a."""
    d = np.asarray(a, dtype=float) - b
    return wrap_components(d, idx) if idx else d


def near(a, ref, idx):
    """``a`` with its components ``idx`` moved by whole turns to the branch nearest ``ref``
    (``ref − wrap(ref − a)``), so that ``ref − near(a, ref)`` is the wrapped residual; where
    ``ref`` is NaN (a missing measurement) ``a`` as it is."""
    if not idx:
        return a
    a = np.array(np.broadcast_to(a, np.broadcast_shapes(np.shape(a), np.shape(ref))), dtype=float)
    r = np.broadcast_to(ref, a.shape)[..., idx]
    moved = r - wrap(r - a[..., idx])
    a[..., idx] = np.where(np.isnan(r), a[..., idx], moved)
    return a


def circular_mean(X, w, idx):
    """The weighted mean of the points ``X (..., N, d)`` with weights ``w`` (``(N,)`` or ``(..., N)``,
    summing to 1), the components ``idx`` by the circular weighted mean ``atan2(Σ w sin, Σ w cos)``
    and the others by ``Σ w X``."""
    X = np.asarray(X, dtype=float)
    wb = np.asarray(w)[..., None]
    mean = np.sum(wb * X, axis=-2)
    if idx:
        A = X[..., idx]
        mean[..., idx] = np.arctan2(np.sum(wb * np.sin(A), axis=-2), np.sum(wb * np.cos(A), axis=-2))
    return mean


def deviations(X, mean, idx):
    """``X − mean`` over the nodes (``X (..., N, d)``, ``mean (..., d)``), the components ``idx``
    wrapped."""
    return residual(X, mean[..., None, :], idx)


def _index(name, item, size, names, what):
    """One component: an index ``0 <= i < size`` or (states) a symbol or its name."""
    if isinstance(item, (bool, np.bool_)):
        raise TypeError(f"angles: got the {name} entry {item!r} (a bool); expected {what}")
    if isinstance(item, (int, np.integer)) and 0 <= item < size:
        return int(item)
    if names is not None and not isinstance(item, (int, np.integer)) and str(item) in names:
        return names.index(str(item))
    raise ValueError(f"angles: got the {name} component {item!r}, which does not exist; expected {what}")


def declare(angles, n: int, m: int, states=None) -> Angles:
    """The :class:`Angles` of a declaration ``{"states": [...], "measurements": [...]}`` (either key
    optional; a list alone declares states), states given by index, symbol or name, measurements by
    index into ``h``. A component that does not exist, a repeated one or another key is refused,
    naming it (``ValueError``/``TypeError``)."""
    if angles is None:
        return NO_ANGLES
    if isinstance(angles, Angles):
        angles = angles._asdict()
    if isinstance(angles, (list, tuple)):
        angles = {"states": angles}
    if not isinstance(angles, dict):
        raise TypeError(f"angles: got {type(angles).__name__}; expected a dict {{'states': [...], "
                        "'measurements': [...]}")
    extra = set(angles) - {"states", "measurements"}
    if extra:
        raise ValueError(f"angles: got the unknown key(s) {sorted(map(str, extra))}; expected 'states' and/or "
                         "'measurements'")
    names = None if states is None else [str(s) for s in states]
    out = {}
    for key, size in (("states", n), ("measurements", m)):
        items = angles.get(key, ())
        if isinstance(items, (str, int, np.integer)) or not hasattr(items, "__iter__"):
            raise TypeError(f"angles: got {key} = {items!r}; expected a list of components")
        what = (f"an index from 0 to {size - 1} of the {size} {key}"
                + (f" or a state name {names}" if key == "states" and names else "" if key == "states" else " (of h)"))
        idx = [_index(key, it, size, names if key == "states" else None, what) for it in items]
        if len(set(idx)) != len(idx):
            raise ValueError(f"angles: got {key} {list(items)!r}, which repeats a component; expected each at most once")
        out[key] = tuple(sorted(idx))
    return Angles(out["states"], out["measurements"])


def angles_of(model) -> Angles:
    """The model's :class:`Angles` (:data:`NO_ANGLES` for an object that declares none)."""
    return getattr(model, "angles", NO_ANGLES)


def node_moments(GX, w, idx):
    """``(mean (..., p), deviations (..., N, p))`` of node values ``GX (..., N, p)`` with mean weights
    ``w (N,)``: ``Σ w_i g_i`` and ``g_i − ĝ`` (the node rules' sums, unchanged without angles), the
    components ``idx`` by :func:`circular_mean` and wrapped deviations."""
    if not idx:
        mean = _einsum("i,...ij->...j", w, GX)  # Σ w_i g(X_i)
        return mean, GX - mean[..., None, :]
    mean = circular_mean(GX, w, idx)
    return mean, deviations(GX, mean, idx)


def mixture(w, m, P, idx):
    """The moments of a Gaussian mixture over the axis of its components: weights ``w (..., M)``,
    means ``m (..., M, n)``, covariances ``P (..., M, n, n)`` give ``(m̄, Σ_i w_i [P_i + d_i d_iᵀ])``,
    ``m̄ = Σ_i w_i m_i`` and ``d_i = m_i − m̄``, the components ``idx`` by the circular weighted mean
    and wrapped deviations (the IMM's mixing, combination and smoothing with angles)."""
    mean, spread = weighted_moments(w, m, idx)
    return mean, np.sum(w[..., None, None] * P, axis=-3) + spread


def weighted_moments(w, x, idx, cov: bool = True):
    """Mean ``(..., n)`` and covariance ``(..., n, n)`` (None without ``cov``) of the points
    ``x (..., N, n)`` with normalized weights ``w (..., N)`` (a particle cloud, a grid's points),
    the components ``idx`` by the circular weighted mean and wrapped deviations."""
    x = np.broadcast_to(x, (*np.shape(w), np.shape(x)[-1]))
    mean = circular_mean(x, w, idx)
    if not cov:
        return mean, None
    d = residual(x, mean[..., None, :], idx)
    return mean, (d * w[..., None]).swapaxes(-1, -2) @ d
