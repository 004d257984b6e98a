"""What a filter's run returns: :class:`Estimates` (means, covariances, divergence flags and
per-step extras of every path), batch-first; the run loop that fills it is
:mod:`nlfilter.filters.recorder`, the skeleton :mod:`nlfilter.filters.base`."""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping, NamedTuple

import numpy as np

_NO_EXTRAS = MappingProxyType({})


class Estimates(NamedTuple):
    """Filter output over a batch.

    ``means (..., T, n)``, ``covs (..., T, n, n)`` (NaN where a filter carries no covariance, as
    documented by that filter), ``diverged (...,)`` bool, ``diverged_step (...,)`` int (−1 where
    not diverged), and ``extras``: family-specific per-step outputs ``{name: (..., T, ...)}``
    (for example the phase estimate ``theta`` of the phase filters, the fallback flags of the
    method-of-moments filters), documented by each filter; empty for most."""

    means: np.ndarray
    covs: np.ndarray
    diverged: np.ndarray
    diverged_step: np.ndarray
    extras: Mapping = _NO_EXTRAS

    @property
    def divergence_rate(self) -> float:
        return float(np.mean(self.diverged)) if self.diverged.size else 0.0

    def _extra(self, name):
        try:
            return self.extras[name]
        except KeyError:
            raise ValueError(f"estimates: no {name!r} here; run the filter with loglik=True "
                             "(filters whose likelihood attribute is None give none)") from None

    @property
    def loglik(self) -> np.ndarray:
        """The log-likelihood ``log p(y_0, ..., y_{T-1})`` of each path ``(...,)``: the sum of the
        per-step terms ``extras["loglik"] (..., T)`` (``run(..., loglik=True)``); NaN on the paths
        that diverged (``diverged``)."""
        return self._extra("loglik").sum(axis=-1)

    @property
    def innovations(self) -> np.ndarray:
        """The innovations ``y_k − E[y_k | y_0..y_{k-1}]`` ``(..., T, m)`` (NaN where missing)."""
        return self._extra("innovation")

    @property
    def innovation_covs(self) -> np.ndarray:
        """Their predicted covariances ``(..., T, m, m)`` (NaN where nothing was measured)."""
        return self._extra("innovation_cov")

    def take(self, idx) -> "Estimates":
        """The estimates of the paths ``idx`` (any index of the batch axes)."""
        return Estimates(self.means[idx], self.covs[idx], self.diverged[idx], self.diverged_step[idx],
                         MappingProxyType({k: v[idx] for k, v in self.extras.items()}))

    @staticmethod
    def concatenate(parts) -> "Estimates":
        """Estimates of several runs stacked along the (first) batch axis."""
        parts = list(parts)
        keys = parts[0].extras.keys()
        return Estimates(*(np.concatenate([getattr(p, f) for p in parts]) for f in Estimates._fields[:4]),
                         MappingProxyType({k: np.concatenate([p.extras[k] for p in parts]) for k in keys}))
