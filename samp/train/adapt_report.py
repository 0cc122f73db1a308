"""The before / after table of `python -m samp.train.adapt`: the from-run's policy and the adapted one,
evaluated (`samp.eval.evaluate`, the evaluation protocol's checks and metrics) on the same problems: the
held-out problems the cells' dataset stores for its training scenes (group `cells`) and, when asked, each
benchmark's problems (group: the benchmark's name)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

__all__ = ["compare", "problems", "write"]


def problems(cfg, ds, root: Path) -> list:
    """Every held-out problem of the cells (the dataset's stored evaluation problems of its training scenes,
    never its demonstrations), then `cfg.benchmark_problems` of each benchmark of `cfg.benchmarks`; each
    `Problem`'s split is its table group."""
    from samp.eval.benchmark import open_benchmark
    from samp.eval.problems import problems_from_dataset

    out = [replace(p, split="cells") for p in problems_from_dataset(ds, "train", None, seed=int(cfg.seed))]
    for name in cfg.benchmarks:
        bench = open_benchmark(name, root, int(cfg.workers))
        out += [replace(p, split=name) for p in problems_from_dataset(bench, "test", cfg.benchmark_problems,
                                                                      seed=int(cfg.seed))]
    return out


def _grids(ds):
    """Grids of the cells' dataset where it stores them, else each scene's exact grid (`dataset_grids`)."""
    from samp.eval.problems import dataset_grids, scene_grids

    cells = dataset_grids(ds)
    return lambda p, n_e: cells(p, n_e) if p.split == "cells" else scene_grids(p, n_e)


def compare(cfg, ds, run: Path, root: Path) -> tuple[str, dict]:
    """Evaluate the from-run (`before`) and the adapted run (`after`) on the same problems -> (the markdown
    table, the report: problems, metrics per planner and group, every problem's record)."""
    from samp.console import plural
    from samp.eval import evaluate, load_planner
    from samp.eval.config import rollout_config
    from samp.eval.metrics import markdown_table

    asked = problems(cfg, ds, root)
    groups = list(dict.fromkeys(p.split for p in asked))
    results = {}
    for label, folder in (("before", cfg.from_run), ("after", run)):
        print(f"adapt {3 if label == 'before' else 4}/4: evaluating the policy {label} adaptation ({folder}) on "
              f"{plural(len(asked), 'held-out problem')} ({', '.join(groups)})", flush=True)
        results[label] = evaluate(load_planner(folder), asked, grids=_grids(ds), progress_s=30.0)
    rows = [(label, group, results[label]["metrics"][group]) for group in groups for label in ("before", "after")]
    table = markdown_table(rows, rollout_config(None))
    report = {"from": str(cfg.from_run), "run": str(run), "dataset": f"{ds.name}@{ds.id}", "groups": groups,
              "problems": [{"problem": p.name, "group": p.split, "scene": p.scene.name, "q_start": p.q_start.tolist(),
                            "q_goal": p.q_goal.tolist()} for p in asked],
              "metrics": {label: {g: results[label]["metrics"][g] for g in groups} for label in results},
              "records": {label: [{k: v for k, v in r.items() if k not in ("trajectory", "step_times")}
                                  for r in results[label]["records"]] for label in results}}
    return table, report


def write(run: Path, table: str, report: dict) -> None:
    """`adapt.md` (the table, with what it compares) and `adapt.json` (the report) in the adapted run's folder."""
    from samp.train.adapt import REPORT_FILE, TABLE_FILE

    times = report.get("times") or {}
    head = (f"# Adaptation: {report['from']} -> {report['run']}\n\nHeld-out problems in the cells of "
            f"{report['dataset']} (never its demonstrations), the same for both policies; wall time "
            f"{times.get('total_s', 0) / 60:.1f} min.\n\n")
    (run / TABLE_FILE).write_text(head + table)
    (run / REPORT_FILE).write_text(json.dumps(report, indent=1, default=str))
