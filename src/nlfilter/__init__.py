"""nlfilter: the classic moment-based suboptimal nonlinear filters, with exact error analysis
and near-optimal references, in one library."""

from .models import DiscreteModel, SDEModel
from .noise import Gaussian, Independent, Sampler
from .results import Result, Row

__version__ = "0.1.0"

__all__ = ["DiscreteModel", "SDEModel", "Gaussian", "Independent", "Sampler", "Result", "Row"]
