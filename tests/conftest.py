import numpy as np
import pytest
import sympy as sp

from nlfilter.models import DiscreteModel


@pytest.fixture
def nonlinear3():
    """A random-ish nonlinear 3-state model with state-dependent G, used across tests."""
    x1, x2, x3 = sp.symbols("x1 x2 x3")
    f = [x1 + 0.1 * x2, 0.95 * x2 - 0.1 * sp.sin(x1) + 0.02 * x3**2, 0.9 * x3 + 0.05 * x1 * x2]
    h = [x1**2 / 4 + x3, sp.atan(x2) + 0.3 * x1]
    G = [[1, 0], [0.1 * x1, 1], [0, 0.5 + 0.1 * x3**2]]
    return DiscreteModel([x1, x2, x3], f, h, G, Q=np.diag([0.02, 0.05]), R=np.diag([0.1, 0.2]))
