"""`python -m samp.runs COMMAND ...`: list, show and compare runs; tables and plots over sweeps; the paper's tables.

  ls [KEY=VALUE ...] [--root DIR] [--keys K ...]        runs under runs/ (or --root), filtered by any key
  show RUN                                             one run's record: status, lineage, metrics, files
  compare RUN RUN ... [--metrics M ...]                side by side: lineage, differing config, metrics
  table DIR --by KEY [--metrics M ...] [--out PREFIX]  one row per value of KEY (mean ± std), .md and .csv
  plot DIR --by KEY [--metrics M ...] [--kind curves|bars] [--out FILE.png]
                                                       learning curves from metrics.csv, or bars of final metrics
  paper-tables [--root DIR] [--out DIR]                Table I and Table II from the runs that exist

Keys are config keys (datamodule.n_e, name), record keys (status, seed, dataset_id) and metrics
(val/loss, eval/samp/heldout/success_rate). Tables and plots go beside the runs unless --out says where.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["main"]


def _root(value: str | None) -> Path:
    """A folder argument: as given when it exists from here, else from the repository root; default runs/."""
    from samp.paths import REPO_ROOT
    from samp.runs import runs_root

    if value is None:
        return runs_root()
    path = Path(value).expanduser()
    return path if path.is_absolute() or path.exists() else REPO_ROOT / path


def _runs(folder: str):
    from samp.runs.registry import find_runs

    runs = find_runs(_root(folder))
    if not runs:
        raise FileNotFoundError(f"no runs (folders with a run.json) under {_root(folder)}")
    return runs


def _ls(a) -> None:
    from samp.runs.registry import matches
    from samp.runs.tables import list_table, markdown

    runs = [r for r in _runs(a.root) if matches(r, a.filters)]
    header, rows = list_table(runs, a.keys)
    print(markdown(header, rows) + f"\n{len(rows)} run(s)")


def _show(a) -> None:
    from samp.runs.registry import load_run
    from samp.runs.tables import show_text

    print(show_text(load_run(_root(a.run))), end="")


def _compare(a) -> None:
    from samp.runs.registry import load_run
    from samp.runs.tables import compare_table, markdown

    if len(a.runs) < 2:
        raise ValueError("compare needs two or more run folders")
    print(markdown(*compare_table([load_run(_root(r)) for r in a.runs], a.metrics)), end="")


def _table(a) -> None:
    from samp.runs.tables import default_metrics, group_table, markdown, write_table

    runs = _runs(a.dir)
    header, rows = group_table(runs, a.by, a.metrics or default_metrics(runs))
    print(markdown(header, rows), end="")
    prefix = Path(a.out) if a.out else _root(a.dir) / f"table_by_{a.by.replace('/', '_')}"
    print("wrote " + ", ".join(str(p) for p in write_table(prefix, header, rows)))


def _plot(a) -> None:
    from samp.runs.plots import CURVE_METRICS, plot_bars, plot_curves
    from samp.runs.tables import default_metrics

    runs = _runs(a.dir)
    tag = a.by.replace("/", "_")
    if a.kind == "curves":
        out = Path(a.out) if a.out else _root(a.dir) / f"curves_by_{tag}.png"
        path = plot_curves(runs, a.by, a.metrics or list(CURVE_METRICS), out, x=a.x)
    else:
        out = Path(a.out) if a.out else _root(a.dir) / f"bars_by_{tag}.png"
        path = plot_bars(runs, a.by, a.metrics or default_metrics(runs, limit=4), out)
    print(f"wrote {path}")


def _paper_tables(a) -> None:
    from samp.runs.paper import paper_tables
    from samp.runs.registry import find_runs
    from samp.runs.tables import markdown, write_table

    root = _root(a.root)
    runs = find_runs(root) if root.is_dir() else []
    out = Path(a.out) if a.out else root / "paper_tables"
    titles = {"table_1": "Table I: motion planning (training / held-out scenes)",
              "table_2": "Table II: anchor size (n_e per axis)"}
    for name, (header, rows) in paper_tables(runs, root).items():
        print(f"{titles[name]}\n\n{markdown(header, rows)}")
        print("wrote " + ", ".join(str(p) for p in write_table(out / name, header, rows, titles[name])) + "\n")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m samp.runs", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("ls", help="list runs")
    s.add_argument("filters", nargs="*", help="KEY=VALUE")
    s.add_argument("--root", default=None)
    s.add_argument("--keys", nargs="*", default=[], help="extra columns")
    s.set_defaults(fn=_ls)
    s = sub.add_parser("show", help="one run")
    s.add_argument("run")
    s.set_defaults(fn=_show)
    s = sub.add_parser("compare", help="runs side by side")
    s.add_argument("runs", nargs="+")
    s.add_argument("--metrics", nargs="*", default=None)
    s.set_defaults(fn=_compare)
    for name, fn in (("table", _table), ("plot", _plot)):
        s = sub.add_parser(name, help=f"{name} over the runs in DIR grouped by a key")
        s.add_argument("dir")
        s.add_argument("--by", required=True)
        s.add_argument("--metrics", nargs="*", default=None)
        s.add_argument("--out", default=None)
        if name == "plot":
            s.add_argument("--kind", choices=("curves", "bars"), default="curves")
            s.add_argument("--x", choices=("epoch", "step"), default="epoch")
        s.set_defaults(fn=fn)
    s = sub.add_parser("paper-tables", help="Table I and Table II")
    s.add_argument("--root", default=None)
    s.add_argument("--out", default=None)
    s.set_defaults(fn=_paper_tables)
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        args.fn(args)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
