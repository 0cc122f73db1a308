"""The names evaluation writes and reads, as the evaluation code has always imported them (defined once
in `samp.names`)."""

from __future__ import annotations

from samp.names import (ALL_SPLITS, BEST_CKPT, CHECKPOINT_PREFERENCE, EVAL_DIR, METRICS_JSON, METRICS_MD,
                        PROBLEMS_JSONL, RECONSTRUCTION_RRD, RECORDING_RRD, RUN_JSON, SPLITS)
from samp.names import CHECKPOINTS_DIR as CHECKPOINT_DIR
from samp.names import EVAL_PREFIX as METRIC_PREFIX
from samp.names import LAST_CHECKPOINT as LAST_CKPT

__all__ = ["BEST_CKPT", "CHECKPOINT_DIR", "CHECKPOINT_PREFERENCE", "EVAL_DIR", "LAST_CKPT", "METRICS_JSON", "METRICS_MD",
           "METRIC_PREFIX", "PROBLEMS_JSONL", "RECONSTRUCTION_RRD", "RECORDING_RRD", "RUN_JSON", "SPLITS", "ALL_SPLITS"]
