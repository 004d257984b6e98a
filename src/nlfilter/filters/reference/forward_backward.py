"""The optimal smoothers of the reference filters: the backward passes of the grid filter
(forward–backward) and of the particle filter (forward-filtering backward-smoothing), pure
functions over the filtered beliefs of every step that ``Filter.smooth`` keeps.

Both compute the marginal smoothing laws ``p(x_k | y_0..y_{T-1})`` from the filtered laws
``p(x_k | y_0..y_k)`` and the transition density ``τ(x_{k+1} | x_k)`` by the backward recursion
(Kitagawa 1987; Särkkä 2013, *Bayesian Filtering and Smoothing*, Thm. 8.1)::

    p(x_k | y_{0:T-1}) = p(x_k | y_{0:k}) ∫ τ(x_{k+1} | x_k) p(x_{k+1} | y_{0:T-1}) / p(x_{k+1} | y_{0:k}) dx_{k+1}

with ``p(x_{k+1} | y_{0:k}) = ∫ τ(x_{k+1} | x) p(x | y_{0:k}) dx`` the prediction, starting from
the filtered law at the last step.

Grid (:func:`grid_smoother`): on the grid, with the filter's own transition kernel ``K_k``
(``p⁻_{k+1} ∝ p_k K_k``: the discretized transition density of a discrete model, or
``expm(L dt)`` of Kushner's chain for an SDE)::

    pˢ_k ∝ p_k ⊙ (K_k (pˢ_{k+1} ⊘ p⁻_{k+1}))        (0/0 = 0 where p⁻_{k+1} = 0)

exact for the grid's Markov chain, so it converges to the optimal smoother as the grid is refined,
at the filter's rate. Memory: the forward pass keeps every step's density, ``B × T × N`` floats
(B paths, T steps, N grid points); ``smooth(..., chunk=)`` bounds B.

Particles (:func:`ffbsm`): the forward-filtering backward-smoothing of the marginals (Doucet,
Godsill & Andrieu 2000, *Statistics and Computing* 10, eq. 22; Hürzeler & Künsch 1998)
reweights the filtered clouds ``{x_k,i, w_k,i}`` backwards::

    wˢ_k,i ∝ w_k,i Σ_j wˢ_{k+1,j} τ(x_{k+1,j} | x_k,i) / Σ_l w_k,l τ(x_{k+1,j} | x_k,l)

(``wˢ_{T-1} = w_{T-1}``). It draws nothing. Its cost is ``O(Np²)`` per step and path (every pair
of particles of two consecutive steps), computed in blocks of paths by one batched matrix product
per step; memory ``O(block · Np²)`` (:data:`BLOCK`). At the default 2000 particles that is
``4·10⁶`` transition densities per step and path, about 0.1 s on one core (1-D, measured; the
forward pass costs ~1 ms): for long records or many paths build the particle filter with fewer
``particles`` (the smoother's Monte Carlo error then grows as ``1/√Np``, as the filter's).

Trajectory draws (:func:`nlfilter.sample_posterior`) go through the same backward kernel, one
state at a time, from the last step down: since ``p(x_k | x_{k+1:T-1}, y_{0:T-1}) =
p(x_k | x_{k+1}, y_{0:k}) ∝ τ(x_{k+1} | x_k) p(x_k | y_{0:k})`` (Särkkä 2013, Thm. 8.1's backward
kernel; Carter & Kohn 1994 for the Gaussian case)::

    x̃_{T-1} ~ p(x_{T-1} | y_{0:T-1}),    x̃_k ~ ∝ p(x_k | y_{0:k}) τ(x̃_{k+1} | x_k)

* Grid (:func:`grid_ffbs`, forward filtering backward sampling): ``P(x̃_k = X_i | x̃_{k+1} = X_j)
  ∝ p_k,i K_k,ij``, the filtered grid weights times the column of the filter's own kernel at the
  drawn point: exact draws of the grid's Markov chain posterior (their marginals are
  :func:`grid_smoother`'s), grid points.
* Particles (:func:`backward_simulation`, Godsill, Doucet & West 2004, *JASA* 99, §3: the
  backward-simulation smoother): ``P(x̃_k = x_k,i | x̃_{k+1}) = w_{k|k+1},i ∝ w_k,i τ(x̃_{k+1} |
  x_k,i)``, the filtered particles reweighted by the transition density to the drawn state
  (their marginals, given the clouds, are :func:`ffbsm`'s), ``O(Np)`` per step and draw.
"""

from __future__ import annotations

import numpy as np

from ...errors import DivergenceError
from ...angles import angles_of, residual, weighted_moments
from ..pointmass import apply_kernel, cloud_moments, moments, weights

__all__ = ["grid_smoother", "ffbsm", "transition_logpdf", "grid_ffbs", "backward_simulation"]

BLOCK = 2**22  #: elements of the pairwise arrays (paths × Np × Np × n) per block of the particle smoother


def grid_smoother(filtered, kernel, X, angles=()):
    """The forward–backward grid smoother (module docstring).

    ``filtered``: the filtered probability vectors of steps ``0..T-1``, a sequence of ``(B, N)``;
    ``kernel(k)``: the transition kernel from step ``k`` to step ``k + 1`` (``(N, N)``, dense or
    scipy sparse, ``p⁻ ∝ p @ K``); ``X (N, n)`` the grid points (``angles``: its periodic axes,
    averaged circularly, :func:`~nlfilter.angles.weighted_moments`). Returns the smoothed
    ``(means (B, T, n), covs (B, T, n, n))``.

    >>> import numpy as np
    >>> K = np.array([[0.9, 0.1], [0.1, 0.9]])   # a two-state chain; step 1 is sure of state 0
    >>> X = np.array([[0.0], [1.0]])
    >>> m, _ = grid_smoother([np.array([[0.5, 0.5]]), np.array([[1.0, 0.0]])], lambda k: K, X)
    >>> m[0, :, 0].round(6).tolist()      # p(x_0 = 1 | y) = 0.5 · 0.1 / (0.5 · 0.9 + 0.5 · 0.1)
    [0.1, 0.0]
    """
    T = len(filtered)
    B = filtered[-1].shape[0]
    n = X.shape[-1]
    means, covs = np.empty((B, T, n)), np.empty((B, T, n, n))
    if T == 0:
        return means, covs
    ps = filtered[-1]
    summary = (lambda p_, X_: weighted_moments(p_, X_, angles)) if angles else moments
    means[:, -1], covs[:, -1] = summary(ps, X)
    for k in range(T - 2, -1, -1):
        p = filtered[k]
        K = kernel(k)
        pred = apply_kernel(p, K)
        pred = pred / pred.sum(axis=-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(pred > 0, ps / pred, 0.0)  # 0/0 = 0: no predicted mass, no smoothed mass
        ps = p * apply_kernel(r, K.T)  # K r, for each path: r @ Kᵀ
        s = ps.sum(axis=-1, keepdims=True)
        ps = np.where(s > 0, ps / np.where(s > 0, s, 1.0), p)  # a dead path keeps its filtered density
        means[:, k], covs[:, k] = summary(ps, X)
    return means, covs


def ffbsm(xs, logws, logtau, block: int | None = None, logg=None, angles=()):
    """The forward-filtering backward-smoothing of the marginals (module docstring).

    ``xs``, ``logws``: the filtered particles ``(B, Np, n)`` and their (unnormalized) log-weights
    ``(B, Np)`` of steps ``0..T-1``; ``logtau(x, x1, k) -> (b, Np, Np)``: the log transition
    density ``log τ(x1_j | x_i)`` from step ``k`` to ``k + 1`` for a block of paths; ``block``:
    paths per block (default: as many as keep the pairwise arrays under :data:`BLOCK` elements);
    ``logg(x, k, sl) -> (b, Np)`` (optional): where the measurement of step ``k + 1`` depends on
    the state of step ``k`` (an SDE's increment over ``[t_{k+1}, t_{k+2}]`` with the left-point
    ``∫ h ds = h(x_k) dt``, one Euler–Maruyama substep), its log-likelihood at the particles
    ``x`` of step ``k`` (paths ``sl``): the backward kernel is then ``∝ w_k τ g_{k+1}(x_k)``.
    Returns the smoothed ``(means (B, T, n), covs (B, T, n, n))`` (``angles``: the angular state
    components, averaged circularly, :func:`~nlfilter.angles.weighted_moments`).

    >>> import numpy as np
    >>> x0, x1 = np.array([[[0.0], [1.0]]]), np.array([[[0.0]]])   # two particles, then one
    >>> lt = lambda x, y, k: -0.5 * (y[:, None, :, 0] - x[:, :, None, 0]) ** 2   # τ = N(x, 1)
    >>> m, _ = ffbsm([x0, x1], [np.zeros((1, 2)), np.zeros((1, 1))], lt)
    >>> round(float(m[0, 0, 0]), 6)       # wˢ_0 ∝ (1, e^{-1/2}): mean e^{-1/2} / (1 + e^{-1/2})
    0.377541
    """
    T = len(xs)
    B, _, n = xs[-1].shape
    means, covs = np.empty((B, T, n)), np.empty((B, T, n, n))
    if T == 0:
        return means, covs
    Np = max(x.shape[1] for x in xs)
    if block is None:
        block = max(1, BLOCK // (Np * Np * n))
    for lo in range(0, B, block):
        sl = slice(lo, min(lo + block, B))
        ws = weights(logws[-1][sl])
        summary = (lambda w_, x_: weighted_moments(w_, x_, angles)) if angles else cloud_moments
        means[sl, -1], covs[sl, -1] = summary(ws, xs[-1][sl])
        for k in range(T - 2, -1, -1):
            w = weights(logws[k][sl])
            lt = logtau(xs[k][sl], xs[k + 1][sl], k)  # (b, i, j): log τ(x_{k+1,j} | x_k,i)
            if logg is not None:  # y_{k+1} depends on x_k: p(x_k | x_{k+1}, y_{:k+1}) ∝ w τ g_{k+1}(x_k)
                lt = lt + logg(xs[k][sl], k, sl)[..., :, None]
            mx = np.max(lt, axis=1, keepdims=True)  # per column j: the ratio τ_ij / Σ_l w_l τ_lj is scale-free
            lt -= np.where(np.isfinite(mx), mx, 0.0)
            A = np.exp(lt, out=lt)
            den = np.einsum("bi,bij->bj", w, A)  # Σ_l w_k,l τ(x_{k+1,j} | x_k,l)
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.where(den > 0, ws / den, 0.0)
            new = w * np.einsum("bij,bj->bi", A, v)
            s = new.sum(axis=-1, keepdims=True)
            ws = np.where(s > 0, new / np.where(s > 0, s, 1.0), w)  # no support at all: keep the filter's
            means[sl, k], covs[sl, k] = summary(ws, xs[k][sl])
    return means, covs


def transition_logpdf(model, x, x1, k, dt=None):
    """``log τ(x1_j | x_i) (..., Np, Np1)`` for particles ``x (..., Np, n)`` and ``x1 (..., Np1, n)``.

    A discrete model ``x' = f(x, k) + G(x, k) w``: with Gaussian noise ``N(x'; f, G Q Gᵀ)``
    (``G Q Gᵀ`` non-singular); with another noise law that has a density and a square ``G``,
    ``log p_w(G⁻¹ (x' − f)) − log |det G|``. An SDE (``dt`` given): the Euler–Maruyama step over
    ``dt`` at time ``k``, ``N(x'; x + f(x, k) dt, G Q Gᵀ dt)``. A fixed ``G Q Gᵀ`` (the common
    case) whitens both clouds once, and the quadratic form is one matrix product,
    ``|a_j − b_i|² = |a_j|² + |b_i|² − 2 b_i·a_j``. A transition without a density (singular
    ``G Q Gᵀ``) raises ``ValueError``."""
    from ...noise import Gaussian
    md, n = model, model.n
    if dt is None:
        f = md.f(x, k)
        law = md.process_noise
        if not isinstance(law, Gaussian):
            if not (md.r == md.n and law.has_density):
                raise ValueError("process_noise: the particle smoother needs a Gaussian law, or a law with a "
                                 "density and a square G")
            G = md.G(x, k)
            det = np.linalg.det(G)
            if not np.all(np.abs(det) > 0):
                raise ValueError("model: the particle smoother needs a transition density; G(x) is singular")
            z = np.einsum("...iab,...ijb->...ija", np.linalg.inv(G), x1[..., None, :, :] - f[..., :, None, :])
            return law.logpdf(z) - np.log(np.abs(det))[..., :, None]
        scale = 1.0
    else:
        f = x + md.f(x, k) * dt
        scale = dt
    fixed = getattr(md, "_GQG0", None) is not None
    C = (md.GQGT(np.zeros(n)) if fixed else md.GQGT(x, k)) * scale
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        raise ValueError("process_noise: the particle smoother needs a transition density; G Q Gᵀ is singular "
                         "(a state without process noise)") from None
    Li = np.linalg.inv(L)
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1) + n * np.log(2 * np.pi)
    ang = angles_of(md).states
    if ang:  # angular states: the pairwise residuals x1_j − f_i wrapped (nlfilter.angles)
        z = np.einsum("...ab,...ijb->...ija" if fixed else "...iab,...ijb->...ija", Li,
                      residual(x1[..., None, :, :], f[..., :, None, :], ang))
        return -0.5 * np.sum(z * z, axis=-1) - 0.5 * (logdet if fixed else logdet[..., :, None])
    if fixed:  # whitened clouds a = L⁻¹ x1, b = L⁻¹ f: one matrix product per path
        a, b = x1 @ Li.T, f @ Li.T
        q = b @ np.swapaxes(a, -1, -2)  # in place below: the (..., Np, Np1) array is the cost
        q *= -2.0
        q += np.sum(b * b, axis=-1)[..., :, None]
        q += np.sum(a * a, axis=-1)[..., None, :]
        np.maximum(q, 0.0, out=q)
        q *= -0.5
        q -= 0.5 * logdet
        return q
    z = np.einsum("...iab,...ijb->...ija", Li, x1[..., None, :, :] - f[..., :, None, :])
    return -0.5 * np.sum(z * z, axis=-1) - 0.5 * logdet[..., :, None]


def _categorical(w, u, k, lo=0):
    """Indices ``(b, d)``: row ``(i, j)`` drawn from the unnormalized weights ``w[i, j] (N,)`` by the
    uniform ``u[i, j]`` (inverse CDF: the index whose cumulative-weight interval holds ``u · Σ w``;
    a zero weight is never drawn). Weights with no positive, finite total raise
    :class:`DivergenceError` (``what="sampler"``) naming the step and paths."""
    c = np.cumsum(w, axis=-1)
    tot = c[..., -1]
    bad = ~(tot > 0) | ~np.isfinite(tot)
    if bad.any():
        idx = lo + np.flatnonzero(bad.any(axis=-1))
        raise DivergenceError(f"sample_posterior: the backward kernel has no finite positive mass at step {k} on "
                              f"{idx.size} path(s), first {idx[:5].tolist()}", step=k, paths=idx, what="sampler")
    return np.minimum(np.sum(c <= (u * tot)[..., None], axis=-1), w.shape[-1] - 1)


def grid_ffbs(filtered, kernel, X, u, block: int | None = None):
    """Trajectory draws through the grid filter (module docstring, forward filtering backward
    sampling): ``filtered``, ``kernel``, ``X`` as :func:`grid_smoother`; ``u (B, T, d)``
    uniforms in [0, 1), one per path, step and draw. Returns the draws ``(B, d, T, n)``, grid
    points. Memory ``block × d × N`` per step (``block`` paths at a time, default: as many as keep
    it under :data:`BLOCK` elements).

    >>> import numpy as np
    >>> K = np.array([[1.0, 0.0], [0.0, 1.0]])   # the chain stays put: the whole path is the last draw
    >>> X = np.array([[0.0], [1.0]])
    >>> grid_ffbs([np.array([[0.5, 0.5]])] * 3, lambda k: K, X, np.array([[[0.2, 0.7]] * 3]))[0, :, :, 0].tolist()
    [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
    """
    T = len(filtered)
    B, _, d = u.shape
    N = X.shape[0]
    idx = np.empty((B, d, T), dtype=np.intp)
    if T == 0:
        return np.empty((B, d, 0, X.shape[1]))
    block = max(1, BLOCK // (d * N)) if block is None else block
    for lo in range(0, B, block):
        sl = slice(lo, min(lo + block, B))
        idx[sl, :, T - 1] = _categorical(filtered[-1][sl, None, :], u[sl, T - 1], T - 1, lo)
        for k in range(T - 2, -1, -1):
            K = kernel(k)
            j = idx[sl, :, k + 1]  # the drawn points of step k + 1: the columns K[:, j]
            cols = K.T[j] if isinstance(K, np.ndarray) else K.T.tocsr()[j.ravel()].toarray().reshape(*j.shape, N)
            idx[sl, :, k] = _categorical(filtered[k][sl, None, :] * cols, u[sl, k], k, lo)  # p_k,i K_k,ij
    return X[idx]


def backward_simulation(xs, logws, logtau, u, block: int | None = None, logg=None):
    """Trajectory draws through the particle filter's clouds (module docstring; Godsill, Doucet &
    West 2004): ``xs``, ``logws``, ``logtau``, ``logg`` as :func:`ffbsm` (``logtau`` evaluated
    with the drawn states as ``x1 (b, d, n)``); ``u (B, T, d)`` uniforms in [0, 1). Returns the
    draws ``(B, d, T, n)``, particles of each step's cloud. Cost ``O(Np)`` per step and draw;
    memory ``O(block · Np · d)``.

    >>> import numpy as np
    >>> x0, x1 = np.array([[[-1.0], [1.0]]]), np.array([[[1.0]]])   # τ = N(x, 0.1): x̃_0 = 1 almost surely
    >>> lt = lambda x, y, k: -5.0 * (y[:, None, :, 0] - x[:, :, None, 0]) ** 2
    >>> backward_simulation([x0, x1], [np.zeros((1, 2)), np.zeros((1, 1))], lt, np.full((1, 2, 3), 0.01))[0, :, 0, 0].tolist()
    [1.0, 1.0, 1.0]
    """
    T = len(xs)
    B, _, d = u.shape
    n = xs[-1].shape[-1]
    out = np.empty((B, d, T, n))
    if T == 0:
        return out
    Np = max(x.shape[1] for x in xs)
    block = max(1, BLOCK // (Np * d * n)) if block is None else block
    for lo in range(0, B, block):
        sl = slice(lo, min(lo + block, B))
        rows = np.arange(sl.stop - sl.start)[:, None]
        j = _categorical(weights(logws[-1][sl])[:, None, :], u[sl, T - 1], T - 1, lo)
        x = out[sl, :, T - 1] = xs[-1][sl][rows, j]
        for k in range(T - 2, -1, -1):
            lw = logws[k][sl]
            if logg is not None:  # y_{k+1} depends on x_k (an SDE's left point): ∝ w τ g_{k+1}(x_k)
                lw = lw + logg(xs[k][sl], k, sl)
            a = np.swapaxes(logtau(xs[k][sl], x, k), -1, -2) + lw[:, None, :]  # (b, d, Np): log w_k,i τ(x̃_{k+1} | x_k,i)
            mx = np.max(a, axis=-1, keepdims=True)
            a -= np.where(np.isfinite(mx), mx, 0.0)
            j = _categorical(np.exp(a, out=a), u[sl, k], k, lo)
            x = out[sl, :, k] = xs[k][sl][rows, j]
    return out
