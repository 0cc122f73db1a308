"""Table III in one run: SAMP's hash grid, NN-SDF, RDF (N = 8) and RDF (N = 24) on the same samples.

The two networks are trained by the ordinary recipe (`samp.train`, each in its own run folder inside the
comparison's folder, with the same experiment and overrides; never under `runs/robot_sdf_<robot>/`, so the
comparison does not change which robot SDF a later policy run resolves by name); the RDF models are fitted by
least squares on the samples those runs used. All four are then evaluated together (`evaluate_methods`) into
one comparison folder, `runs/robot_sdf_compare_<robot>/<timestamp>/`: robot_sdf_table.{md,json},
robot_sdf.rrd, the RDF artifacts and a run.json that names the runs and the dataset. `tools/bench.py
robot_sdf` calls this.
"""

from __future__ import annotations

import time
from pathlib import Path

__all__ = ["RDF_DEFAULTS", "compare_methods"]

# Least-squares settings per RDF size: N = 8 is solved exactly; N = 24 runs 60 CG iterations after an
# N = 8 warm start (more iterations lowered the near-surface error no further on the Panda's links and
# raised the error in the sparsely sampled box corners).
RDF_DEFAULTS = {8: {}, 24: {"max_iterations": 60, "tolerance": 1e-6, "warm_start": True}}
NETWORK_MODELS = ("robot_sdf_hash", "robot_sdf_nn")


def compare_methods(robot: str = "panda", overrides: list[str] | tuple = (), rdf: dict | None = None,
                    evaluation: dict | None = None, runs_root: Path | str | None = None) -> tuple[dict, Path]:
    """Train, fit and evaluate the four methods; returns (the evaluation report, the comparison folder).

    `overrides` go to both network runs (e.g. `trainer.accelerator=cpu`, `robot_sdf_samples=tiny`);
    `rdf` maps N -> `fit_bernstein` keyword arguments (default `RDF_DEFAULTS`); `evaluation` holds
    `SDFEvalConfig` fields.
    """
    import dataclasses
    import json

    import torch

    from samp.data.registry import resolve_ref
    from samp.robot import load_robot
    from samp.robot_sdf.artifact import load_robot_sdf, net_spec, save_artifact
    from samp.robot_sdf.baselines import fit_bernstein
    from samp.robot_sdf.evaluate import SDFEvalConfig, evaluate_methods
    from samp.robot_sdf.samples import dataset_name, load_samples
    from samp.robot_sdf.whole_robot import RobotSDF
    from samp.runs import RunFolder, runs_root as default_root
    from samp.train import train

    folder = RunFolder.create(Path(runs_root) if runs_root else default_root(), f"robot_sdf_compare_{robot}")
    with folder.record(experiment=f"robot_sdf_compare_{robot}", overrides=list(overrides)):
        model = load_robot(robot, dtype=torch.float32)
        methods, runs, network_configs = {}, {}, {}
        for name in NETWORK_MODELS:
            # Inside the comparison's own folder: a run under runs/robot_sdf_<robot>/ would be what a later
            # `system.robot_sdf=robot_sdf_<robot>` picks up (the newest completed run of that name).
            run = train([f"+experiment=robot_sdf_{robot}", f"model={name}", "~robot_sdf_eval", *overrides],
                        run_dir=folder.path / name)
            record = run.read()
            sdf = load_robot_sdf(run.path, model)
            methods[sdf.method] = {"model": sdf, "train_time_s": record["metrics"].get("train_time_s")}
            runs[sdf.method] = {"run_dir": str(run.path), "dataset_id": record.get("dataset_id"),
                                "seed": record.get("seed")}
            network_configs[sdf.method] = record.get("config")
        dataset_ids = {r["dataset_id"] for r in runs.values()}
        if len(dataset_ids) != 1:
            raise RuntimeError(f"the network runs used different sample sets {sorted(dataset_ids)}")
        dataset_id = dataset_ids.pop()
        datasets = Path(run.read()["config"]["paths"]["datasets_dir"])  # where the runs found their samples
        samples = load_samples(resolve_ref(f"{dataset_name(robot)}@{dataset_id}", datasets))
        for n_basis, kwargs in (rdf or RDF_DEFAULTS).items():
            t0 = time.perf_counter()
            net, info = fit_bernstein(samples, int(n_basis), **kwargs)
            seconds = time.perf_counter() - t0
            sdf = RobotSDF(model, net, samples.centres, samples.scales, method=net.label)
            save_artifact(folder.path / f"robot_sdf_rdf{n_basis}.pt", sdf, net_spec(net), dataset_id,
                          {"train_time_s": seconds, "fit": {"iterations": info.iterations, "residuals": info.residuals}})
            methods[sdf.method] = {"model": sdf, "train_time_s": seconds}
            runs[sdf.method] = {"fit_iterations": info.iterations, "fit_residuals": info.residuals}
        eval_config = SDFEvalConfig(**(evaluation or {}))
        report = evaluate_methods(model, methods, eval_config, folder.path)
        report["runs"], report["dataset_id"] = runs, dataset_id
        (folder.path / "robot_sdf_table.json").write_text(json.dumps(report, indent=2))
        seeds = {r["seed"] for r in runs.values() if "seed" in r}
        # What traces the table back: the networks' seed and resolved configs (their runs), the RDF settings,
        # and the evaluation's sizes and seed.
        config = {"robot": robot, "overrides": list(overrides), "network_models": list(NETWORK_MODELS),
                  "rdf": {str(n): dict(kw) for n, kw in (rdf or RDF_DEFAULTS).items()},
                  "evaluation": dataclasses.asdict(eval_config),
                  "networks": network_configs}
        folder.update(dataset_id=dataset_id, runs=runs, seed=seeds.pop() if len(seeds) == 1 else sorted(seeds),
                      evaluation_seed=eval_config.seed, config=config,
                      metrics={f"{label}/{key}/{k}": v for label, res in report["methods"].items()
                               for key in ("whole_robot", "per_link") for k, v in res[key].items()})
    return report, folder.path
