"""nlfilter: the classic moment-based suboptimal nonlinear filters, with exact error analysis
and near-optimal references, in one library.

Models (:mod:`~nlfilter.models`, :mod:`~nlfilter.bilinear`), simulation
(:mod:`~nlfilter.simulate`), filters (:mod:`nlfilter.filters`), the moment engine
(:mod:`nlfilter.moments`), evaluation (:mod:`~nlfilter.evaluate`) and the papers' experiments
(:mod:`nlfilter.experiments`, the ``nlfilter`` command).

The names below are imported on first use (PEP 562): ``import nlfilter`` itself loads nothing
heavy, so the ``nlfilter`` command installs its Ctrl-C handling before NumPy, SymPy and the
filters load (:mod:`nlfilter.cli`).
"""

import importlib
import os
import signal
import sys
import types


def _interrupted_early(signum, frame):  # pragma: no cover - exercised by the fuzz suite's processes
    os.write(2, b"nlfilter: interrupted\n")
    os._exit(130)


# Started as the `nlfilter` program (`python -m nlfilter.cli`: argv[0] is "-m" while the package
# loads; the console script: argv[0] ends in "nlfilter"), Ctrl-C exits quietly from this line on,
# until nlfilter.cli.main installs its own handler; a library import changes no signal handling.
_argv0 = (getattr(sys, "argv", None) or [""])[0]
if (_argv0 == "-m" or os.path.basename(_argv0) == "nlfilter") and \
        signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    try:
        signal.signal(signal.SIGINT, _interrupted_early)
    except ValueError:  # not the main thread: no handler can be set there
        pass

__version__ = "0.1.0"

_WHERE = {"BilinearModel": "bilinear", "compare": "comparison", "mse": "evaluate", "mse_per_step": "evaluate",
          "nees": "evaluate", "paired_difference": "evaluate", "fit": "fitting", "fit_em": "fitting",
          "load_model": "modelfile", "DiscreteModel": "models", "SDEModel": "models", "Gaussian": "noise",
          "Independent": "noise", "Sampler": "noise", "Result": "results", "Row": "results",
          "Simulation": "simulate", "simulate": "simulate", "sample_posterior": "filters.sampling",
          "fixed_lag": "filters.fixed_lag", "SwitchingModel": "switching"}
_SUBMODULES = ("filters", "moments", "problems")

__all__ = ["DiscreteModel", "SDEModel", "BilinearModel", "SwitchingModel", "Gaussian", "Independent", "Sampler",
           "simulate", "Simulation", "compare", "load_model", "fit", "fit_em", "sample_posterior", "fixed_lag", "mse", "mse_per_step", "nees", "paired_difference", "Result", "Row",
           "filters", "moments", "problems"]


def __getattr__(name):
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """The package, whose ``simulate`` stays the function once the submodule ``nlfilter.simulate``
    is imported (the import system binds the submodule to the package's attribute of its name)."""

    def __setattr__(self, name, value):
        if isinstance(value, types.ModuleType) and _WHERE.get(name) == name:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
