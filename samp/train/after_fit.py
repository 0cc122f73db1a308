"""What the recipe does with a model once it is trained, in memory (no reload from disk, no second config):

* a policy (`PolicySystemBase`): evaluate it under the evaluation protocol (`samp.eval.report`) — the
  stored evaluation problems of its dataset's validation and training scenes (`evaluation.problems` per
  split) and the standing benchmark (`evaluation.benchmark`), beside the expert and the straight line —
  into `<run>/eval/` (the same files and format as `python -m samp.eval run=RUN`), then a summary plot
  `<run>/plots/summary.png`;
* a robot SDF (`RobotSDFSystem`): export `robot_sdf.pt` and, with a `robot_sdf_eval` config, the
  Table III evaluation files.

Each returns flat metrics for run.json and the loggers. Adding a kind of model means one function here
and one line in `after_fit`.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["after_fit", "evaluate_policy", "export_robot_sdf"]


def evaluate_policy(system, datamodule, run_dir: Path, evaluation) -> dict:
    """The trained policy `system` under the evaluation protocol: the stored evaluation problems of its
    dataset's validation and training scenes (`evaluation.problems` per split) and the standing benchmark
    (`evaluation.benchmark`), with the expert and the straight line beside it; writes `<run_dir>/eval/`
    and the plots (`samp.runs.figures`)."""
    from samp.eval.benchmark import open_benchmarks
    from samp.eval.binding import Provenance
    from samp.eval.config import load_eval_config
    from samp.eval.report import evaluate_sections, flat_report, protocol_sections
    from samp.names import EVAL_DIR, PLOTS_DIR, SUMMARY_PNG

    if not evaluation.problems and not evaluation.benchmark:
        return {}
    ds = datamodule.ds
    splits = ["val", "train"] if evaluation.problems else []  # 0 problems: the benchmark alone
    cfg = load_eval_config({"problems": evaluation.problems or None, "splits": splits, "benchmark": evaluation.benchmark,
                            "benchmark_problems": evaluation.get("benchmark_problems"),
                            "overwrite": True, "root": str(Path(ds.path).parents[1])})
    benches = open_benchmarks(cfg.benchmark, cfg.root)
    system.eval()
    planner = system.planner()
    sections = protocol_sections(cfg, ds if cfg.splits else None, benches, planner.robot, trained=ds)
    out = Path(run_dir) / EVAL_DIR
    out.mkdir(parents=True, exist_ok=True)
    # the model just fitted, in memory: tied to its dataset by construction (its binding), nothing to verify
    provenance = Provenance(system.dataset_id, f"{ds.name}@{ds.id}")
    report = evaluate_sections(planner, sections, cfg, out, run_path=Path(run_dir), dataset=f"{ds.name}@{ds.id}",
                               provenance=provenance)
    try:  # a page of curves and rates beside the tables; a plotting failure must not lose the run
        from samp.runs.plots import plot_run_summary
        from samp.runs.registry import load_run

        from samp.runs.figures import plot_run

        run = load_run(run_dir)
        for path in [plot_run_summary(run, Path(run_dir) / PLOTS_DIR / SUMMARY_PNG), *plot_run(run)]:
            print(f"plot: {path}", flush=True)
    except Exception as err:  # noqa: BLE001 - reported, not raised
        print(f"warning: the summary plot was not written ({type(err).__name__}: {err})", flush=True)
    return flat_report(report, system.kind)


def export_robot_sdf(system, run_dir: Path, evaluation: dict | None) -> dict:
    """Write `robot_sdf.pt` and (unless `evaluation` is None) the Table III files of the trained network."""
    from samp.robot_sdf.artifact import ARTIFACT_FILE, artifact_id, save_artifact
    from samp.robot_sdf.evaluate import SDFEvalConfig, evaluate_methods

    model = system.robot_sdf().eval()
    path = save_artifact(Path(run_dir) / ARTIFACT_FILE, model, system.spec, system.dataset_id,
                         {"train_time_s": system.train_time_s})
    metrics = {"robot_sdf_artifact_id": artifact_id(path), "train_time_s": system.train_time_s}
    if evaluation is not None:
        report = evaluate_methods(model.robot, {system.method: {"model": model, "train_time_s": system.train_time_s}},
                                  SDFEvalConfig(**evaluation), run_dir)
        res = report["methods"][system.method]
        for key in ("whole_robot", "per_link"):
            metrics.update({f"eval/{key}/{k}": v for k, v in res[key].items() if not k.startswith("count")})
        metrics.update({f"eval/infer_ms_B{b}": v for b, v in res["infer_ms"].items()})
    return metrics


def after_fit(cfg, system, datamodule, run_dir: Path) -> dict:
    """The step after `trainer.fit` for whatever `system` is; flat metrics (empty for other systems)."""
    from omegaconf import OmegaConf

    from samp.policy.base import PolicySystemBase
    from samp.robot_sdf.system import RobotSDFSystem

    if isinstance(system, PolicySystemBase):
        metrics = evaluate_policy(system, datamodule, run_dir, cfg.evaluation)
        from samp.runs.cards import write_model_card

        print(f"model card: {write_model_card(run_dir)}", flush=True)
        return metrics
    if isinstance(system, RobotSDFSystem):
        evaluation = cfg.get("robot_sdf_eval")
        return export_robot_sdf(system, run_dir, None if evaluation is None else OmegaConf.to_container(evaluation))
    return {}
