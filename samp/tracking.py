"""MLflow tracking, the pieces every layer uses (the run folder's side is `samp.runs.tracking`, docs/runs.md
"Tracking in MLflow"): which store (`resolve_uri`), a client on it, experiments, a folder's files as
artifacts, a dataset as an input, and an evaluation logged as a section of its run (`track_evaluation`, for
`python -m samp.eval`).

The store: `tracking.uri` of the training config, else `$SAMP_TRACKING_URI`, else `sqlite:///<runs
folder>/mlflow.db` (a local store, no server; its artifacts in `<runs folder>/mlflow-artifacts/`); `off` in
either place turns tracking off. A run's store and MLflow run id are kept in its run.json (`loggers.mlflow`);
a local store recorded there is followed only on the machine that has it (`tracked_here`: a pulled run).
MLflow is imported only here, inside the functions, so `--help` and the commands that do not track stay fast.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from samp.names import RUN_JSON, TRACKING_ARTIFACTS_DIR, TRACKING_DB

__all__ = ["EVAL_EXPERIMENT", "EXPERIMENT_KIND", "OFF", "TRACKING_ENV", "client", "experiment_id", "flatten",
           "log_dataset", "log_files", "log_params", "resolve_uri", "track_evaluation", "tracked_at", "tracked_here"]

TRACKING_ENV = "SAMP_TRACKING_URI"
OFF = "off"
EVAL_EXPERIMENT = "eval"  # evaluations of a planner without a run folder
# Not uploaded: checkpoints and exported networks (large, and the run folder keeps them), other loggers' folders.
SKIPPED = ("checkpoints", "tensorboard", "wandb", ".hydra")
SKIPPED_SUFFIXES = (".ckpt", ".pt", ".tmp")
# The experiment tag MLflow's UI reads to choose its layout (mlflow 3.x, server/js: `ExperimentKind`): without
# it the UI may open an experiment in its GenAI layout (traces, prompts); samp's runs are model training.
EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")


def resolve_uri(configured: str | None, runs_dir: str | Path) -> str | None:
    """The tracking URI: `configured` (tracking.uri), else $SAMP_TRACKING_URI, else the local store
    `sqlite:///<runs_dir>/mlflow.db`; None when either says `off`."""
    uri = configured if configured not in (None, "") else os.environ.get(TRACKING_ENV) or None
    if uri is not None and str(uri).strip().lower() == OFF:
        return None
    return str(uri) if uri is not None else f"sqlite:///{Path(runs_dir).resolve() / TRACKING_DB}"


def _local_db(uri: str) -> Path | None:
    """The database file of a local `sqlite:///` store, None for other stores."""
    return Path(uri.removeprefix("sqlite:///")) if uri.startswith("sqlite:///") else None


def _local_root(uri: str) -> Path | None:
    """The runs folder of a local `sqlite:///` store (where its artifacts go), None for other stores."""
    db = _local_db(uri)
    return None if db is None else db.parent


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
    """The id of experiment `name`, created (with a local store's artifact folder) when missing, and marked as
    model training for MLflow's UI (`EXPERIMENT_KIND`) unless it is marked already."""
    from mlflow.exceptions import MlflowException

    found = mlflow_client.get_experiment_by_name(name)
    if found is None:
        try:
            return mlflow_client.create_experiment(name, artifact_location=_artifact_location(uri, name),
                                                   tags=dict([EXPERIMENT_KIND]))
        except MlflowException:  # made meanwhile by another process (sweep members in parallel), else raised again
            found = mlflow_client.get_experiment_by_name(name)
            if found is None:
                raise
    if EXPERIMENT_KIND[0] not in found.tags:  # an experiment made before samp set the kind, or by hand
        mlflow_client.set_experiment_tag(found.experiment_id, *EXPERIMENT_KIND)
    return found.experiment_id


def _previous(record: dict) -> dict:
    return (record.get("loggers") or {}).get("mlflow") or {}


def tracked_at(record: dict) -> tuple[str, str] | None:
    """(tracking URI, MLflow run id) of a run.json record, None when the run is not tracked."""
    info = _previous(record)
    return (info["tracking_uri"], info["run_id"]) if info.get("run_id") and info.get("tracking_uri") else None


def tracked_here(record: dict, instead: str) -> tuple[str, str] | None:
    """`tracked_at(record)` when that store is reachable from this machine and holds the run, else None with a
    one-line note that `instead` (this machine's store) takes the run. A local store (`sqlite:///PATH`) is a
    file of the machine the run trained on: a pulled run's record names the pusher's path, which is missing
    here or, in a clone at the same path, is another store without that run. Opening it would create it (or
    log into a run it lacks), so it is followed only when its file exists and holds the run. Servers are
    followed as recorded: a team's server is the same store from every machine."""
    previous = tracked_at(record)
    db = _local_db(previous[0]) if previous else None
    if db is None:
        return previous
    if not db.is_file():
        why = "is not on this machine"
    else:
        from mlflow.exceptions import MlflowException

        try:
            client(previous[0]).get_run(previous[1])
            return previous
        except MlflowException:
            why = f"does not hold its run {previous[1]}"
    print(f"note: {RUN_JSON} records the MLflow store {previous[0]}, which {why} (a run from another machine?); "
          f"tracking into {instead} instead", file=sys.stderr, flush=True)
    return None


def flatten(node, prefix: str = "") -> dict:
    """{"a": {"b": 1}, "c": [2]} -> {"a.b": 1, "c": [2]}: nested dicts become dotted keys; lists stay."""
    if not isinstance(node, dict):
        return {prefix: node} if prefix else {}
    out = {}
    for key, value in node.items():
        path = f"{prefix}.{key}" if prefix else str(key)
        out.update(flatten(value, path) if isinstance(value, dict) else {path: value})
    return out


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


def track_evaluation(out: Path, report: dict, metrics: dict[str, float], run_path: Path | None = None,
                     datasets_root: Path | None = None) -> str | None:
    """Log an evaluation written into `out`: into the MLflow run of `run_path` as the section named after `out`
    (`eval-2/...`), or as a run of the experiment `eval` when no run was evaluated (its dataset, under
    `datasets_root`, as an input) or the run was not tracked. `metrics`: the flat `eval/...` metrics, renamed
    to the section. Returns the MLflow run id (None when tracking is off)."""
    from samp.paths import runs_root

    configured = resolve_uri(None, runs_root())
    if configured is None:  # off wins, a tracked run's store included
        return None
    section = _section(out, run_path)
    record = json.loads((Path(run_path) / RUN_JSON).read_text()) if run_path is not None else {}
    previous = tracked_here(record, configured)
    uri = previous[0] if previous else configured
    mlflow_client = client(uri)
    if previous:
        run_id = previous[1]
    else:
        # (a run trained with tracking off, or in another machine's local store: its evaluations are runs of
        # their own, its run.json left as it is)
        name = record.get("experiment") or EVAL_EXPERIMENT
        tags = {"samp.run_dir": str(run_path)} if run_path is not None else None
        run = mlflow_client.create_run(experiment_id(mlflow_client, uri, name), tags=tags,
                                       run_name=f"{out.parent.name}/{out.name}")
        run_id = run.info.run_id
        log_params(mlflow_client, run_id, flatten(record.get("config") or report.get("config") or {}))
    _log_section(mlflow_client, run_id, section, report, metrics, int(record.get("steps") or 0))
    if not previous:  # a tracked run's evaluation reads the dataset it trained on, an input already
        log_dataset(mlflow_client, run_id, report.get("dataset"), datasets_root, "evaluation")
    recording = bool(((record.get("config") or {}).get("tracking") or {}).get("recording", True))
    log_files(mlflow_client, run_id, out, artifact_path=section, recording=recording)
    if not previous:
        mlflow_client.set_terminated(run_id)
    print(f"tracked: {uri} run {run_id} ({section})", flush=True)
    return run_id


def _section(out: Path, run_path: Path | None) -> str:
    """The evaluation's section: `eval` for an evaluation without a run (the MLflow run is the evaluation),
    else its folder's name (`eval-2`; `out=/tmp/bench` gives `bench`) in the characters MLflow allows in names."""
    from samp.names import EVAL_DIR

    return EVAL_DIR if run_path is None else _mlflow_name(Path(out).name)


def _mlflow_name(name: str) -> str:
    """`name` with every character MLflow refuses in a metric or section name (anything but letters, digits,
    `_ - . /` and spaces) as `_`: the planner `samp+check` logs as `samp_check`."""
    import re

    return re.sub(r"[^\w\-. /]", "_", name)


def log_params(mlflow_client, run_id: str, params: dict) -> None:
    """`params` (flat) as the run's params, each value as text of at most 6000 characters (MLflow's limit)."""
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
    items = [Metric(_mlflow_name(f"{section}/{k.removeprefix(EVAL_PREFIX)}"), float(v), now, step)
             for k, v in metrics.items()]
    for start in range(0, len(items), 1000):  # MLflow takes at most 1000 metrics a batch
        mlflow_client.log_batch(run_id, metrics=items[start:start + 1000])
    prefix = "samp." if section == "eval" else f"samp.{section}."
    tags = {**benchmark_tags(report.get("benchmarks") or {}), "eval_dataset_id": report.get("dataset")}
    for key, value in tags.items():
        if value:
            mlflow_client.set_tag(run_id, prefix + key, str(value))


def benchmark_tags(benchmarks: dict[str, str]) -> dict[str, str]:
    """An evaluation's benchmarks ({section: `name@id`}) as tag keys: `benchmark_id` for the headline section,
    `<section>_benchmark_id` (`hard_benchmark_id`) for the others."""
    return {("benchmark_id" if section == "benchmark" else f"{section}_benchmark_id"): ref
            for section, ref in benchmarks.items()}
