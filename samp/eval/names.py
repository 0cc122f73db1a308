"""Names the evaluation code writes and reads, defined once: run-folder files, metric prefixes, splits.

When the project grows a shared constants module for run folders, these move there unchanged.
"""

from __future__ import annotations

__all__ = ["BEST_CKPT", "CHECKPOINT_DIR", "CHECKPOINT_PREFERENCE", "EVAL_DIR", "LAST_CKPT", "METRICS_JSON", "METRICS_MD",
           "METRIC_PREFIX", "PROBLEMS_JSONL", "RECORDING_RRD", "RUN_JSON", "SPLITS", "ALL_SPLITS"]

RUN_JSON = "run.json"  # a run folder's record (DESIGN section 6)
CHECKPOINT_DIR = "checkpoints"
BEST_CKPT = "best.ckpt"  # written by EvalCallback when the rollout success rate improves
LAST_CKPT = "last.ckpt"  # Lightning's ModelCheckpoint(save_last=True)
CHECKPOINT_PREFERENCE = (BEST_CKPT, LAST_CKPT)

EVAL_DIR = "eval"  # under a run folder
METRICS_JSON = "metrics.json"
METRICS_MD = "metrics.md"
PROBLEMS_JSONL = "problems.jsonl"  # one per-problem record per line
RECORDING_RRD = "recording.rrd"

METRIC_PREFIX = "eval/"  # logged metrics during training, e.g. eval/success_rate
SPLITS = ("train", "heldout")  # scene splits of a dataset
ALL_SPLITS = "all"  # the pooled metrics over every problem evaluated
