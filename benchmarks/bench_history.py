"""The NumPy loop against its own history: the same jobs on this tree and on an older commit's,
in alternation, paired (issue 28, item 7: "the NumPy loop no slower than two weeks ago on any
benchmark row").

``--against COMMIT`` (or a directory holding an nlfilter tree, e.g. a ``git worktree``): the commit
is exported once (``git archive``, into ``$TMPDIR/nlfilter-history/<sha>``: a plain copy of its
tree, no worktree registered in the repository). ``--head`` is the tree compared (default: the one
holding this script). Each tree runs in its own long-lived process (its ``src`` first on the path,
pinned by :mod:`_pin` like every benchmark: one core, one thread); the parent sends both the same
job in turn — A then B, then B then A in the next round (``--rounds``, 5) — so that the two times
of a pair see the same load. Each turn is the best of ``--repeat`` (3) calls after a first,
warming call (code generation, caches) reported apart, timed by the wall clock or (``--clock cpu``)
by the process's CPU time, which leaves out the waits of a core shared with other work.

The jobs are the benchmark rows' NumPy-loop jobs, on the same data for both trees (simulated here
in NumPy, seeded, :func:`_models.simulate_np`: no tree's ``simulate`` is involved): ``FILTER/MODEL/PATHSxSTEPS`` with
``cubic`` the scalar cubic sensor of ``bench_ekf.py`` / ``bench_single_path.py`` and ``chainN``
the chain of ``bench_dimensions.py``; ``--jobs`` takes names or shell patterns (``'*/chain4/*'``).
A tree whose ``run`` has a ``backend`` argument runs with ``backend="numpy"`` (the NumPy loop,
whatever the default call is); a job a tree cannot run (a filter it does not have) is reported.

Reported per job: each side's best, the per-round ratios ``against / head`` (> 1: this tree
faster) and their median, and whether the filtered means are bitwise equal (a hash of the bytes).
Writes the run ``--label`` of ``benchmarks/results/bench_history.json``.

Run: ``taskset -c 1 python benchmarks/bench_history.py --against e2a8081 [--rounds 5] [--jobs ...]``
"""

from __future__ import annotations

import _pin  # noqa: F401  (first: one core, one thread, in the parent and in each tree's process)

import argparse  # noqa: E402
import fnmatch  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import pathlib  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402

import numpy as np  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
OUT = HERE / "results" / "bench_history.json"
FILTER_NAMES = ("ekf", "ukf", "ckf", "second-order")
EXPORTED = {}  # tree directory -> the commit exported into it
DEFAULT_JOBS = ["ekf/cubic/1000x1000", "ekf/cubic/1x2000", "ukf/cubic/1x2000", "ekf/chain4/1x2000",
                "ukf/chain4/1x2000", "ekf/chain2/1000x200", "ukf/chain2/1000x200", "second-order/chain2/1000x200",
                "ekf/chain4/1000x200", "ukf/chain4/1000x200"]


def all_jobs():
    """Every job name: the rows of bench_ekf, bench_single_path and bench_dimensions."""
    names = ["ekf/cubic/1000x1000"]
    names += [f"{k}/{m}/1x2000" for m in ("cubic", "chain4") for k in ("ekf", "ukf", "second-order")]
    names += [f"{k}/chain{n}/1000x200" for n in (1, 2, 4, 8, 16) for k in FILTER_NAMES]
    return names


# ---- the child: one tree, jobs read from stdin, timings written as JSON lines ---------------------

def child(name: str, tree: str, datadir: str):
    """Serve jobs for the nlfilter of ``tree`` (its ``src`` first on ``sys.path``); the side ``name``'s
    filtered means go to ``datadir`` for the parent's comparison."""
    import time

    out = os.fdopen(os.dup(1), "w")
    sys.stdout = sys.stderr  # anything the library prints stays off the protocol
    sys.path.insert(0, str(pathlib.Path(tree) / "src"))
    import nlfilter
    from nlfilter import filters as F

    backend = _pin.default_backend()
    args = {} if backend is None else {"backend": "numpy"}
    out.write(json.dumps({"ready": True, "nlfilter": os.path.dirname(nlfilter.__file__),
                          "run_has_backend": backend is not None, **_pin.commit_of(nlfilter.__file__)}) + "\n")
    out.flush()

    from _models import chain, cubic

    def model(name):
        return cubic() if name == "cubic" else chain(int(name[5:]))

    prepared = {}
    for line in sys.stdin:
        req = json.loads(line)
        job = req["job"]
        try:
            if job not in prepared:
                kind, mname, size = job.split("/")
                cls = {"ekf": "EKF", "ukf": "UKF", "ckf": "CKF", "second-order": "SecondOrderFilter"}[kind]
                if not hasattr(F, cls):
                    raise LookupError(f"this tree has no {cls}")
                opts = {"form": "truncated"} if kind == "second-order" and size.startswith("1x") else {}
                flt = getattr(F, cls)(model(mname), **opts)
                d = np.load(pathlib.Path(datadir) / f"{mname}-{size}.npz")
                ys, m0, P0 = d["ys"], d["m0"], d["P0"]
                t = time.perf_counter()
                est = flt.run(ys, m0, P0, **args)
                first = time.perf_counter() - t
                digest = hashlib.sha256(np.ascontiguousarray(est.means).tobytes()).hexdigest()[:16]
                np.save(pathlib.Path(datadir) / f"{name}-{job.replace('/', '_')}.npy", est.means)
                prepared[job] = (lambda flt=flt, ys=ys, m0=m0, P0=P0: flt.run(ys, m0, P0, **args), first, digest)
                best = None
            fn, first, digest = prepared[job]
            if req.get("clock") == "cpu":  # the process's CPU time (a shared core's waits left out)
                best = float("inf")
                for _ in range(req["repeat"]):
                    t = time.process_time()
                    fn()
                    best = min(best, time.process_time() - t)
            else:
                best, _ = _pin.best_of(fn, req["repeat"])
            reply = {"best": best, "first": first, "digest": digest}
        except Exception as exc:  # a job this tree cannot run: reported, not fatal
            reply = {"error": f"{type(exc).__name__}: {exc}"}
        out.write(json.dumps(reply) + "\n")
        out.flush()


# ---- the parent -------------------------------------------------------------------------------------

def tree_of(spec: str) -> pathlib.Path:
    """A directory holding an nlfilter tree, or a commit exported once into the temporary directory."""
    p = pathlib.Path(spec)
    if (p / "src" / "nlfilter").is_dir():
        return p.resolve()
    sha = subprocess.run(["git", "-C", str(HERE), "rev-parse", "--verify", f"{spec}^{{commit}}"],
                         capture_output=True, text=True)
    if sha.returncode:
        raise SystemExit(f"--against/--head: {spec!r} is neither an nlfilter tree nor a commit of {HERE.parent}")
    sha = sha.stdout.strip()
    dest = pathlib.Path(tempfile.gettempdir()) / "nlfilter-history" / sha
    EXPORTED[dest] = sha
    if not (dest / "src" / "nlfilter").is_dir():
        archive = subprocess.run(["git", "-C", str(HERE.parent), "archive", sha, "src"], capture_output=True,
                                 check=True)
        part = dest.with_name(sha + ".part")
        part.mkdir(parents=True, exist_ok=True)
        subprocess.run(["tar", "-x", "-C", str(part)], input=archive.stdout, check=True)
        part.rename(dest)  # whole or absent
    return dest


class Side:
    """One tree's process."""

    def __init__(self, name, tree, datadir):
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        env["PYTHONPATH"] = str(HERE)  # _pin, bench_dimensions; the tree's src goes first in child()
        self.proc = subprocess.Popen([sys.executable, str(pathlib.Path(__file__).resolve()), "--child", name,
                                      str(tree), datadir], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"the process of the tree {tree} ended before its first job (its error is above)")
        self.info = json.loads(line)

    def ask(self, job, repeat, clock="wall"):
        self.proc.stdin.write(json.dumps({"job": job, "repeat": repeat, "clock": clock}) + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def main(argv=None):
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "--child":
        return child(*sys.argv[2:5])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", required=True, help="an older commit (or a directory with its tree)")
    ap.add_argument("--head", default=str(HERE.parent), help="the tree compared (default: this script's)")
    ap.add_argument("--jobs", nargs="+", default=DEFAULT_JOBS, help=f"names or patterns among: {' '.join(all_jobs())}")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=3, help="calls per turn (best taken), after a first, warming call")
    ap.add_argument("--quick", action="store_true", help="smoke: two small jobs, 2 rounds, 1 call")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="time each call by the wall clock or by the process's CPU time (a shared machine)")
    ap.add_argument("--label", default="pinned", help="the run's name in the JSON (other runs kept)")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    if a.quick:
        a.jobs, a.rounds, a.repeat = ["ekf/cubic/1x2000", "ukf/chain2/1000x200"], 2, 1
    jobs = [j for pat in a.jobs for j in all_jobs() if fnmatch.fnmatchcase(j, pat)]
    if not jobs:
        raise SystemExit(f"--jobs: none of {a.jobs} names a job; expected among {all_jobs()}")
    jobs = list(dict.fromkeys(jobs))
    from _models import simulate_np  # here, not at the top: a tree's process imports its own nlfilter

    trees = {"head": tree_of(a.head), "against": tree_of(a.against)}
    with tempfile.TemporaryDirectory() as datadir:
        for mname, size in {tuple(j.split("/")[1:]) for j in jobs}:
            paths, steps = map(int, size.split("x"))
            ys, m0, P0 = simulate_np(mname, paths, steps)
            np.savez(pathlib.Path(datadir) / f"{mname}-{size}.npz", ys=ys, m0=m0, P0=P0)
        sides = {k: Side(k, t, datadir) for k, t in trees.items()}
        try:
            turns = {j: {"head": [], "against": []} for j in jobs}
            replies = {j: {} for j in jobs}
            for rnd in range(a.rounds):
                for j in jobs:
                    for k in (("head", "against") if rnd % 2 == 0 else ("against", "head")):
                        rep = sides[k].ask(j, a.repeat, a.clock)
                        replies[j][k] = rep
                        if "best" in rep:
                            turns[j][k].append(rep["best"])
                print(f"round {rnd + 1}/{a.rounds} done", flush=True)
            diffs = {}
            for j in jobs:
                got = [pathlib.Path(datadir) / f"{k}-{j.replace('/', '_')}.npy" for k in ("head", "against")]
                if all(g.exists() for g in got):
                    h, o = (np.load(g) for g in got)
                    diffs[j] = float(np.max(np.abs(h - o)) / (np.max(np.abs(o)) or 1.0)) if h.shape == o.shape else None
        finally:
            infos = {k: s.info for k, s in sides.items()}
            for k, t in trees.items():
                infos[k].setdefault("exported_commit", EXPORTED.get(t))
            for s in sides.values():
                s.close()
    rows = []
    for j in jobs:
        h, o = turns[j]["head"], turns[j]["against"]
        row = {"job": j, "head_best": min(h) if h else None, "against_best": min(o) if o else None,
               "errors": {k: r["error"] for k, r in replies[j].items() if "error" in r}}
        if h and o:
            ratios = [b / c for b, c in zip(o, h)]
            row.update(paired_against_over_head=ratios, median_against_over_head=statistics.median(ratios),
                       first_call={k: replies[j][k]["first"] for k in ("head", "against")},
                       bitwise_equal_means=replies[j]["head"]["digest"] == replies[j]["against"]["digest"],
                       max_rel_difference_of_means=diffs[j])
            print(f"{j}: head {min(h):.4g} s, against {min(o):.4g} s, median against/head "
                  f"{row['median_against_over_head']:.3f}, means bitwise equal: {row['bitwise_equal_means']} "
                  f"(max rel. difference {diffs[j]})")
        else:
            print(f"{j}: {row['errors']}")
        rows.append(row)
    _pin.write(a.out, a.label, {"trees": infos, "against": a.against, "rounds": a.rounds, "repeat": a.repeat,
                                "clock": a.clock,
                                "units": "seconds per call (best of the turns); ratios > 1: head faster",
                                "rows": rows}, benchmark="history")


if __name__ == "__main__":
    main()
