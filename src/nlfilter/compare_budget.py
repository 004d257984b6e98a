"""The reference's budget in a comparison: what the automatic reference will cost, said before it
runs, and capped when asked (``compare(reference_budget=seconds, max_particles=N)``, CLI
``--reference-budget S --max-particles N``).

The cost of a reference run is estimated from a *pilot*: the rung's filter timed on
:data:`PILOT_PATHS` paths of the comparison's data (not kept: its numbers are not used), scaled to
the paths the run takes — per path for a grid (each grid size has its own pilot), per path and
particle for a particle filter (one pilot, scaled linearly in the particles: a particle filter's
work per step is linear in them). The per-path cost of a small batch is higher (fixed costs per
step), so the estimate errs on the long side: on a 5-state tracking model (200 paths × 40 steps)
a 2-path pilot estimated 55 s for a reference (1300 particles, its check at 5200 on 64 paths)
that took 30 s, a 4-path pilot 59 s for one (2000, its check at 8000) that took 60 s on the same,
then busier, machine. A rung costs its run on all paths plus its check, the refinement (``4×`` the
particles, ``2×`` the grid points per axis) on the ``certify_paths`` paths.

With ``seconds`` the ladder of :func:`nlfilter.yardstick.certified_reference` is capped:

* the first rung: a grid that would not fit is replaced by particles; particles that would not
  fit are reduced to what fits (at least :data:`MIN_PARTICLES`; when even those do not fit, they
  run anyway and a note says that the budget is exceeded);
* a further rung (``4×`` the particles) runs only if its estimated cost fits what is left; else
  the ladder stops there and the reference is labelled as not converged, the note naming the
  budget.

A budget in seconds makes the reference depend on the machine's speed (its pilot's timing): the
certificate and ``params["reference_budget"]`` record what was chosen, and a comparison resumed
from the store (:mod:`nlfilter.compare_tasks`) may choose another reference and compute it afresh
(the filters' tasks are read back all the same). Every decision is a line of
``ReferenceBudget.log`` (printed on stderr before the runs with ``progress``, and kept in
``Result.params["reference_budget"]`` and a note when a budget was set).
"""

from __future__ import annotations

import sys
import time

from .yardstick import PARTICLES

PILOT_PATHS = 4          #: paths a pilot runs on
MIN_PARTICLES = 200      #: the smallest particle reference a budget may cut the first rung to
LONG = 10.0              # seconds: an estimate above it is announced before the reference runs


def _fmt_s(s: float) -> str:
    return f"{s:.2g} s" if s < 10 else f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


class ReferenceBudget:
    """The budget of one comparison's automatic reference (module docstring).

    ``seconds``: the most the reference may take (None: no cap, the estimate is only said);
    ``run(flt, ys, tag)``: runs a filter on some of the data without keeping it; ``ys``: the
    comparison's measurements; ``certify_paths``: the paths of a check; ``build(rung)``: the
    filter of a rung; ``say``: prints one line (or None)."""

    def __init__(self, seconds, *, run, ys, certify_paths, build, say=None):
        self.seconds = None if seconds is None else float(seconds)
        self.run, self.ys, self.build, self.say = run, ys, build, say
        self.paths = ys.shape[0]
        self.check_paths = min(certify_paths, self.paths)
        self.t0 = time.perf_counter()
        self.log: list[str] = []
        self.capped = False
        self._per_path: dict = {}

    # -- estimates ---------------------------------------------------------------------------------
    def per_path(self, rung) -> float:
        """Seconds per path of ``rung``'s filter on this comparison's data, from a pilot."""
        if rung.kind == "particle":
            if "particle" not in self._per_path:
                n = min(int(rung.size), PARTICLES)
                self._per_path["particle"] = (self._pilot(type(rung)("particle", n)) / n, n)
            rate, _ = self._per_path["particle"]
            return rate * int(rung.size)
        key = ("grid", tuple(rung.size))
        if key not in self._per_path:
            self._per_path[key] = self._pilot(rung)
        return self._per_path[key]

    def _pilot(self, rung) -> float:
        p = min(PILOT_PATHS, self.paths)
        t = time.perf_counter()
        self.run(self.build(rung), self.ys[:p], f"pilot {rung.kind} {rung.size}")
        return (time.perf_counter() - t) / p

    def cost(self, rung) -> tuple[float, float]:
        """``(run on all paths, check on the certification paths)``, estimated seconds."""
        return self.per_path(rung) * self.paths, self.per_path(rung.refined()) * self.check_paths

    def left(self) -> float:
        return float("inf") if self.seconds is None else self.seconds - (time.perf_counter() - self.t0)

    def _note(self, text: str) -> None:
        self.log.append(text)
        if self.say is not None:
            self.say(text)

    # -- decisions -----------------------------------------------------------------------------------
    def first(self, rung, reason, *, switch=True):
        """The first rung to run: ``rung`` if its estimated cost fits, else one that does (module
        docstring; a grid is replaced by particles only with ``switch``, else it runs anyway);
        ``(rung, reason)``. Says what the reference will cost."""
        main, check = self.cost(rung)
        if main + check > self.left() and rung.kind == "grid":
            what = f"{rung.describe()} (est. {_fmt_s(main + check)})"
            self.capped = True
            if switch:
                rung = type(rung)("particle", PARTICLES)
                reason = f"the budget of {self.seconds:g} s does not hold {what}: particles"
                main, check = self.cost(rung)
            else:
                reason = f"the budget of {self.seconds:g} s does not hold {what}: run anyway (reference='grid')"
        if main + check > self.left() and rung.kind == "particle":
            per = (main + check) / int(rung.size)  # seconds per particle (linear in them)
            fit = int(self.left() / per) if per > 0 else int(rung.size)
            n = max(MIN_PARTICLES, min(int(rung.size), _round_down(fit)))
            self.capped = True
            before = rung.size
            rung = type(rung)("particle", n)
            main, check = self.cost(rung)
            over = main + check > self.left()
            reason = (f"the budget of {self.seconds:g} s holds "
                      + (f"{n} particles (not {before})" if not over else
                         f"not even {MIN_PARTICLES} particles (est. {_fmt_s(main + check)}): run anyway"))
        text = (f"reference: {rung.describe()} on {self.paths} paths (est. {_fmt_s(main)}) and its check at "
                f"{rung.refined().describe()} on {self.check_paths} paths (est. {_fmt_s(check)})"
                + (f"; budget {self.seconds:g} s" if self.seconds is not None else "")
                + (f": {reason}" if self.capped else ""))
        if self.capped or self.seconds is not None or main + check > LONG:
            self._note(text)
        return rung, reason

    def allows(self, rung) -> bool:
        """Whether the next rung ``rung`` (run when the last was not certified) fits what is left;
        says so either way when it is long or refused."""
        main, check = self.cost(rung)
        left = self.left()
        if main + check > left:
            self.capped = True
            self._note(f"reference: not certified; the next rung, {rung.describe()} on {self.paths} paths and its "
                       f"check (est. {_fmt_s(main + check)}), exceeds what is left of the budget of {self.seconds:g} s "
                       f"({_fmt_s(max(left, 0.0))}): the ladder stops here")
            return False
        if main + check > LONG or self.seconds is not None:
            self._note(f"reference: not certified; next {rung.describe()} on {self.paths} paths and its check "
                       f"(est. {_fmt_s(main + check)})")
        return True

    def to_dict(self) -> dict:
        return {"seconds": self.seconds, "capped": self.capped, "log": list(self.log)}


def _round_down(n: int) -> int:
    """``n`` rounded down to two significant digits (a particle count that reads as chosen)."""
    if n < 100:
        return n
    k = 10 ** (len(str(n)) - 2)
    return n // k * k


def stderr_say(text: str) -> None:
    """One line on stderr: ``compare: <text>``."""
    print(f"compare: {text}", file=sys.stderr, flush=True)
