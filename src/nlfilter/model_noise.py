"""A model's noise: Q and R given as numbers or as SymPy expressions in the parameters (R also in
the states: ``R(x, k)``), the laws that simulate w and v, correlated noise (``cross_noise``) and a
time-varying Q carried by G (:mod:`nlfilter.models`, "Structure"); bound to one set of parameter
values with the model's functions."""

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


def noise_covariances(model, Q, R, process_noise, measurement_noise) -> None:
    """Read ``Q`` (r x r) and ``R`` (mv x mv) into ``model``: numbers (checked covariances, with
    their laws ``process_noise``, ``measurement_noise``, Gaussian by default, whose covariance
    must agree), or SymPy matrices in the parameters, R also in the states and the time (kernels
    evaluated at each parameter value by :func:`bind_noise`)."""
    model._given_laws = (process_noise, measurement_noise)
    # Q and R: numbers, checked once as before, or SymPy matrices in the parameters
    model._QR = {}
    for nm, val, dim in (("Q", Q, model.r), ("R", R, model.mv)):
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
    if "Q" not in model._QR:
        model._Q0 = V.covariance("Q", np.eye(model.r) if Q is None and process_noise is None
                                else (process_noise.cov if Q is None else Q), model.r)
    if "R" not in model._QR:
        if R is None and measurement_noise is None:
            raise ValueError("R: expected the measurement noise covariance (m x m), got None")
        model._R0 = V.covariance("R", measurement_noise.cov if R is None else R, model.mv)
        model._R_law = as_law("measurement_noise", measurement_noise, model._R0)
    if "Q" not in model._QR:
        model._Q_law = as_law("process_noise", process_noise, model._Q0)
    for nm, key in (("process_noise", "Q"), ("measurement_noise", "R")):
        if key in model._QR:
            continue
        law, cov = getattr(model, f"_{key}_law"), getattr(model, f"_{key}0")
        if law.cov.shape != cov.shape or not np.allclose(law.cov, cov, rtol=1e-8, atol=1e-12):
            raise ValueError(f"{nm}: its covariance {law.cov.tolist()} differs from the given "
                             f"{key} {cov.tolist()}")
    if model.meas_noise_symbols and "R" in model._QR and model._QR["R"].varies:
        raise ValueError("R: a state-dependent R with non-additive measurement noise (meas_noise=) is not "
                         "supported; state the dependence in h(x, v)")


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
    of the functions and covariances that vary with time there): R one matrix or ``R(x)``
    (:func:`R_at`); a time-varying Q folded into G (``G Q_t^{1/2}``, ``model.Q`` the identity);
    the joint law of correlated noise, checked positive semi-definite; the Gaussian laws of Q and R
    built when first read (:class:`LazyGaussian`)."""
    model.R_constant = True
    if "R" in model._QR:
        if "R" in tv:
            raise ValueError(f"R: depends on time-varying parameter(s) {sorted(map(str, model._uses['R'] & values.arrays))}; "
                             "a time-varying R is not supported (filters read model.R as one matrix)")
        if model._QR["R"].varies:  # R(x, k): a function of the state (and time), R_of
            model.R_constant = False
            model._R, model._measurement_noise = None, None
            model._R_fn = Batched(model._QR["R"], values)
        else:
            model.R = covariance_at(model, "R", model.mv, values)
            model.measurement_noise = LazyGaussian
    else:
        model.R, model.measurement_noise = model._R0, model._R_law
    model._fold = "Q" in tv
    if model._fold and (model.cross_noise is not None or not model.additive):
        raise ValueError("Q: a time-varying Q with correlated (cross_noise) or non-additive noise is not supported")
    if model._fold:  # Q_t = L_t L_tᵀ moved into G: the filters see Q = I and the same G Q Gᵀ
        per = max((values.values[p].ndim - 1 for p in model._uses["Q"] & values.per_path), default=0)
        Qfn = Batched(model._QR["Q"], values)
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
            raise ValueError("cross_noise: correlated noise with a state-dependent R is not supported")
        J = np.block([[model.Q, model.cross_noise], [model.cross_noise.T, model.R]])
        low = np.linalg.eigvalsh(J)[0]
        if low < -1e-12 * max(1.0, np.abs(J).max()):
            raise ValueError(f"cross_noise: the joint covariance [[Q, S], [Sᵀ, R]] of (w, v) is not positive "
                             f"semi-definite (smallest eigenvalue {low:.3g}); got S = {model.cross_noise.tolist()}")
        model._joint_noise = Gaussian(J)


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
