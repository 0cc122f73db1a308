"""EvalCallback: rollouts every k epochs during training, eval/* metrics logged, best.ckpt by success."""

from __future__ import annotations

import pytest
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, TensorDataset

from samp.data import open_dataset
from samp.eval import EvalCallback, StraightLinePolicy, evaluate

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


class _Still:
    """Never moves: success 0 on every problem."""

    name, n_e = "still", None

    def __init__(self, robot):
        self.robot = robot

    def step(self, q, q_goal, env):
        return q.clone()


class TinySystem(pl.LightningModule):
    """A module whose policy is the straight line on odd epochs and a still policy on even ones, so the
    success rate goes 0 -> s -> 0 and the best checkpoint must be the one of epoch 1."""

    def __init__(self, robot):
        super().__init__()
        self.robot = robot
        self.w = torch.nn.Parameter(torch.ones(3))

    def planner(self):
        return StraightLinePolicy(self.robot) if self.current_epoch % 2 == 1 else _Still(self.robot)

    def training_step(self, batch, _):
        return ((self.w * batch[0]) ** 2).mean()

    def validation_step(self, batch, _):
        self.log("val/loss", ((self.w * batch[0]) ** 2).mean())

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.01)

    def train_dataloader(self):
        return DataLoader(TensorDataset(torch.randn(4, 3)), batch_size=2)

    def val_dataloader(self):
        return DataLoader(TensorDataset(torch.randn(4, 3)), batch_size=2)


def _trainer(tmp_path, callback, epochs: int) -> pl.Trainer:
    return pl.Trainer(max_epochs=epochs, limit_train_batches=1, limit_val_batches=1, logger=False,
                      enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                      default_root_dir=tmp_path, callbacks=[callback], accelerator="cpu", num_sanity_val_steps=0)


def test_the_callback_logs_eval_metrics_and_keeps_the_best_checkpoint(tiny_problems, panda, tmp_path):
    _, problems = tiny_problems
    expected = evaluate(StraightLinePolicy(panda), problems)["metrics"]
    assert 0 < expected["all"]["success_rate"] < 1, "the test needs a success rate between the extremes"
    # split: the problems are given; EvalCallback's own default ("heldout") predates the three splits.
    callback = EvalCallback(problems=problems, every_k_epochs=1, split="val")
    trainer = _trainer(tmp_path, callback, epochs=3)
    trainer.fit(TinySystem(panda))
    scores = [h["eval/success_rate"] for h in callback.history]
    assert scores == [0.0, expected["all"]["success_rate"], 0.0], scores
    for split in ("train", "val", "test"):
        assert callback.history[1][f"eval/{split}/success_rate"] == expected[split]["success_rate"], split
    assert callback.history[1]["eval/collision_rate"] == expected["all"]["collision_rate"]
    assert "eval/success_rate" in trainer.callback_metrics, "metrics go through pl_module.log"
    best = torch.load(tmp_path / "checkpoints" / "best.ckpt", weights_only=False)
    assert best["epoch"] == 1, f"best.ckpt should be from epoch 1 (the best success), got epoch {best['epoch']}"
    state = next(v for k, v in best["callbacks"].items() if "EvalCallback" in k)
    assert state["best"] == expected["all"]["success_rate"]


def test_a_resumed_run_keeps_the_best_score_and_its_checkpoint(tiny_problems, panda, tmp_path):
    """Stopped after epoch 1 (scores 0, s) and resumed from its checkpoint for epoch 2 (score 0): the callback
    restores best = s from the checkpoint, so epoch 2 does not overwrite best.ckpt, and its history goes on.
    A callback that forgot its best score on resume would take epoch 2's 0 as a new best."""
    _, problems = tiny_problems
    first = EvalCallback(problems=problems, every_k_epochs=1, split="val")
    trainer = _trainer(tmp_path, first, epochs=2)
    trainer.fit(TinySystem(panda))
    s = first.best
    assert s is not None and s > 0, first.history
    trainer.save_checkpoint(tmp_path / "last.ckpt")
    again = EvalCallback(problems=problems, every_k_epochs=1, split="val")
    _trainer(tmp_path, again, epochs=3).fit(TinySystem(panda), ckpt_path=tmp_path / "last.ckpt")
    assert again.best == s and [h["eval/success_rate"] for h in again.history] == [0.0, s, 0.0], again.history
    best = torch.load(tmp_path / "checkpoints" / "best.ckpt", weights_only=False)
    assert best["epoch"] == 1, f"best.ckpt must stay the one of epoch 1, got epoch {best['epoch']}"


def test_the_callback_runs_every_k_epochs_only(tiny_problems, panda, tmp_path):
    callback = EvalCallback(problems=tiny_problems[1][:2], every_k_epochs=2, save_best=False, split="val")
    _trainer(tmp_path, callback, epochs=3).fit(TinySystem(panda))
    assert [h["epoch"] for h in callback.history] == [1]
    assert not (tmp_path / "checkpoints").exists()


def test_a_module_without_a_planner_or_a_dataset_is_refused(tiny_problems, tmp_path):
    with pytest.raises(ValueError, match="give dataset=REF"):
        EvalCallback(problems=8, split="val")

    class NoPolicy(TinySystem):
        planner = None

    callback = EvalCallback(problems=tiny_problems[1][:1], split="val")
    with pytest.raises(TypeError, match=r"NoPolicy.planner\(\)"):
        _trainer(tmp_path, callback, epochs=1).fit(NoPolicy(None))


def test_the_callback_finds_its_dataset_in_the_folder_it_is_given(tiny_eval, monkeypatch, tmp_path):
    """A dataset outside the default datasets folder is found through `root` (as conf/callbacks/eval.yaml
    passes the run's folder), and only there."""
    folder, root = tiny_eval
    monkeypatch.setenv("SAMP_DATASETS_DIR", str(tmp_path))  # the default folder holds no such dataset
    with pytest.raises(Exception, match="tiny_eval"):
        EvalCallback(problems=1, dataset="tiny_eval", split="val").problems()
    problems = EvalCallback(problems=1, dataset="tiny_eval", split="val", root=str(root)).problems()
    assert len(problems) == 1 and problems[0].scene.name in {s.name for s in open_dataset(folder).scenes}
