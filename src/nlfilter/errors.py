"""Exceptions specific to nlfilter.

Input errors are plain ``ValueError``/``TypeError`` whose message names the argument; the
classes here describe failures *during* a computation (a covariance that lost positive
definiteness, a moment closure that blew up), and carry where it happened.
"""

from __future__ import annotations

import numpy as np


class NLFilterError(Exception):
    """Base class of nlfilter's run-time failures."""


class DivergenceError(NLFilterError, FloatingPointError):
    """A filter's mean or covariance became non-finite or lost positive definiteness.

    Attributes
    ----------
    step : int
        Time index (0-based) at which it happened.
    paths : tuple of int
        Flat indices of the affected Monte Carlo paths (batch axes raveled).
    what : str
        Which quantity failed (``"covariance"``, ``"mean"``, ``"loglik"``: a log-likelihood
        term that is not finite, ``"smoother"``: a backward pass ...).
    """

    def __init__(self, message: str, *, step: int | None = None, paths=(), what: str = ""):
        super().__init__(message)
        self.step = step
        self.paths = tuple(int(p) for p in paths)
        self.what = what


class ClosureDivergedError(NLFilterError, FloatingPointError):
    """A moment system (closure) blew up or produced a negative variance.

    Attributes
    ----------
    time : float
        Time at which it was detected.
    moment : tuple
        Multi-index of the offending moment.
    """

    def __init__(self, message: str, *, time: float | None = None, moment=None):
        super().__init__(message)
        self.time = time
        self.moment = moment


class CompileError(NLFilterError, TypeError):
    """numba could not compile the model's functions (``backend="numba"`` raises it;
    ``backend="auto"`` runs the NumPy loop instead)."""


class NotPolynomialError(NLFilterError, ValueError):
    """A model term is not polynomial in the state but an exact polynomial method was asked for."""


class SingularSystemError(NLFilterError, np.linalg.LinAlgError):
    """A steady-state or moment system has no unique solution."""


class NoStationaryLawError(SingularSystemError, ClosureDivergedError):
    """A steady state was asked of a system that has none: the moment equations have a mode that
    does not decay (an eigenvalue with non-negative real part, or of modulus ≥ 1 in discrete
    time), or the solution of the steady-state equations is not the moments of any law (a negative
    even moment, a covariance or moment matrix that is not positive semi-definite).

    It is a :class:`SingularSystemError` (so a ``ValueError``, through
    ``numpy.linalg.LinAlgError``) and a :class:`ClosureDivergedError` at ``time = inf`` (what
    :func:`~nlfilter.moments.solve.steady_state` raised for these cases before); ``moment`` names
    a monomial of the offending mode when known."""


class MomentsNotClosedError(NLFilterError, ValueError):
    """The monomials reachable from the requested ones by the Itô generator exceed the size cap:
    the moment hierarchy does not close (a drift of degree > 1 raises the degree)."""


class ReferenceWarning(UserWarning):
    """A comparison's reference filter is not converged (its refinement moved its MSE by more
    than the tolerance, its grid bounds cut the density off, or paths diverged): its rows are
    labelled ``"reference (not converged)"``; or it is contradicted (its NEES outside the band
    of the exact posterior, or a compared filter beats it by more than 2 s.e.): labelled
    ``"reference (contradicted: ...)"`` (:mod:`nlfilter.yardstick`, :mod:`nlfilter.certificate_checks`)."""
