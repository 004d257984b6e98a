"""Where a model file's measurements sit in time, for the commands that make and read data
(``nlfilter simulate``, ``nlfilter fit``, ``nlfilter compare`` on a continuous-discrete model):
the simulation a file's kind calls for (:func:`simulate_spec`) and the data and filter options a
fit on a data file needs (:func:`fit_inputs`).

Kinds (``[model] kind``): ``discrete`` (steps ``k = 0, 1, ...``, the data's ``t`` the step), ``sde``
(increments ``dy`` over ``[k dt, (k+1) dt]``, ``t`` the interval's end) and ``continuous-discrete``
(an SDE measured at times ``t_1 < t_2 < ...`` after the prior at 0: ``y_k = h(x(t_k)) + v_k``,
:func:`~nlfilter.simulate.simulate_continuous_discrete`), the times regular (``[measurement] dt``)
or not (``[measurement] times``, the data's ``t`` column, ``simulate --times``)."""

from __future__ import annotations

import numpy as np

from .simulate import simulate, simulate_continuous_discrete


def _times_option(text: str) -> np.ndarray:
    try:
        times = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise ValueError(f"--times: got {text!r}; expected comma-separated numbers (the measurement times)") from None
    return times


def spec_times(spec, steps=None, text=None, option: bool = True):
    """The measurement times of a continuous-discrete ``spec``: ``--times`` (``text``), else the
    file's ``times``, else ``dt, 2 dt, ..., steps dt``; checked strictly increasing after 0."""
    from ._validate import measurement_times
    if text is not None:
        times = measurement_times("--times", _times_option(text))
    elif spec.times is not None:
        times = np.asarray(spec.times, dtype=float)
    else:
        if spec.dt is None:
            raise ValueError(_NO_TIMES.format(path=spec.path, how=" or --times T1,T2,..." if option else ""))
        n = spec.steps if steps is None else steps
        return spec.dt * np.arange(1, n + 1)
    if steps is not None and steps != len(times):
        raise ValueError(f"--steps: got {steps}; the measurement times are {len(times)} (give one or the other)")
    return times


_NO_TIMES = ("{path}: measurement: a continuous-discrete model with neither dt nor times; expected the "
             "measurement times: [measurement] dt or times in the file{how}, or data with a t column")


def simulate_spec(spec, steps, paths, seed, times_text=None):
    """``(Simulation, times (T,))`` of ``paths`` records of the model file ``spec`` (``steps``
    None: the file's ``[run] steps``), from the seed ``seed``."""
    if times_text is not None and spec.kind != "continuous-discrete":
        raise ValueError(f"--times: a {spec.kind} model is measured on its own grid; --times is for "
                         "continuous-discrete models")
    kw = {"paths": paths, "rng": seed, "m0": spec.m0, "P0": spec.P0}
    if spec.kind == "continuous-discrete":
        times = spec_times(spec, steps, times_text)
        sim = simulate_continuous_discrete(spec.model, len(times), times=times, **kw)  # its Euler–Maruyama default
        return sim, times
    n = spec.steps if steps is None else steps
    sim = simulate(spec.model, n, **kw, **({"dt": spec.dt} if spec.kind == "sde" else {}))
    return sim, np.asarray(sim.t, dtype=float)


def compare_timing(spec, steps):
    """``(steps, keywords of compare)`` for ``nlfilter compare`` on ``spec`` (``steps`` None:
    the file's): ``dt`` of an SDE, the measurement times of a continuous-discrete model."""
    if spec.kind != "continuous-discrete":
        return (spec.steps if steps is None else steps), {"dt": spec.dt}
    times = spec_times(spec, steps, option=False)
    return len(times), {"times": times}


def fit_inputs(spec, data, cls):
    """``(ys, keywords of fit)`` for fitting ``spec`` on ``data`` (:class:`~nlfilter.data_csv.Data`)
    with the filter class ``cls``: the measurement interval of an SDE, the measurement times of
    a continuous-discrete model (a filter built on them); a filter of another kind of data is
    refused naming it."""
    kind_of = {"discrete": ("discrete", "discrete"), "sde": ("sde", "continuous"),
               "continuous-discrete": ("sde", "discrete")}[spec.kind]
    if spec.kind == "continuous-discrete" and "sde" in getattr(cls, "accepts", ()) and cls.time == "discrete":
        ok = True
    else:
        ok = kind_of[0] in getattr(cls, "accepts", ()) and getattr(cls, "time", None) == kind_of[1]
    if not ok or getattr(cls, "likelihood", None) is None:
        raise ValueError(f"--filter: {getattr(cls, 'name', cls.__name__)} does not give a log-likelihood of a "
                         f"{spec.kind} model's measurements; expected a filter that does, e.g. "
                         + {"discrete": "ukf, ekf, ckf", "sde": "continuous-ekf",
                            "continuous-discrete": "continuous-discrete-ukf, continuous-discrete-ekf"}[spec.kind])
    if spec.kind == "discrete":
        return data.ys, {}
    if spec.kind == "sde":
        return data.ys, {"dt": spec.dt}
    if data.times is None and spec.dt is None:
        raise ValueError(_NO_TIMES.format(path=spec.path, how=""))
    times = data.times if data.times is not None else spec.dt * np.arange(1, data.ys.shape[1] + 1)
    return data.ys, {"filter": lambda md: cls(md, None).at_times(times)}


__all__ = ["simulate_spec", "spec_times", "compare_timing", "fit_inputs"]
