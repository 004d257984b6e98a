"""Parameter estimation: maximum likelihood on any filter's log-likelihood, and EM for
linear-Gaussian models.

:func:`fit` maximizes ``Σ_paths log p(y_0..y_{T-1} | θ)`` as computed by a filter's
``run(..., loglik=True)`` (the prediction-error decomposition of the Gaussian filters — exact on
a linear-Gaussian model, an approximation (quasi-likelihood) otherwise; the grid filter's
log-evidence; the particle filter's estimate) over the model parameters named in ``params0``
(SymPy symbols of the model, :meth:`~nlfilter.models.Model.with_params`: no code is generated per
evaluation). A parameter whose symbol is declared positive (``sp.Symbol("q", positive=True)``) or
bounded below (``bounds={"q": (0, None)}``) is optimized on the log scale, one bounded on both
sides on the logit scale, others as they are. Standard errors come from the observed information:
the central-difference Hessian of ``−log L`` at the optimum in the natural parametrization
(Harvey 1989, §3.5; the inverse Hessian is the asymptotic covariance of the MLE).

:func:`fit_em` is the EM algorithm of Shumway & Stoffer (1982) for ``x_{k+1} = F x_k + w_k``,
``y_k = H x_k + v_k``: the E-step is the Kalman (RTS) smoother with its lag-one covariances, the
M-step the closed-form updates of F, H, Q, R (and, optionally, m0, P0). Each iteration does not
decrease the likelihood; its fixed point is a stationary point of the likelihood (the MLE that
:func:`fit` finds, to the tolerance).

>>> import numpy as np, sympy as sp
>>> from nlfilter import DiscreteModel, simulate
>>> x, a = sp.symbols("x a"); q = sp.Symbol("q", positive=True)
>>> model = DiscreteModel([x], [a * x], [x], Q=[[q]], R=0.5, params={a: 0.8, q: 0.3})
>>> ys = simulate(model, 300, paths=2, m0=[0.0], P0=[[1.0]], rng=1).ys
>>> res = fit(model, ys, {"a": 0.5, "q": 1.0}, filter="kf", m0=[0.0], P0=[[1.0]])
>>> res.converged, abs(res.params["a"] - 0.8) < 2 * res.se["a"]
(True, True)
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from . import _validate as V
from ._fit_checks import check_options, diffuse_check, fit_data, parameter_kinds
from .errors import CompileError, DivergenceError

__all__ = ["fit", "FitResult", "fit_em", "EMResult"]


@dataclass(frozen=True)
class FitResult:
    """What :func:`fit` found, and how.

    ``params``/``se``: ``{name: value}`` at the optimum and their standard errors (NaN where the
    observed information is not positive definite: ``se_ok`` False, and ``message`` says so);
    ``cov``: the asymptotic covariance (inverse observed information, parameter order of
    ``names``); ``loglik``: the maximized log-likelihood; ``converged``/``message``/``nfev``/
    ``nit``: the optimizer's word; ``model``: the model at the estimate; ``filter``, ``method``,
    ``seconds``: how it was made."""

    params: dict
    se: dict
    cov: np.ndarray
    loglik: float
    converged: bool
    se_ok: bool
    message: str
    nfev: int
    nit: int
    names: tuple
    filter: str
    method: str
    seconds: float
    model: object = field(repr=False)

    def to_dict(self) -> dict:
        return {"params": dict(self.params), "se": dict(self.se), "cov": self.cov.tolist(), "loglik": self.loglik,
                "converged": self.converged, "se_ok": self.se_ok, "message": self.message, "nfev": self.nfev,
                "nit": self.nit, "filter": self.filter, "method": self.method, "seconds": self.seconds}

    def __str__(self):
        lines = [f"fit by {self.filter} ({self.method}): log L = {self.loglik:.6g}, "
                 f"{'converged' if self.converged else 'NOT converged'} ({self.message}), {self.nfev} evaluations"]
        lines += [f"  {k:>12s} = {v: .6g} ± {self.se[k]:.3g}" for k, v in self.params.items()]
        return "\n".join(lines)


def _logit(t, lo, hi):
    u = (t - lo) / (hi - lo)
    return math.log(u / (1 - u))


def _clip(z):
    """``z`` bounded to ±700: ``exp`` of it stays finite."""
    return max(min(z, 700.0), -700.0)


#: per kind of parameter: ``(θ -> z, z -> θ)`` given the bounds ``lo``, ``hi`` (see :class:`_Transform`)
_MAPS = {"id": (lambda t, lo, hi: t, lambda z, lo, hi: z),
         "lo": (lambda t, lo, hi: math.log(t - lo), lambda z, lo, hi: lo + math.exp(min(z, 700.0))),
         "hi": (lambda t, lo, hi: math.log(hi - t), lambda z, lo, hi: hi - math.exp(min(z, 700.0))),
         "logit": (_logit, lambda z, lo, hi: lo + (hi - lo) / (1 + math.exp(-_clip(z))))}


class _Transform:
    """Per parameter: identity, log(θ − lo), log(hi − θ) or logit on (lo, hi)."""

    def __init__(self, kinds):
        self.kinds = kinds  # list of (kind, lo, hi)

    def to_free(self, theta):
        return np.array([_MAPS[kind][0](t, lo, hi) for t, (kind, lo, hi) in zip(theta, self.kinds)])

    def dnatural(self, z, i):
        """``dθ_i / dz_i`` at the free coordinate ``z`` of parameter ``i``."""
        kind, lo, hi = self.kinds[i]
        if kind == "id":
            return 1.0
        if kind in ("lo", "hi"):
            return math.exp(min(z, 700.0))
        e = math.exp(-abs(_clip(z)))
        return (hi - lo) * e / (1 + e) ** 2

    def to_natural(self, z):
        return np.array([_MAPS[kind][1](v, lo, hi) for v, (kind, lo, hi) in zip(z, self.kinds)])


def _make_filter(filter, filter_options, dt, start):
    """``(build: model -> Filter, label)`` for :func:`fit`: ``start`` (None: the filter's default,
    or the data's) and ``dt`` reach the filter with or without ``filter_options``."""
    from .filters import REGISTRY
    from .filters.base import Filter
    from .filters.registry import get

    if filter_options is not None and not isinstance(filter_options, dict):
        raise TypeError(f"filter_options: expected a dict of the filter's keyword options, got {filter_options!r}")
    opts = dict(filter_options or {})
    if isinstance(filter, str):
        cls = get(REGISTRY, filter)
        label = filter
    elif isinstance(filter, type) and issubclass(filter, Filter):
        cls, label = filter, filter.__name__
    elif callable(filter):
        if opts:
            raise ValueError("filter_options: a callable filter builds its own filter; expected None, got "
                             f"{filter_options!r}")
        return filter, None  # labelled by the class it builds
    else:
        raise TypeError(f"filter: expected a registry name, a Filter class or a callable model -> Filter, "
                        f"got {type(filter).__name__}")
    for key, given in (("start", start), ("dt", dt)):
        if key in opts and given is not None and opts[key] != given:
            raise ValueError(f"filter_options: {key}={opts[key]!r} differs from {key}={given!r} of fit")

    def build(model):
        if not opts:
            return cls.for_model(model, dt=dt, start=start)
        kw = dict(opts)
        if cls.time == "discrete" and start is not None:
            kw.setdefault("start", start)
        kind = getattr(model, "kind", None)
        continuous = kind in ("sde", "phase") or (kind == "bilinear" and not getattr(model, "discrete", False))
        if continuous and dt is not None and "dt" not in kw:
            return cls(model, dt, **kw)
        return cls(model, **kw)

    return build, label


def fit(model, ys, params0, *, filter="ukf", m0=None, P0=None, initial=None, bounds=None, method: str = "L-BFGS-B",
        dt: float | None = None, start: str | None = None, filter_options=None, rng=0, se: bool = True,
        options=None, progress: bool = False, backend: str = "auto") -> FitResult:
    """Maximum-likelihood estimate of the model parameters named in ``params0``.

    Parameters
    ----------
    model : DiscreteModel or SDEModel with parameters (``params=`` at construction)
    ys : measurements ``(..., T, m)``: independent records that share the parameters; or a
        :class:`~nlfilter.simulation.Simulation`, whose timing convention (``start``, ``t0``, ``dt``)
        the filter reads (a conflicting ``start`` or ``dt`` given here is a ValueError naming both)
    params0 : ``{name or symbol: starting value}``; the other parameters stay at the model's values
    filter : a registry name (``"kf"``, ``"ukf"``, ``"grid"``, ...), a Filter class, or a callable
        ``model -> Filter`` (e.g. ``lambda md: GridFilter(md, (-5, 5), 201)``); it must define a
        likelihood (``Filter.likelihood``)
    m0, P0, initial : the prior, fixed (as in ``run``)
    bounds : ``{name: (lo, hi)}`` (``None`` or ±inf for an open side); positive symbols are bounded below by 0
    method : ``"L-BFGS-B"`` (default, finite-difference gradient), ``"Nelder-Mead"`` (for a particle
        filter's noisy likelihood) or another of ``nlfilter._fit_checks.METHODS``
    dt, start, filter_options : how the filter is built (continuous-time models need ``dt``; a
        Simulation gives it); ``start`` None: the filter's default, or the Simulation's; both reach
        the filter with or without ``filter_options``
    rng : the particle filter's seed, the same at every evaluation (common random numbers)
    se : compute standard errors (2p² + 1 more likelihood evaluations)
    options : ``scipy.optimize.minimize`` options of ``method`` (checked: names and types)
    progress : show the number of evaluations and the best log-likelihood (tqdm)
    backend : the filter's run loop (``Filter.run``): ``"numba"`` compiles the discrete KF, EKF,
        UKF, CKF, GHKF, SLF and second-order filters once for every parameter value (the
        parameters, the KF's matrices, are read at run time), often 2-10× faster per evaluation;
        ``"auto"`` (default) chooses once for the whole fit, counting its evaluations
        (:meth:`~nlfilter.filters.base.Filter.backend_for`)

    Returns
    -------
    FitResult
        Where the filter diverges on some path, or the model refuses the parameter values (a
        negative variance), the objective is not flat: it is the start's value plus a penalty
        growing with the distance from the start, above every value the optimizer has accepted,
        so that its line search backs off. ``converged`` is True only when the optimizer says so
        *and* the log-likelihood is at least the start's *and* the gradient is small (with a
        positive definite observed information: the Newton step would raise log L by less than
        0.01; otherwise every component of the gradient in the optimizer's coordinates below
        0.01) *and* no parameter ran to a bound (a free coordinate beyond ±30: a value within e⁻³⁰ of
        its bound, e.g. a variance going to 0 with the likelihood unbounded above: ``message``
        says "degenerate"); ``message`` says which failed.
    """
    t_start = time.perf_counter()
    if not isinstance(params0, dict) or not params0:
        raise TypeError(f"params0: expected a non-empty dict {{name: starting value}}, got {params0!r}")
    if not callable(getattr(model, "with_params", None)):
        raise TypeError(f"model: expected a DiscreteModel or SDEModel with parameters, got {type(model).__name__}")
    syms = [model.symbol(k) for k in params0]
    names = tuple(str(s) for s in syms)
    if len(set(names)) != len(names):
        raise ValueError(f"params0: a parameter is given twice: {list(params0)}")
    for nm, flag in (("se", se), ("progress", progress)):
        if not isinstance(flag, (bool, np.bool_)):
            raise TypeError(f"{nm}: expected True or False, got {flag!r}")
    kinds, theta0 = parameter_kinds(syms, names, params0, bounds)
    options = check_options(method, options)
    if start is not None:
        V.choice("start", start, {"update", "predict"})
    if getattr(model, "kind", None) == "discrete" and dt is not None:
        raise ValueError(f"dt: a DiscreteModel has no time step; expected None, got {dt!r}")
    data, ys, dt = fit_data(ys, dt)
    tr = _Transform(kinds)
    build, label = _make_filter(filter, filter_options, dt, start)
    first = build(model)
    label = label or getattr(first, "name", type(first).__name__)
    if getattr(first, "likelihood", None) is None:
        raise TypeError(f"filter: {label} defines no log-likelihood; use a Gaussian filter, grid or particle")
    diffuse_check(P0, flt=first, label=label)  # an infinite variance: refused before any evaluation without a diffuse form
    fallback = backend == "auto"  # one choice for the fit, counting its evaluations (L-BFGS-B: ~20 gradients)
    if fallback:  # and the NumPy loop where numba cannot compile the model
        reps = 20 * (len(names) + 1) + (2 * len(names) ** 2 + 1 if se else 0)
        backend = first.backend_for(int(np.prod(ys.shape[:-2])), ys.shape[-2], repeats=reps, record=True)[0]
    why, loop = {}, [backend]
    seen = {}  # θ (bytes) -> log L: the optimizer's last point, the estimate and the Hessian's centre are one

    def loglik(theta):
        key = np.asarray(theta, dtype=float).tobytes()
        if key not in seen:
            seen[key] = _loglik(theta)
        return seen[key]

    def _loglik(theta):
        try:
            md = model.with_params(dict(zip(names, theta)))
        except ValueError as exc:  # the model refuses these values (e.g. a negative variance)
            why["refused"] = str(exc).splitlines()[0]
            return -np.inf
        flt = build(md)
        try:
            try:
                est = flt.run(data, m0, P0, initial=initial, rng=rng, on_divergence="mark", loglik=True, backend=loop[0])
            except CompileError:  # chosen by auto: numba cannot compile the model's functions
                if not fallback:
                    raise
                loop[0] = "numpy"
                return _loglik(theta)
        except (DivergenceError, np.linalg.LinAlgError, FloatingPointError):
            why["diverged"] = True
            return -np.inf
        if est.diverged.any():
            why["diverged"] = True
            return -np.inf
        total = float(np.sum(est.loglik))
        return total if math.isfinite(total) else -np.inf

    bar, best = None, [-np.inf]
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(desc=f"fit ({label})", unit="eval", leave=False)
    ll0 = loglik(theta0)
    if not math.isfinite(ll0):
        raise ValueError(f"params0: the filter's log-likelihood at the starting values {dict(zip(names, theta0.tolist()))} "
                         f"is not finite ({why.get('refused', 'a path diverged')}); start elsewhere")
    z0 = tr.to_free(theta0)
    scale = 1.0 + abs(ll0)

    def objective(z):
        ll = loglik(tr.to_natural(z))
        if bar is not None:
            best[0] = max(best[0], ll)
            bar.update(1)
            bar.set_postfix(loglik=f"{best[0]:.6g}")
        if math.isfinite(ll):
            return -ll
        # not flat: above the start's value, rising away from the start (the optimizer backs off)
        return -ll0 + scale * (1.0 + float(np.sum((np.asarray(z) - z0) ** 2)))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        opt = optimize.minimize(objective, z0, method=method, options=options or None)
    z_hat = np.asarray(opt.x, dtype=float)
    theta = tr.to_natural(z_hat)
    ll_hat = loglik(theta)
    if not (math.isfinite(ll_hat) and ll_hat >= ll0):  # the optimizer's point is worse than the start
        theta, ll_hat, z_hat = theta0, ll0, z0
    checks = []  # what keeps the fit from counting as converged
    if not opt.success:
        checks.append(f"the optimizer stopped: {opt.message}")
    # a free coordinate past ±30: the parameter within e⁻³⁰ (relative) of a bound, or rounded onto it
    at_bound = [nm for nm, z, t, (kind, lo, hi) in zip(names, z_hat, theta, kinds)
                if kind != "id" and (abs(z) > 30.0 or t == lo or t == hi)]
    degenerate = bool(at_bound)
    if degenerate:
        near = {"lo": lambda z, lo, hi: lo, "hi": lambda z, lo, hi: hi, "logit": lambda z, lo, hi: lo if z < 0 else hi}
        where = ", ".join(f"{nm} = {t:.3g}, bound {near[kind](z, lo, hi):g}"
                          for nm, t, z, (kind, lo, hi) in zip(names, theta, z_hat, kinds) if nm in at_bound)
        checks.append(f"degenerate: the likelihood keeps rising toward a bound ({where}, log L = {ll_hat:.6g}): the "
                      "maximum is not inside the parameter space, and the likelihood may be unbounded there (e.g. a "
                      "variance going to 0); fix that parameter or bound it away")
    p = len(names)
    cov = np.full((p, p), np.nan)
    se_ok = False
    grad, Hm = _derivatives(lambda t: -loglik(t), theta, kinds, hessian=se and not degenerate)
    if Hm is not None:
        if np.all(np.isfinite(Hm)):
            w = np.linalg.eigvalsh(0.5 * (Hm + Hm.T))
            if w.min() > 0:
                cov = np.linalg.inv(Hm)
                cov = 0.5 * (cov + cov.T)
                se_ok = True
    notes = []  # what the message adds
    if getattr(first, "random", False):  # a likelihood estimate: its finite differences are noise
        notes.append("the gradient is not checked (a random likelihood estimate)")
    elif not degenerate:
        if not np.all(np.isfinite(grad)):
            checks.append("the log-likelihood is not finite next to the estimate: no gradient check")
        elif se_ok:
            gain = 0.5 * float(grad @ cov @ grad)  # what a Newton step would add to log L
            if not gain < 0.01:
                checks.append(f"the gradient is not small: a Newton step would raise log L by {gain:.3g}")
        else:
            gz = grad * np.array([tr.dnatural(z, i) for i, z in enumerate(z_hat)])
            if not np.max(np.abs(gz)) < 0.01:
                checks.append(f"the gradient is not small: |d log L / dz| = {np.max(np.abs(gz)):.3g}")
    if np.array_equal(theta, theta0) and (degenerate or getattr(first, "random", False) or any(
            c.startswith(("the gradient", "the log-likelihood is not finite next")) for c in checks)):
        # the start itself may be the optimum (a small gradient there says so); otherwise say it
        checks.append("no point better than the start was found")
    if "diverged" in why:  # the penalty made the optimizer back off from them
        notes.append("the filter diverged at some trial values (backed off)")
    if "refused" in why:
        notes.append(f"the model refused some trial values ({why['refused']}) (backed off)")
    if Hm is not None and not se_ok:
        notes.append("the observed information is not positive definite: no standard errors")
    converged = not checks
    message = "; ".join([str(opt.message)] if converged else checks) + "".join(f"; {n}" for n in notes)
    if bar is not None:
        bar.close()
    return FitResult(dict(zip(names, map(float, theta))), dict(zip(names, map(float, np.sqrt(np.diag(cov))))),
                     cov, float(ll_hat), converged, se_ok, message, int(opt.nfev), int(getattr(opt, "nit", 0)),
                     names, label, method, time.perf_counter() - t_start, model.with_params(dict(zip(names, theta))))


def _derivatives(f, theta, kinds, rel: float = 1e-4, hessian: bool = True):
    """Central-difference gradient and (``hessian``) Hessian of ``f`` at ``theta``: steps
    ``h_i = rel · max(|θ_i|, 1e-3)``, kept inside the bounds (a one-sided parameter near its
    bound gets a step of a tenth of the distance); NaN where a value is not finite. The gradient
    reuses the Hessian's diagonal evaluations."""
    p = len(theta)
    h = np.array([rel * max(abs(t), 1e-3) for t in theta])
    for i, (kind, lo, hi) in enumerate(kinds):
        if lo is not None:
            h[i] = min(h[i], 0.1 * (theta[i] - lo))
        if hi is not None:
            h[i] = min(h[i], 0.1 * (hi - theta[i]))
    f0 = f(theta)
    E = np.diag(h)
    fp = np.array([f(theta + E[i]) for i in range(p)])
    fm = np.array([f(theta - E[i]) for i in range(p)])
    with np.errstate(invalid="ignore", divide="ignore"):
        g = (fp - fm) / (2 * h)
        g[~np.isfinite(g)] = np.nan
    if not hessian:
        return g, None
    H = np.empty((p, p))
    for i in range(p):
        H[i, i] = (fp[i] - 2 * f0 + fm[i]) / h[i] ** 2
        for j in range(i):
            H[i, j] = H[j, i] = (f(theta + E[i] + E[j]) - f(theta + E[i] - E[j]) - f(theta - E[i] + E[j])
                                 + f(theta - E[i] - E[j])) / (4 * h[i] * h[j])
    return g, H


@dataclass(frozen=True)
class EMResult:
    """:func:`fit_em`'s estimate ``F, H, Q, R, m0, P0``, the log-likelihood at each iteration
    (``loglik``: non-decreasing, the EM property), ``converged`` (relative change below ``tol``),
    ``iterations``."""

    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    m0: np.ndarray
    P0: np.ndarray
    loglik: np.ndarray
    converged: bool
    iterations: int

    def model(self):
        """The fitted model (:meth:`~nlfilter.models.DiscreteModel.linear`)."""
        from .models import DiscreteModel
        return DiscreteModel.linear(self.F, self.H, self.Q, self.R)


def fit_em(ys, F, H, Q, R, m0, P0, *, estimate=("F", "H", "Q", "R"), iterations: int = 500, tol: float = 1e-9,
           progress: bool = False) -> EMResult:
    """EM for the linear-Gaussian model (Shumway & Stoffer 1982; Ghahramani & Hinton 1996).

    ``ys (..., T, m)`` independent records (no missing data: a NaN is refused), starting values
    ``F (n, n)``, ``H (m, n)``, ``Q``, ``R``, the prior ``m0``, ``P0``; ``estimate``: which of
    ``"F", "H", "Q", "R", "m0", "P0"`` to update (the others stay fixed). With the smoothed moments
    ``x̂_k = E[x_k|Y]``, ``P_k``, ``P_{k,k+1} = Cov[x_k, x_{k+1}|Y]`` (RTS with its lag-one
    covariances, :func:`~nlfilter.filters.smoothing.rts`) and
    ``S_ab = Σ E[x_a x_bᵀ | Y]`` summed over the steps and records::

        F = S_{k+1,k} S_{k,k}⁻¹,   Q = (S_{k+1,k+1} − F S_{k,k+1}) / N_w
        H = (Σ y_k x̂_kᵀ)(Σ E[x_k x_kᵀ])⁻¹,   R = Σ (y_k y_kᵀ − H x̂_k y_kᵀ) / N_y

    (the sums over k = 0..T-2 for the dynamics; Shumway & Stoffer eqs. 12-14). Stops when the
    relative change of the log-likelihood is below ``tol`` or after ``iterations``.
    """
    from .filters.kalman import KalmanFilter
    from .models import DiscreteModel

    ys = V.as_float_array("ys", ys, ndim_min=2)
    if np.isnan(ys).any():
        raise ValueError("ys: fit_em takes complete records (no NaN); use fit() for missing data")
    F, H, Q, R = (np.array(V.as_float_array(nm, a, ndim=2)) for nm, a in (("F", F), ("H", H), ("Q", Q), ("R", R)))
    m0 = np.array(V.as_float_array("m0", m0, ndim=1))
    diffuse_check(P0, estimate=estimate)  # a diffuse P0: no m0 or P0 to estimate
    P0 = np.array(V.as_float_array("P0", P0, ndim=2))
    est = set(estimate)
    unknown = est - {"F", "H", "Q", "R", "m0", "P0"}
    if unknown:
        raise ValueError(f"estimate: expected some of F, H, Q, R, m0, P0, got {sorted(unknown)}")
    Y = ys.reshape(-1, *ys.shape[-2:])
    B, T, m = Y.shape
    if T < 2 and est & {"F", "Q"}:
        raise ValueError(f"ys: fit_em estimates {sorted(est & {'F', 'Q'})} from the transitions between steps; "
                         f"expected at least 2 time steps, got T = {T}")
    hist, converged = [], False
    steps = range(V.positive("iterations", iterations, integer=True))
    if progress:
        from tqdm.auto import tqdm
        steps = tqdm(steps, desc="EM", leave=False)
    it = 0
    for it in steps:
        kf = KalmanFilter(DiscreteModel.linear(F, H, Q, R))
        ll = float(np.sum(kf.run(Y, m0, P0, loglik=True).loglik))
        hist.append(ll)
        if len(hist) > 1 and abs(hist[-1] - hist[-2]) <= tol * abs(hist[-1]):
            converged = True
            break
        sm = kf.smooth(Y, m0, P0)
        xs, Ps, C = sm.means, sm.covs, sm.extras["lag_one_cov"]  # C[:, k] = Cov[x_k, x_{k+1} | Y]
        Exx = Ps + xs[..., :, None] * xs[..., None, :]  # E[x_k x_kᵀ | Y]
        S00 = Exx[:, :-1].sum(axis=(0, 1))
        S11 = Exx[:, 1:].sum(axis=(0, 1))
        S01 = (C[:, :-1] + xs[:, :-1, :, None] * xs[:, 1:, None, :]).sum(axis=(0, 1))  # Σ E[x_k x_{k+1}ᵀ]
        if "F" in est:
            F = _solve_moments(S00, S01, "F").T  # S_{k+1,k} S_{k,k}⁻¹
        if "Q" in est:
            Qn = (S11 - F @ S01 - S01.T @ F.T + F @ S00 @ F.T) / (B * (T - 1))
            Q = 0.5 * (Qn + Qn.T)
        Sxx = Exx.sum(axis=(0, 1))
        Syx = np.einsum("bti,btj->ij", Y, xs)
        if "H" in est:
            H = _solve_moments(Sxx, Syx.T, "H").T
        if "R" in est:
            Syy = np.einsum("bti,btj->ij", Y, Y)
            Rn = (Syy - H @ Syx.T - Syx @ H.T + H @ Sxx @ H.T) / (B * T)
            R = 0.5 * (Rn + Rn.T)
        if "m0" in est:
            m0 = xs[:, 0].mean(axis=0)
        if "P0" in est:
            d = xs[:, 0] - m0
            P0 = Ps[:, 0].mean(axis=0) + np.einsum("bi,bj->ij", d, d) / B
    return EMResult(F, H, Q, R, m0, P0, np.array(hist), converged, it + 1)


def _solve_moments(S, rhs, what):
    """``S⁻¹ rhs`` of the M-step; a singular second-moment matrix (the smoothed states do not span
    the state space: too little data, or a state the data never inform) is a named error."""
    try:
        return np.linalg.solve(S, rhs)
    except np.linalg.LinAlgError:
        raise ValueError(f"ys: the smoothed second moments are singular, {what} is not identified by these data "
                         f"(too few steps or records, or a state the data never inform); fix {what} (estimate=)") from None
