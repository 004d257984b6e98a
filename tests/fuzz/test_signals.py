"""Fuzz of the command line under Ctrl-C (issue 26): ``nlfilter compare`` started as a program
(``python -m nlfilter.cli``) in a session of its own, and SIGINT sent to its whole process group —
what a terminal's Ctrl-C does, Dask's worker processes included — at seeded moments from the
process's start: during the imports, the model's build, the runs, and once with
``--executor dask`` (during the cluster's start or its tasks). Each is ``clean`` when the process
exits 130 with the one line ``nlfilter: interrupted`` (followed, once the run has a store, by
where its finished tasks are kept) (or 0 if it finished first), no traceback,
within the harness's limit. The processes run side by side: about 10 s of wall time in all.

The interpreter's own start (the first ~20-80 ms, before the package's first line runs) is out of
nlfilter's reach; the moments start after it (:data:`EARLIEST`)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("dask.distributed")

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "examples" / "models" / "pendulum.toml"
EARLIEST = 0.15  # seconds: Python's own start-up precedes any nlfilter code (see the module docstring)
SEED = 26


def _session():  # a process group of its own (killpg reaches its children); Ctrl-C not ignored
    os.setsid()
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _moments():
    r = random.Random(SEED)
    local = [round(r.uniform(EARLIEST, 0.6), 2), round(r.uniform(0.6, 2.0), 2), round(r.uniform(2.0, 4.0), 2)]
    return [(t, []) for t in local] + [(round(r.uniform(1.5, 6.0), 2), ["--executor", "dask", "--workers", "1"])]


def test_ctrl_c_at_seeded_moments_is_one_line_and_exit_130(fuzz, tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))}
    procs = []
    for t, extra in _moments():
        out = tmp_path / str(t)  # a folder and a store each: no process reuses another's finished tasks
        out.mkdir()              # (a run that did would finish with a line saying so)
        cmd = [sys.executable, "-m", "nlfilter.cli", "compare", str(MODEL), "--no-progress", "--paths", "8",
               "--steps", "20", "--filters", "ekf,ukf", "--json", str(out / "out.json"), *extra]
        procs.append((t, extra, subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                                 env={**env, "NLFILTER_STORE": str(out / "results.sqlite")},
                                                 preexec_fn=_session)))
    start = time.monotonic()
    pending = sorted(procs, key=lambda p: p[0])
    for t, extra, p in pending:  # send each its SIGINT at its moment
        time.sleep(max(0.0, start + t - time.monotonic()))
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGINT)
    failures = []
    for t, extra, p in procs:
        try:
            out, err = p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            out, err = p.communicate()
            outcome, clean = "hang", False
        else:
            lines = [ln for ln in err.strip().splitlines() if ln.strip()]
            # one line: "nlfilter: interrupted" (and where the run's finished tasks are kept, if any)
            clean = "Traceback" not in err and ((p.returncode == 130 and len(lines) == 1
                                                 and lines[0].startswith("nlfilter: interrupted"))
                                                or (p.returncode == 0 and not lines))
            outcome = "clean" if clean else "unclean"
        label = f"SIGINT at {t} s{' (dask)' if extra else ''}: exit {p.returncode}, {err[-300:]!r}"
        fuzz.count("command line: Ctrl-C", outcome, clean, label=label)
        if not clean:
            failures.append(label)
    assert not failures, failures


_LATE = """
import os, signal, sys, time
from nlfilter import _interrupt
_interrupt.install()
_interrupt.finished(3 if sys.argv[1] == "returned" else 0)
if sys.argv[1] == "returned":        # after the command returned: at once, its code
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(5)
class Late:                          # during finalization, after the exit hooks: ignored
    def __del__(self):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
late = Late()
"""


@pytest.mark.parametrize("when", ["returned", "finalization"])
def test_ctrl_c_after_the_command_returned(when):
    """A Ctrl-C after the command has returned ends the process with the command's code at once;
    in the interpreter's last moments (after the exit hooks, where Python restores the default
    action: exit −2, no line) it is ignored (nlfilter._interrupt.finished)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))}
    p = subprocess.run([sys.executable, "-c", _LATE, when], capture_output=True, text=True, env=env, timeout=60,
                       preexec_fn=_session)
    assert (p.returncode, p.stderr) == ((3, "") if when == "returned" else (0, ""))
