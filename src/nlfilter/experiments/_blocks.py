"""What the experiments' Monte Carlo blocks share (:func:`nlfilter.montecarlo.montecarlo`): the
``block`` parameter (paths per block, declared in the registry, :data:`nlfilter.experiments.EXPERIMENTS`;
0, the default, puts all of a run's paths in one block, so a default run is one batch) and the per-path arrays a block returns — the seed-000 filters' means and
extras (:func:`block_arrays`), or whole :class:`~nlfilter.filters.estimates.Estimates`
(:func:`estimates_arrays`) — read back from the concatenated blocks."""

from __future__ import annotations

import numpy as np

from ..filters.base import Estimates
from ..filters.moment_bayes import refresh_failure_rate


def block_size(res, params, paths):
    """The paths per Monte Carlo block that run (recorded in ``res.params``): ``params["block"]``,
    0 for all ``paths`` in one block."""
    return res.used("block", int(params["block"])) or paths


def block_arrays(name, run, *extras) -> dict:
    """A Monte Carlo block's per-path arrays of the seed-000 filter ``name``'s ``run``: its
    estimates ``est:{name}``, the ``extras`` named (``{extra}:{name}``, per step) and for an
    adaptive filter its refresh failure rate ``refresh:{name}``
    (:func:`~nlfilter.filters.moment_bayes.refresh_failure_rate`)."""
    out = {f"est:{name}": run.means, **{f"{x}:{name}": run.extras[x] for x in extras}}
    if "refreshed" in run.extras:
        out[f"refresh:{name}"] = refresh_failure_rate(run)
    return out


def block_estimates(mc) -> dict:
    """``{name: estimates}`` from the concatenated blocks' ``est:{name}`` arrays, in block order."""
    return {k.partition(":")[2]: v for k, v in mc.items() if k.startswith("est:")}


def estimates_arrays(xs, ests) -> dict:
    """A block's per-path arrays: the true states ``xs`` and every filter's Estimates (the extras
    the report reads — the particle reference's move counts — included)."""
    out = {"xs": xs}
    for name, e in ests.items():
        out.update({f"{name}:{f}": np.asarray(getattr(e, f)) for f in Estimates._fields[:4]})
        out.update({f"{name}:extra:{x}": np.asarray(v) for x, v in e.extras.items() if x in ("accepted", "proposed")})
    return out


def estimates_of(arrays) -> tuple:
    """``(xs, {filter: Estimates})`` from the concatenated blocks of :func:`estimates_arrays`."""
    ests = {}
    for key in arrays:
        name, _, field = key.partition(":")
        if field == "means":
            ests[name] = Estimates(*(arrays[f"{name}:{f}"] for f in Estimates._fields[:4]),
                                   {x.rpartition(":")[2]: v for x, v in arrays.items()
                                    if x.startswith(f"{name}:extra:")})
    return arrays["xs"], ests
