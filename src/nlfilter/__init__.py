"""nlfilter: the classic moment-based suboptimal nonlinear filters, with exact error analysis
and near-optimal references, in one library.

Models (:mod:`~nlfilter.models`, :mod:`~nlfilter.bilinear`), simulation
(:mod:`~nlfilter.simulate`), filters (:mod:`nlfilter.filters`), the moment engine
(:mod:`nlfilter.moments`), evaluation (:mod:`~nlfilter.evaluate`) and the papers' experiments
(:mod:`nlfilter.experiments`, the ``nlfilter`` command).
"""

from . import filters, moments, problems
from .bilinear import BilinearModel
from .comparison import compare
from .evaluate import mse, mse_per_step, nees, paired_difference
from .fitting import fit, fit_em
from .modelfile import load_model
from .models import DiscreteModel, SDEModel
from .noise import Gaussian, Independent, Sampler
from .results import Result, Row
from .simulate import Simulation, simulate

__version__ = "0.1.0"

__all__ = ["DiscreteModel", "SDEModel", "BilinearModel", "Gaussian", "Independent", "Sampler",
           "simulate", "Simulation", "compare", "load_model", "fit", "fit_em", "mse", "mse_per_step", "nees", "paired_difference", "Result", "Row",
           "filters", "moments", "problems"]
