"""``compare`` on a jump-Markov model (:class:`~nlfilter.switching.SwitchingModel`): which
filters run, which reference judges them, and the mode rows.

The data are :func:`~nlfilter.simulate_switching.simulate_switching`'s (modes drawn from the
chain, per-path streams); the reference is the certified
:class:`~nlfilter.filters.reference.JumpParticleFilter` (particles over (mode, state): the
yardstick's particle ladder, :func:`~nlfilter.yardstick.certified_reference`, from its first
rung); ``filters="all"`` is the IMM over EKFs and over UKFs of the modes (``"imm-ekf"``,
``"imm-ukf"``) and the EKF and UKF of each single mode (``"ekf (mode j)"``, ``"ukf (mode j)"``:
what a filter that ignores the switching does). Every filter reporting mode probabilities
(``extras["mode_probs"]``: the IMMs and the reference) also gets a ``mode_error`` row: the share
of the window's steps whose most probable mode is not the true one, ± its s.e. over paths.
"""

from __future__ import annotations

import numpy as np

from . import _validate as V
from .evaluate import _window
from .filters import EKF, IMM, REGISTRY, UKF
from .switching import SwitchingModel

__all__ = ["switching_setup", "switching_filters", "mode_rows"]

IMM_MEMBERS = {"imm-ekf": EKF, "imm-ukf": UKF}


def switching_setup(model, reference, smooth, times, dt):
    """``(first mode's model, reference)`` of a comparison on the switching ``model``: the checks
    (discrete data, no smoother, no grid) and ``"auto"`` as ``"particle"`` (the jump-Markov
    particle ladder)."""
    if not isinstance(model, SwitchingModel):
        raise TypeError(f"model: expected a SwitchingModel, got {type(model).__name__}")
    if times is not None or dt is not None:
        raise ValueError("times/dt: a SwitchingModel is a discrete model; expected times=None and dt=None")
    if smooth:
        raise ValueError("smooth: compare has no smoother of a switching model's reference; expected smooth=False")
    if reference == "grid":
        raise ValueError("reference: a switching model's reference is particles over (mode, state); expected "
                         "'auto', 'particle', None or a filter instance, got 'grid'")
    return model.models[0], ("particle" if reference == "auto" else reference)


def switching_filters(model, filters, start):
    """``(dict name -> filter, skipped)`` for a comparison on the switching ``model``: a dict is
    taken as given; ``"all"`` (module docstring); a list of names: ``"imm-ekf"``/``"imm-ukf"``,
    or registry names (each built for every mode: ``"name (mode j)"``)."""
    if isinstance(filters, dict):
        return dict(filters), {}
    if isinstance(filters, str) and filters == "all":
        names = [*IMM_MEMBERS, "ekf", "ukf"]
    elif isinstance(filters, (list, tuple)) and filters and all(isinstance(f, str) for f in filters):
        names = list(filters)
    else:
        raise TypeError(f"filters: expected 'all', a list of names or a non-empty dict of name -> filter instance, "
                        f"got {V.shown(filters)}")
    out = {}
    for name in names:
        if name in IMM_MEMBERS:
            build = IMM_MEMBERS[name]
            out[name] = IMM([build(md, start=start) for md in model.models], model.transition, model.mode_probs0,
                            start=start)
        elif name in REGISTRY and getattr(REGISTRY[name], "family", "") != "reference":
            for j, md in enumerate(model.models):
                out[f"{name} (mode {j})"] = REGISTRY[name].for_model(md, start=start)
        else:
            raise ValueError(f"filters: expected 'imm-ekf', 'imm-ukf' or a registry name outside the reference family, "
                             f"got {V.shown(name)}")
    return out, {}


def mode_rows(res, est, modes, window):
    """A ``mode_error`` row (window average over steps, mean ± s.e. over the paths that did not
    diverge) for every estimate with ``extras["mode_probs"]``."""
    sl = _window(modes.shape[1], window)
    for name, e in est.items():
        probs = getattr(e, "extras", {}).get("mode_probs")
        if probs is None:
            continue
        ok = ~np.asarray(e.diverged, bool)
        wrong = (np.argmax(np.nan_to_num(probs, nan=-1.0), axis=-1) != modes)[:, sl].mean(axis=1)[ok]
        if wrong.size > 1:
            res.add(name, "mode_error", float(wrong.mean()), float(wrong.std(ddof=1) / np.sqrt(wrong.size)))
