"""The sides the benchmarks time, shared (import :mod:`_pin` before this module).

* :func:`nlfilter_sides`: one nlfilter filter through the **default call** (``run`` with no
  ``backend=``; what it resolves to is recorded), ``backend="numpy"`` and ``backend="numba"``,
  each with its first call (compile, cache load) apart and included;
* :func:`filterpy_pair`: filterpy's ``ExtendedKalmanFilter`` and ``UnscentedKalmanFilter`` (a Python
  loop per path and step) on NumPy functions of one state;
* :func:`dynamax_filters`: dynamax's ``extended_kalman_filter`` and ``unscented_kalman_filter`` in
  float64 under ``jit`` (with ``vmap`` over paths, or on one trajectory), the cubature rule as its
  unscented filter with ``alpha = 1, beta = 0, kappa = 0`` (λ = 0: the 2n points ±√n L e_i with
  equal weights, no centre point — the CKF's rule); compile apart and included;
* :func:`jax_second_order`: dynamax has no second-order filter; this is one in its style (float64,
  ``jit`` + ``vmap``, ``lax.scan`` over the steps, ``jax.jacfwd`` / ``jax.hessian`` of f and h),
  computing what nlfilter's ``SecondOrderFilter`` (default form ``"truncated"``) computes.
"""

from __future__ import annotations

import numpy as np

from _pin import default_backend, default_calls, first_and_best


def maxdiff(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


def relmaxdiff(a, b) -> float:
    """max |a − b| / max |b| (a relative difference of whole arrays)."""
    scale = float(np.max(np.abs(b))) or 1.0
    return maxdiff(a, b) / scale


def nlfilter_sides(make, ys, m0, P0, repeat, columns=("default", "numpy", "numba"), warm=None, default_repeat=None,
                   **kw):
    """Time ``make().run(ys, m0, P0, **kw)`` for each column, in order: ``"default"`` (no backend
    argument: first, so that a compile it decides on is its own), ``"numpy"``, ``"numba"``.
    ``warm``: None (the default call in this process, on the cache as it is: cold in a benchmark),
    or ``(factory, args[, fill])`` for :func:`_warm.warm_default` (the default call in a fresh
    process, the disk cache filled beforehand by another one: its estimates carry ``means``); then
    the columns ``"numba-fresh"``, ``"numba-shared-fresh"`` are that backend in a fresh process on
    that cache. ``default_repeat``: the default column's calls at most (default ``repeat``), as
    :func:`_pin.default_calls`: enough for the automatic rule to reach its steady state in a process
    repeating the job.

    Returns ``(timings, estimates, notes)``: ``timings[col]`` as :func:`_pin.first_and_best` (its
    "compile" is the first call's extra over the best: a compile, a cache load, or noise for the
    NumPy loop); where the default call *is* ``backend="numpy"`` (the imported nlfilter's default)
    the numpy column is that measurement, not a second one; a backend that refuses the filter is
    a note, not a column.
    """
    timings, est, notes = {}, {}, []
    default = default_backend()
    if default != "numpy" and "default" in columns and "numba" in columns and warm is None:
        notes.append(f"the default call ({default!r}) runs first: where it compiled, backend='numba' finds the "
                     "compiled loop in this process and its 'compile' is what is left (a cold compile is the "
                     "default call's)")
    fresh = {"default": None, "numba-fresh": "numba", "numba-shared-fresh": "numba-shared"}
    for col in columns:
        if col in fresh and warm is not None:
            from _warm import warm_default

            calls = default_repeat or repeat if col == "default" else repeat
            timings[col], est[col], more = warm_default(*warm[:2], ys, m0, P0, calls, backend=fresh[col],
                                                        fill=warm[2] if len(warm) > 2 else None)
            notes += [x for x in more if x not in notes]
            continue
        if col in fresh and col != "default":
            notes.append(f"{col}: only with a warm cache (--cache warm or shape)")
            continue
        if col == "numpy" and "default" in timings and default == "numpy":
            timings["numpy"], est["numpy"] = timings["default"], est["default"]
            notes.append("the default call is backend='numpy' here: one measurement for both columns")
            continue
        flt = make()
        args = {} if col == "default" else {"backend": col}
        try:
            if col == "default" and default_repeat:
                timings[col], est[col] = default_calls(lambda: flt.run(ys, m0, P0, **kw), default_repeat)
            else:
                timings[col], est[col] = first_and_best(lambda: flt.run(ys, m0, P0, **args, **kw), repeat)
        except TypeError as exc:
            if "backend" not in str(exc):
                raise
            notes.append(f"{col}: {exc}")
    return timings, est, notes


def filterpy_pair(fns, ys, m0, P0, Qm, Rm, repeat):
    """filterpy's EKF and UKF over every path of ``ys (paths, T, m)`` with the NumPy functions
    ``fns = (fx, hx, F, H)`` of one state ``(n,)``: seconds per path-step (best of ``repeat``) and
    the means ``(paths, T, n)``. filterpy predicts first (nlfilter's ``start="predict"``)."""
    from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

    from _pin import best_of

    fx, hx, F, H = fns
    n, m = len(m0), ys.shape[-1]
    npth, T = ys.shape[:2]

    class FP(ExtendedKalmanFilter):
        def predict(self, u=0):
            self.F = F(self.x[:, 0])
            self.x = fx(self.x[:, 0])[:, None]
            self.P = self.F @ self.P @ self.F.T + self.Q

    def ekf():
        out = np.empty((npth, T, n))
        for p in range(npth):
            f = FP(n, m)
            f.x, f.P, f.Q, f.R = np.array(m0, float)[:, None], np.array(P0, float), Qm, Rm
            for k in range(T):
                f.predict()
                f.update(ys[p, k][:, None], lambda x: H(x[:, 0]), lambda x: hx(x[:, 0])[:, None])
                out[p, k] = f.x[:, 0]
        return out

    def ukf():
        out = np.empty((npth, T, n))
        for p in range(npth):
            pts = MerweScaledSigmaPoints(n, alpha=1.0, beta=2.0, kappa=0.0)
            f = UnscentedKalmanFilter(n, m, 1.0, hx, fx, pts)
            f.x, f.P, f.Q, f.R = np.array(m0, float), np.array(P0, float), Qm, Rm
            for k in range(T):
                f.predict()
                f.update(ys[p, k])
                out[p, k] = f.x
        return out

    te, me = best_of(ekf, repeat)
    tu, mu = best_of(ukf, repeat)
    return {"ekf": te / (npth * T), "ukf": tu / (npth * T)}, {"ekf": me, "ukf": mu}


def dynamax_filters(spec, ys, repeat, vmap=True, kinds=("ekf", "ukf", "ckf")):
    """dynamax's filters (float64, ``jit``; over the paths of ``ys (paths, T, m)`` with ``vmap``, or
    one trajectory ``ys (T, m)`` without) on the model ``spec(jnp) = (m0, P0, f, Q, h, R)``.

    Each job returns the filtered means and covariances, as nlfilter's run does.
    Returns ``(timings, means)``: ``timings[kind]`` as :func:`_pin.first_and_best` on the whole job
    (its "compile" is jit's trace and XLA compile, "included" the first call), ``means[kind]``.
    The UKF with nlfilter's defaults (``alpha = 1, beta = 2, kappa = 0``), the CKF as above.
    Raises ImportError where jax or dynamax is missing.
    """
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from dynamax.nonlinear_gaussian_ssm import (ParamsNLGSSM, UKFHyperParams, extended_kalman_filter,
                                                unscented_kalman_filter)

    m0, P0, f, Qm, h, Rm = spec(jnp)
    params = ParamsNLGSSM(initial_mean=m0, initial_covariance=P0, dynamics_function=f, dynamics_covariance=Qm,
                          emission_function=h, emission_covariance=Rm)
    hyper = {"ukf": UKFHyperParams(alpha=1.0, beta=2.0, kappa=0.0),
             "ckf": UKFHyperParams(alpha=1.0, beta=0.0, kappa=0.0)}
    over = jax.vmap if vmap else (lambda fn: fn)

    def both(post):  # the job nlfilter's run does: filtered means and covariances (means only lets XLA
        return post.filtered_means, post.filtered_covariances  # skip writing the covariances)

    def job(kind):
        if kind == "ekf":
            return jax.jit(over(lambda y: both(extended_kalman_filter(params, y))))
        return jax.jit(over(lambda y: both(unscented_kalman_filter(params, y, hyper[kind]))))

    yj = jnp.asarray(ys)
    timings, means = {}, {}
    for kind in kinds:
        run = job(kind)
        timings[kind], out = first_and_best(lambda: jax.block_until_ready(run(yj)), repeat)
        means[kind] = np.asarray(out[0])
    return timings, means


def second_order_filter(spec, jnp):
    """A second-order EKF in dynamax's style on the model ``spec(jnp) = (m0, P0, f, Q, h, R)``:
    ``run(ys (T, m)) -> (filtered means (T, n), filtered covariances (T, n, n))``, update first.

    The equations of nlfilter's ``SecondOrderFilter(model)`` (form ``"truncated"``, seed 004 eqs.
    18-23: the rule ``Taylor2("truncated")`` over the discrete Gaussian skeleton; G = I here)::

        update:   ŷ = h(m) + ½ (P h_xx),   H = h_x(m),   S = H P Hᵀ + R,   K = P Hᵀ S⁻¹,
                  m⁺ = m + K (y − ŷ),   P⁺ = sym((I − K H) P (I − K H)ᵀ + K R Kᵀ)   (Joseph)
        predict:  m⁻ = f(m⁺) + ½ (P⁺ f_xx),   P⁻ = sym(F P⁺ Fᵀ + Q),   F = f_x(m⁺)

    with ``(P g_xx)_i = Σ_jl P_jl ∂²g_i/∂x_j∂x_l`` and ``sym(A) = ½ (A + Aᵀ)`` (nlfilter symmetrizes
    the predicted covariance and the Joseph form's result; no fourth-moment term, no forcing term).
    The gain by a Cholesky solve (dynamax's ``psd_solve``).
    """
    import jax
    from jax import lax

    m0, P0, f, Qm, h, Rm = spec(jnp)
    F, H = jax.jacfwd(f), jax.jacfwd(h)
    f_xx, h_xx = jax.hessian(f), jax.hessian(h)
    eye = jnp.eye(m0.shape[-1])

    def sym(A):
        return 0.5 * (A + A.T)

    def step(carry, y):
        m, P = carry
        Hx = H(m)
        yhat = h(m) + 0.5 * jnp.einsum("jl,ijl->i", P, h_xx(m))
        S = Hx @ P @ Hx.T + Rm
        K = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(S), Hx @ P).T
        IKH = eye - K @ Hx
        mf = m + K @ (y - yhat)
        Pf = sym(IKH @ P @ IKH.T + K @ Rm @ K.T)
        Fx = F(mf)
        mp = f(mf) + 0.5 * jnp.einsum("jl,ijl->i", Pf, f_xx(mf))
        Pp = sym(Fx @ Pf @ Fx.T + Qm)
        return (mp, Pp), (mf, Pf)

    def run(ys):
        return lax.scan(step, (m0, P0), ys)[1]

    return run


def jax_second_order(spec, ys, repeat, vmap=True):
    """:func:`second_order_filter` under ``jit`` (with ``vmap`` over the paths of ``ys (paths, T, m)``,
    or on one trajectory ``ys (T, m)`` without), float64, as :func:`dynamax_filters` times dynamax.

    Returns ``(timings, means)`` keyed ``"second-order"``: the timing as :func:`_pin.first_and_best`
    on the whole job (filtered means and covariances; its "compile" is jit's trace and XLA compile),
    the filtered means. Raises ImportError where jax is missing."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    run = second_order_filter(spec, jnp)
    job = jax.jit(jax.vmap(run) if vmap else run)
    yj = jnp.asarray(ys)
    timing, out = first_and_best(lambda: jax.block_until_ready(job(yj)), repeat)
    return {"second-order": timing}, {"second-order": np.asarray(out[0])}


def per_step(timing: dict, steps: int) -> dict:
    """A :func:`_pin.first_and_best` timing with ``best`` also per (path-)step in µs."""
    cpu = {"cpu_us_per_step": timing["best_cpu"] / steps * 1e6} if "best_cpu" in timing else {}
    return {**timing, "us_per_step": timing["best"] / steps * 1e6, **cpu}


def column_name(col: str) -> str:
    """How a row names an nlfilter column."""
    if col == "default":
        return f"default call, no backend= (here {default_backend()!r})"
    if col in ("numba-fresh", "numba-shared-fresh"):
        return f"backend={col[:-6]!r} in a fresh process"
    return f"backend={col!r}"


def rows_against(ours: dict, peer: str, theirs: dict, steps: int, cache: str | None = None) -> list:
    """Rows naming both sides, for every filter kind in both and every nlfilter column.

    ``ours[kind][col]`` and ``theirs[kind]`` are :func:`_pin.first_and_best` timings of the same
    job of ``steps`` (path-)steps (a peer timing without "first" has no compile-included row; where
    both have CPU times, each row also gives ``cpu_peer_over_ours`` compile apart and included).
    A column that is the default call's measurement itself (the default is that backend) gives
    no second row. ``cache`` (e.g. ``"warm"``) names the disk cache's state in the rows (key
    ``cache`` and the name of nlfilter's side). Each pair gives a row of µs per (path-)step with the compile apart (the best calls) and, where
    both sides have a first call, a row of seconds to the first result (compile included).
    """
    from _pin import side_by_side

    rows = []
    for kind, t_peer in theirs.items():
        for col, t_ours in ours.get(kind, {}).items():
            if col != "default" and t_ours is ours[kind].get("default"):
                continue  # the default call's own measurement (its row names what it resolved to)
            name = f"nlfilter {kind}, {column_name(col)}"
            extra = {"kind": kind, "column": col}
            if t_ours.get("best_backend"):  # (the default call's: what its best later call ran on)
                extra["best_call_backend"] = t_ours["best_backend"]
            if "best_cpu" in t_ours and "best_cpu" in t_peer:  # a shared core inflates wall time, not CPU time
                extra["cpu_peer_over_ours"] = {"apart": t_peer["best_cpu"] / t_ours["best_cpu"]}
                if all(t.get("included") == t.get("first") for t in (t_ours, t_peer)):  # (not a build added)
                    extra["cpu_peer_over_ours"]["included"] = t_peer["first_cpu"] / t_ours["first_cpu"]
            if cache is not None:
                state = "fresh process" if col in ("default", "numba-fresh", "numba-shared-fresh") else \
                    "in the benchmark's process"
                name += f", {cache} disk cache ({state})"
                extra["cache"] = cache
            rows.append(side_by_side(name, f"{peer} {kind}", t_ours["best"] / steps * 1e6,
                                     t_peer["best"] / steps * 1e6, "µs per (path-)step, compile apart",
                                     **extra, compile="apart"))
            if "first" in t_peer:
                rows.append(side_by_side(name, f"{peer} {kind}", t_ours["included"], t_peer["included"],
                                         "s to the first result of the whole job, compile included",
                                         **extra, compile="included"))
    return rows


def scaled(timing: dict, factor: float) -> dict:
    """A :func:`_pin.first_and_best` timing of a job ``factor`` times shorter than the peers', as if
    of the whole job: the best and the run part of the first call scaled, the compile kept."""
    best = timing["best"] * factor
    cpu = {}
    if "best_cpu" in timing:
        cpu = {"best_cpu": timing["best_cpu"] * factor,
               "first_cpu": max(timing["first_cpu"] - timing["best_cpu"], 0.0) + timing["best_cpu"] * factor}
    return {**timing, "best": best, "first": timing["compile"] + best, "included": timing["compile"] + best,
            **cpu, "scaled_by": factor}
