"""The ``nlfilter`` command: ``nlfilter list`` (``--filters``: the filter registry), ``nlfilter reproduce ID``
and ``nlfilter compare MODEL.toml`` (every filter that applies against the certified reference, on a
model stated in a file: :mod:`nlfilter.modelfile`).

Errors in what the user typed (unknown experiment, unknown or malformed ``--param``, a model file
that cannot be read, an unknown filter) print one line on stderr and exit with code 2, never a
traceback.
"""

from __future__ import annotations

import argparse
import os
import sys

from . import experiments


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
                    help="list the filter registry instead: name, family, time, model kinds, needs, source")
    r = sub.add_parser("reproduce", help="run one experiment and print its table")
    r.add_argument("id", help="experiment id (see `nlfilter list`)")
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
    c.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return p


def _parse_params(items) -> dict:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--param {item!r}: expected NAME=VALUE")
        out[name.strip()] = value.strip()
    return out


def _show(value) -> str:
    """A default as ``--param`` takes it (lists comma-separated)."""
    if isinstance(value, (list, tuple)):
        return ",".join(map(str, value))
    return str(value)


def main(argv=None) -> int:
    try:
        return _main(argv)
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early: not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 0


def _main(argv) -> int:
    args = _parser().parse_args(argv)
    if args.command == "list" and args.filters:
        from .filters import REGISTRY
        from .filters.registry import table

        for row in table(REGISTRY):
            print("\t".join([row["name"], row["class"], row["family"] or "-", row["time"] or "-",
                              row["accepts"] or "-", row["needs"] or "-", row["likelihood"] or "-",
                              row["smoother"] or "-", row["source"] or "-"]))
        return 0
    if args.command == "list":
        for exp in experiments.registry().values():
            print(f"{exp.id}\t{exp.title}\t{exp.source}")
            if args.params:
                for name, default in sorted(exp.params.items()):
                    print(f"    --param {name}={_show(default)}")
        return 0
    if args.command == "compare":
        return _compare(args, argv)
    try:
        exp = experiments.get(args.id)
        params = {k: exp.convert(k, v) for k, v in _parse_params(args.param).items()}
        if args.runs is not None and args.runs < 1:
            raise ValueError(f"--runs: expected a positive integer, got {args.runs}")
        if args.chunk is not None and args.chunk < 1:
            raise ValueError(f"--chunk: expected a positive integer, got {args.chunk}")
    except ValueError as exc:
        print(f"nlfilter: error: {exc}", file=sys.stderr)
        return 2
    try:
        result = exp.run(params, quick=args.quick, runs=args.runs, seed=args.seed,
                         progress=not args.no_progress, chunk=args.chunk)
    except ValueError as exc:  # a parameter value the experiment itself rejects
        print(f"nlfilter: error: {exc}", file=sys.stderr)
        return 2
    result.meta["command"] = " ".join(["nlfilter", *(sys.argv[1:] if argv is None else argv)])
    _write(result, args)
    return 0


def _error(exc) -> int:
    """One line on stderr (the first of the message), exit code 2."""
    msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    print(f"nlfilter: error: {msg}", file=sys.stderr)
    return 2


def _compare(args, argv) -> int:
    """``nlfilter compare MODEL.toml``: :func:`nlfilter.comparison.compare` on the file's model and
    prior, the file's ``[run]`` defaults overridden by the options; the file's path and sha256 in
    ``meta``."""
    from .comparison import compare
    from .modelfile import load_model

    try:
        spec = load_model(args.model)
        for opt, value, low in (("--paths", args.paths, 2), ("--steps", args.steps, 1), ("--seed", args.seed, 0)):
            if value is not None and value < low:
                raise ValueError(f"{opt}: got {value}; expected an integer ≥ {low}")
        filters = spec.filters
        if args.filters is not None:
            names = [f.strip() for f in args.filters.split(",")]
            if args.filters.strip() == "all":
                filters = "all"
            elif not all(names):
                raise ValueError(f"--filters: got {args.filters!r}; expected 'all' or comma-separated registry names")
            else:
                filters = names
        paths = spec.paths if args.paths is None else args.paths
        steps = spec.steps if args.steps is None else args.steps
        seed = spec.seed if args.seed is None else args.seed
        result = compare(spec.model, filters if filters == "all" else list(filters), steps, paths=paths, m0=spec.m0,
                         P0=spec.P0, rng=seed, dt=spec.dt, progress=not args.no_progress)
    except ValueError as exc:  # the file, an option, or a filter the model cannot serve
        return _error(exc)
    result.meta.update(model_file=str(args.model), model_sha256=spec.sha256,
                       given={k: v for k, v in (("paths", args.paths), ("steps", args.steps),
                                                ("filters", args.filters), ("seed", args.seed)) if v is not None},
                       command=" ".join(["nlfilter", *(sys.argv[1:] if argv is None else argv)]))
    _write(result, args)
    return 0


def _write(result, args) -> None:
    """Print the table; write the JSON and the figure when asked."""
    print(result.table())
    if args.json:
        result.to_json(args.json)
        print(f"wrote {args.json}")
    if args.plot:
        from .plots import plot_result

        plot_result(result, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
