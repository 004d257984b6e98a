"""``nlfilter simulate MODEL.toml --out DATA.csv`` (data from a model file) and ``nlfilter fit
MODEL.toml DATA.csv --params q,r`` (maximum likelihood of the file's parameters on the data,
:func:`nlfilter.fitting.fit`): the two commands that join a model file (:mod:`nlfilter.modelfile`)
and a data file (:mod:`nlfilter.data_csv`). Errors in what was typed or in the files: one line,
exit code 2 (as :mod:`nlfilter.cli`). Only the standard library at the top: NumPy, SymPy and the
filters load when a command runs."""

from __future__ import annotations

import json
import sys

#: the filter ``nlfilter fit`` uses by default, per kind of model file
DEFAULT_FILTER = {"discrete": "ukf", "sde": "continuous-ekf", "continuous-discrete": "continuous-discrete-ukf"}
LEVEL_Z = 1.959963984540054  # the 97.5 % standard normal quantile: nominal 95 % Wald intervals


def add_commands(sub) -> None:
    """The ``simulate`` and ``fit`` sub-commands of the ``nlfilter`` parser ``sub``."""
    s = sub.add_parser("simulate", help="simulate a model file's measurements into a CSV file")
    s.add_argument("model", metavar="MODEL.toml", help="the model file (see nlfilter.modelfile)")
    s.add_argument("--out", metavar="DATA.csv", required=True, help="the CSV file to write (nlfilter.data_csv)")
    s.add_argument("--steps", type=int, default=None,
                   help="measurements per record (default: the file's [run] steps, else 100; with measurement "
                        "times: their number)")
    s.add_argument("--paths", type=int, default=1, help="independent records (default 1; more: a 'path' column)")
    s.add_argument("--seed", type=int, default=None, help="seed of the random streams (default: the file's, else 0)")
    s.add_argument("--times", metavar="T1,T2,...", default=None,
                   help="continuous-discrete models: the measurement times (increasing; default the file's "
                        "[measurement] times, or dt, 2 dt, ...)")
    s.add_argument("--states", action="store_true", help="also write the true states (columns named after them)")
    f = sub.add_parser("fit", help="fit a model file's parameters to a CSV file of measurements (maximum likelihood)")
    f.add_argument("model", metavar="MODEL.toml", help="the model file (see nlfilter.modelfile)")
    f.add_argument("data", metavar="DATA.csv", help="the measurements (columns: the model's measurement names, t)")
    f.add_argument("--params", required=True, metavar="NAME,NAME",
                   help="the [parameters] to fit (the others keep the file's values, which are also the start)")
    f.add_argument("--filter", default=None, metavar="NAME",
                   help="the filter whose log-likelihood is maximized (default: ukf for a discrete model, "
                        "continuous-ekf for an sde, continuous-discrete-ukf for a continuous-discrete one)")
    f.add_argument("--json", metavar="PATH", help="write the estimate, standard errors and intervals as JSON")


def run(args, argv, error) -> int:
    """Run ``args.command`` (``simulate`` or ``fit``); ``error(exc)`` prints one line and gives 2."""
    return (_simulate if args.command == "simulate" else _fit)(args, argv, error)


def _command(argv) -> str:
    return " ".join(["nlfilter", *(sys.argv[1:] if argv is None else argv)])


def _out_path(opt, path, ext) -> None:
    from ._cli_results import check_output
    check_output(opt, path, ext)


def _simulate(args, argv, error) -> int:
    from .data_csv import write_csv
    from .modelfile import load_model
    from .modelfile_times import simulate_spec

    try:
        spec = load_model(args.model)
        _out_path("--out", args.out, ".csv")
        for opt, value, low in (("--paths", args.paths, 1), ("--steps", args.steps, 1), ("--seed", args.seed, 0)):
            if value is not None and value < low:
                raise ValueError(f"{opt}: got {value}; expected an integer ≥ {low}")
        seed = spec.seed if args.seed is None else args.seed
        sim, times = simulate_spec(spec, args.steps, args.paths, seed, args.times)
    except (ValueError, TypeError) as exc:
        return error(exc)
    write_csv(args.out, spec, sim.ys, times, sim.xs if args.states else None)
    print(f"wrote {args.out}: {args.paths} record(s) × {len(times)} measurement(s) of {spec.model.name or 'the model'}"
          f" ({spec.kind}, seed {seed})")
    return 0


def _fit(args, argv, error) -> int:
    from .data_csv import read_csv
    from .filters import REGISTRY
    from .fitting import fit
    from .modelfile import load_model
    from .modelfile_kinds import positive_parameters
    from .modelfile_times import fit_inputs

    try:
        spec = load_model(args.model)
        names = [p.strip() for p in args.params.split(",")]
        known = dict(spec.model.params)
        if not all(names) or len(set(names)) != len(names):
            raise ValueError(f"--params: got {args.params!r}; expected distinct comma-separated parameter names")
        unknown = [p for p in names if p not in known]
        if unknown:
            raise ValueError(f"--params: got the unknown parameter {unknown[0]!r}; expected names from the file's "
                             f"[parameters] {sorted(known) or '(none)'}")
        name = args.filter or DEFAULT_FILTER[spec.kind]
        if name not in REGISTRY:
            raise ValueError(f"--filter: got {name!r}; expected a registry name (`nlfilter list --filters`)")
        if args.json:
            _out_path("--json", args.json, ".json")
        data = read_csv(args.data, spec)
        ys, kw = fit_inputs(spec, data, REGISTRY[name])
        bounds = {k: v for k, v in positive_parameters(spec).items() if k in names}
        res = fit(spec.model, ys, {p: known[p] for p in names}, filter=kw.pop("filter", name), m0=spec.m0,
                  P0=spec.P0, bounds=bounds, **kw)
    except (ValueError, TypeError) as exc:
        return error(exc)
    print(str(res))
    prior = (spec.symbolic or {}).get(("prior", "cov"))
    held = sorted(str(v) for v in (prior.free_symbols if prior is not None else ()) if str(v) in names)
    note = (f"the prior's cov is written in {held}: it is held at the file's values (P0 = {spec.P0.tolist()}), not "
            "moved with the estimate" if held else None)
    if note:
        print(f"  note: {note}")
    rows = {}
    for p in names:
        v, se = res.params[p], res.se[p]
        lo, hi = v - LEVEL_Z * se, v + LEVEL_Z * se
        rows[p] = {"value": v, "se": se, "interval95": [lo, hi]}
        print(f"  {p:>12s}: 95 % interval [{lo:.6g}, {hi:.6g}] (file: {known[p]:.6g})")
    if args.json:
        out = dict(res.to_dict(), intervals95={p: r["interval95"] for p, r in rows.items()},
                   model_file=str(args.model), model_sha256=spec.sha256, data_file=str(args.data),
                   records=int(ys.shape[0]), measurements=int(ys.shape[1]), command=_command(argv),
                   notes=[note] if note else [])
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=1)
        print(f"wrote {args.json}")
    return 0


__all__ = ["add_commands", "run", "DEFAULT_FILTER"]
