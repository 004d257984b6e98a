"""The optimal filter of a jump-Markov model (:class:`~nlfilter.switching.SwitchingModel`): a
bootstrap particle filter over the pair (mode, state), batched over paths — the reference that
``compare`` certifies on switching models, against which the IMM's gap is measured.

Each particle carries a mode ``r`` and a state ``x`` (Doucet, Gordon & Krishnamurthy 2001,
"Particle filters for state estimation of jump Markov linear systems", IEEE TSP 49(3), §III, in
its bootstrap form). One cycle, per particle ``i``:

1. resample (systematic) when the effective sample size is below ``threshold · particles``;
2. mode transition: ``r_k^i ~ Π[r_{k−1}^i, ·]`` (inversion of one uniform);
3. state transition by that mode's dynamics: ``x_k^i = f_{r_k^i}(x_{k−1}^i, k−1) + G w``,
   ``w`` from mode ``r_k^i``'s process noise;
4. weight by that mode's likelihood: ``w_k^i ∝ w_{k−1}^i p_{r_k^i}(y_k | x_k^i)``.

At step 0 (``start="update"``) the modes are drawn from ``μ0`` with the states from ``N(m0, P0)``.
The joint posterior of ``(r_k, x_k)`` is approximated consistently as ``particles → ∞``, so the
state's conditional mean is the MMSE estimate: ``Estimates.means``/``covs`` are the particles'
weighted moments and ``extras["mode_probs"] (..., T, M)`` the weighted share of each mode
(``P(r_k = j | y_0..y_k)``), ``extras["ess"]`` the effective sample size, as the
:class:`~nlfilter.filters.reference.ParticleFilter`. The pieces (resampling, the measurement
likelihood, the moments) are that filter's; the mode is kept as one more column of the particle
array (so resampling carries it). Every path draws from its own stream (:mod:`nlfilter.streams`).
"""

from __future__ import annotations

import numpy as np

from ...angles import angles_of, wrap_components
from ...streams import FILTER, PathRNG
from ...switching import SwitchingModel
from ..base import check_structure
from ._reference_base import _check_time_step
from .particle import ParticleBelief, ParticleFilter, _draw, _weights

__all__ = ["JumpParticleFilter"]


def _modes_from(u, cum):
    """Modes by inversion of uniforms ``u (...)`` through cumulative probabilities ``cum (..., M)``."""
    return np.minimum((u[..., None] >= cum).sum(-1), cum.shape[-1] - 1)


class JumpParticleFilter(ParticleFilter):
    """Particle filter over (mode, state) of a :class:`~nlfilter.switching.SwitchingModel`
    (module docstring): the optimal (as ``particles → ∞``) filter of a jump-Markov system.

    Parameters
    ----------
    model : SwitchingModel
    particles : particles per path
    threshold : resample when ESS < threshold · particles
    start : step convention (:mod:`nlfilter.filters.base`)

    Notes
    -----
    No smoother and no likelihood output (``run(..., loglik=True)`` is refused); not in the
    registry (it filters switching models only; ``compare`` builds it as the reference of one).
    """

    name = "jump-particle"
    source = ("bootstrap particle filter over (mode, state) of a jump-Markov system (Doucet, Gordon & "
              "Krishnamurthy 2001, IEEE TSP 49(3))")
    accepts = ("switching",)
    structures = ("time-varying R", "non-additive noise", "angles")
    smoother = None
    likelihood = None

    def __init__(self, model, particles: int = 2000, *, threshold: float = 0.5, start: str | None = None):
        if not isinstance(model, SwitchingModel):
            raise TypeError(f"model: expected a SwitchingModel (nlfilter.switching), got {type(model).__name__}")
        super().__init__(model.models[0], particles, threshold=threshold, start=start)
        for md in model.models[1:]:
            check_structure(self, md)
            _check_time_step(self, md, None, "jump-Markov particle filter")
        self.switching = model
        self._cum0 = np.cumsum(model.mode_probs0)
        self._cum = np.cumsum(model.transition, axis=1)

    def _set_smoother(self):
        self.smoother = None

    # -- the belief: particles (B, Np, n + 1), the mode in the last column ----------------------------
    def init(self, m0, P0, batch, *, initial=None, rng=None) -> ParticleBelief:
        """As :meth:`ParticleFilter.init`, then each particle's mode from ``μ0`` (one uniform per
        particle, from the path's stream, after its states)."""
        B = int(np.prod(batch))
        rng = PathRNG.of(rng, B, key=FILTER)
        b = super().init(m0, P0, batch, initial=initial, rng=rng)
        r = _modes_from(rng.random((self.particles,)), self._cum0)
        return b._replace(x=np.concatenate([b.x, r[..., None].astype(float)], axis=-1))

    def predict(self, belief: ParticleBelief, k) -> ParticleBelief:
        """Resample, then every particle's mode by ``Π`` and its state by that mode's dynamics
        (the uniforms of the modes first, then each mode's process noise for every particle)."""
        self._need("discrete", "predict")
        x, logw = self._resample(belief)
        rng = belief.rng
        r = _modes_from(rng.random((self.particles,)), self._cum[x[..., -1].astype(np.intp)])
        xs = x[..., :-1]
        new = np.empty_like(x)
        new[..., -1] = r
        for j, md in enumerate(self.switching.models):
            w = _draw(md.process_noise, rng, (self.particles,))
            sel = r == j
            if sel.any():
                new[..., :-1] = np.where(sel[..., None], _transition(md, xs, w, k), new[..., :-1])
        return ParticleBelief(new, logw, rng)

    def _loglik(self, x, y, k, hbar=None, md=None):
        """Each particle's log-likelihood under its own mode's measurement model."""
        r, xs = x[..., -1].astype(np.intp), x[..., :-1]
        ll = np.zeros(r.shape)
        for j, mdj in enumerate(self.switching.models):
            sel = r == j
            if sel.any():
                ll = np.where(sel, super()._loglik(xs, y, k, md=mdj), ll)
        return ll

    def summary(self, belief: ParticleBelief):
        """The weighted moments of the states (the mode column left out)."""
        return super().summary(belief._replace(x=belief.x[..., :-1], w=_weights(belief)))

    def extras(self, belief: ParticleBelief):
        """``ess (B,)`` and ``mode_probs (B, M)``: the weighted share of each mode."""
        w = _weights(belief)
        r = belief.x[..., -1].astype(np.intp)
        probs = np.stack([np.sum(np.where(r == j, w, 0.0), axis=1) for j in range(self.switching.modes)], axis=1)
        return {"ess": 1.0 / np.sum(w * w, axis=1), "mode_probs": probs}

    def _update_info(self, belief, y, k):
        raise TypeError("loglik: the jump-Markov particle filter gives no likelihood; expected loglik=False")


def _transition(md, x, w, k):
    """``f(x, k) + G(x, k) w`` of the mode ``md`` (angular states wrapped)."""
    return wrap_components(md.transition(x, w, k), angles_of(md).states)

