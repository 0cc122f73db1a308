"""Every run is also a run of an MLflow tracking store (docs/runs.md, "Tracking in MLflow"); the run folder stays
the source of files, the store is where a tracker UI (`mlflow ui`, a team's MLflow server) finds them. The
store, the client and the evaluation's side are `samp.tracking`; this is the training's side.

A training run (a robot SDF run too) is one MLflow run, named after its folder: its resolved config as params,
the metrics Lightning logs per step, the evaluation's metrics with their interval bounds, its lineage as tags
(`samp.*`: commit, dataset id, robot SDF id, benchmark id), its dataset as a dataset input, and its files as
artifacts (plots, model card, `eval/` with metrics.md and problems.jsonl, and the recording unless
`tracking.recording=false`). A sweep is a parent run; its members are child runs (tag `mlflow.parentRunId`).
The MLflow run id and the store's URI are kept in run.json (`loggers.mlflow`): a resumed run, and
`python -m samp.eval run=RUN`, log into the same MLflow run.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from samp.eval.report import benchmark_refs
from samp.tracking import (benchmark_tags, client, experiment_id, log_dataset, log_files, resolve_uri,
                           tracked_here)

__all__ = ["finish_training", "sweep_parent", "training_logger"]

SWEEP_STATE_PREFIX = ".mlflow-sweep-"  # + a hash of the store's URI: the sweep's parent run there (sweep_parent)


def training_logger(cfg, folder):
    """A Lightning MLFlowLogger for the training run in `folder` (None when tracking is off): params from its
    resolved config, tags from its lineage, a child of its sweep's run when it is a sweep member, and the same
    MLflow run (in the store it was started in, when that store is here) when the folder is resumed. Rank 0 only."""
    from samp.runs.lineage import flatten, lineage_tags
    from samp.runs.tracker_guard import GuardedMLFlowLogger

    configured = resolve_uri(cfg.tracking.uri, cfg.paths.runs_dir)
    if configured is None:  # off wins, a resumed run's store included
        return None
    record = folder.read()
    previous = tracked_here(record, configured)  # a pulled run's local store is the pusher's, not followed
    uri = previous[0] if previous else configured
    mlflow_client = client(uri)
    sweep = record.get("sweep") or {}
    experiment = _sweep_experiment(sweep["dir"], cfg.paths.runs_dir) if sweep else str(cfg.name)
    experiment_id(mlflow_client, uri, experiment)  # with the local store's artifact folder
    tags = lineage_tags(record)
    if sweep and not previous:
        tags["mlflow.parentRunId"] = sweep_parent(sweep["dir"], uri, experiment)
    logger = GuardedMLFlowLogger(experiment_name=experiment, run_name=_run_name(folder.path, sweep), tracking_uri=uri,
                                 tags=tags, run_id=previous[1] if previous else None, run_dir=folder.path)
    if not previous:  # MLflow params never change: a resumed run keeps those of its first start
        logger.log_hyperparams(flatten(record.get("config") or {}))
    folder.update(loggers={**(record.get("loggers") or {}), "mlflow": {
        "run_id": logger.run_id, "tracking_uri": uri, "experiment_name": experiment}})
    print(f"tracked: {uri} run {logger.run_id}", flush=True)
    return logger


def _run_name(path: Path, sweep: dict) -> str:
    return path.name if sweep else f"{path.parent.name}/{path.name}"


def _sweep_experiment(sweep_dir: str, runs_dir: str | Path) -> str:
    """A sweep's experiment: its folder under the runs folder (`sweeps/anchor_size`), else the folder's name."""
    path, root = Path(sweep_dir).resolve(), Path(runs_dir).resolve()
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else path.name


def sweep_parent(sweep_dir: str, uri: str, experiment: str) -> str:
    """The id of the sweep's parent run in store `uri`, kept in a file of the sweep's folder: found again by
    later members and by a rerun of the sweep. Members may start at once in several processes or hosts, so
    the file is claimed without a lock (some cluster file systems have none): each writes its own complete
    file and hard-links it into place, which succeeds for one; the others delete the parent they made and
    take the winner's."""
    import hashlib

    folder = Path(sweep_dir)
    folder.mkdir(parents=True, exist_ok=True)
    state = folder / f"{SWEEP_STATE_PREFIX}{hashlib.sha256(uri.encode()).hexdigest()[:12]}.json"
    if state.is_file():
        return json.loads(state.read_text())["run_id"]
    mlflow_client = client(uri)
    run = mlflow_client.create_run(experiment_id(mlflow_client, uri, experiment), run_name=folder.name,
                                   tags={"samp.sweep_dir": str(folder.resolve()), "samp.kind": "sweep"})
    mlflow_client.set_terminated(run.info.run_id)  # a container: its members hold the metrics
    mine = folder / f"{state.name}.{os.getpid()}.tmp"
    mine.write_text(json.dumps({"tracking_uri": uri, "run_id": run.info.run_id}, indent=2))
    try:
        os.link(mine, state)
    except FileExistsError:  # another member was first
        mlflow_client.delete_run(run.info.run_id)
    finally:
        mine.unlink()
    return json.loads(state.read_text())["run_id"]


def finish_training(logger, record: dict, run_dir: Path) -> None:
    """What a tracked training run gets once it is complete: the benchmark id as a tag, the dataset input and
    its files as artifacts (the recording unless the config's `tracking.recording` is false)."""
    from samp.names import EVAL_DIR, METRICS_JSON

    mlflow_client, run_id = logger.experiment, logger.run_id
    report = Path(run_dir) / EVAL_DIR / METRICS_JSON
    written = json.loads(report.read_text()) if report.is_file() else {}
    for key, ref in benchmark_tags(benchmark_refs(written)).items():  # samp.benchmark_id, samp.hard_benchmark_id
        mlflow_client.set_tag(run_id, f"samp.{key}", ref)
    config = record.get("config") or {}
    log_dataset(mlflow_client, run_id, record.get("dataset_id"), (config.get("paths") or {}).get("datasets_dir"),
                "training")
    recording = bool((config.get("tracking") or {}).get("recording", True))
    log_files(mlflow_client, run_id, Path(run_dir), recording=recording)
