"""Names the evaluation code writes and reads: run-folder files (from `samp.runs`), metric prefixes, splits."""

from __future__ import annotations

from samp.runs.folder import CHECKPOINTS_DIR as CHECKPOINT_DIR
from samp.runs.folder import LAST_CHECKPOINT as LAST_CKPT
from samp.runs.folder import RUN_JSON

__all__ = ["BEST_CKPT", "CHECKPOINT_DIR", "CHECKPOINT_PREFERENCE", "EVAL_DIR", "LAST_CKPT", "METRICS_JSON", "METRICS_MD",
           "METRIC_PREFIX", "PROBLEMS_JSONL", "RECONSTRUCTION_RRD", "RECORDING_RRD", "RUN_JSON", "SPLITS", "ALL_SPLITS"]

BEST_CKPT = "best.ckpt"  # written by EvalCallback when the rollout success rate improves
CHECKPOINT_PREFERENCE = (BEST_CKPT, LAST_CKPT)

EVAL_DIR = "eval"  # under a run folder
METRICS_JSON = "metrics.json"
METRICS_MD = "metrics.md"
PROBLEMS_JSONL = "problems.jsonl"  # one per-problem record per line
RECORDING_RRD = "recording.rrd"
RECONSTRUCTION_RRD = "reconstruction.rrd"  # grid_source=reconstructed: clouds, reconstructed and exact slices

METRIC_PREFIX = "eval/"  # logged metrics during training, e.g. eval/success_rate
SPLITS = ("train", "heldout")  # scene splits of a dataset
ALL_SPLITS = "all"  # the pooled metrics over every problem evaluated
