"""The interacting multiple model (IMM) filter over any discrete Gaussian filters of nlfilter.

A jump-Markov system switches between ``M`` models (modes) by a Markov chain
``Π[i, j] = P(r_{k+1} = j | r_k = i)``; mode ``j`` is the model of one member filter (its own f,
G, Q, h, R over the same state and measurement dimensions, and its own rule: EKF, UKF, CKF, the
Kalman filter, ...). The IMM filter (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan 2001,
*Estimation with Applications to Tracking and Navigation*, §11.6.6) carries one Gaussian
``N(m_j, P_j)`` per mode and the mode probabilities ``μ_j``. One cycle (the steps of
Bar-Shalom, Li & Kirubarajan 2001, §11.6.6, in their notation):

1. mixing (interaction), from the filtered beliefs of step k::

       c̄_j = Σ_i Π_ij μ_i,     μ_{i|j} = Π_ij μ_i / c̄_j,
       m⁰_j = Σ_i μ_{i|j} m_i,   P⁰_j = Σ_i μ_{i|j} [P_i + (m_i − m⁰_j)(m_i − m⁰_j)ᵀ]

2. mode-matched prediction: member j's own ``predict`` from ``N(m⁰_j, P⁰_j)``; the predicted mode
   probabilities are ``c̄_j``;
3. mode-matched update: member j's own update on ``y_k``, with its likelihood
   ``Λ_j = N(y_k; ŷ_j, S_j)`` (its own predictive moments; missing components drop out as in the
   members: ``Λ_j`` is the density of the observed components, 1 when nothing is measured);
4. mode probabilities: ``μ_j = c̄_j Λ_j / c``, ``c = Σ_j c̄_j Λ_j``; the step's
   log-likelihood is ``log c`` (the predictive density of ``y_k`` is the mixture Σ_j c̄_j N(ŷ_j, S_j));
5. combination (output only)::

       m = Σ_j μ_j m_j,   P = Σ_j μ_j [P_j + (m_j − m)(m_j − m)ᵀ]

The members' steps are their own (``_predict_unchecked``, ``_update_info``: the rules are not
written again); the mixing and the combination are this module's only algebra. ``Estimates.means``
and ``covs`` are the combination, ``extras["mode_probs"] (..., T, M)`` the filtered ``μ``; with
``loglik=True`` ``extras["loglik"]`` is ``log c`` and ``innovation``/``innovation_cov`` are the
mean ``Σ c̄_j (y − ŷ_j)`` and covariance ``Σ c̄_j [S_j + (ŷ_j − ŷ)(ŷ_j − ŷ)ᵀ]`` of the predictive
mixture (NaN innovation in a missing component, whose ``ŷ_j`` the members do not report: the
spread term is 0 in its rows and columns). The probabilities are updated in log space
(``log c̄_j + log Λ_j``, the log-sum-exp), so a mode's likelihood that underflows a double does
not zero it; a path where every mode's likelihood is 0 or NaN (the measurement is impossible
under every mode) is a divergence (raised or marked, as the other filters:
:mod:`~nlfilter.filters.base`).

Smoothing (``smooth``): the backward pass of Kim (1994, "Dynamic linear models with
Markov-switching", J. Econometrics 60; Kim & Nelson 1999, *State-Space Models with Regime
Switching*, ch. 5) over the IMM's forward beliefs — the standard approximate smoother of a
jump-Markov Gaussian model (exact when the mode never switches, Π = I: Bayesian model averaging
of the members' RTS smoothers). From the last step, where it is the filter, back to step k,
with ``c̄_{k+1} = μ_k Π`` (the predicted mode probabilities)::

    P(r_k = i, r_{k+1} = j | all) = μ_k(i) Π_ij μˢ_{k+1}(j) / c̄_{k+1}(j),   μˢ_k(i) = Σ_j of it
    (m⁻_ij, P⁻_ij, D_ij) = member j's prediction from N(m_k^i, P_k^i) (its own rule, as its RTS smoother)
    G_ij = D_ij (P⁻_ij)⁻¹,   mˢ_ij = m_k^i + G_ij (mˢ_{k+1,j} − m⁻_ij),
    Pˢ_ij = P_k^i + G_ij (Pˢ_{k+1,j} − P⁻_ij) G_ijᵀ

and mode i's smoothed Gaussian is the moment match of ``N(mˢ_ij, Pˢ_ij)`` over j with the weights
``P(r_{k+1} = j | r_k = i, all)``; the output is the combination (5.) with ``μˢ_k``, and
``extras["mode_probs"]`` the smoothed ``μˢ``. With one mode it is the member's RTS smoother.

Step convention: the members' ``start`` is ignored; the IMM's own (``start``, as every discrete
filter). With ``start="update"`` the prior ``N(m0, P0)`` is every mode's at step 0 with the mode
probabilities ``mode_probs0``; with ``start="predict"`` (filterpy's ``IMMEstimator``: predict,
then update) the first cycle mixes from them.

>>> import numpy as np; from nlfilter import DiscreteModel
>>> from nlfilter.filters import KalmanFilter
>>> quiet = DiscreteModel.linear([[1.0]], [[1.0]], [[0.01]], [[1.0]])
>>> loud = DiscreteModel.linear([[1.0]], [[1.0]], [[4.0]], [[1.0]])
>>> imm = IMM([KalmanFilter(quiet), KalmanFilter(loud)], [[0.95, 0.05], [0.05, 0.95]])
>>> est = imm.run(np.array([[0.1], [0.0], [9.0], [18.0]]), m0=[0.0], P0=[[1.0]])
>>> est.extras["mode_probs"].shape, bool(est.extras["mode_probs"][-1, 1] > 0.9)   # the jumps: mode 1
((4, 2), True)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.special import logsumexp

from .. import _validate as V
from ..switching import markov_chain
from ..angles import angles_of, mixture, residual, wrap_components
from .base import DiscreteFilter, Filter, check_structure, gaussian_prior, set_start
from .beliefs import GaussianState
from .gaussian import GaussianFilter
from .kalman import KalmanFilter
from .linalg import symmetrize
from .smoothing import _solve_right

__all__ = ["IMM", "IMMState", "TwoModeIMM"]


class IMMState(NamedTuple):
    """The IMM's belief: per-mode means ``(B, M, n)``, covariances ``(B, M, n, n)`` and the mode
    probabilities ``(B, M)`` (predicted ``c̄`` after a prediction, filtered ``μ`` after an update)."""

    mean: np.ndarray
    cov: np.ndarray
    probs: np.ndarray


def _combine(w, m, P, angles=()):
    """``(Σ_i w_i m_i, Σ_i w_i [P_i + (m_i − m̄)(m_i − m̄)ᵀ])`` over the mode axis: ``w (B, M)``,
    ``m (B, M, n)``, ``P (B, M, n, n)`` (the moments of a Gaussian mixture; angular components
    ``angles``: :func:`~nlfilter.angles.mixture`)."""
    if angles:
        return mixture(w, m, P, angles)
    mean = np.einsum("bi,bin->bn", w, m)
    d = m - mean[:, None, :]
    cov = np.einsum("bi,bikl->bkl", w, P) + np.einsum("bi,bik,bil->bkl", w, d, d)
    return mean, cov


class IMM(DiscreteFilter):
    """The interacting multiple model filter over discrete Gaussian ``filters`` (module docstring).

    Parameters
    ----------
    filters : list of M discrete Gaussian filters (``KalmanFilter``, ``EKF``, ``UKF``, ``CKF``, a
        ``GaussianFilter`` over any rule, the second-order and continuous-discrete Gaussian
        filters), one per mode, over the same state and measurement dimensions (their models may
        differ: a constant-velocity and a coordinated-turn model; so may their rules)
    transition : ``(M, M)`` Markov matrix, ``transition[i, j] = P(mode j at k+1 | mode i at k)``
        (non-negative, rows summing to 1 to 1e-9)
    mode_probs0 : the mode probabilities of the prior (default uniform, ``1/M`` each)
    start : ``"update"`` or ``"predict"`` (see :mod:`nlfilter.filters.base`; None: the default)

    Notes
    -----
    ``smooth``: Kim's smoother over the IMM's forward pass (module docstring, "Smoothing"),
    smoothed mode probabilities in ``extras["mode_probs"]``. No compiled loop (``backend="auto"``
    runs the NumPy loop; ``backend="numba"`` is refused), no correlated process and measurement
    noise (the members' beliefs would carry the measurement).
    """

    name = "imm"
    family = "multiple-model"
    source = ("Blom & Bar-Shalom 1988, IEEE TAC 33(8); Bar-Shalom, Li & Kirubarajan 2001, Estimation with "
              "Applications to Tracking and Navigation, §11.6.6")
    accepts = ("discrete",)
    structures = ("state-dependent R", "time-varying R", "non-additive noise", "non-additive measurement noise",
                  "angles")
    likelihood = "mixture-prediction-error"
    compiled = False  # the mixing is not lowered: the compiled loop refuses the IMM (auto: NumPy)
    smoother = "imm-kim"
    smoother_keeps = True  # the backward pass reads every step's per-mode beliefs

    def __init__(self, filters, transition, mode_probs0=None, *, start: str | None = None):
        if isinstance(filters, Filter) or not isinstance(filters, (list, tuple)) or not filters:
            raise TypeError(f"filters: expected a non-empty list of discrete Gaussian filters (one per mode), "
                            f"got {V.shown(filters)}")
        for j, f in enumerate(filters):
            if not isinstance(f, (GaussianFilter, KalmanFilter)) or f.time != "discrete":
                raise TypeError(f"filters: expected discrete Gaussian filters (KalmanFilter, EKF, UKF, CKF, a "
                                f"GaussianFilter, ...), got {type(f).__name__} at position {j}")
            check_structure(self, f.model)
        first = filters[0]
        for j, f in enumerate(filters[1:], 1):
            dims = (f.state_dim, f.data_dim, f.model.kind, getattr(f, "dt", None))
            want = (first.state_dim, first.data_dim, first.model.kind, getattr(first, "dt", None))
            if angles_of(f.model) != angles_of(first.model):
                raise ValueError(f"filters: every mode must declare the same angles (nlfilter.angles); filter {j} "
                                 f"has {angles_of(f.model)}, filter 0 {angles_of(first.model)}")
            if dims != want:
                raise ValueError(f"filters: every mode must have the same state and measurement dimensions, model "
                                 f"kind and dt; filter {j} ({type(f).__name__}) has (n, m, kind, dt) = {dims}, "
                                 f"filter 0 ({type(first).__name__}) {want}")
        M = len(filters)
        Pi, mu0 = markov_chain(transition, mode_probs0, M, "filter")
        self.filters, self.transition, self.mode_probs0 = tuple(filters), Pi, mu0
        self.model = first.model  # the first mode's (state_dim, data_dim, the data's kind)
        self._angles = angles_of(first.model).states  # angular states: circular mixing (nlfilter.angles)
        set_start(self, start)

    @classmethod
    def from_params(cls, build, model, modes, transition, mode_probs0=None, *, start: str | None = None):
        """The IMM of one ``model`` whose modes are values of its parameters: mode j's filter is
        ``build(model.with_params(modes[j]))`` (the generated code shared, no SymPy per mode).

        Parameters
        ----------
        build : a callable ``model -> discrete Gaussian filter`` (a class: ``EKF``, ``UKF``, ``KalmanFilter``, ...)
        model : a model stated with ``params=`` (:meth:`~nlfilter.models.Model.with_params`)
        modes : a list of dicts of parameter values, one per mode (e.g. ``[{"q": 0.01}, {"q": 1.0}]``)
        transition, mode_probs0, start : as :class:`IMM`

        Examples
        --------
        >>> import numpy as np, sympy as sp; from nlfilter import DiscreteModel
        >>> from nlfilter.filters import KalmanFilter
        >>> x, q = sp.symbols("x q")
        >>> walk = DiscreteModel([x], [x], [x], Q=[[q]], R=1.0, params={q: 0.01})
        >>> imm = IMM.from_params(KalmanFilter, walk, [{"q": 0.01}, {"q": 4.0}], [[0.95, 0.05], [0.05, 0.95]])
        >>> [float(f.model.Q[0, 0]) for f in imm.filters]
        [0.01, 4.0]
        """
        if not callable(build):
            raise TypeError(f"build: expected a callable model -> filter (e.g. EKF), got {V.shown(build)}")
        if not isinstance(modes, (list, tuple)) or not modes or not all(isinstance(v, dict) for v in modes):
            raise TypeError(f"modes: expected a non-empty list of dicts of parameter values (one per mode), "
                            f"got {V.shown(modes)}")
        if not callable(getattr(model, "with_params", None)):
            raise TypeError(f"model: expected a model with parameters (params=), got {type(model).__name__}")
        return cls([build(model.with_params(v)) for v in modes], transition, mode_probs0, start=start)

    @property
    def modes(self) -> int:
        return len(self.filters)

    # -- the belief functions ------------------------------------------------------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None):
        if initial is not None:
            raise ValueError(f"initial: IMM starts from a Gaussian prior (m0, P0); expected None, "
                             f"got {type(initial).__name__}")
        g = gaussian_prior(m0, P0, self.state_dim, batch, who=type(self).__name__)
        B, M = g.mean.shape[0], self.modes
        return IMMState(np.repeat(g.mean[:, None], M, axis=1), np.repeat(g.cov[:, None], M, axis=1),
                        np.broadcast_to(self.mode_probs0, (B, M)).copy())

    def _mix(self, state):
        """Step 1: ``(c̄ (B, M), m⁰ (B, M, n), P⁰ (B, M, n, n))``. A mode no path can reach
        (``c̄_j = 0``) mixes with the current probabilities (its weight is 0 in every output)."""
        mu, Pi = state.probs, self.transition
        cbar = mu @ Pi
        w = Pi[None] * mu[:, :, None]  # (B, i, j): Π_ij μ_i
        pos = cbar > 0
        w = np.where(pos[:, None, :], w / np.where(pos, cbar, 1.0)[:, None, :], mu[:, :, None])  # μ_{i|j}
        if self._angles:  # circular mixing (nlfilter.angles)
            return (cbar, *mixture(w.swapaxes(1, 2), state.mean[:, None], state.cov[:, None], self._angles))
        m0 = np.einsum("bij,bin->bjn", w, state.mean)
        d = state.mean[:, :, None, :] - m0[:, None, :, :]  # (B, i, j, n): m_i − m⁰_j
        P0 = np.einsum("bij,bikl->bjkl", w, state.cov) + np.einsum("bij,bijk,bijl->bjkl", w, d, d)
        return cbar, m0, P0

    def _predict_unchecked(self, state, k):
        cbar, m0, P0 = self._mix(state)
        means, covs, bad = [], [], None
        for j, f in enumerate(self.filters):  # step 2: each member's own prediction
            new, b = f._predict_unchecked(GaussianState(m0[:, j], P0[:, j]), k)
            means.append(new.mean)
            covs.append(new.cov)
            bad = b if bad is None else (bad if b is None else bad | b)
        return IMMState(np.stack(means, axis=1), np.stack(covs, axis=1), cbar), bad

    def _update_info(self, state, y, k):
        """Steps 3-4: the members' updates and likelihoods, the mode probabilities, the step's
        ``log c`` and the predictive mixture's innovation moments."""
        y = np.asarray(y, dtype=float)
        means, covs, lls, es, Ss, bad = [], [], [], [], [], None
        for j, f in enumerate(self.filters):
            new, b, info = f._update_info(GaussianState(state.mean[:, j], state.cov[:, j]), y, k)
            means.append(new.mean)
            covs.append(new.cov)
            lls.append(info["loglik"])
            es.append(info["innovation"])
            Ss.append(info["innovation_cov"])
            bad = b if bad is None else (bad if b is None else bad | b)
        cbar = state.probs
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            a = np.log(cbar) + np.stack(lls, axis=1)  # log c̄_j + log Λ_j (log 0 = −inf: an unreachable mode)
            a = np.where(cbar > 0, a, -np.inf)
            logc = logsumexp(a, axis=-1)  # −inf where no mode is reachable; NaN propagates
            ok = np.isfinite(logc)
            mu = np.exp(a - np.where(ok, logc, 0.0)[:, None])
        if not ok.all():  # no mode explains y on these paths: a divergence (NaN, raised or marked by run)
            bad = ~ok if bad is None else bad | ~ok
            mu = np.where(ok[:, None], mu, np.nan)
        es = np.stack(es, axis=1)
        e = np.einsum("bi,bim->bm", cbar, es)  # NaN where the component is missing
        d = np.nan_to_num(es - e[:, None, :], nan=0.0)  # ŷ − ŷ_j; unknown (0) in a missing component's rows
        S = np.einsum("bi,bikl->bkl", cbar, np.stack(Ss, axis=1)) + np.einsum("bi,bik,bil->bkl", cbar, d, d)
        new = IMMState(np.stack(means, axis=1), np.stack(covs, axis=1), mu)
        return new, bad, {"loglik": logc, "innovation": e, "innovation_cov": S}

    def _update_unchecked(self, state, y, k):
        new, bad, _ = self._update_info(state, y, k)
        return new, bad

    def predict(self, state, k):
        new, bad = self._predict_unchecked(state, k)
        return _poison(new, bad)

    def update(self, state, y, k):
        new, bad = self._update_unchecked(state, y, k)
        return _poison(new, bad)

    def summary(self, state):
        """Step 5: the combination ``(Σ μ_j m_j, Σ μ_j [P_j + (m_j − m)(m_j − m)ᵀ])``."""
        return _combine(state.probs, state.mean, state.cov, self._angles)

    def extras(self, state):
        return {"mode_probs": state.probs}

    def _smooth(self, est, beliefs, ys, t0):
        """Kim's backward pass (module docstring, "Smoothing") over the forward beliefs of every step."""
        if not beliefs:  # no step: nothing to smooth
            return est.means, est.covs, {"mode_probs": np.empty((*est.means.shape[:2], self.modes))}
        mean = np.stack([b.mean for b in beliefs], axis=1)  # (B, T, M, n)
        cov = np.stack([b.cov for b in beliefs], axis=1)
        mu = np.stack([b.probs for b in beliefs], axis=1)  # (B, T, M)
        B, T, M, n = mean.shape
        off = 0 if self.start == "update" else 1
        xs, Xs, mus = mean[:, -1], cov[:, -1], mu[:, -1]
        out_m, out_P, out_mu = np.empty((B, T, n)), np.empty((B, T, n, n)), np.empty((B, T, M))
        ang = self._angles
        out_m[:, -1], out_P[:, -1] = _combine(mus, xs, Xs, ang)
        out_mu[:, -1] = mus
        for k in range(T - 2, -1, -1):
            m, P = mean[:, k], cov[:, k]
            cbar = mu[:, k] @ self.transition  # P(r_{k+1} = j | y_0..y_k)
            ratio = np.where(cbar > 0, mus / np.where(cbar > 0, cbar, 1.0), 0.0)
            joint = mu[:, k, :, None] * self.transition[None] * ratio[:, None, :]  # P(r_k = i, r_{k+1} = j | all)
            mus_k = joint.sum(axis=-1)
            w = np.where(mus_k[..., None] > 0, joint / np.where(mus_k > 0, mus_k, 1.0)[..., None],
                         self.transition[None])  # P(r_{k+1} = j | r_k = i, all)
            x_ij, P_ij = np.empty((B, M, M, n)), np.empty((B, M, M, n, n))
            for i in range(M):
                for j, f in enumerate(self.filters):  # mode i's filtered belief through model j
                    pred, D = f._predict_cross(GaussianState(m[:, i], P[:, i]), k + off)
                    G = _solve_right(pred.cov, D)
                    x_ij[:, i, j] = wrap_components(m[:, i] + np.einsum("...ij,...j->...i", G, residual(
                        xs[:, j], pred.mean, ang)), ang)
                    P_ij[:, i, j] = symmetrize(P[:, i] + G @ (Xs[:, j] - pred.cov) @ np.swapaxes(G, -1, -2))
            if ang:  # circular (nlfilter.angles)
                xs, Xs = mixture(w, x_ij, P_ij, ang)
            else:
                xs = np.einsum("bij,bijn->bin", w, x_ij)
                d = x_ij - xs[:, :, None, :]
                Xs = np.einsum("bij,bijkl->bikl", w, P_ij) + np.einsum("bij,bijk,bijl->bikl", w, d, d)
            mus = mus_k
            out_m[:, k], out_P[:, k] = _combine(mus, xs, Xs, ang)
            out_mu[:, k] = mus
        return out_m, out_P, {"mode_probs": out_mu}


def _poison(state, bad):
    """NaN on the paths ``bad`` (the run loop's check flags them)."""
    if bad is None or not np.any(bad):
        return state
    return IMMState(*(np.where(bad.reshape(-1, *(1,) * (a.ndim - 1)), np.nan, a) for a in state))


class TwoModeIMM(IMM):
    """The registry's IMM (``"imm"``): two EKFs of one ``model`` — mode 0 the model itself, mode 1
    a manoeuvre mode, the same model with fading memory ``alpha`` (its prediction from
    ``N(m, α² P)``: more process uncertainty, ``nlfilter.filters.fading``) — switching with
    probability ``1 − stay`` per step, mode probabilities 1/2 each at the start. What ``compare``
    and the contract build from one model (``cls(model, start=...)``); an IMM of other modes is
    :class:`IMM` over filters of their own models.

    Parameters
    ----------
    model : DiscreteModel
    alpha : the manoeuvre mode's fading-memory factor (> 1; default 1.5)
    stay : the probability of staying in a mode (in (0, 1]; default 0.95)
    start : ``"update"`` or ``"predict"``
    """

    name = "imm"

    def __init__(self, model, *, alpha: float = 1.5, stay: float = 0.95, start: str | None = None):
        from .ekf import EKF
        DiscreteFilter.__init__(self, model, start=start)  # the model's kind and structures checked, named
        if isinstance(stay, (bool, np.bool_)) or not isinstance(stay, (int, float, np.floating)):
            raise TypeError(f"stay: expected a probability in (0, 1], got {V.shown(stay)}")
        if not (math.isfinite(stay) and 0.0 < stay <= 1.0):
            raise ValueError(f"stay: expected a probability in (0, 1] (of staying in a mode), got {V.shown(stay)}")
        if isinstance(alpha, (int, float, np.floating)) and not isinstance(alpha, bool) and alpha == 1.0:
            raise ValueError("alpha: expected a fading-memory factor > 1 (alpha = 1 makes the two modes one)")
        base = EKF(model)
        Pi = [[stay, 1.0 - stay], [1.0 - stay, stay]]
        super().__init__([base, base.fading_memory(alpha)], Pi, start=start)

    structures = ("state-dependent R", "time-varying R", "angles")  # the EKF's, but correlated noise (the IMM's beliefs)
