"""PolicySystem: shapes for batch sizes 1 and 50, the collision loss's hinge, learning on a small set,
checkpoints that reload to identical outputs (robot SDF inside), and clear errors."""

from __future__ import annotations

import pytest
import torch

from samp.data import generate
from samp.data.module import TrajectoryDataModule
from samp.policy.system import PolicySystem

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

SPEC = {"name": "pol", "robot": "panda", "seed": 5, "train_scenes": 1, "val_scenes": 1,
        "trajectories_per_scene": 2, "eval_problems_per_scene": 2, "generators": ["tabletop"], "resolutions": [16]}
SMALL_NET = {"channels": 2, "env_hidden": [32], "point_hidden": [16, 32], "config_hidden": [16], "fusion_hidden": [32]}


@pytest.fixture(scope="module")
def setup(tmp_path_factory, robots, small_robot_sdf):
    folder = generate(SPEC, root=tmp_path_factory.mktemp("datasets"), progress=False)
    dm = TrajectoryDataModule(str(folder), n_e=16, batch_size=50, noise=0.0)
    dm.setup()
    payload = small_robot_sdf(robots["panda"])
    return dm, payload


def _system(setup, **kw) -> PolicySystem:
    dm, payload = setup
    system = PolicySystem(robot="panda", robot_sdf_payload=payload, **{"model": SMALL_NET, **kw})
    system.bind(dm.binding)
    return system


@pytest.mark.parametrize("batch", [1, 50])
def test_output_shapes_and_limits(setup, batch):
    dm, _ = setup
    system = _system(setup).eval()
    b = dm.train_samples[torch.arange(batch)]
    features = system.encode(dm.grids)
    with torch.no_grad():
        q_next = system.predict(b["q"], b["q_goal"], features, b["scene"], dm.bounds)
    assert q_next.shape == (batch, 7)
    lim = system.robot.joint_limits.float()
    assert (q_next >= lim[:, 0] - 1e-6).all() and (q_next <= lim[:, 1] + 1e-6).all()
    losses = system._losses(b)
    assert set(losses) == {"match", "coll", "config", "loss"} and all(torch.isfinite(v) for v in losses.values())


def test_two_hundred_steps_drive_the_loss_down_tenfold(setup):
    dm, _ = setup
    torch.manual_seed(0)
    system = _system(setup, collision_loss=False).train()
    batch = dm.train_samples[torch.arange(64)]
    opt = torch.optim.Adam(system.net.parameters(), lr=1e-3)
    first = None
    for _ in range(200):
        loss = system._losses(batch)["loss"]
        first = first if first is not None else float(loss.detach())
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss) < first / 10, (first, float(loss))


def test_collision_loss_switch_and_ablations(setup):
    dm, _ = setup
    b = dm.train_samples[torch.arange(8)]
    assert float(_system(setup, collision_loss=False)._losses(b)["coll"]) == 0.0
    no_points = _system(setup, model={**SMALL_NET, "point_encoder": False})
    assert not hasattr(no_points.net, "point_mlp")
    assert torch.isfinite(_system(setup, robot_sdf_feature=False)._losses(b)["loss"])


def test_checkpoint_reloads_to_identical_outputs(setup, tmp_path):
    import pytorch_lightning as pl

    dm, _ = setup
    system = _system(setup)
    trainer = pl.Trainer(max_steps=2, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    trainer.fit(system, datamodule=dm)
    path = tmp_path / "policy.ckpt"
    trainer.save_checkpoint(path)
    again = PolicySystem.from_checkpoint(path)
    system.eval()
    b = dm.train_samples[torch.arange(5)]
    with torch.no_grad():
        want = system.predict(b["q"], b["q_goal"], system.encode(dm.grids), b["scene"], dm.bounds)
        got = again.predict(b["q"], b["q_goal"], again.encode(dm.grids), b["scene"], again.bounds)
    assert torch.equal(want, got)
    assert again.binding == dm.binding and again.binding.meta()["n_e"] == 16  # what it was trained on, without grids
    assert again.grids is None and "grids" not in again.state_dict()  # the dataset's grids are not saved
    assert again.kind == "samp" and not {"n_e", "bounds", "dataset_id"} & set(again.hparams)


def test_fit_does_not_rewrite_the_hyperparameters(setup):
    import pytorch_lightning as pl

    dm, _ = setup
    system = PolicySystem(robot="panda", robot_sdf_payload=setup[1], model=SMALL_NET)
    before = dict(system.hparams)
    trainer = pl.Trainer(max_steps=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    trainer.fit(system, datamodule=dm)
    assert dict(system.hparams) == before
    assert system.binding.dataset_id == dm.dataset_id and system.grids.shape == dm.grids.shape


def test_a_dataset_of_another_robot_is_refused_at_bind(setup):
    from dataclasses import replace

    dm, payload = setup
    system = PolicySystem(robot="panda", robot_sdf_payload=payload, model=SMALL_NET)
    with pytest.raises(ValueError, match="is for robot 'iiwa'"):
        system.bind(replace(dm.binding, robot="iiwa"))
    with pytest.raises(ValueError, match="never fitted"):
        system.planner()


def test_the_optimizer_and_scheduler_come_from_config(setup):
    sgd = {"_target_": "torch.optim.SGD", "_partial_": True, "lr": 0.5}
    step = {"_target_": "torch.optim.lr_scheduler.StepLR", "_partial_": True, "step_size": 3}
    system = _system(setup, optimizer=sgd, scheduler=step)
    out = system.configure_optimizers()
    assert isinstance(out["optimizer"], torch.optim.SGD) and out["optimizer"].defaults["lr"] == 0.5
    assert isinstance(out["lr_scheduler"]["scheduler"], torch.optim.lr_scheduler.StepLR)
    assert isinstance(_system(setup, optimizer=sgd, scheduler={}).configure_optimizers(), torch.optim.SGD)
    with pytest.raises(ValueError, match="optimizer must be a config node with a _target_"):
        _system(setup, optimizer={"lr": 1.0})


def test_the_default_optimizer_is_fused_adamw_with_the_same_updates(setup):
    """The default (and conf/optimizer/adamw_*) AdamW runs fused; its steps equal the per-operation AdamW's
    (the oracle) up to float rounding, from the same weights and gradients."""
    from omegaconf import OmegaConf

    from samp.paths import conf_dir

    for name in ("adamw_warm_restarts", "adamw_constant"):
        assert OmegaConf.load(conf_dir() / "optimizer" / f"{name}.yaml").optimizer.fused is True, name
    fused = _system(setup)
    opt = fused.configure_optimizers()["optimizer"]
    assert isinstance(opt, torch.optim.AdamW) and opt.defaults["fused"] is True
    plain = _system(setup)
    plain.load_state_dict(fused.state_dict())
    reference = torch.optim.AdamW(plain.net.parameters(), lr=1e-4, weight_decay=1e-2)
    torch.manual_seed(0)
    for _ in range(3):
        for a, b in zip(fused.net.parameters(), plain.net.parameters()):
            a.grad = torch.randn_like(a)
            b.grad = a.grad.clone()
        opt.step()
        reference.step()
    for (name, a), b in zip(fused.net.named_parameters(), plain.net.parameters()):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-8, msg=lambda m: f"{name}: {m}")


def test_robot_sdf_for_another_robot_is_refused(setup):
    _, payload = setup
    other = {**payload, "info": {**payload["info"], "robot": "iiwa"}}
    with pytest.raises(ValueError, match="robot SDF is for robot 'iiwa'"):
        PolicySystem(robot="panda", model=SMALL_NET, robot_sdf_payload=other)


def test_missing_robot_sdf_says_how_to_build_it(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"no robot SDF at .*build_missing.robot_sdf=true"):
        PolicySystem(robot="panda", robot_sdf=str(tmp_path / "nowhere"))
    from samp.train.prerequisites import resolve_robot_sdf

    with pytest.raises(FileNotFoundError, match=r"python -m samp.train experiment=robot_sdf_panda"):
        resolve_robot_sdf("robot_sdf_panda", tmp_path)


def test_a_non_finite_loss_stops_training_with_a_message(setup):
    from samp.policy.system import NonFiniteLossError

    dm, _ = setup
    system = _system(setup).train()
    with torch.no_grad():
        system.net.fusion[-1].bias.fill_(float("nan"))  # a diverged network
    with pytest.raises(NonFiniteLossError, match=r"samp training loss is nan at epoch 0, step 0 \(match nan.*checkpoints/"):
        system.training_step(dm.train_samples[torch.arange(8)], 0)
