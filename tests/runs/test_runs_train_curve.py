"""Every epoch logs its training loss at least once (issue 53): a run with fewer steps than
`trainer.log_every_n_steps` used to log no `train/*` value, so MLflow showed it without a training curve
(only `val/*`). The fast test fits a two-parameter module with Lightning and the run's CSV logger; the slow one
trains a tiny robot SDF run through `python -m samp.train` and reads its metrics.csv."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch

from samp.names import METRICS_CSV, TRAIN_PREFIX

LOSS = f"{TRAIN_PREFIX}loss"


def _train_rows(path: Path) -> list[tuple[int, float]]:
    with open(path) as f:
        return [(int(r["step"]), float(r[LOSS])) for r in csv.DictReader(f) if r.get(LOSS)]


def test_a_run_shorter_than_the_logging_interval_logs_its_training_loss_every_epoch(tmp_path):
    import pytorch_lightning as pl

    from samp.runs.loggers import LogEveryEpoch, RunCSVLogger

    class Line(pl.LightningModule):
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(1))

        def training_step(self, batch, batch_idx):
            (x,) = batch
            loss = (self.w * x - 2 * x).square().mean()
            self.log(LOSS, loss)
            return loss

        def configure_optimizers(self):
            return torch.optim.SGD(self.parameters(), lr=0.1)

    data = torch.utils.data.DataLoader(torch.utils.data.TensorDataset(torch.ones(8, 1)), batch_size=2)  # 4 a epoch
    trainer = pl.Trainer(max_steps=12, log_every_n_steps=25, logger=RunCSVLogger(str(tmp_path)),
                         callbacks=[LogEveryEpoch()], enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, accelerator="cpu")
    trainer.fit(Line(), data)

    rows = _train_rows(tmp_path / METRICS_CSV)
    assert [step for step, _ in rows] == [3, 7, 11], f"expected the loss at each epoch's last step, got {rows}"
    assert rows[-1][1] < rows[0][1], f"the loss should fall over the three epochs: {rows}"


@pytest.mark.slow
def test_a_tiny_robot_sdf_run_has_a_training_curve(cli, tiny_sdf, tmp_path):
    overrides = [*tiny_sdf, "datamodule.steps_per_epoch=10", "trainer.max_steps=20", "trainer.log_every_n_steps=25"]
    done = cli("samp.train", ["+experiment=robot_sdf_panda", *overrides], tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "smaller than the logging interval" not in done.stderr, done.stderr[-3000:]
    (run,) = (tmp_path / "robot_sdf_panda").iterdir()
    rows = _train_rows(run / METRICS_CSV)
    assert [step for step, _ in rows] == [9, 19], f"expected {LOSS} at the end of both epochs, got {rows}"
