"""The certificate's checks that can fail (issue 25): refinement alone (:mod:`nlfilter.yardstick`)
cannot see a reference of the wrong *model* (a wrong likelihood converges as well as a right one),
so :func:`contradictions`, run by ``compare`` on every reference, automatic or given, and by the
experiments on their own, checks what holds for the exact posterior whatever the model:

a. **NEES per component** (:func:`nees_check`): for the exact posterior mean and variance,
   ``E[e_i² / P_ii] = 1`` at every step. Each path's window average of ``e_i² / P_ii`` is one
   draw (paths independent); their mean must lie in the band ``1 ± (z se + NEES_SLACK)``, ``se``
   its standard error over the ``N`` paths, ``z`` the two-sided Student quantile (``N − 1``
   degrees of freedom) at the family-wise rate :data:`NEES_ALPHA` over the ``n`` components
   (Bonferroni: ``z = t_{N−1}(1 − α / 2n)``; 2.66 for n = 1, 3.05 for n = 3 at α = 0.01 and
   N = 64; 2.58 and 2.94 as N grows) and :data:`NEES_SLACK` = 0.1 the particle approximation's
   own excess (a weighted cloud of effective size ESS has NEES ≈ 1 + 2/ESS: 0.1 at ESS = 20);
b. **no filter beats it** (:func:`beaten_check`): no compared filter's paired gap to the
   reference (``MSE − MSE(reference)`` on the same paths, its s.e. the paired one and the
   reference's refinement error in quadrature, as in the table) is below ``−2`` s.e. in any
   component. A filter that diverged on more than :data:`BEATEN_MAX_DIVERGED` of the paths is
   not judged (its gap is over selected survivors).

Both judge only on at least :data:`CHECK_PATHS` = 16 paths (a standard error from fewer is too
unreliable to contradict anything: with 4 paths a window of 5 steps gave NEES 0.34 ± 0.07 for
an exact grid on a linear model); below, the check is recorded as not run. Limits of check a:
per-path NEES is right-skewed, so the lower edge is the fragile one with few paths (Lorenz-63,
30 paths, an exact particle reference: 0.74 ± 0.06 in one component on one seed, inside the
band by its slack); and one path whose variance collapsed to a tiny value inflates mean and
s.e. alike and does not fail it (the smoothing experiment's 2-D particle reference has total
NEES 2.4e6 ± 2.1e6 from one such path) — an exact zero variance under an error does fail.

Either failing withdraws the word "optimal": the label becomes ``"reference (contradicted:
<check>, <component or filter/component>)"``, a :class:`~nlfilter.errors.ReferenceWarning`
says what failed, and the certificate records it (``contradicted``: one dict per failure).

The experiments' hand-configured references go through the same checks from their per-path arrays
(:func:`reference_checks`) or whole estimates (:func:`estimates_checks`): a note under their tables.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from .errors import ReferenceWarning
from .evaluate import _means_and_mask, _window, mse, paired_difference

NEES_ALPHA = 0.01       #: family-wise rate of the NEES band over the components
NEES_SLACK = 0.1        #: a particle cloud's own NEES excess (≈ 2/ESS)
BEATEN_Z = 2.0          #: a filter "beats the optimum" when its gap is below −BEATEN_Z s.e.
BEATEN_MAX_DIVERGED = 0.1  #: the largest diverged fraction at which a filter may still "beat the optimum"
CHECK_PATHS = 16        #: the fewest paths (not diverged) on which the checks judge: below, s.e. are unreliable
CONTRADICTED = "reference (contradicted: {})"


def nees_band(per, *, alpha: float = NEES_ALPHA, slack: float = NEES_SLACK, components=None):
    """Check (a) on per-path values ``per (paths, n)`` — each path's window average of
    ``e_i² / P_ii``, paths independent (those that diverged left out): per component a dict
    ``{component, nees, stderr, band, z, ok}``, the mean over paths, its standard error and the
    band ``1 ± (z se + slack)``, ``z = t_{N−1}(1 − alpha / 2n)`` (module docstring). An infinite
    value (a zero variance under an error) fails. Empty below :data:`CHECK_PATHS` paths."""
    from scipy.special import stdtrit  # the Student quantile scipy.stats.t.ppf calls, without importing scipy.stats (0.6 s)
    per = np.asarray(per, float)
    if per.ndim != 2 or per.shape[0] < CHECK_PATHS:
        return []
    n = per.shape[1]
    z = float(stdtrit(per.shape[0] - 1, 1.0 - alpha / (2 * n)))
    out = []
    for i in range(n):
        m = float(np.mean(per[:, i]))
        se = float(np.std(per[:, i], ddof=1) / np.sqrt(per.shape[0])) if np.all(np.isfinite(per[:, i])) else float("inf")
        half = z * se + slack if np.isfinite(se) else 0.0
        lo, hi = 1.0 - half, 1.0 + half
        out.append({"component": components[i] if components else f"x{i + 1}", "nees": m, "stderr": se,
                    "band": [lo, hi], "z": z, "ok": bool(np.isfinite(m) and lo <= m <= hi)})
    return out


def nees_per_component(est, xs, *, window=0.5, angles=()):
    """``(paths, n)``: each path's window average of ``e_i² / P_ii`` (the estimates' error and
    their own variance; a zero variance under an error is infinite), the paths that diverged left
    out; None when the estimates have no covariances."""
    covs = getattr(est, "covs", None)
    if covs is None:
        return None
    means, xs, ok = _means_and_mask(est, xs, angles)  # angles: wrapped errors
    n, T = xs.shape[-1], xs.shape[-2]
    means, xs, ok = means.reshape(-1, T, n), xs.reshape(-1, T, n), np.reshape(ok, -1)
    var = np.diagonal(np.asarray(covs, float), axis1=-2, axis2=-1).reshape(-1, T, n)
    w = _window(T, window)
    e2, v = (means - xs)[ok][:, w] ** 2, var[ok][:, w]
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(v > 0, e2 / np.where(v > 0, v, 1.0), np.where(e2 > 0, np.inf, 1.0))
    return np.mean(q, axis=1)


def nees_check(est, xs, *, window=0.5, alpha: float = NEES_ALPHA, slack: float = NEES_SLACK, components=None,
               angles=()):
    """Check (a) on a reference's estimates: :func:`nees_band` of :func:`nees_per_component`
    (empty when fewer than :data:`CHECK_PATHS` paths did not diverge or there are no covariances)."""
    per = nees_per_component(est, xs, window=window, angles=angles)
    return [] if per is None else nees_band(per, alpha=alpha, slack=slack, components=components)


def gap_verdict(name, component, gap, stderr, paths, *, scale: float = 0.0):
    """Check (b) on one paired gap ``MSE(filter) − MSE(reference)`` (``gap ± stderr`` over
    ``paths`` paths): a dict ``{filter, component, gap, stderr, ok}``, ``ok`` unless the gap is
    below ``−BEATEN_Z`` s.e. (and below rounding, ``1e-9 · scale``, the reference's MSE: an exact
    filter equal to an exact reference has a zero gap and s.e.); None (not judged) over fewer than
    :data:`CHECK_PATHS` paths or when not finite."""
    if paths < CHECK_PATHS or not (np.isfinite(gap) and np.isfinite(stderr)):
        return None
    return {"filter": name, "component": component, "gap": float(gap), "stderr": float(stderr),
            "ok": bool(gap >= -BEATEN_Z * stderr - 1e-9 * abs(scale))}


def beaten_check(ref_est, judged, xs, *, window=0.5, reference_error=None, components=None, angles=()):
    """Check (b) on estimates: :func:`gap_verdict` of every judged filter (name -> Estimates) and
    component, its paired gap to ``ref_est`` on the same paths with the standard error of the
    table (the paired one and ``reference_error(i)``, the reference's own, in quadrature).
    Filters that diverged on more than :data:`BEATEN_MAX_DIVERGED` of the paths are left out (a
    gap over selected survivors)."""
    out = []
    n = xs.shape[-1]
    scale = [abs(mse(ref_est, xs, component=i, window=window, angles=angles).value) for i in range(n)]
    for name, e in judged.items():
        div = np.asarray(getattr(e, "diverged", np.zeros(1, bool)), bool)
        if div.size and np.mean(div) > BEATEN_MAX_DIVERGED:
            continue
        for i in range(n):
            d = paired_difference(e, ref_est, xs, component=i, window=window, angles=angles)
            se = math.hypot(d.stderr, reference_error(i) if reference_error else 0.0)
            row = gap_verdict(name, components[i] if components else f"x{i + 1}", d.value, se, d.paths, scale=scale[i])
            if row is not None:
                out.append(row)
    return out


def _failures(nees_rows, gap_rows):
    """``(failures, texts, tags)`` of the rows of checks (a) and (b)."""
    fails, texts, tags = [], [], []
    bad = [r for r in nees_rows if not r["ok"]]
    if bad:
        fails += [{"check": "NEES", **r} for r in bad]
        tags.append(f"NEES, {bad[0]['component']}")
        texts += [f"its NEES of {r['component']} is {r['nees']:.3g} ± {r['stderr']:.2g}, outside the band "
                  f"[{r['band'][0]:.3g}, {r['band'][1]:.3g}] of the exact posterior" for r in bad]
    beaten = [r for r in gap_rows if not r["ok"]]
    if beaten:
        fails += [{"check": "beaten", **r} for r in beaten]
        tags.append(f"beaten, {beaten[0]['filter']}/{beaten[0]['component']}")
        texts += [f"{r['filter']} beats it in {r['component']} by {-r['gap']:.3g} ({r['gap'] / r['stderr']:+.1f} s.e.)"
                  for r in beaten]
    return fails, texts, tags


def contradictions(cert, ref_est, judged, xs, *, window=0.5, components=None, who="compare", angles=()):
    """Run :func:`nees_check` and :func:`beaten_check` on a reference (its estimates ``ref_est``,
    the compared filters' ``judged``: name -> Estimates, the truth ``xs``) and record the failures
    in ``cert.contradicted``; when any fails, the reference loses the word "optimal":
    ``cert.label`` becomes ``"reference (contradicted: <check>, <where>)"`` (the first failure of
    each check) and a :class:`~nlfilter.errors.ReferenceWarning` (``who``: the caller's name)
    says what failed. Returns ``cert.contradicted`` (empty: the reference stands)."""
    fails, texts, tags = _failures(nees_check(ref_est, xs, window=window, components=components, angles=angles),
                                   beaten_check(ref_est, judged or {}, xs, window=window, angles=angles,
                                                reference_error=cert.reference_error, components=components))
    cert.contradicted = fails
    if fails:
        cert.label = CONTRADICTED.format("; ".join(tags))
        warnings.warn(f"{who}: the reference ({cert.kind} {cert.size}) is contradicted: {'; '.join(texts)}. Its rows "
                      f"are labelled {cert.label!r} and its gaps are to the reference, not to the optimum (a wrong "
                      "model or likelihood in the reference, or too few particles for its covariance)",
                      ReferenceWarning, stacklevel=3)
    return fails


def contradiction_note(cert) -> str:
    """One line for a table's notes: the checks of :func:`contradictions` passed, or what failed."""
    return _note(cert.contradicted)


def _note(fails, ran: bool = True) -> str:
    if not ran:
        return f"reference checks: not run (fewer than {CHECK_PATHS} paths)"
    if not fails:
        return "reference checks: NEES per component within its band, no filter below −2 s.e.: passed"
    parts = []
    for r in fails:
        if r["check"] == "NEES":
            parts.append(f"NEES of {r['component']} {r['nees']:.3g} ± {r['stderr']:.2g} outside "
                         f"[{r['band'][0]:.3g}, {r['band'][1]:.3g}]")
        else:
            parts.append(f"{r['filter']} below it in {r['component']} by {-r['gap']:.3g} ({r['gap'] / r['stderr']:+.1f} s.e.)")
    return "reference checks FAILED (contradicted): " + "; ".join(parts)


def reference_checks(nees_per, gaps, *, components=None, who="experiment"):
    """Checks (a) and (b) on a hand-configured reference whose numbers come from per-path arrays
    (an experiment's Monte Carlo blocks): ``nees_per (paths, n)`` the reference's per-path window
    averages of ``e_i² / P_ii`` (:func:`nees_per_component`; None: no NEES check) and ``gaps`` a
    list of ``(filter, component, gap, stderr, paths, scale)`` — the paired gaps its table prints.
    Returns ``(failures, note)``: the note is one line for the table (passed, or what failed),
    and a failure warns (:class:`~nlfilter.errors.ReferenceWarning`, naming ``who``). Nothing
    the table prints moves: the experiments' labels stay, the note says whether they stand."""
    nees_rows = [] if nees_per is None else nees_band(nees_per, components=components)
    gap_rows = [r for r in (gap_verdict(f, c, g, se, n, scale=sc) for f, c, g, se, n, sc in gaps) if r is not None]
    return _given_checks(nees_rows, gap_rows, who)


def estimates_checks(ref_est, judged, xs, *, window=None, components=None, who="experiment"):
    """:func:`reference_checks` for an experiment that keeps whole Estimates: the reference's
    ``ref_est``, the filters' ``judged`` (name -> Estimates on the same paths ``xs``), the
    experiment's ``window``; ``(failures, note)``."""
    return _given_checks(nees_check(ref_est, xs, window=window, components=components),
                         beaten_check(ref_est, judged, xs, window=window, components=components), who)


def _given_checks(nees_rows, gap_rows, who):
    fails, texts, _ = _failures(nees_rows, gap_rows)
    if fails:
        warnings.warn(f"{who}: the reference is contradicted: {'; '.join(texts)}", ReferenceWarning, stacklevel=3)
    return fails, _note(fails, ran=bool(nees_rows or gap_rows))
