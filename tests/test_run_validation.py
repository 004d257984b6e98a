"""Issue 15: bad input at the run / simulate / evaluate boundary is refused up front, naming the
argument, with what was given and what was expected; nothing hangs or returns NaN silently."""

from __future__ import annotations

import time

import numpy as np
import pytest
import sympy as sp

from nlfilter import SDEModel
from nlfilter.errors import ClosureDivergedError
from nlfilter.filters import MQLF, QLF
from nlfilter.filters import quasilinear

x = sp.Symbol("x")
CUBIC = SDEModel([x], [-x**3], [x], Q=0.05, R=0.05)
DYS = np.zeros((2, 5, 1))


def refused(call, err, pattern):
    with pytest.raises(err, match=pattern):
        call()


# -- the QLF's off-line solve: bounded ------------------------------------------------------------
@pytest.mark.parametrize("F", [QLF, MQLF])
@pytest.mark.parametrize("P0", [1e150, 1e300])
def test_huge_prior_of_the_qlf_is_refused_not_a_hang(F, P0):
    t = time.monotonic()
    refused(lambda: F(CUBIC, 0.01).run(DYS, m0=[0.0], P0=[[P0]]), ValueError,
            r"^P0: the off-line moment/Riccati equations of this prior cannot be integrated.*below 1e\+150")
    assert time.monotonic() - t < 5


def test_stalled_off_line_solve_is_a_named_error(monkeypatch):
    monkeypatch.setattr(quasilinear, "OFFLINE_SECONDS", 0.0)
    refused(lambda: QLF(CUBIC, 0.01).run(DYS, m0=[0.0], P0=[[1.0]]), ClosureDivergedError,
            r"^qlf: the off-line moment/Riccati equations did not reach t = 0.05 within 0 s .*prior m0/P0")


@pytest.mark.parametrize("t0", [np.nan, np.inf])
def test_non_finite_t0_of_the_qlf_is_refused(t0):
    for call in (lambda: QLF(CUBIC, 0.01).run(DYS, m0=[0.0], P0=[[1.0]], t0=t0),
                 lambda: QLF(CUBIC, 0.01).offline([0.0], [[1.0]], 5, t0=t0)):
        refused(call, ValueError, r"^t0: expected a finite real number, got")


def test_numerically_singular_prior_of_the_qlf_names_P0():
    refused(lambda: QLF(CUBIC, 0.01).run(DYS, m0=[0.5], P0=[[1e-300]]), ValueError,
            r"^P0: the statistical linearization .* positive definite .*got smallest eigenvalue 1e-300")
