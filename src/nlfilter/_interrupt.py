"""Ctrl-C in the ``nlfilter`` command (:mod:`nlfilter.cli`): the first SIGINT raises one
KeyboardInterrupt, which :func:`nlfilter.cli.main` turns into one line and exit code 130; a second
one while the first unwinds exits at once; one that lands where Python ignores exceptions (a
weakref callback, a ``__del__``) is sent again once that context is left. Standard library only,
so that the handler is in place before NumPy, SymPy and the filters load.
"""

from __future__ import annotations

import atexit
import os
import signal
import sys
import threading


def install():
    """Ctrl-C raises KeyboardInterrupt (caught by :func:`main`) once; a second one while the
    first unwinds (closing a Dask cluster, the store) exits at once with code 130. Returns the
    previous handler (None outside the main thread, where no handler can be set, and when the
    process was started with Ctrl-C ignored, which stays so)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # started with Ctrl-C ignored (`nohup`, `cmd &`)
        return None
    if not _LATE:
        _LATE.append(None)
        atexit.register(_ignore_late)  # registered first, so run after the other exit hooks
    return signal.signal(signal.SIGINT, on_sigint)


_LATE: list = []  # whether _ignore_late is registered


def finished(code: int) -> None:
    """The command has returned ``code``: a Ctrl-C from here to the process's end exits at once
    with ``code`` (the run is complete; nothing to report), and once the exit hooks have run it is
    ignored (:func:`_ignore_late`)."""
    def late(signum, frame):  # pragma: no cover - exercised by the fuzz suite's processes
        _exit(int(code or 0))
    late.nlfilter_late = True
    signal.signal(signal.SIGINT, late)


def _ignore_late():
    """Python's finalization puts the default action back for the signals it handles (a Ctrl-C
    in its last moments would kill the process by the signal, exit −2, no line), but leaves an
    ignored one ignored: after a finished command nothing is left to interrupt."""
    if threading.current_thread() is threading.main_thread() and \
            getattr(signal.getsignal(signal.SIGINT), "nlfilter_late", False):
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def on_sigint(signum, frame):
    signal.signal(signal.SIGINT, exit_on_sigint)
    quiet()
    if sys.unraisablehook is not _unraisable:
        HOOK.append(sys.unraisablehook)
        sys.unraisablehook = _unraisable
    raise KeyboardInterrupt


HOOK: list = []  # the unraisable hook on_sigint replaced


def _unraisable(unraisable):
    """A KeyboardInterrupt raised where Python ignores exceptions (a weakref callback during an
    import, a ``__del__``) would print "Exception ignored" and be lost: send the SIGINT again a
    moment later, once that context is left."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and \
            threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, on_sigint)
        threading.Timer(0.01, os.kill, (os.getpid(), signal.SIGINT)).start()  # once this context is left
        return
    (HOOK[-1] if HOOK else sys.__unraisablehook__)(unraisable)


def exit_on_sigint(signum, frame):  # pragma: no cover - exercised by the fuzz suite's processes
    _exit(130)


def _exit(code: int) -> None:  # pragma: no cover - exercised by the fuzz suite's processes
    """Flush the standard streams and end the process at once with ``code`` (no exit hooks)."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    finally:
        os._exit(code)


def quiet() -> None:
    """Silence what libraries log while an interrupted run unwinds (dask.distributed logs each
    cancelled task and closing comm at ERROR level)."""
    import logging
    for name in ("distributed", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
