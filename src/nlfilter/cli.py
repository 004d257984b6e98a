"""The ``nlfilter`` command: ``nlfilter list`` (``--filters``: the filter registry) and ``nlfilter reproduce ID``.

Errors in what the user typed (unknown experiment, unknown or malformed ``--param``) print one
line on stderr and exit with code 2, never a traceback.
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
    p = _Parser(prog="nlfilter", description="Moment-based nonlinear filters: reproduce the papers' experiments.")
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
    print(result.table())
    if args.json:
        result.to_json(args.json)
        print(f"wrote {args.json}")
    if args.plot:
        from .plots import plot_result

        plot_result(result, args.plot)
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
