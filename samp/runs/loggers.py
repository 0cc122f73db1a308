"""Loggers that know their run folder: the CSV log every run keeps, and the optional ones.

- `RunCSVLogger`: `metrics.csv` in the run folder, continued when a run is resumed (`samp.train
  resume=RUN_DIR` goes on from the checkpoint's step; `RunFolder.trim_metrics` has set aside rows logged
  after that checkpoint).
- `tensorboard_logger`: Lightning's TensorBoardLogger, event files in `<run>/tensorboard/`.
- `wandb_logger`: Lightning's WandbLogger, offline by default, tagged with the run's lineage; its run id is
  kept in run.json so a resumed run logs into the same W&B run.
- `LogEveryEpoch`: a callback of every training run, so every epoch logs its training loss at least once.

MLflow is no logger option: every run is tracked there unless tracking is off (`samp.runs.tracking`, which
makes its logger). `finish_loggers` adds what is only known after training (dataset id, robot SDF id,
evaluation metrics, and for MLflow the files).
"""

from __future__ import annotations

import csv
from pathlib import Path

from pytorch_lightning import Callback
from pytorch_lightning.loggers import Logger, MLFlowLogger, WandbLogger
from pytorch_lightning.utilities import rank_zero_only

from samp.names import HPARAMS_YAML, METRICS_CSV
from samp.runs.distributed import is_rank_zero
from samp.runs.folder import RunFolder
from samp.runs.lineage import lineage_tags

__all__ = ["LogEveryEpoch", "RunCSVLogger", "finish_loggers", "tensorboard_logger", "wandb_logger"]


class RunCSVLogger(Logger):
    """`<save_dir>/metrics.csv` (and hparams.yaml), continued across resumes of the same run folder.

    A Logger of its own on Lightning's public API (Lightning's CSVLogger deletes an existing metrics.csv when it
    starts). The file keeps that logger's format, which `samp.runs` reads: one row per `log_metrics` call, the
    columns every key logged so far in sorted order with `step` among them, blank where a row has no value; a
    new key rewrites the file under the wider header. Rows are buffered and written every
    `flush_logs_every_n_steps` steps, on `save` and at the end."""

    def __init__(self, save_dir: str, flush_logs_every_n_steps: int = 100):
        super().__init__()
        self._dir = Path(save_dir)
        self._every = int(flush_logs_every_n_steps)
        self._rows: list[dict] = []
        self._keys: list[str] | None = None  # the header on disk, read when first needed

    @property
    def name(self) -> str:
        return ""

    @property
    def version(self) -> str:
        return ""

    @property
    def save_dir(self) -> str:
        return str(self._dir)

    @property
    def log_dir(self) -> str:
        return str(self._dir)

    @property
    def path(self) -> Path:
        return self._dir / METRICS_CSV

    def has_rows(self) -> bool:
        """Whether any row was logged, written or still buffered."""
        return bool(self._rows) or self.path.is_file()

    @rank_zero_only
    def log_hyperparams(self, params, *args, **kwargs) -> None:
        from pytorch_lightning.core.saving import save_hparams_to_yaml

        self._dir.mkdir(parents=True, exist_ok=True)
        save_hparams_to_yaml(self._dir / HPARAMS_YAML, params if isinstance(params, dict) else vars(params))

    @rank_zero_only
    def log_metrics(self, metrics: dict, step: int | None = None) -> None:
        row = {k: v.item() if hasattr(v, "item") else v for k, v in metrics.items()}
        row["step"] = len(self._rows) if step is None else int(step)
        self._rows.append(row)
        if (row["step"] + 1) % self._every == 0:
            self.save()

    @rank_zero_only
    def save(self) -> None:
        if not self._rows:
            return
        if self._keys is None:
            self._keys = self._header()
        new = sorted(set().union(*self._rows) - set(self._keys))
        if new:
            self._keys = sorted([*self._keys, *new])
            if self.path.is_file():  # a wider header: the rows on disk are written again under it, then swapped in
                tmp = self.path.with_name(f".{METRICS_CSV}.tmp")
                self._write("w", self._read(), tmp)
                tmp.replace(self.path)
        self._write("a" if self.path.is_file() else "w", self._rows)
        self._rows = []

    @rank_zero_only
    def finalize(self, status: str) -> None:
        self.save()

    def _header(self) -> list[str]:
        if not self.path.is_file():
            return []
        with open(self.path, newline="") as f:
            return sorted(csv.DictReader(f).fieldnames or [])

    def _read(self) -> list[dict]:
        with open(self.path, newline="") as f:
            return list(csv.DictReader(f))

    def _write(self, mode: str, rows: list[dict], path: Path | None = None) -> None:
        self._dir.mkdir(parents=True, exist_ok=True)
        with open(path or self.path, mode, newline="") as f:
            writer = csv.DictWriter(f, fieldnames=self._keys)
            if mode == "w":
                writer.writeheader()
            writer.writerows(rows)


def _missing(package: str, extra: str) -> ModuleNotFoundError:
    return ModuleNotFoundError(f"logger={extra} needs the `{package}` package: pip install -e '.[{extra}]' "
                               f"(or leave logger at its default, csv)")


def _previous_id(folder: RunFolder, tracker: str) -> str | None:
    return ((folder.read().get("loggers") or {}).get(tracker) or {}).get("run_id")


def _remember(folder: RunFolder, tracker: str, **info) -> None:
    if is_rank_zero():
        folder.update(loggers={**(folder.read().get("loggers") or {}), tracker: info})


def tensorboard_logger(run_dir: str, name: str = "tensorboard"):
    """Lightning's TensorBoardLogger writing its event files into `<run_dir>/<name>/` (no version folders:
    a resumed run appends to the same folder); `tensorboard --logdir RUN_DIR/tensorboard` shows them."""
    import importlib.util

    if importlib.util.find_spec("tensorboard") is None and importlib.util.find_spec("tensorboardX") is None:
        raise _missing("tensorboard", "tensorboard")
    from pytorch_lightning.loggers import TensorBoardLogger

    return TensorBoardLogger(save_dir=run_dir, name=name, version="", default_hp_metric=False)


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


class LogEveryEpoch(Callback):
    """Every epoch logs its training metrics at least once. Lightning logs them every `log_every_n_steps`
    optimizer steps of the whole run, so a run with fewer steps than that (or with shorter epochs between
    two logging steps) logged no `train/*` value and showed no training curve, in MLflow as in metrics.csv:
    at the start of training the interval is shortened to the steps of one epoch (and to `max_steps`) where
    it is longer. Lightning's warning about the short epoch, which this answers, is left out."""

    def setup(self, trainer, pl_module, stage: str) -> None:
        import warnings

        warnings.filterwarnings("ignore", message=r"The number of training batches \(\d+\) is smaller than the "
                                                  r"logging interval")

    def on_train_start(self, trainer, pl_module) -> None:
        every = trainer.log_every_n_steps
        if not every:  # 0: the user asked for no step logging
            return
        steps = trainer.max_steps if trainer.max_steps > 0 else every
        batches = trainer.num_training_batches  # inf for a loader without a length
        if batches != float("inf"):
            steps = min(steps, int(batches) // max(1, trainer.accumulate_grad_batches))
        trainer.log_every_n_steps = max(1, min(every, steps))


def _numeric(metrics: dict) -> dict[str, float]:
    return {k: float(v) for k, v in metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


def finish_loggers(loggers: list, record: dict, metrics: dict, step: int, final: dict | None = None) -> None:
    """After training: log `metrics` not logged yet (the final evaluation) at `step`, and the lineage now
    complete (dataset and robot SDF ids) as tags, to every logger; a tracked run's files go to MLflow
    (`samp.runs.tracking.finish_training`). `final` (the last values of the run) goes to a CSV log that would
    otherwise stay empty: a run shorter than `log_every_n_steps`, without validation or evaluation, still
    gets its metrics.csv."""
    from samp.runs.tracking import finish_training

    numeric, tags = _numeric(metrics), lineage_tags(record)
    for logger in loggers:
        if isinstance(logger, RunCSVLogger) and not numeric and final and not logger.has_rows():
            logger.log_metrics({"epoch": float(record.get("epochs") or 0), **_numeric(final)}, step=step)
        if numeric:
            logger.log_metrics(numeric, step=step)
        logger.save()
        if isinstance(logger, MLFlowLogger):
            def finish(logger=logger) -> None:
                for key, value in tags.items():
                    logger.experiment.set_tag(logger.run_id, key, value)
                finish_training(logger, record, Path(record["run_dir"]))

            # a guarded logger (samp.runs.tracker_guard) turns itself off instead of failing the finished run
            logger.guarded("logging tags and files", finish) if hasattr(logger, "guarded") else finish()
        elif isinstance(logger, WandbLogger):
            logger.experiment.config.update(tags, allow_val_change=True)
        logger.finalize("success")
