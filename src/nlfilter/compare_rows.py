"""The rows, notes and figure of a comparison (:func:`nlfilter.comparison.compare`) from the
filters' estimates on the shared simulation.

Honest rows for diverging filters. A filter's MSE, its paired gap to the reference and its NEES
are means over the paths on which it did not diverge. When it diverged on many paths, those
survivors are a sample selected by the filter's own success — the paths on which it happened to
do well —, and the paired gap over them is biased by that selection, by more than its standard
error can say: a filter that diverged on 58 of 60 paths of a fast SDE came out "0.0002 ± 0.00002
below the optimum" from its 2 survivors. So a filter that diverged on some path and whose surviving paths are
fewer than :data:`MIN_SURVIVORS` or than :data:`MIN_SURVIVING_FRACTION` of the paths gets no ``mse``,
``gap_*``, ``nees`` or ``offline_mse`` row (nor a line in the figure): its ``divergence_rate``
row and a note say how often it diverged; above that, a note says that its numbers are over its
surviving paths only.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import DivergenceError
from .evaluate import _window, mse, mse_per_step, nees, paired_difference
from .yardstick import OPTIMAL

MIN_SURVIVORS = 10
"""The fewest surviving paths a filter's MSE, gap and NEES rows are reported from: the standard
error of a mean over n paths is itself uncertain by about 1/√(2(n − 1)) of it (24 % at n = 10), and
below ten paths a "± s.e." claims a precision it does not have."""

MIN_SURVIVING_FRACTION = 0.5
"""The smallest share of the paths that must survive for a filter's rows to be reported: when
most paths diverged, the survivors are a minority selected by the filter's own success, and a
paired gap over them measures that selection rather than the filter (module docstring)."""


def enough_paths(e, paths: int) -> bool:
    """Whether the estimates ``e`` survived on enough of the ``paths`` paths to be reported: on
    all of them (nothing selected them), or on at least :data:`MIN_SURVIVORS` and at least
    :data:`MIN_SURVIVING_FRACTION` of them."""
    ok = int(np.sum(~np.asarray(e.diverged, bool)))
    return ok == paths or (ok >= MIN_SURVIVORS and ok >= MIN_SURVIVING_FRACTION * paths)


def _divergence_note(name, e, paths) -> str | None:
    """The note of a filter that diverged on some paths (None if on none)."""
    div = np.asarray(e.diverged, bool)
    k = int(div.sum())
    if k == 0:
        return None
    first = int(np.min(np.asarray(e.diverged_step)[div]))
    if not enough_paths(e, paths):
        return (f"{name}: diverged on {k} of {paths} paths (first at step {first}): no MSE, gap or NEES — "
                f"{paths - k} surviving path(s) are fewer than {MIN_SURVIVORS} or than "
                f"{MIN_SURVIVING_FRACTION:.0%} of the paths, and numbers over them would be biased by their "
                "selection (nlfilter.compare_rows)")
    return (f"{name}: diverged on {k} of {paths} paths (first at step {first}): its MSE, gap and NEES are over "
            f"its {paths - k} surviving paths only")


def filter_rows(res, est, every, sim, *, n, steps, paths, window, cert, ref_name, gap, angles=()):
    """The rows of every filter and of the reference (``est``: name -> Estimates; ``every``: name
    -> filter instance or None) — per component ``mse`` and ``gap`` (paired with the reference,
    its s.e. and the reference's error in quadrature), ``nees`` (posterior covariances) or
    ``offline_mse`` (off-line gains), ``divergence_rate`` — and the divergence notes."""
    for name, e in est.items():
        note = _divergence_note(name, e, paths)
        if note is not None:
            res.notes.append(note)
        if not enough_paths(e, paths):
            res.add(name, "divergence_rate", float(np.mean(e.diverged)))
            continue
        judged = cert is not None and name != ref_name and enough_paths(est[ref_name], paths)
        for i in range(n):
            s_ = mse(e, sim.xs, component=i, window=window, angles=angles)
            res.add(name, "mse", s_.value, s_.stderr, component=i)
            if judged and np.any(~(np.asarray(e.diverged, bool) | np.asarray(est[ref_name].diverged, bool))):
                d = paired_difference(e, est[ref_name], sim.xs, component=i, window=window, angles=angles)
                res.add(name, gap, d.value, math.hypot(d.stderr, cert.reference_error(i)), component=i)
        flt = every.get(name)
        covariance = getattr(flt, "covariance", "posterior") if flt is not None else "posterior"
        ok = ~np.asarray(e.diverged, bool)
        if covariance == "posterior" and ok.any() and np.all(np.isfinite(e.covs[ok])):
            try:
                s_ = nees(e, sim.xs, window=window, label=name, angles=angles)
                res.add(name, "nees", s_.value, s_.stderr)
            except ValueError as exc:
                res.notes.append(f"nees of {name} not computed: {exc}")
        elif covariance == "off-line" and ok.any():
            w = _window(steps, window)
            for i in range(n):
                v = np.diagonal(e.covs[ok][..., w, :, :], axis1=-2, axis2=-1)[..., i]
                if np.all(np.isfinite(v)):
                    res.add(name, "offline_mse", float(np.mean(v)), component=i)
        res.add(name, "divergence_rate", float(np.mean(e.diverged)))


def mse_series(res, est, sim, comps, *, paths, kind, angles=()):
    """One figure panel per component: MSE per step of every reported filter, ± 2 s.e. bands."""
    for i, c in enumerate(comps):
        lines, bands = {}, {}
        for name, e in est.items():
            if not enough_paths(e, paths):
                continue  # nothing to draw honestly: most paths diverged (module docstring)
            lines[name], se = mse_per_step(e, sim.xs, component=i, angles=angles)
            bands[name] = (lines[name] - 2 * se, lines[name] + 2 * se)
        res.series[f"MSE of {c} per step ({paths} paths)"] = {
            "x": sim.t, "lines": lines, "bands": bands, "ylabel": f"E ({c} − {c}̂)²",
            "xlabel": "t" if kind == "sde" else "step k"}


def certificate_note(cert) -> str:
    """One line: what the reference is and how far from converged."""
    size = "×".join(map(str, cert.size)) + " grid" if cert.kind == "grid" else (
        f"{cert.size} particles" if cert.kind == "particle" else cert.kind)
    if cert.certified is None:
        return f"reference: {size}, given by the caller (not checked)"
    err = ", ".join(f"{d:+.2g} ± {se:.2g}" for d, se in cert.error)
    verdict = "certified" if cert.certified else "NOT converged"
    tol = ", ".join(f"{t:.2g}" for t in (cert.rungs[-1].get("tolerance", []) if cert.rungs else []))
    return (f"reference: {size}, {verdict}: a finer reference on {cert.paths} paths changed its MSE by {err} "
            f"(tolerance {tol or '?'}: rtol = {cert.rtol:g} of its MSE or the gaps' smallest s.e.; "
            f"{len(cert.rungs)} rung(s), {cert.seconds:.1f} s)")


def smoothers(filters, est, failed, ref_name, ref_flt, cert, sim, run, on_divergence):
    """``(name -> smoothed Estimates, params["smoothing"])``: every filter with a smoother (its
    forward pass on its own stream, as its run), then the reference's smoother (the reference's
    stream: its forward pass is the reference's run)."""
    sm, info = {}, {"no_smoother": {}, "failed": {}}
    for name, flt in filters.items():
        if name in failed or name not in est:
            continue
        if getattr(flt, "smoother", None) is None or not callable(getattr(flt, "smooth", None)):
            info["no_smoother"][name] = type(flt).__name__
            continue
        try:
            sm[name] = run(name, flt, sim.ys, smooth=True)
        except (np.linalg.LinAlgError, FloatingPointError, OverflowError, ValueError) as exc:
            if on_divergence == "raise" or isinstance(exc, DivergenceError):
                raise
            info["failed"][name] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    if ref_name is not None:
        kind = getattr(ref_flt, "smoother", None)
        info["reference"] = {"label": ref_name, "smoother": kind,
                             "certificate": "the reference filter's (the smoother reuses its resolution; "
                                            "not certified separately)"}
        if kind is None:
            info["reference"]["reason"] = (f"{type(ref_flt).__name__} has no smoother"
                                           + (" on an SDE with substeps > 1" if getattr(ref_flt, "substeps", 1) != 1
                                              and getattr(ref_flt, "time", "") == "continuous" else ""))
        else:  # the reference's stream (key "optimal"): its forward pass is the reference's run
            try:
                sm[ref_name] = run(OPTIMAL, ref_flt, sim.ys, key=OPTIMAL, smooth=True)
            except (np.linalg.LinAlgError, FloatingPointError, OverflowError, ValueError) as exc:
                if on_divergence == "raise" or isinstance(exc, DivergenceError):
                    raise
                info["reference"]["smoother"] = None
                info["reference"]["reason"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    for k in ("no_smoother", "failed"):
        if not info[k]:
            del info[k]
    return sm, info


def smoothed_rows(res, sm, ref_name, cert, sim, n, window, angles=()):
    """``smoothed_mse`` per smoother and component; ``smoothed_gap_to_optimal`` (or ``_to_reference``)
    against the reference smoother on the same paths, ± the paired s.e. and the reference's error."""
    ref = sm.get(ref_name)
    gap = "smoothed_gap_to_optimal" if cert is None or cert.label == OPTIMAL else "smoothed_gap_to_reference"
    paths = sim.xs.shape[0]
    for name, e in sm.items():
        ok = ~np.asarray(e.diverged, bool)
        if not enough_paths(e, paths):
            continue  # as the filters' rows (module docstring)
        for i in range(n):
            s_ = mse(e, sim.xs, component=i, window=window, angles=angles)
            res.add(name, "smoothed_mse", s_.value, s_.stderr, component=i)
            if (ref is not None and name != ref_name and enough_paths(ref, paths)
                    and np.any(ok & ~np.asarray(ref.diverged, bool))):
                d = paired_difference(e, ref, sim.xs, component=i, window=window, angles=angles)
                res.add(name, gap, d.value, math.hypot(d.stderr, cert.reference_error(i)), component=i)


def smoothing_note(info) -> str:
    """One line: which smoothers ran, and what the reference smoother is."""
    parts = []
    ref = info.get("reference")
    if ref is not None:
        parts.append(f"reference smoother: {ref['smoother']} on the {ref['label']} reference's resolution (its "
                     "certificate is the filter's)" if ref["smoother"] else
                     f"no reference smoother ({ref['reason']}): no smoothed gaps")
    if info.get("no_smoother"):
        parts.append("no smoother: " + ", ".join(info["no_smoother"]))
    if info.get("failed"):
        parts.append("smoother failed: " + "; ".join(f"{k}: {v}" for k, v in info["failed"].items()))
    return "smoothing: " + "; ".join(parts) if parts else "smoothing: every filter smoothed"


def uninformed_note(est: dict, names) -> str | None:
    """A note naming the filters of ``names`` whose estimates are the same on every path (on the
    paths where they did not diverge), or None. The measurements moved none of them: each returned
    its prior prediction. It is what every Gaussian filter does where the measurement carries no
    information for it — where Cov[x, h(x)] = 0 under its Gaussian approximation at every step,
    as for stochastic volatility in levels (y = exp(x/2)·v: the information is in the scale of
    y, which a linear update in y cannot see) — and what a Taylor filter does at a point where
    h'(m) = 0 (the cubic sensor from m0 = 0)."""
    blind = []
    for name in names:
        e = est.get(name)
        if e is None:
            continue
        m = np.asarray(e.means, float)[~np.asarray(e.diverged, bool)]
        if m.shape[0] < 2 or not np.isfinite(m).all():
            continue
        if np.max(np.abs(m - m[:1])) <= 1e-12 * (1.0 + np.max(np.abs(m))):
            blind.append(name)
    if not blind:
        return None
    return (f"{', '.join(blind)}: the same estimates on every path — the measurements moved none of them, each "
            "returned its prior prediction: under its Gaussian approximation the measurement carries no "
            "information about the state here (Cov[x, h(x)] = 0 at every step, e.g. y = exp(x/2)·v, whose "
            "information is in its scale; or h'(m) = 0 at a Taylor filter's mean). Their MSE is the prior's; "
            "the reference uses the measurements.")

