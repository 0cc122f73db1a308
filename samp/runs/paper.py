"""The paper's Table I (motion planning) and Table II (anchor size) from whatever runs exist, on the
standing benchmark of unseen scenes (docs/design.md section 4, "Splits and problems").

Which run fills which row is data (`TABLE_I`, `TABLE_II`): a row names an experiment (conf/experiment/),
and its newest completed run with an evaluation (`<run>/eval/metrics.json`, written after training or by
`python -m samp.eval run=RUN_DIR`) fills it, a run evaluated under the current protocol before any older
one (`samp.runs.protocol`); a row without such a run shows dashes. The expert and straight-line rows read
the expert and straight blocks of the Table I runs' evaluations (their trajectories on the same problems),
else a stand-alone `python -m samp.eval planner=expert` (or `planner=straight`) result under `runs/eval/`;
the expert variants (`expert_raw`, `ompl_sampling`, samp.eval.planners.EXPERT_VARIANTS) come from
stand-alone `python -m samp.eval planner=expert_raw` (or `ompl_sampling`) results only.

Cells are the benchmark group's: solution time one problem at a time (B = 1), path length, rates in
percent with their Wilson 95 % interval, success on the benchmark's hard subset, and Table I's success and
collision on the hard benchmark (`bench_hard`, group "hard": every problem needs a detour). A row filled by a
protocol-1 run shows that evaluation's "training / held-out scenes" values as the paper had them, its
label marked "(protocol 1: train / held-out)", never mixed silently with the benchmark's rows. Every table
names the benchmark and the datasets its rows' runs used in its title, and the run of each row, marked
"[unverified]" or "[trained on NAME@ID]" when its evaluation says so (`samp.eval.binding`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from samp.eval.metrics import metric
from samp.eval.report import benchmark_refs
from samp.runs.protocol import (BENCHMARK, CURRENT, HARD_BENCHMARK, SOLUTION_TIME_B1, STEP_TIME_B1, hard, interval_keys,
                                protocol_of)
from samp.runs.registry import Run
from samp.runs.tables import DASH, fmt, percent

__all__ = ["PaperTable", "Row", "TABLE_I", "TABLE_II", "paper_tables"]


@dataclass(frozen=True)
class Row:
    """A table row: its label and the experiment whose run fills it (`planner`: which block of the run's
    eval/metrics.json, "metrics" for the run's own policy, "expert" or "straight" for those beside it)."""

    label: str
    experiments: tuple[str, ...]
    planner: str = "metrics"


class PaperTable(NamedTuple):
    """A table as `python -m samp.runs paper-tables` writes it: title, header, rows and a note below."""

    title: str
    header: list[str]
    rows: list[list[str]]
    note: str


SAMP_RUNS = ("samp_n100", "samp_n160")
# Every Table I training evaluates the expert and the straight line beside its policy on the same benchmark
# problems: their rows take the newest such evaluation.
BESIDE = (*SAMP_RUNS, "mpnet", "simpnet", "mpinet")
TABLE_I = (
    Row("Expert (OMPL)", BESIDE, planner="expert"),
    Row("Expert as planned (no simplification or smoothing)", BESIDE, planner="expert_raw"),
    Row("OMPL sampling (RRTConnect alone)", BESIDE, planner="ompl_sampling"),
    Row("Straight line (joint space)", BESIDE, planner="straight"),
    Row("MPNet", ("mpnet",)),
    Row("SIMPNet", ("simpnet",)),
    Row("MPiNet", ("mpinet",)),
    Row("SAMP (100 anchors)", ("samp_n100",)),
    Row("SAMP (160 anchors)", ("samp_n160",)),
)
TABLE_II = tuple(Row(str(n), (f"samp_n{n}",)) for n in (40, 70, 100, 130, 160))
LEGACY_SPLITS = ("train", "heldout")  # protocol 1's cells: "training scenes / held-out scenes"
LEGACY_MARK = " (protocol 1: train / held-out)"
SUCCESS, REACH, COLLISION = (metric(name).key for name in ("success_rate", "reach_rate", "collision_rate"))
PATH_LENGTH = metric("path_length").key
# Table I's metric columns: (header, key in a benchmark summary, significant digits; a rate: None), and the
# protocol-1 key of the same column (solution time then was not restricted to B = 1).
TABLE_I_COLUMNS = (("soln. time, B = 1 [s]", SOLUTION_TIME_B1, 3, metric("solution_time").key),
                   ("path length [m]", PATH_LENGTH, 2, PATH_LENGTH),
                   ("success [%]", SUCCESS, None, SUCCESS),
                   ("collision [%]", COLLISION, None, COLLISION))
TABLE_II_RATES = (("success [%]", SUCCESS), ("reach [%]", REACH), ("collision [%]", COLLISION))
LEGACY_STEP_TIME = metric("inference_time").key  # protocol 1: seconds per policy step
NOTE = ("Benchmark cells: rates in percent [Wilson 95 % interval]; solution and step time one problem at a time "
        "(B = 1); path length the mean over successful problems; hard subset: the problems whose straight "
        "joint-space line collides; hard benchmark: bench_hard, every problem drawn to need a detour.")
LEGACY_NOTE = (" Rows marked (protocol 1) come from runs evaluated under the legacy protocol: their cells are "
               "\"training scenes / held-out scenes\" of their dataset's demonstration problems, not the benchmark; "
               "evaluate those runs again to put them on the benchmark.")


@dataclass(frozen=True)
class _Evaluation:
    """What fills a row: an eval/metrics.json and where it came from (a run, or a stand-alone evaluation)."""

    report: dict
    source: str

    @property
    def protocol(self) -> int:
        return protocol_of(self.report, {})

    def block(self, planner: str) -> dict:
        """The per-group metrics of `planner` ("metrics", "expert", "straight"); a stand-alone evaluation of
        the expert or the straight line has them under "metrics"."""
        if planner != "metrics" and self.report.get("planner") == planner:
            planner = "metrics"
        return self.report.get(planner) or {}


def _newest_evaluated(runs: list[Run], experiments: tuple[str, ...]) -> Run | None:
    """The newest completed run of any of `experiments` that has an evaluation, under the newest protocol."""
    found = [r for r in runs if r.record.get("experiment") in experiments and r.status == "completed" and r.evaluation]
    return max(found, key=lambda r: (r.protocol or 0, str(r.record.get("start") or ""))) if found else None


def _alone(root: Path, planner: str) -> _Evaluation | None:
    """The newest stand-alone evaluation of `planner` under `<root>/eval/` (`python -m samp.eval planner=...`)."""
    reports = []
    for path in sorted((root / "eval").glob("*/metrics.json")):
        report = json.loads(path.read_text())
        if report.get("planner") == planner:
            reports.append(((protocol_of(report, {}), str(report.get("created") or "")), report, path.parent))
    if not reports:
        return None
    _, report, folder = max(reports, key=lambda t: t[0])
    return _Evaluation(report, f"{folder.name} ({report.get('dataset')})")


def _of_run(run: Run | None) -> _Evaluation | None:
    if run is None:
        return None
    report = run.evaluation
    marks = ([f"trained on {report.get('trained_on')}"] if report.get("other_dataset") else []) + \
        (["unverified"] if report.get("unverified") else [])  # samp.eval.binding: numbers not tied to the run
    return _Evaluation(report, f"{run.name} ({report.get('dataset') or run.record.get('dataset_id')})"
                       + "".join(f" [{m}]" for m in marks))


def _filling(row: Row, runs: list[Run], root: Path) -> _Evaluation | None:
    """The evaluation that fills `row`: its run's; for the expert and the straight line, the run's if it
    has that block, else a stand-alone one (also when that follows a newer protocol); None: no such one."""
    found = _of_run(_newest_evaluated(runs, row.experiments))
    if row.planner == "metrics":
        return found
    candidates = [e for e in (found, _alone(root, row.planner)) if e is not None and e.block(row.planner)]
    return max(candidates, key=lambda e: e.protocol) if candidates else None


def _rate(summary: dict, key: str) -> str:
    """A benchmark rate: "93.3 [84.1, 97.4]"."""
    low, high = (summary.get(k) for k in interval_keys(key))
    value = summary.get(key)
    return percent(None if value is None else float(value), None if low is None or high is None else (low, high))


def _value(summary: dict, key: str, digits: int) -> str:
    value = summary.get(key)
    return DASH if value is None else fmt(float(value), digits)


def _pair(block: dict, key: str, scale: float = 1.0, digits: int = 3) -> str:
    """Protocol 1: "train / heldout" for one metric."""
    values = [(block.get(split) or {}).get(key) for split in LEGACY_SPLITS]
    return " / ".join(DASH if v is None else fmt(float(v) * scale, digits) for v in values)


def _title(name: str, filled: list[_Evaluation]) -> str:
    """The table's name, the benchmark(s) and the datasets of its rows' runs."""
    benchmarks = sorted({ref for e in filled if e.protocol >= CURRENT for ref in benchmark_refs(e.report).values()})
    datasets = sorted({str(e.report.get("dataset")) for e in filled})
    return (f"{name}, on the standing benchmark of unseen scenes (benchmark {', '.join(benchmarks) or DASH}; "
            f"datasets {', '.join(datasets) or DASH})")


def _note(filled: list[_Evaluation]) -> str:
    return NOTE + (LEGACY_NOTE if any(e.protocol < CURRENT for e in filled) else "")


def table_one(runs: list[Run], root: Path) -> PaperTable:
    header = ["method", *(title for title, *_ in TABLE_I_COLUMNS), "hard subset success [%]",
              "hard benchmark success [%]", "hard benchmark collision [%]", "run"]
    rows, filled = [], []
    for row in TABLE_I:
        found = _filling(row, runs, root)
        block = {} if found is None else found.block(row.planner)
        if found is None or found.protocol >= CURRENT:
            bench = block.get(BENCHMARK) or {}
            cells = [_rate(bench, key) if digits is None else _value(bench, key, digits)
                     for _, key, digits, _ in TABLE_I_COLUMNS]
            cells.append(_rate(block.get(hard(BENCHMARK)) or {}, SUCCESS))
            cells += [_rate(block.get(HARD_BENCHMARK) or {}, key) for key in (SUCCESS, COLLISION)]
            label = row.label
        else:
            cells = [_pair(block, legacy, 100.0 if digits is None else 1.0, digits or 3)
                     for _, _, digits, legacy in TABLE_I_COLUMNS] + [DASH] * 3
            label = row.label + LEGACY_MARK
        filled += [found] if found is not None else []
        rows.append([label, *cells, DASH if found is None else found.source])
    return PaperTable(_title("Table I: motion planning", filled), header, rows, _note(filled))


def table_two(runs: list[Run]) -> PaperTable:
    header = ["anchors n_e", "train time / epoch [s]", "step time, B = 1 [s]", *(t for t, _ in TABLE_II_RATES), "run"]
    rows, filled = [], []
    for row in TABLE_II:
        run = _newest_evaluated(runs, row.experiments)
        found = _of_run(run)
        block = {} if found is None else found.block(row.planner)
        epochs, fit_s = (run.record.get("epochs"), run.record.get("fit_time_s")) if run else (None, None)
        per_epoch = fmt(fit_s / epochs, 3) if epochs and fit_s else DASH
        if found is None or found.protocol >= CURRENT:
            bench = block.get(BENCHMARK) or {}
            cells = [_value(bench, STEP_TIME_B1, 2), *(_rate(bench, key) for _, key in TABLE_II_RATES)]
            label = row.label
        else:
            step = (block.get("all") or block.get("heldout") or {}).get(LEGACY_STEP_TIME)
            cells = [DASH if step is None else fmt(float(step), 2),
                     *(_pair(block, key, 100.0) for _, key in TABLE_II_RATES)]
            label = row.label + LEGACY_MARK
        filled += [found] if found is not None else []
        rows.append([label, per_epoch, *cells, DASH if found is None else found.source])
    return PaperTable(_title("Table II: anchor size (n_e per axis)", filled), header, rows, _note(filled))


def paper_tables(runs: list[Run], root: Path) -> dict[str, PaperTable]:
    """{"table_1": PaperTable, "table_2": ...}; "train time / epoch" is the fit wall time over the epochs run
    (validation and in-training evaluation included)."""
    return {"table_1": table_one(runs, root), "table_2": table_two(runs)}
