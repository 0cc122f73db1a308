"""The training's tracker, guarded (`samp.tracking_faults`): a store that is locked past its retries, corrupt
or unreachable turns tracking off for the rest of the run with one warning line; the run itself goes on and
ends as it would untracked (run.json `completed` after a completed fit, the run folder whole).

`start_tracking` makes the MLflow logger of a run (`samp.runs.tracking.training_logger`), or None with the
warning when the store fails at the start (a corrupt `mlflow.db`: tracking is off for this run).
`GuardedMLFlowLogger` is Lightning's MLFlowLogger whose every call into the store goes through
`samp.tracking_faults.call`; `guarded` runs any other tracker step (the files after training) the same way.
"""

from __future__ import annotations

from pytorch_lightning.loggers import MLFlowLogger

from samp.tracking_faults import TrackerDown, call, warn

__all__ = ["GuardedMLFlowLogger", "start_tracking"]


class GuardedMLFlowLogger(MLFlowLogger):
    """MLFlowLogger that never fails its run: a store error turns it off (`down`: the warning), once."""

    def __init__(self, *args, run_dir=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.down: str | None = None
        self._run_dir = run_dir

    def guarded(self, what: str, fn, *args, **kwargs):
        """`fn(*args, **kwargs)` through `samp.tracking_faults.call`; None, and this logger off, when it fails."""
        if self.down is not None:
            return None
        try:
            return call(what, self._tracking_uri, fn, *args, **kwargs)
        except TrackerDown as err:
            self.down = str(err)
            warn(err, self._run_dir)
            return None

    def log_hyperparams(self, params) -> None:
        self.guarded("logging the run's params", super().log_hyperparams, params)

    def log_metrics(self, metrics, step=None) -> None:
        self.guarded("logging metrics", super().log_metrics, metrics, step)

    def after_save_checkpoint(self, checkpoint_callback) -> None:
        self.guarded("logging a checkpoint", super().after_save_checkpoint, checkpoint_callback)

    def finalize(self, status: str = "success") -> None:
        self.guarded("ending the run", super().finalize, status)


def start_tracking(cfg, folder):
    """`training_logger(cfg, folder)`, or None with one warning line when the store fails while the run is set
    up (corrupt, locked past MLflow's own wait, unreachable): the run trains untracked."""
    from samp.runs.tracking import training_logger
    from samp.tracking import resolve_uri

    uri = resolve_uri(cfg.tracking.uri, cfg.paths.runs_dir)
    try:
        logger = call("starting the run", str(uri), training_logger, cfg, folder, attempts=1)
    except TrackerDown as err:
        warn(err, folder.path)
        return None
    return None if logger is None or logger.down is not None else logger  # (a logger that failed has warned)
