"""Tables over runs, as markdown (to read) and CSV (to process): listings, sweeps grouped by a key, and
side-by-side comparisons. A table is (header, rows) of strings; `write_table` puts both files side by side."""

from __future__ import annotations

import csv
import io
import math
import sys
from pathlib import Path

from samp.runs.registry import Run, check_key, varying_keys

__all__ = ["DASH", "compare_table", "default_metrics", "fmt", "group_table", "list_table", "markdown", "show_text", "to_csv",
           "write_table"]

DASH = "-"  # a value that is missing (no such run, or the run has no such metric)
LIST_COLUMNS = ("run", "status", "experiment", "dataset_id", "seed", "steps", "start")


def fmt(value, digits: int = 4) -> str:
    """A cell: numbers to `digits` significant digits, None as a dash."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return DASH
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    return f"{value:.{digits}g}" if isinstance(value, float) else str(value)


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


def write_table(prefix: Path, header: list[str], rows: list[list[str]], title: str = "") -> list[Path]:
    """`<prefix>.md` and `<prefix>.csv` (replacing earlier ones: tables are derived from the runs)."""
    prefix.parent.mkdir(parents=True, exist_ok=True)
    md, cs = prefix.with_suffix(".md"), prefix.with_suffix(".csv")
    md.write_text((f"# {title}\n\n" if title else "") + markdown(header, rows))
    cs.write_text(to_csv(header, rows))
    return [md, cs]


def list_table(runs: list[Run], extra: list[str] = ()) -> tuple[list[str], list[list[str]]]:
    """One row per run: name, status, experiment, dataset, seed, steps, start, then the `extra` keys."""
    rows = [[r.name, r.status, *(fmt(r.get(k)) for k in LIST_COLUMNS[2:]), *(fmt(r.get(k)) for k in extra)]
            for r in runs]
    return list(LIST_COLUMNS) + list(extra), rows


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
    """The numeric metrics every run has (rollout rates first), at most `limit`."""
    common = set.intersection(*(set(r.metrics) for r in runs)) if runs else set()
    numeric = [m for m in common if all(isinstance(r.metrics[m], (int, float)) for r in runs)]
    return sorted(numeric, key=lambda m: (not m.startswith("eval/"), "rate" not in m, m))[:limit]


def group_table(runs: list[Run], by: str, metrics: list[str]) -> tuple[list[str], list[list[str]]]:
    """One row per value of `by`: how many runs, their statuses, and each metric's mean ± std over them."""
    check_key(runs, by, "--by key")
    for m in metrics:
        check_key(runs, m, "metric")
    groups: dict = {}
    for r in runs:
        groups.setdefault(r.get(by), []).append(r)
    rows = []
    for value in sorted(groups, key=_sort_key):
        members = groups[value]
        statuses = sorted({r.status for r in members})
        cells = []
        for m in metrics:
            got = [r.get(m) for r in members]
            cells.append(_mean_std([float(v) for v in got if isinstance(v, (int, float)) and not isinstance(v, bool)]))
        rows.append([fmt(value), str(len(members)), ",".join(statuses), *cells])
    return [by, "runs", "status", *metrics], rows


def compare_table(runs: list[Run], metrics: list[str] | None = None) -> tuple[list[str], list[list[str]]]:
    """Keys as rows, runs as columns: the lineage, every config key that differs, then the metrics.
    Warns on stderr when the runs are for different robots."""
    robots = sorted({str(r.robot) for r in runs})
    if len(robots) > 1:
        print(f"warning: these runs are for different robots ({', '.join(robots)}); their metrics are not "
              "comparable", file=sys.stderr)
    lineage = ["status", "experiment", "dataset_id", "robot_sdf_artifact_id", "code_version.git_commit",
               "code_version.git_dirty", "seed", "steps"]
    differing = varying_keys(runs, sorted(set().union(*(r.values for r in runs)) - set(lineage)))
    metrics = metrics or sorted(set().union(*(r.metrics for r in runs)))
    rows = [[k, *(fmt(r.get(k)) for r in runs)] for k in [*lineage, *differing, *metrics]]
    return ["key", *(r.name for r in runs)], rows


def show_text(run: Run) -> str:
    """A run's record as text: status and times, lineage, overrides, metrics and files."""
    rec, code = run.record, run.record.get("code_version") or {}
    lines = [f"run        {run.path}", f"status     {run.status}" + (f"  ({rec['error']})" if rec.get("error") else ""),
             f"experiment {rec.get('experiment')}   seed {rec.get('seed')}   robot {run.robot}",
             f"started    {rec.get('start')}   ended {rec.get('end')}   starts {len(rec.get('starts') or [])}",
             f"steps      {rec.get('steps')}   epochs {rec.get('epochs')}   fit time {fmt(rec.get('fit_time_s'))} s",
             f"dataset    {rec.get('dataset_id')}   robot SDF {rec.get('robot_sdf_artifact_id')}",
             f"code       {code.get('package')} at {code.get('git_commit')}" + (" (dirty)" if code.get("git_dirty") else ""),
             f"host       {rec.get('host')}",
             "overrides  " + " ".join(rec.get("overrides") or [])]
    if rec.get("sweep"):
        lines.append(f"sweep      {rec['sweep'].get('dir')} member {rec['sweep'].get('member')}")
    if run.metrics:
        lines += ["", markdown(["metric", "value"], [[k, fmt(v)] for k, v in sorted(run.metrics.items())])]
    files = sorted(p.relative_to(run.path).as_posix() + ("/" if p.is_dir() else "") for p in run.path.iterdir())
    lines += ["files      " + "  ".join(files)]
    return "\n".join(lines) + "\n"
