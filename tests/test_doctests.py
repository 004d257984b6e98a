"""Run the docstring examples of every nlfilter module (DESIGN.md rule 7)."""

import doctest
import importlib
import pkgutil

import pytest

import nlfilter

MODULES = sorted(m.name for m in pkgutil.walk_packages(nlfilter.__path__, "nlfilter."))


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    mod = importlib.import_module(name)
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
