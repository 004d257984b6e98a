"""Beliefs: the small frozen containers a filter passes from step to step.

A belief is a ``NamedTuple`` whose array fields carry the batch of paths on their leading axis
(``(B, ...)`` inside :meth:`~nlfilter.filters.base.Filter.run`, any ``(..., )`` batch in the step
functions). The Gaussian filters carry a :class:`GaussianState`; the other families carry their
own container (a moment vector, a grid density, weighted particles, an off-line-gain state, ...),
defined beside the filter that uses it. A field that is not per path (a random generator, a
shared gain schedule position) is listed in the container's ``_shared`` attribute and is left
alone by :func:`where_paths`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class GaussianState(NamedTuple):
    """Mean ``(..., n)`` and covariance ``(..., n, n)`` of a batch of Gaussian beliefs."""

    mean: np.ndarray
    cov: np.ndarray


def where_paths(paths: np.ndarray, new, old):
    """The belief ``new`` on the paths ``paths (B,)`` and ``old`` elsewhere, field by field
    (``np.where`` broadcast over each field's trailing axes). Fields named in the belief's
    ``_shared`` attribute (not per path) are taken from ``old``."""
    shared = getattr(type(old), "_shared", ())
    out = []
    for name, a, b in zip(old._fields, new, old):
        if name in shared or b is None:
            out.append(b)
            continue
        a, b = np.asarray(a), np.asarray(b)
        out.append(np.where(paths.reshape(paths.shape + (1,) * (b.ndim - paths.ndim)), a, b))
    return type(old)(*out)
