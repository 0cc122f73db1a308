"""`EvalCallback`: the rollout evaluation on a fixed subset of problems every k epochs during training.

Contract with the LightningModule: it has a method `planner()` that returns a `StepPolicy` or a
`TrajectoryPlanner` (`samp.policy.interface`) acting with the module's current weights (the callback calls it at every
evaluation; the module is in eval mode then, as at any validation epoch end).

Every `every_k_epochs` validation epochs the callback rolls the policy out on its problems, logs
`eval/<metric>` over all of them and `eval/<split>/<metric>` per split through `pl_module.log`, and when
`eval/success_rate` beats the best so far saves `best.ckpt` in `dirpath` (default
`<trainer.default_root_dir>/checkpoints`), the checkpoint `load_planner(run_dir)` prefers. The
evaluation runs on global rank 0 only; the other ranks receive its metrics, so all of them take part in
`trainer.save_checkpoint` (a collective call under DDP).
"""

from __future__ import annotations

from pathlib import Path

import pytorch_lightning as pl

from samp.eval.config import RolloutConfig, rollout_config
from samp.eval.metrics import logged_metrics, metric
from samp.eval.names import ALL_SPLITS, BEST_CKPT, CHECKPOINT_DIR, METRIC_PREFIX

SELECTION_SPLITS = ("val", "train", "both")

__all__ = ["EvalCallback", "LOGGED_METRICS"]

LOGGED_METRICS = logged_metrics()  # the registry's (samp.eval.metrics.METRICS) metrics marked `logged`
MONITOR = metric("success_rate").key  # the score that picks best.ckpt


class EvalCallback(pl.Callback):
    """Roll the policy out on a fixed problem subset every `every_k_epochs` epochs.

    Args:
        problems: a list of `Problem`s, or a count per split to take from `dataset` (fixed by `seed`).
        every_k_epochs: evaluate after the validation of every k-th epoch (epochs k, 2k, ...).
        dataset: dataset reference (name, name@id or folder), when `problems` is a count.
        split: "val" (the validation scenes' stored evaluation problems: what selects the checkpoint),
            "train" (the training scenes' evaluation problems) or "both"; never the test scenes.
        seed: fixes which problems are taken.
        rollout: `RolloutConfig` keys (max_steps, tolerances, batch_size, ...).
        dirpath: where best.ckpt goes (default `<trainer.default_root_dir>/checkpoints`).
        save_best: write best.ckpt when the success rate improves.
        root: the datasets folder `dataset` is looked up in (default: `$SAMP_DATASETS_DIR`, else datasets/;
            conf/callbacks/eval.yaml passes the run's `paths.datasets_dir`).
    """

    def __init__(self, problems=32, every_k_epochs: int = 1, dataset: str | None = None, split: str = "val",
                 seed: int = 0, rollout: dict | None = None, dirpath: str | None = None, save_best: bool = True,
                 root: str | None = None):
        super().__init__()
        if not isinstance(every_k_epochs, int) or every_k_epochs < 1:
            raise ValueError(f"every_k_epochs must be an integer >= 1, got {every_k_epochs!r}")
        split = "val" if split == "heldout" else split  # the validation scenes' old name
        if split not in SELECTION_SPLITS:
            raise ValueError(f"split must be 'val', 'train' or 'both' (test scenes never take part in training or "
                             f"checkpoint selection), got {split!r}")
        if isinstance(problems, int) and dataset is None:
            raise ValueError(f"EvalCallback(problems={problems}) takes problems from a dataset: give dataset=REF, "
                             "or pass a list of samp.eval.Problem")
        self.every_k_epochs, self.dataset, self.split, self.seed = every_k_epochs, dataset, split, seed
        # Outcomes only: one batch, no second pass one problem at a time for latencies.
        self.rollout = rollout if isinstance(rollout, RolloutConfig) else \
            rollout_config({"batch_size": None, "timed_problems": 0, **(rollout or {})})
        self.dirpath, self.save_best, self.root = dirpath, save_best, root
        self._problems = None if isinstance(problems, int) else list(problems)
        self._count = problems if isinstance(problems, int) else None
        self._grids = None
        self.best: float | None = None
        self.history: list[dict] = []

    # ----------------------------------------------------------------- problems
    def problems(self):
        """The fixed problem subset (taken from the dataset on first use)."""
        if self._problems is None:
            from samp.data import open_dataset
            from samp.eval.problems import dataset_grids, problems_from_dataset

            ds = open_dataset(self.dataset, Path(self.root) if self.root else None)
            splits = ["val", "train"] if self.split == "both" else [self.split]
            self._problems = [p for s in splits for p in problems_from_dataset(ds, s, self._count, self.seed)]
            self._grids = dataset_grids(ds)
        return self._problems

    def setup(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
        if not callable(getattr(pl_module, "planner", None)):
            raise TypeError(f"EvalCallback needs {type(pl_module).__name__}.planner() returning a StepPolicy or "
                            "a TrajectoryPlanner (samp.policy.interface), as every PolicySystemBase has")
        if trainer.is_global_zero:
            self.problems()  # a bad dataset or split fails at the start, not after the first epochs

    # ----------------------------------------------------------------- evaluation
    def _due(self, trainer: pl.Trainer) -> bool:
        return not trainer.sanity_checking and (trainer.current_epoch + 1) % self.every_k_epochs == 0

    def _evaluate(self, pl_module: pl.LightningModule) -> dict[str, float]:
        from samp.eval.harness import evaluate

        result = evaluate(pl_module.planner(), self.problems(), self.rollout, grids=self._grids)
        flat = {}
        for split, m in result["metrics"].items():
            prefix = METRIC_PREFIX if split == ALL_SPLITS else f"{METRIC_PREFIX}{split}/"
            flat.update({prefix + k: float(m[k]) for k in LOGGED_METRICS if m.get(k) is not None})
        return flat

    def on_validation_epoch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if not self._due(trainer):
            return
        flat = self._evaluate(pl_module) if trainer.is_global_zero else None
        flat = trainer.strategy.broadcast(flat, src=0)
        for key, value in flat.items():
            pl_module.log(key, value, sync_dist=False, rank_zero_only=False)
        score = flat.get(METRIC_PREFIX + MONITOR, 0.0)
        self.history.append({"epoch": trainer.current_epoch, **flat})
        if self.save_best and (self.best is None or score > self.best):
            self.best = score
            folder = Path(self.dirpath) if self.dirpath else Path(trainer.default_root_dir) / CHECKPOINT_DIR
            trainer.save_checkpoint(folder / BEST_CKPT, weights_only=False)

    # ----------------------------------------------------------------- resuming keeps the best score
    def state_dict(self) -> dict:
        return {"best": self.best, "history": self.history}

    def load_state_dict(self, state_dict: dict) -> None:
        self.best = state_dict.get("best")
        self.history = list(state_dict.get("history", []))
