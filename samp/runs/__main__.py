"""`python -m samp.runs COMMAND [key=value ...]`: list, show and compare runs; tables and plots over sweeps;
the paper's tables.

usage: python -m samp.runs COMMAND [key=value ...]
  ls [KEY=VALUE ...] [root=DIR] [keys=K,K]         runs under runs/ (or root), filtered by any key, with where
                                                   each is tracked (MLflow run id, store URI)
  show RUN                                         one run's record: status, lineage, protocol, tracking, metrics, files
  compare RUN RUN ... [metrics=M,M]                side by side: lineage, differing config, metrics
  table DIR by=KEY [metrics=M,M] [out=PREFIX]      one row per value of KEY (mean ± std [interval]), .md and .csv
  plot DIR by=KEY [metrics=M,M] [kind=curves|bars] [x=epoch|step] [out=FILE.png]
  plot RUN kind=run [out=DIR]          one run's learning curves, outcomes and SDF slice (RUN/plots/)
                                                   learning curves from metrics.csv, or bars of final metrics
  paper-tables [root=DIR] [out=DIR]                Table I and Table II on the benchmark, from the runs that exist
  push RUN remote=URL [force=true]                 upload an ended run (file://, s3://, hf://)
  pull EXPERIMENT/RUN remote=URL [root=DIR]        download one into runs/, every file checked (or run=URL)

RUN and DIR are run folders (also run=RUN, dir=DIR). Keys are config keys (datamodule.n_e, name), record
keys (status, seed, dataset_id, protocol) and metrics (val/loss, eval/samp/benchmark/success_rate); in `ls`,
every KEY=VALUE other than root= and keys= is a filter. Rates with a recorded interval show in percent
as "rate [low, high]" (Wilson 95 %). Tables and plots go beside the runs unless out= says where. The
older spellings (--by KEY, --metrics M M, --out, --root, --keys, --kind, --x) still work.
"""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["main"]

USAGE = __doc__.split("\n\n", 1)[1].strip()


def _root(value: str | None) -> Path:
    """A folder argument: as given when it exists from here, else from the project folder; default runs/."""
    from samp.paths import project_dir
    from samp.runs import runs_root

    if value is None:
        return runs_root()
    path = Path(value).expanduser()
    return path if path.is_absolute() or path.exists() else project_dir() / path


def _runs(folder: str | None, quiet: bool = False):
    """The intact runs under a folder; each damaged run.json is named on stderr (unless `quiet`)."""
    from samp.runs.registry import scan_runs

    runs, damaged = scan_runs(_root(folder))
    if not quiet:
        _report_damaged(damaged)
    if not runs:
        raise FileNotFoundError(f"no runs (folders with a readable run.json) under {_root(folder)}")
    return runs


def _report_damaged(damaged) -> None:
    for path, why in damaged:
        print(f"damaged run record, left out: {why}", file=sys.stderr)  # `why` names the file


def _args(command: str, args: list[str], keys: tuple[str, ...], subject: str | None = None, lists=("metrics",),
          filters: bool = False) -> tuple[list[str], dict, list[str]]:
    """(folders, options, filters) of one command; `subject` names its folder argument(s) (also `subject=`)."""
    from samp.cli import parse_options

    names = keys + ((subject,) if subject else ())
    bare, opts, extra = parse_options(args, names, lists=lists, filters=filters, positional=subject, command=command)
    if subject in opts:
        bare.append(opts.pop(subject))
    return bare, opts, extra


def _one(command: str, what: str, folders: list[str]) -> str:
    if len(folders) != 1:
        raise ValueError(f"{command} takes one {what} folder, got {len(folders)}: {folders} "
                         f"(see `python -m samp.runs --help`)")
    return folders[0]


def _by(command: str, opts: dict) -> str:
    if not opts.get("by"):
        raise ValueError(f"{command} needs by=KEY: the config, record or metric key whose values make the rows "
                         "(e.g. by=datamodule.n_e, by=name, by=seed)")
    return opts["by"]


def _ls(args: list[str]) -> None:
    from samp.runs.protocol import label
    from samp.runs.registry import check_key, matches, scan_runs
    from samp.runs.tables import list_table, markdown, stores

    _, opts, filters = _args("ls", args, ("root", "keys"), lists=("keys",), filters=True)
    found, damaged = scan_runs(_root(opts.get("root")))
    if not found and not damaged:
        raise FileNotFoundError(f"no runs (folders with a run.json) under {_root(opts.get('root'))}")
    for f in filters:  # a typo (`stauts=completed`) would match nothing and look like an answer
        check_key(found, f.partition("=")[0], "filter key")
    runs = [r for r in found if matches(r, filters)]
    header, rows = list_table(runs, opts.get("keys", []))
    print(markdown(header, rows) + f"\n{len(rows)} run(s)" + (f", {len(damaged)} damaged:" if damaged else ""))
    for _, why in damaged:
        print(f"DAMAGED {why}")  # `why` names the file
    for protocol in sorted({r.protocol for r in runs if r.protocol is not None}, reverse=True):
        print(f"protocol {label(protocol)}")
    for uri, count in stores(runs).items():  # the `tracked` column's run ids are runs of these stores
        print(f"tracked in {uri}: {count} run(s)")


def _show(args: list[str]) -> None:
    from samp.runs.registry import load_run
    from samp.runs.tables import show_text

    folders, _, _ = _args("show", args, (), subject="run")
    print(show_text(load_run(_root(_one("show", "run", folders)))), end="")


def _compare(args: list[str]) -> None:
    from samp.runs.registry import load_run
    from samp.runs.tables import compare_table, markdown

    folders, opts, _ = _args("compare", args, ("metrics",), subject="run")
    if len(folders) < 2:
        raise ValueError("compare needs two or more run folders")
    print(markdown(*compare_table([load_run(_root(r)) for r in folders], opts.get("metrics"))), end="")


def _table(args: list[str]) -> None:
    from samp.runs.tables import default_metrics, group_table, markdown, write_table

    folders, opts, _ = _args("table", args, ("by", "metrics", "out"), subject="dir")
    folder, by = _one("table", "sweep (or runs)", folders), _by("table", opts)
    runs = _runs(folder)
    header, rows = group_table(runs, by, opts.get("metrics") or default_metrics(runs))
    print(markdown(header, rows), end="")
    prefix = Path(opts["out"]) if opts.get("out") else _root(folder) / f"table_by_{by.replace('/', '_')}"
    print("wrote " + ", ".join(str(p) for p in write_table(prefix, header, rows)))


def _plot(args: list[str]) -> None:
    from samp.runs.plots import CURVE_METRICS, plot_bars, plot_curves
    from samp.runs.tables import default_metrics

    folders, opts, _ = _args("plot", args, ("by", "metrics", "out", "kind", "x"), subject="dir")
    kind, x = opts.get("kind", "curves"), opts.get("x", "epoch")
    if kind == "run":  # one run's pictures (samp.runs.figures), into RUN/plots/ or out=DIR
        from samp.runs.figures import plot_run
        from samp.runs.registry import load_run

        run = load_run(_root(_one("plot", "run", folders)))
        for path in plot_run(run, Path(opts["out"]) if opts.get("out") else None):
            print(f"wrote {path}")
        return
    folder, by = _one("plot", "sweep (or runs)", folders), _by("plot", opts)
    if kind not in ("curves", "bars") or x not in ("epoch", "step"):
        raise ValueError(f"plot takes kind=curves|bars|run and x=epoch|step, got kind={kind} x={x}")
    runs = _runs(folder)
    metrics, tag = opts.get("metrics"), by.replace("/", "_")
    if kind == "curves":
        out = Path(opts["out"]) if opts.get("out") else _root(folder) / f"curves_by_{tag}.png"
        path = plot_curves(runs, by, metrics or list(CURVE_METRICS), out, x=x)
    else:
        out = Path(opts["out"]) if opts.get("out") else _root(folder) / f"bars_by_{tag}.png"
        path = plot_bars(runs, by, metrics or default_metrics(runs, limit=4), out)
    print(f"wrote {path}")


def _paper_tables(args: list[str]) -> None:
    from samp.runs.paper import paper_tables
    from samp.runs.registry import scan_runs
    from samp.runs.tables import markdown, write_table

    _, opts, _ = _args("paper-tables", args, ("root", "out"))
    root = _root(opts.get("root"))
    runs, damaged = scan_runs(root) if root.is_dir() else ([], [])
    _report_damaged(damaged)
    out = Path(opts["out"]) if opts.get("out") else root / "paper_tables"
    for name, (title, header, rows, note) in paper_tables(runs, root).items():
        print(f"{title}\n\n{markdown(header, rows)}\n{note}\n")
        print("wrote " + ", ".join(str(p) for p in write_table(out / name, header, rows, title, note)) + "\n")


def _push(args: list[str]) -> None:
    from samp.runs.sharing import push_run

    from samp.cli import flag

    folders, opts, _ = _args("push", args, ("remote", "force"), subject="run")
    if not opts.get("remote"):
        raise ValueError("say where to push: remote=URL (file:///srv/samp, s3://bucket/samp, hf://datasets/ORG/REPO)")
    url, sent, kept = push_run(_root(_one("push", "run", folders)), opts["remote"],
                               force=flag("force", opts.get("force", "false")))
    from samp.console import plural

    print(f"pushed {url}: {plural(sent, 'file')} uploaded, {kept} already there")


def _pull(args: list[str]) -> None:
    from samp.runs.sharing import pull_run

    refs, opts, _ = _args("pull", args, ("remote", "root"), subject="run")
    folder, got, kept = pull_run(_one("pull", "run", refs), opts.get("remote"),
                                 _root(opts["root"]) if opts.get("root") else None)
    if got + kept == 0:
        print(f"run {folder} is here already")
    else:
        from samp.console import plural

        print(f"pulled into {folder}: {plural(got, 'file')} downloaded, {kept} kept from an earlier try; every file matches "
              "its sha256 and the checkpoints the sha256 its run.json recorded")


COMMANDS = {"ls": _ls, "show": _show, "compare": _compare, "table": _table, "plot": _plot,
            "paper-tables": _paper_tables, "push": _push, "pull": _pull}


def main(argv: list[str] | None = None) -> int:
    from samp.cli import run_command

    return run_command(argv, USAGE, COMMANDS)


if __name__ == "__main__":
    sys.exit(main())
