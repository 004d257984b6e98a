"""Run the docstring examples of every nlfilter module (docstrings carry small examples that run)."""

import doctest
import importlib
import pkgutil

import pytest

import nlfilter

MUST_HAVE_EXAMPLES = {"nlfilter.models", "nlfilter.simulate", "nlfilter.evaluate", "nlfilter.polynomials",
                      "nlfilter.moments.ito", "nlfilter.moments.closures", "nlfilter.moments.solve",
                      "nlfilter.moments.quadrature", "nlfilter.filters.ekf", "nlfilter.filters.rules",
                      "nlfilter.filters.gaussian", "nlfilter.filters.cubature", "nlfilter.filters.ukf"}
MODULES = sorted(m.name for m in pkgutil.walk_packages(nlfilter.__path__, "nlfilter."))


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    mod = importlib.import_module(name)
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
    if name in MUST_HAVE_EXAMPLES:
        assert result.attempted > 0, f"{name}: its docstrings lost their examples"
