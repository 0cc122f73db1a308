"""Names defined once (STYLE 8): run-folder files, checkpoint records, batch keys, logged-metric prefixes,
scene splits. Everything that writes or reads one of these imports it from here; this module imports
nothing of samp, so every layer may use it."""

from __future__ import annotations

__all__ = ["ALL_SPLITS", "BATCH_GOAL", "BATCH_NEXT", "BATCH_Q", "BATCH_SCENE", "BATCH_START", "BATCH_STEP",
           "BATCH_STEP_CLEAN", "BATCH_TRAJ", "BEST_CKPT", "CHECKPOINTS_DIR", "CHECKPOINT_PREFERENCE",
           "CHECKPOINT_RECORD", "CONFIG_DIR", "EVAL_DIR", "EVAL_PREFIX", "HPARAMS_YAML", "LAST_CHECKPOINT",
           "METRICS_CSV", "METRICS_JSON", "N_E_MAX", "METRICS_MD", "PLOTS_DIR", "PROBLEMS_JSONL", "RECONSTRUCTION_RRD",
           "RECORDING_RRD", "RUN_JSON", "SPLITS", "SPLIT_ALIASES", "SUMMARY_PNG", "TRACKING_ARTIFACTS_DIR",
           "TRACKING_DB", "TRAIN_LOG", "TRAIN_PREFIX", "VAL_PREFIX"]

# The most anchors per axis of a scene grid: 256^3 float32 distances are 64 MiB per grid (the paper's largest
# n_e is 160). Checked wherever n_e is given (grids, training and evaluation configs), before anything is
# allocated: n_e = 100000 would ask for petabytes.
N_E_MAX = 256

# ---------------------------------------------------------------- a run folder (docs/design.md section 6)
RUN_JSON = "run.json"
METRICS_CSV = "metrics.csv"
HPARAMS_YAML = "hparams.yaml"  # the model's hyperparameters, beside metrics.csv (the CSV logger)
CONFIG_DIR = ".hydra"
CHECKPOINTS_DIR = "checkpoints"
LAST_CHECKPOINT = "last.ckpt"
BEST_CKPT = "best.ckpt"  # written by EvalCallback when the rollout success rate improves
CHECKPOINT_PREFERENCE = (BEST_CKPT, LAST_CHECKPOINT)  # what an evaluation of a run loads
EVAL_DIR = "eval"  # the evaluation's files under a run folder
METRICS_JSON = "metrics.json"
METRICS_MD = "metrics.md"
PROBLEMS_JSONL = "problems.jsonl"  # one per-problem record per line
RECORDING_RRD = "recording.rrd"
RECONSTRUCTION_RRD = "reconstruction.rrd"  # grid_source=reconstructed: clouds, reconstructed and exact slices
PLOTS_DIR = "plots"
SUMMARY_PNG = "summary.png"  # losses and rates of a run, written after training
TRAIN_LOG = "train.log"  # everything the run printed (samp.runs.console.RunLog)
# ---------------------------------------------------------------- the runs folder's local MLflow store (samp.tracking)
TRACKING_DB = "mlflow.db"
TRACKING_ARTIFACTS_DIR = "mlflow-artifacts"  # its artifacts: copies of run files, never scanned as runs

# ---------------------------------------------------------------- checkpoints
CHECKPOINT_RECORD = "samp"  # {"kind": ..., ...}: what a policy checkpoint holds (samp.policy.registry)

# ---------------------------------------------------------------- a training batch of policy steps (samp.data.module)
BATCH_Q = "q"  # (B, n) q_t, radians (with noise during training)
BATCH_NEXT = "q_next"  # (B, n) q_{t+1}
BATCH_GOAL = "q_goal"  # (B, n) the trajectory's last waypoint
BATCH_SCENE = "scene"  # (B,) long, the scene index into the bound grids
BATCH_START = "q_start"  # (B, n) the trajectory's first waypoint
BATCH_STEP_CLEAN = "q_clean"  # (B, n) q_t without the training noise
BATCH_TRAJ = "traj"  # (B,) long, the trajectory index
BATCH_STEP = "step"  # (B,) long, t

# ---------------------------------------------------------------- logged metrics and splits
TRAIN_PREFIX, VAL_PREFIX, EVAL_PREFIX = "train/", "val/", "eval/"
# Scene splits of a dataset (docs/design.md section 4): training scenes hold demonstrations, validation scenes drive
# the validation loss, the evaluation during training and the choice of checkpoint, test scenes are seen
# only by the final evaluation.
SPLITS = ("train", "val", "test")
# Older datasets have one "heldout" split, which both validated and tested: it reads as "val".
SPLIT_ALIASES = {"heldout": "val"}
ALL_SPLITS = "all"  # the pooled metrics over every problem evaluated
