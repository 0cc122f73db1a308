"""Tables over runs, as markdown (to read) and CSV (to process): listings, sweeps grouped by a key, and
side-by-side comparisons. A table is (header, rows) of strings; `write_table` puts both files side by side.

A rate whose Wilson 95 % interval the runs recorded beside it (protocol 2, `samp.runs.protocol`) shows in
percent with the interval, "93.3 [84.1, 97.4]", its row or column marked "[%]"; over several runs,
"mean ± std [interval]": the std is the runs' spread, the interval a bootstrap over the problems they were
evaluated on (`samp.runs.intervals`), left out for runs whose records cannot give it. Its `_ci_low` and `_ci_high` keys
do not get rows of their own.
"""

from __future__ import annotations

import csv
import io
import math
import sys
from pathlib import Path

from samp.eval.report import benchmark_refs
from samp.runs.protocol import BENCHMARK, BLOCKS, HARD_BENCHMARK, PROTOCOL, eval_key, interval_keys, label
from samp.runs.registry import Run, check_key, over_problems, varying_keys
from samp.tracking import tracked_at

__all__ = ["DASH", "compare_table", "default_metrics", "fmt", "group_table", "list_table", "markdown", "percent",
           "show_text", "stores", "to_csv", "write_table"]

DASH = "-"  # a value that is missing (no such run, or the run has no such metric)
TRACKED = "tracked"  # the MLflow run id of a run (samp.tracking), a column of `ls`
LIST_COLUMNS = ("run", "status", "experiment", "dataset_id", PROTOCOL, "seed", "steps", "start", TRACKED)
PERCENT = " [%]"  # marks a row or column of rates shown in percent with their intervals


def fmt(value, digits: int = 4) -> str:
    """A cell: numbers to `digits` significant digits, None as a dash."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return DASH
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    return f"{value:.{digits}g}" if isinstance(value, float) else str(value)


def percent(rate, interval: tuple[float, float] | None = None, std: float | None = None, digits: int = 1) -> str:
    """A rate (a fraction) in percent, "93.3", with its std over runs, "93.3 ± 2.1", and its interval,
    "93.3 [84.1, 97.4]" (as samp.eval.metrics' tables write it); None as a dash."""
    if rate is None:
        return DASH
    text = f"{100 * rate:.{digits}f}" + ("" if std is None else f" ± {100 * std:.{digits}f}")
    return text if interval is None else text + f" [{100 * interval[0]:.{digits}f}, {100 * interval[1]:.{digits}f}]"


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def to_csv(header: list[str], rows: list[list[str]]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return out.getvalue()


def write_table(prefix: Path, header: list[str], rows: list[list[str]], title: str = "", note: str = "") -> list[Path]:
    """`<prefix>.md` (the title above the table, the note below it) and `<prefix>.csv` (replacing earlier
    ones: tables are derived from the runs)."""
    prefix.parent.mkdir(parents=True, exist_ok=True)
    # Appended, not swapped in: a dotted key (`table_by_datamodule.n_e`) is no suffix to replace.
    stem = prefix.name[:-len(prefix.suffix)] if prefix.suffix in (".md", ".csv") else prefix.name
    md, cs = prefix.with_name(stem + ".md"), prefix.with_name(stem + ".csv")
    md.write_text((f"# {title}\n\n" if title else "") + markdown(header, rows) + (f"\n{note}\n" if note else ""))
    cs.write_text(to_csv(header, rows))
    return [md, cs]


def _cell(run: Run, key: str) -> str:
    """`run`'s value of `key`; the protocol as `ls` abbreviates it ("2", "1 (legacy)")."""
    if key == PROTOCOL:
        return DASH if run.protocol is None else label(run.protocol, short=True)
    if key == TRACKED:
        return fmt((tracked_at(run.record) or (None, None))[1])
    return fmt(run.get(key))


def list_table(runs: list[Run], extra: list[str] = ()) -> tuple[list[str], list[list[str]]]:
    """One row per run: name, status, experiment, dataset, evaluation protocol, seed, steps, start, then the
    `extra` keys."""
    rows = [[r.name, r.status, *(_cell(r, k) for k in LIST_COLUMNS[2:]), *(fmt(r.get(k)) for k in extra)] for r in runs]
    return list(LIST_COLUMNS) + list(extra), rows


def stores(runs: list[Run]) -> dict[str, int]:
    """Tracking URI -> how many of `runs` are tracked there."""
    found: dict[str, int] = {}
    for r in runs:
        where = tracked_at(r.record)
        if where:
            found[where[0]] = found.get(where[0], 0) + 1
    return found


def with_intervals(runs: list[Run], metrics: list[str]) -> set[str]:
    """The `metrics` that are rates with an interval recorded beside them in any of `runs`."""
    return {m for m in metrics if any(r.interval(m) is not None for r in runs)}


def _folded(metrics: list[str], runs: list[Run]) -> list[str]:
    """`metrics` less the interval keys of the rates among them shown with their intervals."""
    shown = {k for m in with_intervals(runs, metrics) for k in interval_keys(m)}
    return [m for m in metrics if m not in shown]


def _warn_protocols(runs: list[Run]) -> None:
    """A warning on stderr when `runs` were evaluated under different protocols (their numbers differ in kind)."""
    protocols = sorted({r.protocol for r in runs if r.protocol is not None})
    if len(protocols) > 1:
        print(f"warning: these runs were evaluated under different protocols ({', '.join(map(str, protocols))}); "
              "their evaluation metrics are not comparable (`python -m samp.runs show RUN` says what each means)",
              file=sys.stderr)


# (group, metric) pairs `default_metrics` puts first: what a policy is judged by, easy and hard problems apart
HEADLINE = [(group, key) for group in (BENCHMARK, f"{BENCHMARK}_hard", HARD_BENCHMARK)
            for key in ("success_rate", "collision_rate")]


def _mean_std(values: list[float]) -> str:
    if not values:
        return DASH
    mean = sum(values) / len(values)
    if len(values) == 1:
        return fmt(mean)
    std = math.sqrt(sum((v - mean) ** 2 for v in values) / len(values))
    return f"{fmt(mean)} ± {fmt(std, 2)}"


def _sort_key(value):
    return (0, value, "") if isinstance(value, (int, float)) and not isinstance(value, bool) else (1, 0, str(value))


def default_metrics(runs: list[Run], limit: int = 8) -> list[str]:
    """The numeric metrics every run has, at most `limit`: the run's own success and collision on the
    benchmark, its hard subset and the hard benchmark first (`HEADLINE`), then the evaluation's, the
    benchmarks' before other groups', the run's own planner before the expert and the straight line, rates first
    (their intervals go with them)."""
    common = set.intersection(*(set(r.metrics) for r in runs)) if runs else set()
    numeric = _folded([m for m in common if all(isinstance(r.metrics[m], (int, float)) for r in runs)], runs)

    def order(m: str):
        planner, group, key = eval_key(m) or ("", "", "")
        head = planner not in BLOCKS and (group, key) in HEADLINE  # the run's own success and collision first
        return (not head, HEADLINE.index((group, key)) if head else 0, not m.startswith("eval/"), group != BENCHMARK,
                group != HARD_BENCHMARK, planner in BLOCKS, "rate" not in m, m)

    return sorted(numeric, key=order)[:limit]


def _rate_over(runs: list[Run], key: str) -> str:
    """A rate over `runs` in percent: the mean ± std of their rates, and the bootstrap interval over their
    problems (one run: its own Wilson interval) when every run's records give its per-problem outcomes."""
    values = [float(v) for v in (r.get(key) for r in runs) if isinstance(v, (int, float)) and not isinstance(v, bool)]
    if not values:
        return DASH
    mean = sum(values) / len(values)
    std = math.sqrt(sum((v - mean) ** 2 for v in values) / len(values)) if len(values) > 1 else None
    interval = over_problems(runs, key)
    return percent(mean, interval, std)


def group_table(runs: list[Run], by: str, metrics: list[str]) -> tuple[list[str], list[list[str]]]:
    """One row per value of `by`: how many runs, their statuses, and each metric's mean ± std over them
    (rates with recorded intervals in percent, with the interval over their problems). Warns on stderr when the runs
    were evaluated under different protocols."""
    check_key(runs, by, "--by key")
    for m in metrics:
        check_key(runs, m, "metric")
    _warn_protocols(runs)
    rates = with_intervals(runs, metrics)
    groups: dict = {}
    for r in runs:
        groups.setdefault(r.setting(by), []).append(r)
    rows = []
    for value in sorted(groups, key=_sort_key):
        members = groups[value]
        statuses = sorted({r.status for r in members})
        cells = []
        for m in metrics:
            if m in rates:
                cells.append(_rate_over(members, m))
                continue
            got = [r.get(m) for r in members]
            cells.append(_mean_std([float(v) for v in got if isinstance(v, (int, float)) and not isinstance(v, bool)]))
        rows.append([fmt(value), str(len(members)), ",".join(statuses), *cells])
    return [by, "runs", "status", *(m + PERCENT if m in rates else m for m in metrics)], rows


def compare_table(runs: list[Run], metrics: list[str] | None = None) -> tuple[list[str], list[list[str]]]:
    """Keys as rows, runs as columns: the lineage, every config key that differs, then the metrics (rates
    with recorded intervals in percent, "93.3 [84.1, 97.4]"). Warns on stderr when the runs are for
    different robots or were evaluated under different protocols."""
    robots = sorted({str(r.robot) for r in runs})
    if len(robots) > 1:
        print(f"warning: these runs are for different robots ({', '.join(robots)}); their metrics are not "
              "comparable", file=sys.stderr)
    _warn_protocols(runs)
    lineage = ["status", "experiment", "dataset_id", PROTOCOL, "robot_sdf_artifact_id", "code_version.git_commit",
               "code_version.git_dirty", "seed", "steps"]
    differing = varying_keys(runs, sorted(set().union(*(r.values for r in runs)) - set(lineage)))
    metrics = metrics or _folded(sorted(set().union(*(r.metrics for r in runs))), runs)
    rates = with_intervals(runs, metrics)
    rows = [[k, *(_cell(r, k) for r in runs)] for k in [*lineage, *differing]]
    rows += [[m + PERCENT, *(percent(r.get(m), r.interval(m)) for r in runs)] if m in rates
             else [m, *(fmt(r.get(m)) for r in runs)] for m in metrics]
    return ["key", *(r.name for r in runs)], rows


def _code_line(code: dict) -> str:
    """The code a run ran, as `show` prints it: samp's version, and the commit (dirty or not) only where one is
    known (a wheel install or a copy without `.git` records none)."""
    line = f"samp {code.get('package') or 'of unknown version'}"
    if code.get("git_commit"):
        line += f" at {code['git_commit']}" + (" (dirty)" if code.get("git_dirty") else "")
    return line


def show_text(run: Run) -> str:
    """A run's record as text: status and times, lineage, overrides, metrics and files."""
    rec, code = run.record, run.record.get("code_version") or {}
    benches = benchmark_refs(run.evaluation or {})
    lines = [f"run        {run.path}", f"status     {run.status}" + (f"  ({rec['error']})" if rec.get("error") else ""),
             f"experiment {rec.get('experiment')}   seed {rec.get('seed')}   robot {run.robot}",
             f"started    {rec.get('start')}   ended {rec.get('end')}   starts {len(rec.get('starts') or [])}",
             f"steps      {rec.get('steps')}   epochs {rec.get('epochs')}   fit time {fmt(rec.get('fit_time_s'))} s",
             f"dataset    {rec.get('dataset_id')}   robot SDF {rec.get('robot_sdf_artifact_id')}",
             f"protocol   {label(run.protocol)}" + "".join(f"   {section} {ref}" for section, ref in benches.items()),
             "code       " + _code_line(code),
             f"host       {rec.get('host')}",
             "overrides  " + " ".join(rec.get("overrides") or [])]
    if rec.get("sweep"):
        lines.append(f"sweep      {rec['sweep'].get('dir')} member {rec['sweep'].get('member')}")
    where = tracked_at(rec)
    lines.append(f"tracked    {where[0]} run {where[1]}" if where else "tracked    no (tracking was off)")
    if run.metrics:
        keys = _folded(sorted(run.metrics), [run])
        lines += ["", markdown(["metric", "value"], [[k + PERCENT, percent(run.get(k), run.interval(k))]
                                                     if run.interval(k) else [k, fmt(run.get(k))] for k in keys])]
    files = sorted(p.relative_to(run.path).as_posix() + ("/" if p.is_dir() else "") for p in run.path.iterdir())
    lines += ["files      " + "  ".join(files)]
    return "\n".join(lines) + "\n"
