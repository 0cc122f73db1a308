"""Evaluate one planner on a dataset's problems and write the report: the step shared by
`python -m samp.eval` (a planner loaded from a run folder, or a built-in one) and the evaluation after
training (`samp.train.after_fit`, the model just trained, in memory).

Into `out`: metrics.json (metrics per split, for the planner, the expert and the straight line),
metrics.md (the table), problems.jsonl (one record per problem and planner) and, if `record`,
recording.rrd (and reconstruction.rrd with reconstructed grids).
"""

from __future__ import annotations

import json
import time
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["evaluate_on_dataset", "grid_source"]


def grid_source(cfg, ds, planner):
    """(grid source, its ReconstructedGrids or None): the dataset's exact grids, or grids reconstructed
    from simulated depth cameras (`grid_source=reconstructed`); collisions are checked exactly either way."""
    from samp.eval.problems import dataset_grids

    exact = dataset_grids(ds)
    if cfg.grid_source == "exact":
        return exact, None
    from samp.perception.source import ReconstructedGrids
    from samp.robot import load_robot
    from samp.robot.precision import exact_robot

    robot = getattr(planner, "robot", None) or load_robot(ds.manifest["robot"]["name"])
    source = ReconstructedGrids(cfg.camera, exact_robot(robot), exact=exact, unknown=cfg.unknown)
    return source, source


def evaluate_on_dataset(planner, ds, cfg, out: Path, run_path: Path | None = None) -> dict:
    """Roll out or replay `planner` on `cfg.problems` problems per split of `ds` (`cfg.split`, fixed by
    `cfg.seed`), with the expert and the straight line beside it as `cfg` asks; write the files into
    `out` (which must exist) and return the report (the content of metrics.json)."""
    from samp.eval.harness import evaluate
    from samp.eval.loading import load_planner
    from samp.eval.problems import problems_from_dataset
    from samp.names import SPLITS

    splits = list(SPLITS) if cfg.split == "both" else [cfg.split]
    problems = [p for s in splits for p in problems_from_dataset(ds, s, cfg.problems, cfg.seed)]
    grids, reconstruction = grid_source(cfg, ds, planner)
    counts = {s: sum(p.split == s for p in problems) for s in splits}
    print(f"evaluating {planner.name} on {ds.name}@{ds.id}: " + ", ".join(f"{n} {s} problems" for s, n in counts.items()),
          flush=True)
    t0 = time.perf_counter()
    result = evaluate(planner, problems, cfg.rollout(), grids=grids)
    print(f"  {planner.name}: {time.perf_counter() - t0:.1f} s (rollouts and checks)", flush=True)
    expert = None
    if cfg.compare_expert and planner.name != "expert":
        expert = evaluate(load_planner("expert"), problems, cfg.rollout())
    others = []
    if cfg.compare_straight and planner.name != "straight":
        straight = load_planner("straight", robot=planner.robot if hasattr(planner, "robot") else None,
                                max_step=cfg.straight_max_step, n_e=cfg.n_e)
        others.append(evaluate(straight, problems, cfg.rollout(), grids=grids))
    if reconstruction is not None:
        print("  " + reconstruction.summary())
    return _write(out, cfg, run_path, ds, problems, planner, result, expert, counts, others, reconstruction)


def _write(out: Path, cfg, run_path: Path | None, ds, problems, planner, result: dict, expert: dict | None,
           counts: dict, others: list[dict] = (), reconstruction=None) -> dict:
    """metrics.json, metrics.md, problems.jsonl and (if `record`) recording.rrd into `out`; with
    reconstructed grids also their errors (metrics.json "reconstruction") and reconstruction.rrd."""
    from dataclasses import asdict

    from samp.eval.metrics import markdown_table
    from samp.eval.names import ALL_SPLITS, METRICS_JSON, METRICS_MD, PROBLEMS_JSONL, RECORDING_RRD
    from samp.provenance import code_version

    pooled = len(counts) > 1  # with one split, "all" repeats it
    rows = [(r["planner"], s, m) for r in filter(None, (result, expert, *others)) for s, m in r["metrics"].items()
            if s != ALL_SPLITS or pooled]
    table = markdown_table(rows, cfg.rollout())
    report = {"planner": result["planner"], "run": str(run_path) if run_path else None, "dataset": f"{ds.name}@{ds.id}",
              "problems": counts, "metrics": result["metrics"], "expert": None if expert is None else expert["metrics"],
              **{o["planner"]: o["metrics"] for o in others},
              "config": asdict(cfg), "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "code_version": code_version()}
    if reconstruction is not None:
        report["reconstruction"] = reconstruction.report()
    (out / METRICS_JSON).write_text(json.dumps(report, indent=2))
    (out / METRICS_MD).write_text(f"# {result['planner']} on {ds.name}@{ds.id}\n\n{table}")
    with open(out / PROBLEMS_JSONL, "w") as f:
        for rec in result["records"] + ([] if expert is None else expert["records"]) + [r for o in others for r in o["records"]]:
            f.write(json.dumps(rec) + "\n")
    print("\n" + table)
    written = [METRICS_JSON, METRICS_MD, PROBLEMS_JSONL]
    if cfg.record:
        from samp.eval.recording import write_recording

        path = write_recording(out / RECORDING_RRD, problems, result, expert, robot=getattr(planner, "robot", None),
                               record_rollouts=cfg.record_rollouts, record_points=cfg.record_points, metrics_md=table)
        written.append(f"{RECORDING_RRD} ({path.stat().st_size / 1e6:.1f} MB; open with `rerun {path}`)")
        if reconstruction is not None and reconstruction.scenes:
            from samp.eval.names import RECONSTRUCTION_RRD
            from samp.perception.viz import write_reconstruction_recording

            path = write_reconstruction_recording(out / RECONSTRUCTION_RRD, reconstruction.scenes, reconstruction.cameras)
            written.append(f"{RECONSTRUCTION_RRD} ({path.stat().st_size / 1e6:.1f} MB)")
    print(f"wrote {out}: " + ", ".join(written))
    return report
