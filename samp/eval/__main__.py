"""`python -m samp.eval run=RUN_DIR [split=heldout] [problems=N] [key=value ...]`
`python -m samp.eval planner=expert|expert_raw|ompl_sampling|straight dataset=REF [out=DIR] ...`

Evaluates a run's policy (or the expert, or the straight-line baseline) on fixed, seeded problems from a
dataset's training and held-out scenes, the expert's stored trajectories on the same problems beside it,
and writes into `RUN_DIR/eval/` (or `out`): metrics.json (metrics per split, for the planner and the
expert), metrics.md (the table), problems.jsonl (one record per problem and planner) and recording.rrd.
Settings: conf/eval.yaml (schema: samp/eval/config.py).
"""

from __future__ import annotations

import json
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from samp.cli import compose, output_path, run_command

USAGE = __doc__.split("\n\n")[0] + "\nSettings and their defaults: conf/eval.yaml."


def _config(overrides: list[str]):
    from hydra.errors import ConfigCompositionException
    from omegaconf import OmegaConf

    from samp.eval.config import EvalConfig, load_eval_config
    from samp.paths import conf_dir

    # `dataset=REF` names a config group to Hydra (conf/dataset/ holds dataset specs), so keys that are
    # also group names are set after composition instead of being passed to Hydra.
    valid = list(EvalConfig.__dataclass_fields__)
    for o in overrides:  # a typo is named with the valid keys (Hydra would suggest `+key=`, then refused)
        key = o.partition("=")[0].lstrip("+~").split(".")[0]
        if key not in valid and key != "hydra":
            raise ValueError(f"unknown eval setting {key!r} (in {o!r}); valid keys: {', '.join(valid)}")
    groups = {k for k in valid if (conf_dir() / k).is_dir()}
    late = [o for o in overrides if o.partition("=")[0] in groups]
    try:
        raw = compose("eval", [o for o in overrides if o not in late])
    except ConfigCompositionException as err:
        raise ValueError(f"{err}. Valid keys: {', '.join(valid)}") from None
    raw = OmegaConf.to_container(raw, resolve=True)
    for o in late:
        key, _, value = o.partition("=")
        raw[key] = None if value in ("", "null") else value
    return load_eval_config(raw)


def _open_dataset(cfg, run):
    from samp.data import open_dataset

    ref = cfg.dataset or (run.dataset if run else None)
    if ref is None:
        where = f"{run.path / 'run.json'} names no dataset" if run else "no run was given"
        raise ValueError(f"say which dataset to take problems from: dataset=REF ({where})")
    return open_dataset(ref, Path(cfg.root) if cfg.root else None)


def _planner(cfg, run, ds):
    from samp.eval.loading import load_planner
    from samp.robot import load_robot

    if run is not None:
        from samp.eval.loading import check_policy_robot

        policy = load_planner(run.path)
        check_policy_robot(policy, ds.manifest)
        if cfg.n_e is not None:
            policy.n_e = cfg.n_e
        return policy
    robot = load_robot(ds.manifest["robot"]["name"])
    if cfg.planner == "straight":
        return load_planner("straight", robot=robot, max_step=cfg.straight_max_step, n_e=cfg.n_e)
    from samp.eval.planners import EXPERT_VARIANTS

    if cfg.planner in EXPERT_VARIANTS:  # the dataset's expert settings, planned afresh without post-processing
        from samp.expert import load_expert_config

        config = load_expert_config(ds.manifest.get("config", {}).get("expert_config"), **EXPERT_VARIANTS[cfg.planner])
        return load_planner("expert", robot=robot, mode="plan", config=config, seed=cfg.seed, name=cfg.planner)
    return load_planner("expert", robot=robot, mode=cfg.expert_mode, seed=cfg.seed)


def _grid_source(cfg, ds, planner):
    """(grid source, its ReconstructedGrids or None): the dataset's exact grids, or grids reconstructed
    from simulated depth cameras (`grid_source=reconstructed`); collisions are checked exactly either way."""
    from samp.eval.problems import dataset_grids

    exact = dataset_grids(ds)
    if cfg.grid_source == "exact":
        return exact, None
    from samp.eval.checks import exact_robot
    from samp.perception.source import ReconstructedGrids
    from samp.robot import load_robot

    robot = getattr(planner, "robot", None) or load_robot(ds.manifest["robot"]["name"])
    source = ReconstructedGrids(cfg.camera, exact_robot(robot), exact=exact, unknown=cfg.unknown)
    return source, source


def _out_dir(cfg, run, ds) -> Path:
    from samp.eval.names import EVAL_DIR, METRICS_JSON

    if cfg.out:
        out = output_path(Path(cfg.out) / METRICS_JSON).parent
    elif run is not None:
        out = run.path / EVAL_DIR
    else:
        out = output_path(Path("runs") / "eval" / f"{cfg.planner}_{ds.name}@{ds.id}" / METRICS_JSON).parent
    if (out / METRICS_JSON).exists() and not cfg.overwrite:
        raise ValueError(f"{out / METRICS_JSON} exists from an earlier evaluation; pass overwrite=true to replace it, "
                         "or out=DIR to write elsewhere")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _evaluate(overrides: list[str]) -> Path:
    """The recipe: config, run and dataset, problems, planner, evaluation (and the expert's), files."""
    cfg = _config(overrides)
    # Heavy imports only once the config is known to be good.
    from samp.eval.evaluation import evaluate
    from samp.eval.loading import check_robot, find_checkpoint, load_planner, read_run
    from samp.eval.names import SPLITS
    from samp.eval.problems import problems_from_dataset

    if (cfg.run is None) == (cfg.planner is None):
        raise ValueError("say what to evaluate: run=RUN_DIR (a trained policy) or planner=expert|straight dataset=REF, "
                         "not both")
    run = read_run(cfg.run) if cfg.run else None
    if run is not None:
        find_checkpoint(run.path)  # a missing checkpoint fails before any dataset work
    ds = _open_dataset(cfg, run)
    if run is not None:
        check_robot(run, ds.manifest)
    splits = list(SPLITS) if cfg.split == "both" else [cfg.split]
    problems = [p for s in splits for p in problems_from_dataset(ds, s, cfg.problems, cfg.seed)]
    planner = _planner(cfg, run, ds)
    grids, reconstruction = _grid_source(cfg, ds, planner)
    out = _out_dir(cfg, run, ds)
    counts = {s: sum(p.split == s for p in problems) for s in splits}
    print(f"evaluating {planner.name} on {ds.name}@{ds.id}: " + ", ".join(f"{n} {s} problems" for s, n in counts.items()))
    t0 = time.perf_counter()
    result = evaluate(planner, problems, cfg.rollout(), grids=grids)
    print(f"  {planner.name}: {time.perf_counter() - t0:.1f} s (rollouts and checks)")
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
    _write(out, cfg, run, ds, problems, planner, result, expert, counts, others, reconstruction)
    return out


def evaluate_run(run_dir: str | Path, overrides: list[str] = ()) -> dict:
    """Evaluate a run's policy (as `python -m samp.eval run=RUN_DIR ...`); returns its metrics.json."""
    from samp.eval.names import METRICS_JSON

    out = _evaluate([f"run={run_dir}", *overrides])
    return json.loads((out / METRICS_JSON).read_text())


FLAT_METRICS = ("success_rate", "reach_rate", "collision_rate", "path_length_mean", "solution_time_mean")


def evaluate_trained(run_dir: str | Path, name: str, problems: int, root: str | Path | None = None) -> dict:
    """The evaluation at the end of a training run (a LightningModule's `evaluate_run`): `problems` per
    split with the expert and the straight line beside the policy, `<run>/eval/` and a summary plot
    `<run>/plots/summary.png`; returns flat `eval/<name|expert|straight>/<split>/<metric>` values."""
    overrides = [f"problems={problems}", "compare_straight=true", "overwrite=true"] + ([f"root={root}"] if root else [])
    report = evaluate_run(run_dir, overrides)
    try:  # a page of curves and rates beside the tables; a plotting failure must not lose the run
        from samp.runs.plots import plot_run_summary
        from samp.runs.registry import load_run

        print(f"plot: {plot_run_summary(load_run(run_dir), Path(run_dir) / 'plots' / 'summary.png')}", flush=True)
    except Exception as err:  # noqa: BLE001 - reported, not raised
        print(f"warning: the summary plot was not written ({type(err).__name__}: {err})", flush=True)
    return {f"eval/{planner}/{split}/{metric}": float(m[metric])
            for planner, key in ((name, "metrics"), ("expert", "expert"), ("straight", "straight"))
            for split, m in (report.get(key) or {}).items() for metric in FLAT_METRICS if m.get(metric) is not None}


def _write(out: Path, cfg, run, ds, problems, planner, result: dict, expert: dict | None, counts: dict,
           others: list[dict] = (), reconstruction=None) -> None:
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
    report = {"planner": result["planner"], "run": str(run.path) if run else None, "dataset": f"{ds.name}@{ds.id}",
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


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(USAGE, file=sys.stderr)
        return 2
    return run_command(["evaluate", *argv], USAGE, {"evaluate": _evaluate})


if __name__ == "__main__":
    sys.exit(main())
