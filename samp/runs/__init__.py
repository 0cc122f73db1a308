"""Run folders (`runs/<experiment>/<timestamp>/`, docs/design.md section 6), their records and lineage; the
registry, tables, plots and sweeps over them live in the submodules (`python -m samp.runs`)."""

from samp.runs.folder import (CHECKPOINTS_DIR, CONFIG_DIR, LAST_CHECKPOINT, METRICS_CSV, RUN_JSON, STATUSES, RunFolder,
                              Terminated, runs_root)

__all__ = ["CHECKPOINTS_DIR", "CONFIG_DIR", "LAST_CHECKPOINT", "METRICS_CSV", "RUN_JSON", "STATUSES", "RunFolder",
           "Terminated", "runs_root"]
