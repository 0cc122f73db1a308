"""Run folders (`runs/<experiment>/<timestamp>/`, DESIGN section 6) and their records."""

from samp.runs.folder import (CHECKPOINTS_DIR, CONFIG_DIR, LAST_CHECKPOINT, METRICS_CSV, RUN_JSON, STATUSES, RunFolder,
                              runs_root)

__all__ = ["CHECKPOINTS_DIR", "CONFIG_DIR", "LAST_CHECKPOINT", "METRICS_CSV", "RUN_JSON", "STATUSES", "RunFolder",
           "runs_root"]
