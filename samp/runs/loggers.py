"""Loggers that know their run folder: the CSV log every run keeps, and the opt-in trackers.

- `RunCSVLogger`: `metrics.csv` in the run folder. Lightning's CSVLogger deletes an existing metrics.csv
  when it starts; this one appends to it, so a resumed run (`samp.train resume=RUN_DIR`) keeps its
  earlier rows and goes on from the checkpoint's step (`RunFolder.trim_metrics` has set aside rows
  logged after that checkpoint).
- `mlflow_logger`: Lightning's MLFlowLogger on a `sqlite:///` URI (offline, no server), tagged with the
  run's lineage; its MLflow run id is kept in run.json so a resumed run logs into the same MLflow run.
- `wandb_logger`: Lightning's WandbLogger, offline by default, same lineage and resume behaviour.

`finish_loggers` adds what is only known after training (dataset id, robot SDF id, evaluation metrics).
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

from pytorch_lightning.loggers import CSVLogger, MLFlowLogger, WandbLogger
from pytorch_lightning.loggers.csv_logs import ExperimentWriter

from samp.runs.distributed import is_rank_zero
from samp.runs.folder import METRICS_CSV, RunFolder
from samp.runs.lineage import flatten, lineage_tags

__all__ = ["RunCSVLogger", "finish_loggers", "mlflow_logger", "wandb_logger"]


class _ContinuingWriter(ExperimentWriter):
    """Lightning's CSV writer, except that an existing metrics.csv is continued, not deleted."""

    def _check_log_dir_exists(self) -> None:
        path = Path(self.metrics_file_path)
        if path.is_file():  # its header becomes the known columns; new columns rewrite the header
            with open(path, newline="") as f:
                self.metrics_keys = sorted(csv.DictReader(f).fieldnames or [])


class RunCSVLogger(CSVLogger):
    """`<save_dir>/metrics.csv` (and hparams.yaml), continued across resumes of the same run folder."""

    def __init__(self, save_dir: str, flush_logs_every_n_steps: int = 100):
        super().__init__(save_dir, name="", version="", flush_logs_every_n_steps=flush_logs_every_n_steps)

    @property
    def experiment(self) -> ExperimentWriter:
        if self._experiment is None:
            os.makedirs(self.log_dir, exist_ok=True)
            self._experiment = _ContinuingWriter(log_dir=self.log_dir)
        return self._experiment


def _missing(package: str, extra: str) -> ModuleNotFoundError:
    return ModuleNotFoundError(f"logger={extra} needs the `{package}` package: pip install -e '.[{extra}]' "
                               f"(or leave logger at its default, csv)")


def _previous_id(folder: RunFolder, tracker: str) -> str | None:
    return ((folder.read().get("loggers") or {}).get(tracker) or {}).get("run_id")


def _remember(folder: RunFolder, tracker: str, **info) -> None:
    if is_rank_zero():
        folder.update(loggers={**(folder.read().get("loggers") or {}), tracker: info})


def mlflow_logger(run_dir: str, experiment_name: str, tracking_uri: str, artifact_location: str | None = None):
    """A Lightning MLFlowLogger for the run in `run_dir`: tags from its run.json lineage, and the same
    MLflow run again when the run folder is resumed. `tracking_uri`: `sqlite:///PATH` (MLflow 3 refuses
    plain folders); browse with `mlflow ui --backend-store-uri URI` (needs the full `mlflow` extra)."""
    import importlib.util

    if importlib.util.find_spec("mlflow") is None:
        raise _missing("mlflow", "mlflow")
    folder = RunFolder(run_dir)
    if tracking_uri.startswith("sqlite:///"):
        Path(tracking_uri.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    previous = _previous_id(folder, "mlflow")
    record = folder.read()
    logger = MLFlowLogger(experiment_name=experiment_name, run_name=f"{folder.path.parent.name}/{folder.path.name}",
                          tracking_uri=tracking_uri, tags=lineage_tags(record),
                          artifact_location=artifact_location, run_id=previous)
    if is_rank_zero():
        if previous is None:  # MLflow params never change: a resumed run keeps those of its first start
            logger.log_hyperparams(flatten(record.get("config") or {}))
        _remember(folder, "mlflow", run_id=logger.run_id, tracking_uri=tracking_uri, experiment_name=experiment_name)
    return logger


def wandb_logger(run_dir: str, project: str, offline: bool = True, entity: str | None = None):
    """A Lightning WandbLogger writing into `<run_dir>/wandb/` (offline: `wandb sync` uploads it later),
    with the lineage as config and the same W&B run id when the run folder is resumed."""
    import importlib.util
    import secrets

    if importlib.util.find_spec("wandb") is None:
        raise _missing("wandb", "wandb")
    folder = RunFolder(run_dir)
    run_id = _previous_id(folder, "wandb") or secrets.token_hex(4)
    _remember(folder, "wandb", run_id=run_id, project=project, offline=offline)
    return WandbLogger(project=project, entity=entity, name=f"{folder.path.parent.name}/{folder.path.name}",
                       save_dir=str(folder.path), offline=offline, id=run_id, resume="allow",
                       config=lineage_tags(folder.read()))


def _numeric(metrics: dict) -> dict[str, float]:
    return {k: float(v) for k, v in metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


def finish_loggers(loggers: list, record: dict, metrics: dict, step: int, final: dict | None = None) -> None:
    """After training: log `metrics` not logged yet (the final evaluation) at `step`, and the lineage now
    complete (dataset and robot SDF ids) as tags, to every logger. `final` (the last values of the run)
    goes to a CSV log that would otherwise stay empty: a run shorter than `log_every_n_steps`, without
    validation or evaluation, still gets its metrics.csv."""
    numeric, tags = _numeric(metrics), lineage_tags(record)
    for logger in loggers:
        if isinstance(logger, CSVLogger) and not numeric and final and not logger.experiment.metrics \
                and not (Path(logger.log_dir) / METRICS_CSV).is_file():
            logger.log_metrics({"epoch": float(record.get("epochs") or 0), **_numeric(final)}, step=step)
        if numeric:
            logger.log_metrics(numeric, step=step)
        logger.save()
        if isinstance(logger, MLFlowLogger):
            for key, value in tags.items():
                logger.experiment.set_tag(logger.run_id, key, value)
        elif isinstance(logger, WandbLogger):
            logger.experiment.config.update(tags, allow_val_change=True)
        logger.finalize("success")
