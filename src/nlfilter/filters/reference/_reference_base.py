"""What the reference filters share: the registry attributes, the time kind of the model, the
measurement-step check."""

from __future__ import annotations

import numpy as np

from ... import _validate as V
from ..base import Filter, check_structure, continuous_precision, set_start


def _check_time_step(flt, model, dt, who):
    """SDE models need the measurement step ``dt`` (and use R⁻¹); discrete ones take none and
    need a measurement law with a density. Sets ``flt.time`` (``"continuous"`` for an SDEModel:
    the run loop then calls ``step`` on increments), ``flt.dt`` and ``flt._Rinv``."""
    if model.kind == "sde":
        if dt is None:
            raise ValueError("dt: expected the measurement step for an SDEModel, got None")
        flt.dt = float(V.positive("dt", dt))
        flt._Rinv = continuous_precision(model)
        flt.time = "continuous"
        meas = getattr(getattr(model, "angles", None), "measurements", ())
        if meas:  # dy = h dt + dη: an increment of a wrapped angle is not a wrapped angle
            raise ValueError(f"angles: the {who} reads an SDEModel's measurements as increments dy = h dt + dη, which "
                             f"are not angles; got measurements {list(meas)} declared angular (declare them on "
                             "discrete measurements: the continuous-discrete particle filter)")
    elif dt is not None:
        raise ValueError(f"dt: a DiscreteModel has no time step; expected None, got {dt!r}")
    elif getattr(model, "R_constant", True) and not model.measurement_noise.has_density:
        raise ValueError(f"measurement_noise: the {who} needs a law with a density (logpdf); got "
                         f"{model.measurement_noise!r} (a Gaussian has none when its covariance R is singular)")
    else:
        flt.time = "discrete"


class _ReferenceFilter(Filter):
    """Base of the reference filters: discrete models (``predict``/``update``) and SDE models
    (``step``), the kind decided by the model (``time`` is an instance attribute)."""

    family = "reference"
    accepts = ("discrete", "sde")
    time = "by model"  # each instance: "discrete" on a DiscreteModel, "continuous" on an SDEModel
    screen_predict = False  # a density or particle cloud pushed forward: a failure shows after the update

    def _setup(self, model, dt, start, who):
        check_structure(self, model)
        self.model = model
        set_start(self, start)
        _check_time_step(self, model, dt, who)

    def _need(self, time, call):
        if self.time != time:
            other = "step(belief, dy, t)" if self.time == "continuous" else "predict/update"
            raise TypeError(f"{call}: {type(self).__name__} on a{' DiscreteModel' if self.time == 'discrete' else 'n SDEModel'} "
                            f"uses {other}")

    def _raise_dead(self, bad, where):
        if bad is not None:
            from ...errors import DivergenceError
            idx = np.flatnonzero(bad)
            raise DivergenceError(f"{self.name}: the measurement has zero likelihood everywhere at {where} on "
                                  f"{idx.size} path(s), first {idx[:5].tolist()}", paths=idx, what="likelihood")
