"""The paper's Table I (motion planning) and Table II (anchor size) from whatever runs exist.

Which run fills which row is data (`TABLE_I`, `TABLE_II`): a row names an experiment (conf/experiment/),
and its newest completed run with an evaluation (`<run>/eval/metrics.json`, written after training or by
`python -m samp.eval run=RUN_DIR`) fills it; a row without such a run shows a dash. The expert row reads
the expert block of the SAMP runs' evaluations (the expert's trajectories on the same problems), else a
stand-alone `python -m samp.eval planner=expert` result under `runs/eval/`. Cells are "training scenes /
held-out scenes", as in the paper; rates in percent. Every table says which run each row came from, so a
reader can check that the rows share a dataset.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from samp.eval.metrics import metric
from samp.runs.registry import Run
from samp.runs.tables import DASH, fmt

__all__ = ["Row", "TABLE_I", "TABLE_II", "paper_tables"]


@dataclass(frozen=True)
class Row:
    """A table row: its label and the experiment whose run fills it (`planner`: which block of the run's
    eval/metrics.json, "metrics" for the run's own policy, "expert" for the expert beside it)."""

    label: str
    experiments: tuple[str, ...]
    planner: str = "metrics"


TABLE_I = (
    Row("Expert (OMPL)", ("samp_n100", "samp_n160"), planner="expert"),
    Row("MPNet", ("mpnet",)),
    Row("MPiNet", ("mpinet",)),
    Row("SAMP (100 anchors)", ("samp_n100",)),
    Row("SAMP (160 anchors)", ("samp_n160",)),
)
TABLE_II = tuple(Row(str(n), (f"samp_n{n}",)) for n in (40, 70, 100, 130, 160))
SPLITS = ("train", "heldout")
# Table I's metric columns as the paper has them: (header, key in eval/metrics.json, scale, significant digits).
TABLE_I_COLUMNS = (("soln. time [s]", metric("solution_time").key, 1.0, 3),
                   ("path length [m]", metric("path_length").key, 1.0, 2),
                   ("success [%]", metric("success_rate").key, 100.0, 3),
                   ("collision [%]", metric("collision_rate").key, 100.0, 3))
TABLE_II_RATES = tuple(metric(name).key for name in ("success_rate", "reach_rate", "collision_rate"))  # in percent
INFERENCE_TIME = metric("inference_time").key  # seconds per policy step


def _newest_evaluated(runs: list[Run], experiments: tuple[str, ...]) -> Run | None:
    """The newest completed run of any of `experiments` that has an evaluation."""
    found = [r for r in runs if r.record.get("experiment") in experiments and r.status == "completed" and r.evaluation]
    return max(found, key=lambda r: str(r.record.get("start") or "")) if found else None


def _expert_alone(root: Path) -> tuple[dict | None, str]:
    """The newest stand-alone expert evaluation under `<root>/eval/` (`python -m samp.eval planner=expert`)."""
    reports = []
    for path in sorted((root / "eval").glob("*/metrics.json")):
        report = json.loads(path.read_text())
        if report.get("planner") == "expert":
            reports.append((str(report.get("created") or ""), report, path.parent))
    if not reports:
        return None, DASH
    _, report, folder = max(reports, key=lambda t: t[0])
    return report["metrics"], f"{folder.name} ({report.get('dataset')})"


def _pair(block: dict | None, metric: str, scale: float = 1.0, digits: int = 3) -> str:
    """"train / heldout" for one metric."""
    cells = []
    for split in SPLITS:
        value = ((block or {}).get(split) or {}).get(metric)
        cells.append(DASH if value is None else fmt(float(value) * scale, digits))
    return " / ".join(cells)


def _source(run: Run | None) -> str:
    return DASH if run is None else f"{run.name} ({(run.evaluation or {}).get('dataset') or run.record.get('dataset_id')})"


def table_one(runs: list[Run], root: Path) -> tuple[list[str], list[list[str]]]:
    header = ["method", *(title for title, *_ in TABLE_I_COLUMNS), "run"]
    rows = []
    for row in TABLE_I:
        run = _newest_evaluated(runs, row.experiments)
        block = (run.evaluation or {}).get(row.planner) if run else None
        source = _source(run)
        if block is None and row.planner == "expert":
            block, source = _expert_alone(root)
        cells = [_pair(block, key, scale, digits) for _, key, scale, digits in TABLE_I_COLUMNS]
        rows.append([row.label, *cells, source])
    return header, rows


def table_two(runs: list[Run]) -> tuple[list[str], list[list[str]]]:
    header = ["anchors n_e", "train time / epoch [s]", "inference / step [s]", "success / reach / collision, train [%]",
              "success / reach / collision, held-out [%]", "run"]
    rows = []
    for row in TABLE_II:
        run = _newest_evaluated(runs, row.experiments)
        block = (run.evaluation or {}).get(row.planner) if run else None
        epochs, fit_s = (run.record.get("epochs"), run.record.get("fit_time_s")) if run else (None, None)
        per_epoch = fmt(fit_s / epochs, 3) if epochs and fit_s else DASH
        infer = ((block or {}).get("all") or (block or {}).get("heldout") or {}).get(INFERENCE_TIME)
        rates = []
        for split in SPLITS:
            m = (block or {}).get(split) or {}
            rates.append(" / ".join(DASH if m.get(k) is None else fmt(100 * float(m[k]), 3)
                                    for k in TABLE_II_RATES))
        rows.append([row.label, per_epoch, DASH if infer is None else fmt(float(infer), 2), *rates, _source(run)])
    return header, rows


def paper_tables(runs: list[Run], root: Path) -> dict[str, tuple[list[str], list[list[str]]]]:
    """{"table_1": (header, rows), "table_2": ...}; "train time / epoch" is the fit wall time over the
    epochs run (validation and in-training evaluation included)."""
    return {"table_1": table_one(runs, root), "table_2": table_two(runs)}
