"""A model's noise: Q and R given as numbers or as SymPy expressions in the parameters (R also in
the states: ``R(x, k)``), the laws that simulate w and v, correlated noise (``cross_noise``) and a
time-varying Q carried by G (:mod:`nlfilter.models`, "Structure"); bound to one set of parameter
values with the model's functions.

Noise given per step (a :class:`~nlfilter.models.DiscreteModel`; dynamax's emission covariance
per step): ``R`` an array ``(T, m, m)`` shared by the paths or ``(B, T, m, m)`` per path, ``Q``
``(T, r, r)`` or ``(B, T, r, r)`` — in the constructor or ``model.with_params(R=, Q=)`` — or
``R``/``Q`` written with parameters given as arrays over time (``R=[[r]]``,
``with_params(r=r_k)``). Then ``w_k ~ N(0, Q_k)`` drives ``x_{k+1} = f(x_k) + G w_k`` and
``v_k ~ N(0, R_k)`` corrupts ``y_k = h(x_k) + v_k``: entry ``k`` at step ``k``. ``Q_k`` is
carried by G (``G Q_k^{1/2}``, as a time-varying Q already was); ``R_k`` is read by
:meth:`~nlfilter.models.Model.R_of` (the model's structure ``"time-varying R"``), which every
filter that takes a state-dependent R reads at each step (the Gaussian filters at the predicted
mean, the grid and particle filters at their points), as does the Kalman filter (seed 000 eqs.
1.33-1.36 with ``R_k``, ``Q_k``); the others refuse it by name. Each step's covariance is checked
(finite, symmetric positive semi-definite; the first step that is not is named) when given, and
against the data (at least as many steps, one row per path) when run or simulated
(:func:`check_horizon`).

>>> import numpy as np, sympy as sp
>>> from nlfilter import DiscreteModel
>>> x = sp.Symbol("x")
>>> m = DiscreteModel([x], [0.9 * x], [x], Q=1.0, R=np.array([[[1.0]], [[2.0]], [[4.0]]]))
>>> sorted(m.structure), m.R_of(np.zeros((2, 1)), 2)[:, 0, 0].tolist()
(['time-varying R'], [4.0, 4.0])
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from . import _validate as V
from .model_expressions import check_expressions, is_symbolic, matrix
from .model_functions import Batched, Folded, Kernel
from .model_values import Values
from .noise import Gaussian, as_law

STATE_R = ("model.R: this model's measurement noise covariance depends on the state (R(x)), so it has no "
           "single matrix R; a filter that needs one (off-line gains, QLF/MQLF, moment filters, the Kalman "
           "filter, continuous-time filters) cannot take it. Use a Gaussian filter (EKF, UKF, CKF, GHKF, "
           "second-order: R at the predicted mean), GridFilter or ParticleFilter (R(x) exactly); "
           "model.R_of(x, k) evaluates it")
STEP_R = ("model.R: this model's measurement noise covariance varies over the steps (R given per step, or "
          "written with parameters given per step), so it has no single matrix R; a filter that needs one "
          "(off-line gains, QLF/MQLF, moment filters, continuous-time filters) cannot take it. The Kalman "
          "filter, the Gaussian filters (EKF, UKF, CKF, GHKF, second-order), GridFilter and ParticleFilter "
          "read R_k at each step; model.R_of(x, k) evaluates it")


def step_covariances(name: str, value, dim: int) -> np.ndarray:
    """A covariance given per step, checked: ``(T, d, d)`` shared by the paths or ``(B, T, d, d)``
    per path, ``d = dim``, finite, and at every step symmetric positive semi-definite (the first
    step, and path, that is not is named). Read-only."""
    arr = V.as_float_array(name, value)
    if arr.ndim not in (3, 4) or arr.shape[-2:] != (dim, dim) or arr.shape[-3] == 0:
        raise ValueError(f"{name}: expected one ({dim}, {dim}) covariance per step, an array of shape (T, {dim}, "
                         f"{dim}) shared by the paths or (B, T, {dim}, {dim}) per path, T >= 1; got shape {arr.shape}")
    full = arr.reshape(-1, *arr.shape[-3:])  # (B or 1, T, d, d)
    where = lambda b, k: f"step k = {k}" + (f" of path {b}" if arr.ndim == 4 else "")  # noqa: E731
    nan = ~np.isfinite(full).all(axis=(-1, -2))
    if nan.any():
        b, k = np.argwhere(nan)[0]
        raise ValueError(f"{name}: expected finite values, got a non-finite entry at {where(b, k)}: {full[b, k].tolist()}")
    scale = np.maximum(1.0, np.abs(full).max(axis=(-1, -2)))
    asym = np.abs(full - np.swapaxes(full, -1, -2)).max(axis=(-1, -2)) > 1e-10 * scale
    low = np.linalg.eigvalsh(0.5 * (full + np.swapaxes(full, -1, -2)))[..., 0]
    bad = asym | (low < -1e-10 * scale)
    if bad.any():
        b, k = np.argwhere(bad)[0]
        what = "symmetric" if asym[b, k] else f"positive semi-definite (smallest eigenvalue {low[b, k]:.3g})"
        raise ValueError(f"{name}: expected a symmetric positive semi-definite covariance at every step; at "
                         f"{where(b, k)} it is not {what}: {full[b, k].tolist()}")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


class StepCovariance:
    """A covariance given per step (:func:`step_covariances`) as a function of a state batch
    ``(..., n)`` and the step ``k``, like :class:`~nlfilter.model_functions.Batched`: entry ``k``
    (``values.index``: the step itself), broadcast over the batch; a per-path array ``(B, T, d, d)``
    needs the batch's leading axis to be the ``B`` paths."""

    def __init__(self, name: str, value: np.ndarray, values: Values):
        self.name, self.value, self.values = name, value, values
        self.per_path = value.ndim - 3  # 0 or 1 leading path axis

    def __call__(self, x, t=0.0):
        batch = np.shape(x)[:-1]
        k = self.values.index(self.name, t, self.value.shape[-3])
        d = self.value.shape[-2:]
        if not self.per_path:
            return np.broadcast_to(self.value[k], (*batch, *d))
        B = self.value.shape[0]
        if tuple(batch[:1]) != (B,):
            raise ValueError(f"{self.name}: a per-path array of shape {self.value.shape} needs states whose leading axis "
                             f"is the {B} paths, got a state batch {tuple(batch)} (not a grid filter's points, nor "
                             "Filter.run(chunk=...)); give a (T, d, d) array shared by all paths instead")
        return np.broadcast_to(self.value[:, k].reshape(B, *(1,) * (len(batch) - 1), *d), (*batch, *d))


def check_horizon(model, T: int, B: int, offset: int = 0) -> None:
    """Refuse, naming it, a per-step ``Q``/``R`` array of ``model`` too short for ``T`` steps read
    from step ``offset`` (a filter started by a prediction reads one step further; ``Q`` needs one
    entry fewer than ``R``: the last step predicts nothing), or a per-path one whose rows are not
    the ``B`` paths."""
    for nm, arr in getattr(model, "_steps", {}).items():
        need = T + offset - (nm == "Q")  # R_k at k = offset..T-1+offset; Q_j drives x_{j+1}: j < T-1+offset
        if arr.shape[-3] < need:
            raise ValueError(f"{nm}: given for {arr.shape[-3]} step(s) (shape {arr.shape}); the data have {T} "
                             f"step(s){' read from step 1' if offset else ''}: expected at least {need} "
                             "(one covariance per step)")
        if arr.ndim == 4 and arr.shape[0] != B:
            raise ValueError(f"{nm}: a per-path array of shape {arr.shape} for {B} path(s); expected {B} rows "
                             "(one per path of the data; all paths at once, not Filter.run(chunk=...)) or a "
                             "(T, d, d) array shared by the paths")


def noise_covariances(model, Q, R, process_noise, measurement_noise) -> None:
    """Read ``Q`` (r x r) and ``R`` (mv x mv) into ``model``: numbers (checked covariances, with
    their laws ``process_noise``, ``measurement_noise``, Gaussian by default, whose covariance
    must agree), or SymPy matrices in the parameters, R also in the states and the time (kernels
    evaluated at each parameter value by :func:`bind_noise`)."""
    model._given_laws = (process_noise, measurement_noise)
    # Q and R: numbers, checked once as before, or SymPy matrices in the parameters, or one
    # numeric covariance per step (T, d, d) / (B, T, d, d)
    model._QR, model._steps, model._R_states = {}, {}, False
    for nm, val, dim in (("Q", Q, model.r), ("R", R, model.mv)):
        if not is_symbolic(val) and val is not None and np.ndim(val) >= 3:
            model._steps[nm] = step_covariances(nm, val, dim)
            continue
        if not is_symbolic(val):
            continue
        M = matrix(nm, [[val]] if isinstance(val, sp.Basic) and not isinstance(val, sp.MatrixBase) else val,
                    dim, dim)
        check_expressions(nm, M, True)
        # R may depend on the state (and the time): R(x, k), evaluated by R_of
        ok = set(model._psyms) | (set(model.states) | ({model.time} if model.time is not None else set()) if nm == "R" else set())
        extra = M.free_symbols - ok
        if extra:
            raise ValueError(f"{nm}: uses symbol(s) {sorted(map(str, extra))} that are not given in params"
                             + (" (nor states or the time symbol)" if nm == "R" else ""))
        if model._given_laws[nm == "R"] is not None:
            raise ValueError(f"{'process_noise' if nm == 'Q' else 'measurement_noise'}: a noise law cannot "
                             f"be given with a {nm} that depends on parameters or states; drop the law (Gaussian)")
        if nm == "R" and any(sp.simplify(M[i, j] - M[j, i]) != 0 for i in range(dim) for j in range(i)):
            raise ValueError(f"{nm}: expected a symmetric matrix, got {M.tolist()}")
        model._QR[nm] = Kernel(list(M), model.states, model.time if nm == "R" else None, (dim, dim), model._psyms)
        if nm == "R":
            model._R_states = bool(M.free_symbols & set(model.states))
    if model._steps:
        per_step_noise(model, process_noise, measurement_noise)
    if "Q" not in model._QR and "Q" not in model._steps:
        model._Q0 = V.covariance("Q", np.eye(model.r) if Q is None and process_noise is None
                                else (process_noise.cov if Q is None else Q), model.r)
    if "R" not in model._QR and "R" not in model._steps:
        if R is None and measurement_noise is None:
            raise ValueError("R: expected the measurement noise covariance (m x m), got None")
        model._R0 = V.covariance("R", measurement_noise.cov if R is None else R, model.mv)
        model._R_law = as_law("measurement_noise", measurement_noise, model._R0)
    if "Q" not in model._QR and "Q" not in model._steps:
        model._Q_law = as_law("process_noise", process_noise, model._Q0)
    for nm, key in (("process_noise", "Q"), ("measurement_noise", "R")):
        if key in model._QR or key in model._steps:
            continue
        law, cov = getattr(model, f"_{key}_law"), getattr(model, f"_{key}0")
        if law.cov.shape != cov.shape or not np.allclose(law.cov, cov, rtol=1e-8, atol=1e-12):
            raise ValueError(f"{nm}: its covariance {law.cov.tolist()} differs from the given "
                             f"{key} {cov.tolist()}")
    if model.meas_noise_symbols and "R" in model._QR and model._QR["R"].varies:
        raise ValueError("R: a state-dependent R with non-additive measurement noise (meas_noise=) is not "
                         "supported; state the dependence in h(x, v)")


def per_step_noise(model, process_noise=None, measurement_noise=None) -> None:
    """Refuse what a per-step ``Q``/``R`` array (``model._steps``) cannot go with: a noise law (the
    noise is Gaussian with the step's covariance), a continuous-time model, a state-dependent R's
    non-additive measurement noise."""
    for nm, law, key in (("process_noise", process_noise, "Q"), ("measurement_noise", measurement_noise, "R")):
        if key in model._steps and law is not None:
            raise ValueError(f"{nm}: a noise law cannot be given with a {key} given per step (the noise is Gaussian "
                             f"with the step's covariance); drop the law")
    if model.kind != "discrete":
        raise ValueError(f"{'/'.join(sorted(model._steps))}: one covariance per step is supported for DiscreteModel "
                         f"only; an {type(model).__name__} takes a constant one (or a Q in parameters given as "
                         "arrays over its time grid)")
    if "R" in model._steps and model.meas_noise_symbols:
        raise ValueError("R: a per-step R with non-additive measurement noise (meas_noise=) is not supported")
    if "Q" in model._steps and not model.additive:
        raise ValueError("Q: a per-step Q with non-additive process noise (noise=) is not supported")


def new_noise(model, R, Q) -> None:
    """Replace the numeric ``R``/``Q`` of ``model`` (a copy: :meth:`~nlfilter.models.Model.with_params`)
    by one matrix or one per step (:func:`step_covariances`); an R or Q written in parameters is
    refused (their values are given instead), as is a non-Gaussian noise law."""
    model._steps = dict(model._steps)
    for nm, val, dim, law in (("R", R, model.mv, "measurement_noise"), ("Q", Q, model.r, "process_noise")):
        if val is None:
            continue
        if nm in model._QR:
            raise ValueError(f"{nm}: this model's {nm} is written in its parameters "
                             f"{sorted(map(str, model._QR[nm].params))}; give their values (arrays over time for "
                             f"one {nm} per step) instead of a new {nm}")
        if model._given_laws[nm == "R"] is not None and not isinstance(model._given_laws[nm == "R"], Gaussian):
            raise ValueError(f"{nm}: the model's {law} is a {type(model._given_laws[nm == 'R']).__name__} law with "
                             f"its own covariance; a new {nm} replaces Gaussian noise only")
        if np.ndim(val) >= 3:
            model._steps[nm] = step_covariances(nm, val, dim)
        else:
            C = V.covariance(nm, val, dim)
            model._steps.pop(nm, None)
            setattr(model, f"_{nm}0", C)
            setattr(model, f"_{nm}_law", Gaussian(C))
    if model._steps:
        per_step_noise(model)


def cross_noise_matrix(model, cross_noise):
    """``E[w_k v_kᵀ] = S`` (r x m) checked (Anderson & Moore 1979 §5.5): constant G, additive noises
    drawn jointly Gaussian; ``None`` when not given. Read-only."""
    if cross_noise is None:
        return None
    if not (model.additive and model.additive_measurement):
        raise ValueError("cross_noise: correlated noise with non-additive noise (noise=, meas_noise=) is not "
                         "supported")
    if not model.G_constant:
        raise ValueError("cross_noise: correlated process and measurement noise needs a G that does not "
                         "depend on the state")
    if any(law is not None and not isinstance(law, Gaussian) for law in model._given_laws):
        raise ValueError("cross_noise: correlated noise is drawn jointly Gaussian; expected no (or Gaussian) "
                         "process_noise and measurement_noise laws")
    Sc = V.as_float_array("cross_noise", cross_noise, ndim=2)
    if Sc.shape != (model.r, model.m):
        raise ValueError(f"cross_noise: expected E[w vᵀ] of shape (r, m) = ({model.r}, {model.m}), got {Sc.shape}")
    V.finite("cross_noise", Sc)
    Sc = Sc.copy()
    Sc.setflags(write=False)
    return Sc


class LazyGaussian:
    """The marker of a noise law not built yet: the Gaussian of the model's covariance (Q or R),
    built by the model when first read (:attr:`~nlfilter.models.Model.process_noise`,
    :attr:`~nlfilter.models.Model.measurement_noise`), so that a :meth:`~nlfilter.models.Model.with_params`
    copy — each evaluation of :func:`nlfilter.fit` — pays no factorization it does not use. A class
    (not an instance): it pickles by reference, the marker stays itself in another process."""


def bind_noise(model, values: Values, tv: set) -> None:
    """Q, R and the noise laws of ``model`` at the parameter values ``values`` (``tv``: the names
    of the functions and covariances that vary with time there): R one matrix, ``R(x)`` or ``R_k``
    (:func:`R_at`); a time-varying Q folded into G (``G Q_t^{1/2}``, ``model.Q`` the identity);
    the joint law of correlated noise, checked positive semi-definite; the Gaussian laws of Q and R
    built when first read (:class:`LazyGaussian`).

    ``R`` varies over the steps (``model._R_kind = "time"``) when it is given per step
    (``model._steps``, :class:`StepCovariance`) or written with the time symbol or with
    parameters given as arrays over time, and not in the states (then ``"state"``): either way the
    filters read it by ``R_of(x, k)``. Per-step values from parameter arrays are checked at every
    step here (:func:`check_param_steps`)."""
    model.R_constant, model._R_kind = True, None
    steps = getattr(model, "_steps", {})
    if "R" in steps:
        model.R_constant, model._R_kind = False, "time"
        model._R, model._measurement_noise = None, None
        model._R_fn = StepCovariance("R", steps["R"], values)
    elif "R" in model._QR:
        if "R" in tv and model.kind != "discrete":
            raise ValueError(f"R: depends on time-varying parameter(s) {sorted(map(str, model._uses['R'] & values.arrays))}; "
                             "a time-varying R is supported for DiscreteModel only (an SDEModel's filters read model.R "
                             "as one matrix)")
        if model._QR["R"].varies or "R" in tv:  # R(x, k) or R_k: a function of the state (and time), R_of
            model.R_constant = False
            model._R_kind = "state" if model._R_states else "time"
            model._R, model._measurement_noise = None, None
            model._R_fn = Batched(model._QR["R"], values)
            if "R" in tv:
                check_param_steps(model, "R", model._R_fn, values)
        else:
            model.R = covariance_at(model, "R", model.mv, values)
            model.measurement_noise = LazyGaussian
    else:
        model.R, model.measurement_noise = model._R0, model._R_law
    model._fold, model._per_path_Q = "Q" in tv or "Q" in steps, False
    if model._fold and (model.cross_noise is not None or not model.additive):
        raise ValueError("Q: a time-varying Q with correlated (cross_noise) or non-additive noise is not supported")
    if model._fold:  # Q_t = L_t L_tᵀ moved into G: the filters see Q = I and the same G Q Gᵀ
        if "Q" in steps:
            Qfn = StepCovariance("Q", steps["Q"], values)
            per = Qfn.per_path
        else:
            per = max((values.values[p].ndim - 1 for p in model._uses["Q"] & values.per_path), default=0)
            Qfn = Batched(model._QR["Q"], values)
            check_param_steps(model, "Q", Qfn, values)
        model._per_path_Q = per > 0
        for key in ("G", "G_x", "G_xx"):
            setattr(model, key, Folded(getattr(model, key), Qfn, per))
        model.Q = np.eye(model.r)
        model.process_noise = LazyGaussian
    elif "Q" in model._QR:
        model.Q = covariance_at(model, "Q", model.r, values)
        model.process_noise = LazyGaussian
    else:
        model.Q, model.process_noise = model._Q0, model._Q_law
    if model.cross_noise is not None:
        if not model.R_constant:
            raise ValueError("cross_noise: correlated noise with a state-dependent R (or an R per step) is not supported")
        J = np.block([[model.Q, model.cross_noise], [model.cross_noise.T, model.R]])
        low = np.linalg.eigvalsh(J)[0]
        if low < -1e-12 * max(1.0, np.abs(J).max()):
            raise ValueError(f"cross_noise: the joint covariance [[Q, S], [Sᵀ, R]] of (w, v) is not positive "
                             f"semi-definite (smallest eigenvalue {low:.3g}); got S = {model.cross_noise.tolist()}")
        model._joint_noise = Gaussian(J)


def check_param_steps(model, nm: str, fn, values: Values) -> None:
    """``Q`` or ``R`` written with parameters given as arrays over time (discrete models), checked
    at every step of those arrays (and every path of per-path ones): a ValueError names the first
    step that is not a symmetric positive semi-definite covariance, with the parameter values there."""
    if model.kind != "discrete":
        return
    used = model._uses[nm] & values.arrays
    if not used:
        return
    T = min(values.values[p].shape[-1] for p in used)
    lead = max((values.values[p].shape[:-1] for p in used), key=len)
    C = np.stack([fn(np.zeros((*lead, model.n)), k) for k in range(T)], axis=len(lead))  # (*lead, T, d, d)
    try:
        step_covariances(nm, C.reshape(-1, *C.shape[len(lead):]) if lead else C, C.shape[-1])
    except ValueError as exc:
        raise ValueError(f"{exc} (from the parameter array(s) {sorted(map(str, used))})") from None


def covariance_at(model, nm, dim, values: Values) -> np.ndarray:
    """The covariance ``nm`` ("Q" or "R") of ``model`` given as SymPy, at the values ``values``."""
    C = Batched(model._QR[nm], values)(np.zeros(model.n))
    try:
        return V.covariance(nm, C, dim)
    except ValueError as exc:
        used = {str(p): values.values[p] for p in model._QR[nm].params}
        raise ValueError(f"{exc} (at parameter values {used})") from None


def R_at(model, x, t=0.0) -> np.ndarray:
    """``R(x, t) (..., m, m)`` of ``model`` at the states ``x (..., n)``
    (:meth:`~nlfilter.models.Model.R_of`)."""
    x = np.asarray(x, dtype=float)
    if model.R_constant:
        return np.broadcast_to(model._R, (*x.shape[:-1], *model._R.shape))
    R = model._R_fn(x, t)
    if isinstance(model._R_fn, StepCovariance):  # R_k given per step: checked at every step when given
        return R
    if model.m == 1:
        bad = ~(R[..., 0, 0] > 0)
    else:
        bad = ~np.all(np.linalg.eigvalsh(np.where(np.isfinite(R), R, 0.0)) > 0, axis=-1) | \
            ~np.all(np.isfinite(R), axis=(-1, -2))
    if bad.any():
        idx = np.argwhere(bad)[0]
        raise ValueError(f"R: the state-dependent measurement noise covariance is not positive definite at "
                         f"state x = {x[tuple(idx)].tolist()} ({model.time_name} = {t!r}): R = "
                         f"{R[tuple(idx)].tolist()}; expected R(x) positive definite wherever it is evaluated")
    return R
