"""``nlfilter results list | show RUN | export [RUN ...] --csv PATH | --json PATH`` (the results
store, :mod:`nlfilter.store`) and the check of an output path shared by every subcommand of
:mod:`nlfilter.cli`: errors are ``ValueError``s, which the command line prints as one line."""

from __future__ import annotations

import os


def check_output(option: str, path: str | None, suffix: str | None = None) -> None:
    """Refuse, before any work, an output path that cannot be written."""
    if path is None:
        return
    if not path.strip():
        raise ValueError(f"{option}: expected a file path, got an empty string")
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise ValueError(f"{option} {path!r}: is a folder; expected a file path")
    if not os.path.isdir(folder):
        raise ValueError(f"{option} {path!r}: the folder {folder!r} does not exist")
    if not os.access(folder, os.W_OK) or not _can_create(folder):
        raise ValueError(f"{option} {path!r}: the folder {folder!r} is not writable")
    if suffix is not None and not path.lower().endswith(suffix):
        raise ValueError(f"{option} {path!r}: expected a file name ending in {suffix}")


def _can_create(folder: str) -> bool:
    """Whether a file can be created in ``folder`` (``os.access`` says yes to root under /proc)."""
    import tempfile
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".nlfilter-probe-")
    except OSError:
        return False
    os.close(fd)
    os.unlink(probe)
    return True


def results(args) -> int:
    """``nlfilter results list | show RUN | export [RUN ...] --csv PATH | --json PATH``."""
    from .store import ResultsStore, default_path

    path = args.store or str(default_path())
    if not os.path.exists(path):
        raise ValueError(f"--store {path!r}: no results store there (run `nlfilter reproduce ...` first)")
    with ResultsStore(path) as st:
        if args.action == "list":
            rows = st.runs(args.experiment)
            print("\t".join(["run", "experiment", "status", "seed", "runs", "quick", "started", "seconds", "command"]))
            for r in rows:
                secs = "-" if r["seconds"] is None else f"{r['seconds']:.1f}"
                print("\t".join(str(v) for v in (r["id"], r["experiment"], r["status"], r["seed"],
                                                 "-" if r["runs"] is None else r["runs"], bool(r["quick"]),
                                                 r["started"], secs, r["command"] or "-")))
            return 0
        if args.action == "show":
            run = st.run(args.run_id)
            print(f"run {run['id']}: {run['experiment']} ({run['status']}, started {run['started']}, "
                  f"nlfilter {run['version']}, code {run['code']})")
            if run["result"] is None:
                print(f"no table: the run is {run['status']}; its finished Monte Carlo blocks are in the store "
                      f"({st.count_blocks(run['experiment'])} block(s) of {run['experiment']})")
            elif run["result"].experiment == "compare":
                print(run["result"].table())
            else:
                from .report import render_text
                print(render_text(run["result"], all_rows=args.all, notes=args.notes))
            return 0
        # export
        option = "--csv" if args.csv is not None else "--json"
        out = args.csv if args.csv is not None else args.json
        check_output(option, out, option.replace("--", "."))
        if args.run_ids:
            picked = [st.run(i) for i in args.run_ids]
            bad = [r["id"] for r in picked if r["result"] is None]
            if bad:
                raise ValueError(f"RUN {bad[0]}: not finished (status {picked[0]['status']}); expected a done run")
        else:
            latest = {}
            for r in st.runs():
                if r["status"] == "done" and r["experiment"] not in latest:
                    latest[r["experiment"]] = r["id"]
            picked = [st.run(i) for i in sorted(latest.values())]
        from .results import atomic_write as _atomic_write

        def atomic_write(path, data):  # what the up-front check cannot foresee (a full disk): one line
            try:
                _atomic_write(path, data)
            except OSError as exc:
                raise ValueError(f"{option} {path!r}: cannot write it ({exc.strerror or exc})") from None
        if args.json is not None:
            import json
            text = json.dumps([{"run": r["id"], **r["result"].to_dict()} for r in picked], indent=2,
                              allow_nan=False, ensure_ascii=False) + "\n"
            atomic_write(out, text.encode("utf-8"))
        else:
            import csv
            import io
            import json
            buf = io.StringIO()
            w = csv.writer(buf)
            w.writerow(["run", "experiment", "filter", "quantity", "params", "paper", "value", "stderr"])
            for r in picked:
                for row in r["result"].rows:
                    d = row.to_dict()
                    w.writerow([r["id"], r["experiment"], d["filter"], d["quantity"],
                                json.dumps(d["params"], sort_keys=True), "" if d["paper"] is None else d["paper"],
                                d["value"], "" if d["stderr"] is None else d["stderr"]])
            atomic_write(out, buf.getvalue().encode("utf-8"))
        print(f"wrote {out} ({len(picked)} run(s))")
        return 0
