"""Every run is also a run of an MLflow tracking store (docs/runs.md, "Tracking"); the run folder stays the
source of files, the store is where a tracker UI (`mlflow ui`, a team's MLflow server) finds them.

Where: `tracking.uri` of the training config, else `$SAMP_TRACKING_URI`, else `sqlite:///<runs folder>/mlflow.db`
(a local store, no server); `off` in either place turns tracking off. A local store keeps artifacts under
`<runs folder>/mlflow-artifacts/`; a server (`http://HOST:PORT`) keeps them where it serves them from.

What: a training run (a robot SDF run too) is one MLflow run, named after its folder: its resolved config as
params, the metrics Lightning logs per step, the evaluation's metrics with their interval bounds, its lineage
as tags (`samp.*`: commit, dataset id, robot SDF id, benchmark id), its dataset as a dataset input, and its
files as artifacts (plots, model card, `eval/` with metrics.md and problems.jsonl, and the recording unless
`tracking.recording=false`). A sweep is a parent run; its members are child runs (tag `mlflow.parentRunId`).
`python -m samp.eval run=RUN` logs into the run's own MLflow run, as a new evaluation section named after its
folder (`eval-2/...` metrics and artifacts); an evaluation without a run is a run of the experiment `eval`.
The MLflow run id and the store's URI are kept in run.json (`loggers.mlflow`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from samp.names import TRACKING_ARTIFACTS_DIR, TRACKING_DB

__all__ = ["OFF", "TRACKING_ENV", "client", "log_dataset", "log_files",
           "resolve_uri", "sweep_parent", "track_evaluation", "tracked_at", "training_logger"]

TRACKING_ENV = "SAMP_TRACKING_URI"
OFF = "off"
SWEEP_STATE_PREFIX = ".mlflow-sweep-"  # + a hash of the store's URI: the sweep's parent run there (sweep_parent)
EVAL_EXPERIMENT = "eval"  # evaluations of a planner without a run folder
# Not uploaded: checkpoints and exported networks (large, and the run folder keeps them), other loggers' folders.
SKIPPED = ("checkpoints", "tensorboard", "wandb", ".hydra")
SKIPPED_SUFFIXES = (".ckpt", ".pt", ".tmp")


def resolve_uri(configured: str | None, runs_dir: str | Path) -> str | None:
    """The tracking URI: `configured` (tracking.uri), else $SAMP_TRACKING_URI, else the local store
    `sqlite:///<runs_dir>/mlflow.db`; None when either says `off`."""
    uri = configured if configured not in (None, "") else os.environ.get(TRACKING_ENV) or None
    if uri is not None and str(uri).strip().lower() == OFF:
        return None
    return str(uri) if uri is not None else f"sqlite:///{Path(runs_dir).resolve() / TRACKING_DB}"


def _local_root(uri: str) -> Path | None:
    """The runs folder of a local `sqlite:///` store (where its artifacts go), None for other stores."""
    return Path(uri.removeprefix("sqlite:///")).parent if uri.startswith("sqlite:///") else None


def client(uri: str):
    """An MlflowClient on `uri` (a local store's folder is created first)."""
    try:
        from mlflow.tracking import MlflowClient
    except ModuleNotFoundError:
        raise ModuleNotFoundError("tracking needs the MLflow client: pip install -e . (it installs mlflow-skinny), "
                                  f"or turn tracking off with {TRACKING_ENV}=off") from None
    if not uri.startswith("sqlite:///"):
        return MlflowClient(tracking_uri=uri)
    # A local store is opened (created, or migrated) under a lock on a file beside it: MLflow creates a new
    # store's tables in steps that fail when two processes do it at once (sweep members in parallel). A file
    # system SQLite works on has the locks this needs.
    import fcntl

    db = Path(uri.removeprefix("sqlite:///"))
    db.parent.mkdir(parents=True, exist_ok=True)
    with open(db.with_name(db.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        mlflow_client = MlflowClient(tracking_uri=uri)
        mlflow_client.search_experiments(max_results=1)  # the store is made (or checked) by its first use
    return mlflow_client


def _artifact_location(uri: str, experiment: str) -> str | None:
    root = _local_root(uri)
    return None if root is None else (root / TRACKING_ARTIFACTS_DIR / experiment).resolve().as_uri()


def experiment_id(mlflow_client, uri: str, name: str) -> str:
    """The id of experiment `name`, created (with a local store's artifact folder) when missing."""
    from mlflow.exceptions import MlflowException

    found = mlflow_client.get_experiment_by_name(name)
    if found is not None:
        return found.experiment_id
    try:
        return mlflow_client.create_experiment(name, artifact_location=_artifact_location(uri, name))
    except MlflowException:  # made meanwhile by another process (sweep members in parallel), else raised again
        found = mlflow_client.get_experiment_by_name(name)
        if found is None:
            raise
        return found.experiment_id


def _previous(record: dict) -> dict:
    return (record.get("loggers") or {}).get("mlflow") or {}


def tracked_at(record: dict) -> tuple[str, str] | None:
    """(tracking URI, MLflow run id) of a run.json record, None when the run is not tracked."""
    info = _previous(record)
    return (info["tracking_uri"], info["run_id"]) if info.get("run_id") and info.get("tracking_uri") else None


def training_logger(cfg, folder):
    """A Lightning MLFlowLogger for the training run in `folder` (None when tracking is off): params from its
    resolved config, tags from its lineage, a child of its sweep's run when it is a sweep member, and the same
    MLflow run (in the store it was started in) when the folder is resumed. Rank 0 only.""" 
    from pytorch_lightning.loggers import MLFlowLogger

    from samp.runs.lineage import flatten, lineage_tags

    configured = resolve_uri(cfg.tracking.uri, cfg.paths.runs_dir)
    if configured is None:  # off wins, a resumed run's store included
        return None
    record = folder.read()
    previous = tracked_at(record)
    uri = previous[0] if previous else configured
    mlflow_client = client(uri)
    sweep = record.get("sweep") or {}
    experiment = _sweep_experiment(sweep["dir"], cfg.paths.runs_dir) if sweep else str(cfg.name)
    experiment_id(mlflow_client, uri, experiment)  # with the local store's artifact folder
    tags = lineage_tags(record)
    if sweep and not previous:
        tags["mlflow.parentRunId"] = sweep_parent(sweep["dir"], uri, experiment)
    logger = MLFlowLogger(experiment_name=experiment, run_name=_run_name(folder.path, sweep), tracking_uri=uri,
                          tags=tags, run_id=previous[1] if previous else None)
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


def log_files(mlflow_client, run_id: str, folder: Path, artifact_path: str | None = None,
              recording: bool = True) -> list[str]:
    """Upload the files of `folder` as artifacts of `run_id` (under `artifact_path`), checkpoints, exported
    networks and other loggers' folders left out, recordings (`*.rrd`) unless `recording`; the relative paths."""
    sent = []
    for path in sorted(p for p in Path(folder).rglob("*") if p.is_file()):
        rel = path.relative_to(folder)
        if rel.parts[0] in SKIPPED or path.suffix in SKIPPED_SUFFIXES or rel.name.startswith(".") \
                or (path.suffix == ".rrd" and not recording):
            continue
        where = "/".join(p for p in (artifact_path, rel.parent.as_posix()) if p and p != ".") or None
        mlflow_client.log_artifact(run_id, str(path), where)
        sent.append(rel.as_posix())
    return sent


def log_dataset(mlflow_client, run_id: str, ref: str | None, root: str | Path | None, context: str) -> None:
    """Record dataset `ref` (`NAME@ID`) as an MLflow dataset input of the run, its content id as the digest
    and its folder under `root` as the source; nothing for a run without a dataset."""
    if not ref or "@" not in ref:
        return
    from mlflow.entities import Dataset, DatasetInput, InputTag
    from mlflow.utils.mlflow_tags import MLFLOW_DATASET_CONTEXT

    name, _, content_id = ref.partition("@")
    where = str(root or ".")
    remote = "://" in where  # a remote datasets folder (s3://...) keeps its scheme as the source type
    uri = f"{where.rstrip('/')}/{name}/{content_id}" if remote else str(Path(where) / name / content_id)
    scheme = where.partition("://")[0] if remote else "local"
    dataset = Dataset(name=name, digest=content_id, source_type=scheme, source=json.dumps({"uri": uri}))
    mlflow_client.log_inputs(run_id, [DatasetInput(dataset, [InputTag(MLFLOW_DATASET_CONTEXT, context)])])


def finish_training(logger, record: dict, run_dir: Path) -> None:
    """What a tracked training run gets once it is complete: the benchmark id as a tag, the dataset input and
    its files as artifacts (the recording unless the config's `tracking.recording` is false)."""
    from samp.names import EVAL_DIR, METRICS_JSON

    mlflow_client, run_id = logger.experiment, logger.run_id
    report = Path(run_dir) / EVAL_DIR / METRICS_JSON
    benchmark = json.loads(report.read_text()).get("benchmark") if report.is_file() else None
    if benchmark:
        mlflow_client.set_tag(run_id, "samp.benchmark_id", benchmark)
    config = record.get("config") or {}
    log_dataset(mlflow_client, run_id, record.get("dataset_id"), (config.get("paths") or {}).get("datasets_dir"),
                "training")
    recording = bool((config.get("tracking") or {}).get("recording", True))
    log_files(mlflow_client, run_id, Path(run_dir), recording=recording)


def track_evaluation(out: Path, report: dict, metrics: dict[str, float], run_path: Path | None = None) -> str | None:
    """Log an evaluation written into `out`: into the MLflow run of `run_path` (started now for a run that has
    none) as the section named after `out` (`eval-2/...`), or as a run of the experiment `eval` when no run was
    evaluated. `metrics`: the flat `eval/...` metrics, renamed to the section. Returns the MLflow run id."""
    from samp.runs.folder import RunFolder
    from samp.runs.lineage import flatten, lineage_tags
    from samp.paths import runs_root

    configured = resolve_uri(None, runs_root())
    if configured is None:  # off wins, a tracked run's store included
        return None
    section = _section(out, run_path)
    record = RunFolder(run_path).read() if run_path is not None else {}
    previous = tracked_at(record)
    uri = previous[0] if previous else configured
    mlflow_client = client(uri)
    if previous:
        run_id = previous[1]
    else:
        name = record.get("experiment") or EVAL_EXPERIMENT
        run = mlflow_client.create_run(experiment_id(mlflow_client, uri, name), tags=lineage_tags(record),
                                       run_name=f"{out.parent.name}/{out.name}" if run_path is None else
                                       f"{run_path.parent.name}/{run_path.name}")
        run_id = run.info.run_id
        _log_params(mlflow_client, run_id, flatten(record.get("config") or report.get("config") or {}))
        if run_path is not None:
            RunFolder(run_path).update(loggers={**(record.get("loggers") or {}), "mlflow": {
                "run_id": run_id, "tracking_uri": uri, "experiment_name": name}})
    _log_section(mlflow_client, run_id, section, report, metrics, int(record.get("steps") or 0))
    if run_path is None:  # a run's evaluation reads the dataset it trained on, an input already
        from samp.data.registry import datasets_root

        log_dataset(mlflow_client, run_id, report.get("dataset"), datasets_root(), "evaluation")
    recording = bool(((record.get("config") or {}).get("tracking") or {}).get("recording", True))
    log_files(mlflow_client, run_id, out, artifact_path=section, recording=recording)
    if not previous:
        mlflow_client.set_terminated(run_id)
    print(f"tracked: {uri} run {run_id} ({section})", flush=True)
    return run_id


def _section(out: Path, run_path: Path | None) -> str:
    """The evaluation's section: `eval` for an evaluation without a run (the MLflow run is the evaluation),
    else its folder's name (`eval-2`; `out=/tmp/bench` gives `bench`) in the characters MLflow allows in names."""
    import re

    from samp.names import EVAL_DIR

    return EVAL_DIR if run_path is None else re.sub(r"[^\w\-. /]", "_", Path(out).name)


def _log_params(mlflow_client, run_id: str, params: dict) -> None:
    from mlflow.entities import Param

    items = [Param(k, str(v)[:6000]) for k, v in params.items()]
    for start in range(0, len(items), 100):  # MLflow takes at most 100 params a batch
        mlflow_client.log_batch(run_id, params=items[start:start + 100])


def _log_section(mlflow_client, run_id: str, section: str, report: dict, metrics: dict[str, float],
                 step: int) -> None:
    """The section's metrics (`eval/...` renamed `<section>/...`, intervals included) and its lineage tags."""
    import time

    from mlflow.entities import Metric

    from samp.names import EVAL_PREFIX

    now = int(time.time() * 1000)
    items = [Metric(f"{section}/{k.removeprefix(EVAL_PREFIX)}", float(v), now, step) for k, v in metrics.items()]
    for start in range(0, len(items), 1000):  # MLflow takes at most 1000 metrics a batch
        mlflow_client.log_batch(run_id, metrics=items[start:start + 1000])
    prefix = "samp." if section == "eval" else f"samp.{section}."
    for key, value in (("benchmark_id", report.get("benchmark")), ("eval_dataset_id", report.get("dataset"))):
        if value:
            mlflow_client.set_tag(run_id, prefix + key, str(value))
