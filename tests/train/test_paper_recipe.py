"""The paper-scale recipes (fast): `experiment=samp_paper` composes to the paper's settings (docs/design.md section 4
and the paper's table of key parameters), `samp_paper_ours` to the same scale with our corrections, and the
learning-rate schedule of each, stepped as training steps it, ends annealed, where the warm-restart schedule of
samp_n160 (T_0 = 10, T_mult = 2 over 160 epochs) ends back at its maximum."""

from __future__ import annotations

import pytest
import torch
from omegaconf import OmegaConf

from samp.train import compose_train_config

# The paper's values (its table of key parameters and its training setup).
PAPER = {"n_e": 160, "hash_levels": 32, "channels": 4, "points": 1024, "d_margin": 0.09, "d_target": 0.015,
         "epochs": 160, "lr": 1e-4, "batch_size": 50, "train_scenes": 32, "trajectories_per_scene": 1000}


def _compose(*overrides: str):
    return compose_train_config(list(overrides))


@pytest.mark.parametrize("trainer", [None, "trainer=gpu"])
@pytest.mark.parametrize("experiment", ["samp_paper", "samp_paper_ours"])
def test_both_recipes_compose_at_the_paper_scale(experiment, trainer):
    cfg = _compose(f"experiment={experiment}", *([trainer] if trainer else []))
    assert cfg.name == experiment
    if trainer:
        assert cfg.trainer.accelerator == "gpu"
    d, s, m = cfg.datamodule, cfg.system, cfg.model
    assert (d.dataset, d.n_e, d.batch_size) == ("paper", PAPER["n_e"], PAPER["batch_size"])
    assert d.noise == 0.03  # the authors' code's noise on q_t
    assert (cfg.trainer.max_epochs, cfg.trainer.max_steps) == (PAPER["epochs"], -1)
    assert s.optimizer._target_ == "torch.optim.AdamW" and s.optimizer.lr == PAPER["lr"]
    assert m.channels == PAPER["channels"]
    assert list(m.env_hidden) == [512, 256] and list(m.point_hidden) == [64, 128, 256]
    assert cfg.robot.points.count == PAPER["points"]
    loss = s.loss
    assert (loss.match, loss.collision, loss.config) == (1.0, 20.0, 1.0)
    assert (loss.d_margin, loss.d_target, loss.tau, loss.margin) == (PAPER["d_margin"], PAPER["d_target"], 1.0, "fixed")
    assert s.robot_sdf == "robot_sdf_panda_paper"
    from samp.data import load_spec

    spec = load_spec(d.dataset)
    assert (spec.train_scenes, spec.trajectories_per_scene) == (PAPER["train_scenes"], PAPER["trajectories_per_scene"])
    assert PAPER["n_e"] in spec.resolutions


def test_samp_paper_restores_the_papers_choices():
    cfg = _compose("experiment=samp_paper")
    m, s = cfg.model, cfg.system
    assert (m.norm, m.registration, m.goal_features) == ("batch", "bounds", False)
    assert (s.robot_sdf_tables, s.robot_sdf_pairs) == (0, "all")  # the network at every point-link pair
    assert cfg.datamodule.scenes_per_batch == 0  # batches from every training scene alike
    assert cfg.loss == "paper"
    named = _compose("experiment=samp_cpu", "loss=paper").system.loss  # conf/loss/paper.yaml
    assert OmegaConf.to_container(s.loss) == OmegaConf.to_container(named)


def test_samp_paper_ours_takes_the_cpu_recipes_corrections():
    ours, cpu = _compose("experiment=samp_paper_ours"), _compose("experiment=samp_cpu")
    for key in ("norm", "registration", "goal_features"):
        assert ours.model[key] == cpu.model[key], key
    assert (ours.model.norm, ours.model.registration, ours.model.goal_features) == ("group", "centres", True)
    for key in ("robot_sdf_tables", "loss"):
        assert ours.system[key] == cpu.system[key], key
    assert ours.system.robot_sdf_pairs in ("near", None) and ours.system.robot_sdf_tables >= 2
    assert ours.datamodule.scenes_per_batch == cpu.datamodule.scenes_per_batch == 2
    assert cpu.system.scheduler.T_0 == cpu.trainer.max_epochs and cpu.system.scheduler.T_mult == 1  # one cycle, as ours


def test_the_paper_size_robot_sdf():
    cfg = _compose("experiment=robot_sdf_panda_paper")
    enc = cfg.model.encoding
    assert (enc.levels, enc.log2_table_size, enc.features) == (PAPER["hash_levels"], 19, 2)
    assert cfg.name == "robot_sdf_panda_paper" and cfg.system.time_limit_s is None
    assert cfg.robot_sdf_samples.near_per_link + cfg.robot_sdf_samples.uniform_per_link == 500_000
    assert (cfg.datamodule.near_per_step, cfg.datamodule.uniform_per_step) == (2048, 1024)  # the authors' code


def test_a_named_loss_still_replaces_the_papers():
    assert _compose("experiment=samp_paper", "loss=tau_1cm").system.loss.tau == 0.01


def _epoch_rates(*overrides: str) -> tuple[list[float], str]:
    """The learning rate of every epoch of the composed run: the optimizer and scheduler from the config's `_partial_`
    nodes, through the system's own configure_optimizers, with one dummy parameter; the scheduler stepped at each
    epoch's end (its `interval`), as Lightning steps it. Also that interval."""
    from samp.policy.base import PolicySystemBase

    cfg = _compose(*overrides)
    system = OmegaConf.to_container(cfg.system, resolve=True)

    class Dummy(PolicySystemBase):
        def __init__(self):
            super().__init__(cfg.robot.name, system["optimizer"], system["scheduler"])
            self.net = torch.nn.Linear(1, 1)

    configured = Dummy().configure_optimizers()
    opt, sched = configured["optimizer"], configured["lr_scheduler"]["scheduler"]
    rates = []
    for _ in range(int(cfg.trainer.max_epochs)):
        rates.append(opt.param_groups[0]["lr"])
        opt.step()  # an epoch's training steps (no gradients: no update)
        sched.step()
    return rates, configured["lr_scheduler"]["interval"]


def test_the_old_schedule_ends_on_a_restart():
    cfg = _compose("experiment=samp_n160")
    assert (cfg.system.scheduler.T_0, cfg.system.scheduler.T_mult, cfg.trainer.max_epochs) == (10, 2, 160)
    rates, interval = _epoch_rates("experiment=samp_n160")
    top = max(rates)
    assert interval == "epoch" and len(rates) == 160
    assert rates[149] < 1e-3 * top  # the end of the fourth cycle (epochs 70-149)
    assert rates[150] == pytest.approx(top)  # the restart
    assert rates[-1] > 0.9 * top  # the run, and its last checkpoint, end near the maximum


@pytest.mark.parametrize("experiment", ["samp_paper", "samp_paper_ours"])
def test_the_paper_recipes_end_annealed(experiment):
    rates, interval = _epoch_rates(f"experiment={experiment}")
    assert interval == "epoch" and len(rates) == PAPER["epochs"]
    assert rates[0] == pytest.approx(PAPER["lr"])
    assert all(b <= a for a, b in zip(rates, rates[1:])), "a restart within the run"
    assert rates[-1] < 0.01 * rates[0]


def test_the_schedule_follows_max_epochs():
    rates, _ = _epoch_rates("experiment=samp_paper", "trainer.max_epochs=40")
    assert len(rates) == 40 and all(b <= a for a, b in zip(rates, rates[1:])) and rates[-1] < 0.01 * rates[0]
