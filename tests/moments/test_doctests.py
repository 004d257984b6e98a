import doctest

import pytest

import nlfilter.moments.closures
import nlfilter.moments.ito
import nlfilter.moments.quadrature
import nlfilter.moments.solve
import nlfilter.polynomials

MODULES = [nlfilter.polynomials, nlfilter.moments.ito, nlfilter.moments.closures, nlfilter.moments.solve,
           nlfilter.moments.quadrature]


@pytest.mark.parametrize("mod", MODULES, ids=lambda m: m.__name__)
def test_doctests(mod):
    res = doctest.testmod(mod)
    assert res.attempted > 0 and res.failed == 0
