"""The ``nlfilter`` command: ``nlfilter list`` (``--filters``: the filter registry), ``nlfilter
reproduce ID | all``, ``nlfilter compare MODEL.toml`` (every filter that applies against the
certified reference, on a model stated in a file: :mod:`nlfilter.modelfile`), ``nlfilter simulate
MODEL.toml --out DATA.csv`` and ``nlfilter fit MODEL.toml DATA.csv --params q,r``
(``nlfilter._cli_model``) and ``nlfilter results list | show | export`` (the results store,
:mod:`nlfilter.store`).

Errors in what the user typed (unknown experiment, unknown or malformed ``--param``, a model file
that cannot be read, an unknown filter, an output path that cannot be written) print one line on
stderr and exit with code 2, never a traceback, before any work starts. Ctrl-C — at any moment,
from the imports on — prints one line and exits with code 130 (a second Ctrl-C while shutting
down exits at once); every Monte Carlo block finished by then is in the store, and the same command
resumes from there. An error nlfilter did not anticipate prints one line naming it and exits with
code 1 (``NLFILTER_TRACEBACK=1`` shows its traceback).

This module imports only the standard library at its top: :func:`main` installs the Ctrl-C handler
first, then loads NumPy, SymPy and the filters — only where the command needs them: ``nlfilter list``
(``--params``) reads the experiment registry, which imports no experiment, and ``nlfilter results``
reads the store, so neither loads NumPy, SymPy, SciPy, numba or matplotlib
(``tests/test_experiments_registry.py``).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys

from . import _interrupt
from ._cli_results import check_output as _check_output
from ._cli_results import results as _results


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2
        print(f"nlfilter: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="nlfilter", description="Moment-based nonlinear filters: reproduce the papers' experiments, compare the filters on your model.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    ls = sub.add_parser("list", help="list the experiments: id, title, source")
    ls.add_argument("--params", action="store_true",
                    help="also list each experiment's parameters (what --param accepts) with their defaults")
    ls.add_argument("--filters", action="store_true",
                    help="list the filter registry instead: by family, name, time, model kinds, source")
    ls.add_argument("--wide", action="store_true",
                    help="with --filters: every field (class, needs, likelihood, smoother, measurement convention)")
    r = sub.add_parser("reproduce", help="run one experiment and print its table")
    r.add_argument("id", help="experiment id (see `nlfilter list`), or `all`: every experiment")
    r.add_argument("--report", metavar="DIR", default=None,
                   help="write DIR/index.md (paper · nlfilter · s.e. · optimum · verdict per experiment, "
                        "provenance) with each result's JSON and figure")
    r.add_argument("--quick", action="store_true", help="small version (same code path), for tests and CI")
    r.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="override an experiment parameter (repeatable)")
    r.add_argument("--runs", type=int, default=None, help="number of Monte Carlo paths")
    r.add_argument("--seed", type=int, default=0, help="seed of the random streams (default 0)")
    r.add_argument("--chunk", type=int, default=None,
                   help="simulate and filter N Monte Carlo paths at a time (same numbers for any N)")
    r.add_argument("--json", metavar="PATH", help="write the result table as JSON")
    r.add_argument("--plot", metavar="PATH", help="write the figure as PNG")
    r.add_argument("--no-progress", action="store_true", help="hide progress bars")
    r.add_argument("--all", action="store_true", help="also print the rows without a paper value, by quantity")
    r.add_argument("--notes", action="store_true", help="also print the experiment's notes (the JSON has them)")
    _execution_options(r)
    res = sub.add_parser("results", help="the results store: list runs, show one, export tables")
    rsub = res.add_subparsers(dest="action", required=True, parser_class=_Parser)
    for name, helptext in (("list", "list the stored runs (latest first)"),
                           ("show", "print a stored run's table (or its status)"),
                           ("export", "write stored results as CSV rows or JSON")):
        a = rsub.add_parser(name, help=helptext)
        a.add_argument("--store", metavar="PATH", default=None,
                       help="the store's SQLite file (default $NLFILTER_STORE or ~/.cache/nlfilter/results.sqlite)")
        if name == "list":
            a.add_argument("--experiment", metavar="ID", default=None, help="only this experiment's runs")
        if name == "show":
            a.add_argument("run_id", type=int, metavar="RUN", help="run id (see `nlfilter results list`)")
            a.add_argument("--all", action="store_true", help="also the rows without a paper value")
            a.add_argument("--notes", action="store_true", help="also the notes")
        if name == "export":
            a.add_argument("run_ids", type=int, nargs="*", metavar="RUN",
                           help="run ids (default: the latest finished run of each experiment)")
            fmt = a.add_mutually_exclusive_group(required=True)
            fmt.add_argument("--csv", metavar="PATH", help="one line per table row")
            fmt.add_argument("--json", metavar="PATH", help="a list of the results' JSON")
    c = sub.add_parser("compare", help="compare every filter that applies with the certified reference, on a "
                                       "model stated in a TOML file")
    c.add_argument("model", metavar="MODEL.toml", help="the model file (see nlfilter.modelfile; examples/models/)")
    c.add_argument("--paths", type=int, default=None, help="Monte Carlo paths (default: the file's [run] paths, else 200)")
    c.add_argument("--steps", type=int, default=None, help="measurement steps (default: the file's [run] steps, else 100)")
    c.add_argument("--filters", default=None, metavar="all|NAME,NAME",
                   help="'all' or comma-separated registry names (`nlfilter list --filters`; default: the file's "
                        "[run] filters, else all)")
    c.add_argument("--seed", type=int, default=None, help="seed of the random streams (default: the file's, else 0)")
    c.add_argument("--json", metavar="PATH", help="write the result table as JSON")
    c.add_argument("--plot", metavar="PATH", help="write the figure (MSE per step per component) as PNG")
    c.add_argument("--report", metavar="DIR", default=None,
                   help="write DIR/index.md with the table, the JSON and the figure")
    c.add_argument("--no-progress", action="store_true", help="hide progress bars")
    c.add_argument("--block", type=int, default=None, metavar="N",
                   help="run every filter (and the reference) on blocks of N paths, each block a task of the "
                        "executor (default: all paths in one batch, one task per filter)")
    c.add_argument("--chunk", type=int, default=None,
                   help="filter N paths at a time within a task (memory; same numbers for any N)")
    c.add_argument("--reference", choices=("auto", "grid", "particle", "none"), default="auto",
                   help="the yardstick: the certified automatic reference (default), its grid or particle "
                        "ladder only, or none (no gaps)")
    c.add_argument("--max-particles", type=int, default=None, metavar="N",
                   help="the most particles the reference runs on all paths (default 32000; its check runs 4×N "
                        "on 64 paths)")
    c.add_argument("--reference-budget", type=float, default=None, metavar="SECONDS",
                   help="cap the reference by its cost estimated from a pilot: fewer particles, or a ladder "
                        "that stops early (said in a note); the estimate is printed before a long reference")
    _execution_options(c)
    from ._cli_model import add_commands
    add_commands(sub)  # simulate, fit
    return p


def _execution_options(r):
    r.add_argument("--store", metavar="PATH", default=None,
                   help="results store (SQLite) that keeps every finished Monte Carlo block, so an interrupted "
                        "run resumes (default $NLFILTER_STORE or ~/.cache/nlfilter/results.sqlite)")
    r.add_argument("--no-store", action="store_true", help="keep nothing: compute every block afresh")
    _executor_options(r)


def _executor_options(r):
    r.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="where the Monte Carlo blocks run: this process (default) or a dask.distributed "
                        "cluster (pip install \"nlfilter[dask]\"); the numbers are the same")
    r.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="dask scheduler address (default: start a LocalCluster)")
    r.add_argument("--workers", type=int, default=None, metavar="N",
                   help="worker processes of the LocalCluster (default 2)")


def _parse_params(items) -> dict:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--param {item!r}: expected NAME=VALUE")
        out[name.strip()] = value.strip()
    return out


def main(argv=None) -> int:
    """The ``nlfilter`` command (``python -m nlfilter.cli`` and the console script both enter
    here). ``argv`` None: ``sys.argv[1:]``, a program run — a Ctrl-C after the command has returned
    then ends the process at once with the command's exit code, and is ignored once the exit hooks
    have run (``nlfilter._interrupt.finished``); given (a test), the caller's handler is put back."""
    previous = _interrupt.install()
    code = 1  # the exit code, for a Ctrl-C that lands after the command has returned (_interrupt.finished)
    try:
        return (code := _main(argv))
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return (code := 0)
    except KeyboardInterrupt:  # Ctrl-C: one line, exit 130 (the store keeps every finished block)
        _interrupt.quiet()
        print("nlfilter: interrupted" + _KEPT.get(), file=sys.stderr)
        if argv is None:  # a program run: its finally blocks have run (the store, the executor); exit now,
            # skipping the atexit hooks of what the interrupt cut short (a half-built Dask cluster's
            # close_clusters prints tracebacks there)
            _interrupt.exit_on_sigint(signal.SIGINT, None)
        return 130
    except Exception as exc:  # noqa: BLE001 - the command line prints no traceback
        if os.environ.get("NLFILTER_TRACEBACK"):
            raise
        msg = str(exc).splitlines()[0] if str(exc) else ""
        print(f"nlfilter: internal error: {type(exc).__name__}: {msg} (please report it; NLFILTER_TRACEBACK=1 "
              "shows the traceback)", file=sys.stderr)
        return 1
    finally:
        if _interrupt.HOOK and argv is not None:  # a test's process: its own hook back
            sys.unraisablehook = _interrupt.HOOK.pop()
        if previous is not None:
            if argv is None:  # a program run: a Ctrl-C from here to the process's end exits quietly with its code
                _interrupt.finished(code)
            else:
                signal.signal(signal.SIGINT, previous)


class _Kept:
    """What an interrupted run leaves behind, for the one line printed on Ctrl-C."""

    text = ""

    def get(self):
        return self.text


_KEPT = _Kept()


# The largest seed: the results store keeps it as an SQLite INTEGER (a signed 64-bit integer).
MAX_SEED = 2**63 - 1


def _check_seed(seed) -> None:
    if seed is not None and not 0 <= seed <= MAX_SEED:
        raise ValueError(f"--seed: got {seed}; expected an integer from 0 to 2**63 - 1 (the store keeps it as a "
                         "64-bit integer)")


def _check_execution(args) -> None:
    """``--chunk``, ``--workers``, ``--scheduler`` as the executor can take them."""
    if args.chunk is not None and args.chunk < 1:
        raise ValueError(f"--chunk: expected a positive integer, got {args.chunk}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers: expected a positive integer, got {args.workers}")
    if args.executor == "local" and (args.scheduler is not None or args.workers is not None):
        raise ValueError("--scheduler/--workers: need --executor dask")


def _open_store(args):
    from .store import ResultsStore
    if getattr(args, "no_store", False):
        if args.store is not None:
            raise ValueError("--no-store: given with --store; expected one of them")
        return None
    return ResultsStore(args.store)


def _main(argv) -> int:
    _KEPT.text = ""  # what a Ctrl-C leaves behind: set once a run has a store
    args = _parser().parse_args(argv)
    from . import experiments
    if args.command == "list":
        from ._cli_list import list_experiments, list_filters
        if args.wide and not args.filters:
            return _error(ValueError("--wide: only with --filters"))
        if args.filters:
            print("\n".join(list_filters(args.wide)))
        else:
            list_experiments(args.params)
        return 0
    if args.command == "compare":
        return _compare(args, argv)
    if args.command in ("simulate", "fit"):
        from ._cli_model import run
        return run(args, argv, _error)
    if args.command == "results":
        try:
            return _results(args)
        except ValueError as exc:
            return _error(exc)
    command = " ".join(["nlfilter", *(sys.argv[1:] if argv is None else argv)])
    if args.id == "all":
        return _reproduce_all(args, command)
    try:
        if args.report is not None:
            _check_folder(args.report)
        exp = experiments.get(args.id)
        params = {k: exp.convert(k, v) for k, v in _parse_params(args.param).items()}
        if args.runs is not None and not 1 <= args.runs <= experiments.MAX_RUNS:
            raise ValueError(f"--runs: expected an integer from 1 to {experiments.MAX_RUNS:,}, got {args.runs}")
        _check_seed(args.seed)
        _check_execution(args)
        _check_output("--json", args.json, ".json")
        _check_output("--plot", args.plot, ".png")
        store = _open_store(args)
    except (ValueError, TypeError) as exc:
        return _error(exc)
    run_id = None
    if store is not None:
        run_id = store.start_run(exp.id, params=params, seed=args.seed, runs=args.runs, quick=args.quick,
                                 command=command)
        _KEPT.text = (f"; the finished Monte Carlo blocks are kept in {store.path} (run {run_id}): "
                      "rerun the same command to resume")
    status = "failed"
    try:
        result = exp.run(params, quick=args.quick, runs=args.runs, seed=args.seed,
                         progress=not args.no_progress, chunk=args.chunk, executor=args.executor,
                         store=store, scheduler=args.scheduler, workers=args.workers)
        status = "done"
    except KeyboardInterrupt:
        status = "interrupted"
        raise
    except ValueError as exc:  # a parameter value the experiment itself rejects
        return _error(exc)
    finally:
        if store is not None:
            if status != "done":
                store.finish_run(run_id, status)
                store.close()
    result.meta["command"] = command
    if store is not None:
        store.finish_run(run_id, "done", result)
        store.close()
        ex = result.meta.get("execution", {})
        if ex.get("blocks_reused"):
            print(f"reused {ex['blocks_reused']} finished Monte Carlo block(s) from {store.path}", file=sys.stderr)
    _write(result, args)
    return 0


def _error(exc) -> int:
    """One line on stderr (the first of the message), exit code 2."""
    from .sources import cite
    msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    print(f"nlfilter: error: {cite(msg)}", file=sys.stderr)
    return 2


def _compare(args, argv) -> int:
    """``nlfilter compare MODEL.toml``: :func:`nlfilter.comparison.compare` on the file's model and
    prior, the file's ``[run]`` defaults overridden by the options; the file's path and sha256 in
    ``meta``. The run is recorded in the results store (experiment ``compare``) and every finished
    task is kept there: the same command resumes an interrupted comparison."""
    from . import montecarlo as mc
    from .comparison import compare
    from .modelfile import load_model

    command = " ".join(["nlfilter", *(sys.argv[1:] if argv is None else argv)])
    try:
        spec = load_model(args.model)
        _check_output("--json", args.json, ".json")
        _check_output("--plot", args.plot, ".png")
        if args.report is not None:
            _check_folder(args.report)
        _check_execution(args)
        for opt, value, low in (("--paths", args.paths, 2), ("--steps", args.steps, 1), ("--seed", args.seed, 0),
                                ("--block", args.block, 1), ("--max-particles", args.max_particles, 1)):
            if value is not None and value < low:
                raise ValueError(f"{opt}: got {value}; expected an integer ≥ {low}")
        if args.reference_budget is not None and not args.reference_budget > 0:
            raise ValueError(f"--reference-budget: got {args.reference_budget}; expected a positive number of seconds")
        if args.reference == "none" and (args.max_particles is not None or args.reference_budget is not None):
            raise ValueError("--reference none: given with --max-particles/--reference-budget; expected a reference "
                             "to budget")
        filters = spec.filters
        if args.filters is not None:
            names = [f.strip() for f in args.filters.split(",")]
            if args.filters.strip() == "all":
                filters = "all"
            elif not all(names):
                raise ValueError(f"--filters: got {args.filters!r}; expected 'all' or comma-separated registry names")
            else:
                filters = names
        if filters != "all":  # a typo is refused before a run is recorded
            from .compare_filters import check_names
            check_names(filters)
        paths = spec.paths if args.paths is None else args.paths
        from .modelfile_times import compare_timing
        steps, timing = compare_timing(spec, args.steps)  # dt, or a continuous-discrete model's times
        seed = spec.seed if args.seed is None else args.seed
        _check_seed(seed)
        ref_kw = {"reference": None if args.reference == "none" else args.reference,
                  "reference_budget": args.reference_budget}
        if args.max_particles is not None:
            ref_kw["max_particles"] = args.max_particles
        store = _open_store(args)
    except (ValueError, TypeError) as exc:  # the file, an option
        return _error(exc)
    params = {"model_sha256": spec.sha256, "paths": paths, "steps": steps, "seed": seed,
              "filters": filters if filters == "all" else list(filters), "block": args.block, **ref_kw}
    run_id = None
    if store is not None:
        run_id = store.start_run("compare", params=params, seed=seed, runs=paths, quick=False, command=command)
        _KEPT.text = (f"; the finished tasks are kept in {store.path} (run {run_id}): rerun the same command "
                      "to resume")
    status = "failed"
    try:
        with mc.session(executor=args.executor, store=store, experiment="compare", seed=seed,
                        scheduler=args.scheduler, workers=args.workers):
            result = compare(spec.model, filters if filters == "all" else list(filters), steps, paths=paths,
                             m0=spec.m0, P0=spec.P0, rng=seed, **timing, progress=not args.no_progress,
                             block=args.block, chunk=args.chunk, **ref_kw)
        status = "done"
    except KeyboardInterrupt:
        status = "interrupted"
        raise
    except (ValueError, TypeError) as exc:  # a filter the model cannot serve, a reference it cannot have
        return _error(exc)
    finally:
        if store is not None and status != "done":
            store.finish_run(run_id, status)
            store.close()
    result.meta.update(model_file=str(args.model), model_sha256=spec.sha256,
                       given={k: v for k, v in (("paths", args.paths), ("steps", args.steps),
                                                ("filters", args.filters), ("seed", args.seed),
                                                ("reference", None if args.reference == "auto" else args.reference),
                                                ("max_particles", args.max_particles),
                                                ("reference_budget", args.reference_budget)) if v is not None},
                       command=command)
    if store is not None:
        store.finish_run(run_id, "done", result)
        store.close()
        reused = result.meta.get("execution", {}).get("tasks_reused")
        if reused:
            print(f"reused {reused} finished task(s) from {store.path}", file=sys.stderr)
    _write(result, args)
    return 0


def _write(result, args) -> None:
    """Print the table (an experiment's: :func:`nlfilter.report.render_text`); write the JSON and
    the figure when asked."""
    print(_text(result, args))
    if args.json:
        result.to_json(args.json)
        print(f"wrote {args.json}")
    if args.plot:
        from .plots import plot_result

        plot_result(result, args.plot)
        print(f"wrote {args.plot}")
    if args.report:
        from .report import write_report

        print(f"wrote {write_report([result], args.report)}")
    return 0


def _text(result, args) -> str:
    """An experiment's compact table (``--all``, ``--notes``: more); a comparison's whole table."""
    if result.experiment == "compare":
        return result.table()
    from .report import render_text
    return render_text(result, all_rows=args.all, notes=args.notes)


def _check_folder(path: str) -> None:
    if not path.strip():
        raise ValueError("--report: expected a folder path, got an empty string")
    if os.path.exists(path) and not os.path.isdir(path):
        raise ValueError(f"--report {path!r}: is a file; expected a folder")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise ValueError(f"--report {path!r}: the folder {parent!r} does not exist")


def _reproduce_all(args, command) -> int:
    """``nlfilter reproduce all``: every experiment in turn; with a store, an experiment already
    finished with the same settings and code is read back instead of run again, so an interrupted
    ``reproduce all`` resumes (its unfinished experiment from its finished blocks)."""
    from . import experiments
    from .plots import plot_result
    from .report import write_report

    try:
        for opt, val in (("--param", args.param), ("--runs", args.runs), ("--json", args.json), ("--plot", args.plot)):
            if val:
                raise ValueError(f"{opt}: not with `reproduce all` (each experiment has its own); use --report DIR")
        _check_seed(args.seed)
        _check_execution(args)
        if args.report is not None:
            _check_folder(args.report)
            os.makedirs(args.report, exist_ok=True)
        store = _open_store(args)
    except ValueError as exc:
        return _error(exc)
    results = []
    try:
        for exp in experiments.registry().values():
            found = None if store is None else store.find_done(exp.id, params={}, seed=args.seed, runs=None,
                                                               quick=args.quick)
            if found is not None:
                print(f"{exp.id}: finished earlier, read back from {store.path}", file=sys.stderr)
                result = found
            else:
                run_id = None
                if store is not None:
                    run_id = store.start_run(exp.id, params={}, seed=args.seed, runs=None, quick=args.quick,
                                             command=command)
                    _KEPT.text = (f" during {exp.id}; finished experiments and Monte Carlo blocks are kept in "
                                  f"{store.path}: rerun the same command to resume")
                status = "failed"
                try:
                    result = exp.run({}, quick=args.quick, seed=args.seed, progress=not args.no_progress,
                                     chunk=args.chunk, executor=args.executor, store=store,
                                     scheduler=args.scheduler, workers=args.workers)
                    result.meta["command"] = command
                    status = "done"
                except KeyboardInterrupt:
                    status = "interrupted"
                    raise
                finally:
                    if store is not None:
                        store.finish_run(run_id, status, result if status == "done" else None)
                if args.report is not None and result.series:
                    plot_result(result, os.path.join(args.report, f"{exp.id}.png"))
            print(_text(result, args))
            print()
            results.append(result)
    finally:
        if store is not None:
            store.close()
    if args.report is not None:
        print(f"wrote {write_report(results, args.report, figures=False)}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
