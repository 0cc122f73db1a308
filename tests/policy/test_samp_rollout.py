"""The real SAMP policy rolled out, fast: a few training steps on the tiny dataset, the checkpoint loaded by
`load_policy`, `step` equal to the network's own prediction, and the refusals of `SAMPStepPolicy` (a
never-fitted system, other workspace bounds, grids at another n_e). The fake policy of the CLI tests and the
dummy systems elsewhere cannot catch a step that drifts from the trained network or a check that is gone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from samp.policy.interface import EnvBatch

SMALL_NET = {"channels": 2, "env_hidden": [32], "point_hidden": [16, 32], "config_hidden": [16], "fusion_hidden": [32]}


@pytest.fixture(scope="module")
def trained(tiny_datamodule, robots, tmp_path_factory, small_robot_sdf):
    """(data module, fitted system, checkpoint path): three Lightning steps on the tiny dataset."""
    import pytorch_lightning as pl

    from samp.policy.system import PolicySystem

    dm = tiny_datamodule(32)
    torch.manual_seed(0)
    system = PolicySystem(robot="panda", robot_sdf_payload=small_robot_sdf(robots["panda"]), model=SMALL_NET)
    system.bind(dm.binding)
    trainer = pl.Trainer(max_steps=3, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    trainer.fit(system, datamodule=dm)
    path = tmp_path_factory.mktemp("samp_policy") / "policy.ckpt"
    trainer.save_checkpoint(path)
    return dm, system.eval(), path


def _env(dm, rows: int = 5) -> tuple[EnvBatch, dict]:
    b = dm.train_samples[torch.arange(rows)]
    bounds = torch.as_tensor(dm.bounds, dtype=torch.float64)[None].expand(len(dm.grids), 2, 3)
    return EnvBatch(dm.grids, bounds, b["scene"]), b


def test_load_policy_steps_as_the_trained_network_predicts(trained):
    """`load_policy(checkpoint, compiled=False).step` is the fitted network's `predict` on the same inputs, bit
    for bit, and the default (compiled inputs, `samp.policy.compiled`) agrees to float32 rounding. Catches a step
    that reads other grids, bounds or scenes, or a checkpoint that loses weights."""
    from samp.policy import load_policy
    from samp.policy.step import SAMPStepPolicy

    dm, system, path = trained
    policy, compiled = load_policy(path, compiled=False), load_policy(path)
    assert isinstance(policy, SAMPStepPolicy) and policy.n_e == 16
    env, b = _env(dm)
    policy.reset(env)
    compiled.reset(env)
    got = policy.step(b["q"], b["q_goal"], env)
    with torch.no_grad():
        want = system.predict(b["q"], b["q_goal"], system.encode(dm.grids), b["scene"], dm.bounds,
                              near=policy.system.robot_sdf_pairs == "near")
    assert torch.equal(got, want), f"max difference {float((got - want).abs().max())}"
    assert torch.allclose(compiled.step(b["q"], b["q_goal"], env), want, atol=1e-5)
    assert not torch.allclose(got, b["q"]), "a step must move the arm"
    lim = system.robot.joint_limits.to(got)
    assert ((got >= lim[:, 0] - 1e-6) & (got <= lim[:, 1] + 1e-6)).all(), "steps stay within the joint limits"


def test_a_never_fitted_system_is_refused(robots, small_robot_sdf):
    from samp.policy.step import SAMPStepPolicy
    from samp.policy.system import PolicySystem

    system = PolicySystem(robot="panda", robot_sdf_payload=small_robot_sdf(robots["panda"]), model=SMALL_NET)
    with pytest.raises(ValueError, match="never fitted to a dataset"):
        SAMPStepPolicy(system)


def test_other_bounds_and_another_n_e_are_refused(trained):
    from samp.policy import load_policy

    dm, _, path = trained
    policy = load_policy(path)
    env, b = _env(dm)
    shifted = EnvBatch(env.grids, env.bounds + torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64), env.scene_index)
    with pytest.raises(ValueError, match="trained on workspace bounds"):
        policy.reset(shifted)
    coarse = EnvBatch(env.grids[:, ::2, ::2, ::2].contiguous(), env.bounds, env.scene_index)
    with pytest.raises(ValueError, match="reads grids at n_e = 16"):
        policy.reset(coarse)
    fresh = load_policy(path)  # a first step resets: the checks run there too
    with pytest.raises(ValueError, match="reads grids at n_e = 16"):
        fresh.step(b["q"], b["q_goal"], coarse)


def test_a_stride_scales_the_predicted_step(trained):
    """`stride=s` moves s times the network's predicted step far from the goal, and near it no more than half
    the joint-space distance left but never less than the plain step, clamped to the joint limits (the oracle:
    the plain step of the same policy, scaled in numpy); a stride that is no number in (0, 4] is refused, and
    samp+check refuses one."""
    from samp.policy import load_policy
    from samp.policy.interface import clamp_to_limits

    dm, system, path = trained
    env, b = _env(dm)
    plain = load_policy(path, compiled=False)
    plain.reset(env)
    q = b["q"].double().numpy()
    for stride in (2.0, 0.5):
        long = load_policy(path, compiled=False, stride=stride)
        long.reset(env)
        for goal in (b["q_goal"], b["q"] + 0.01 * (b["q_goal"] - b["q"])):  # as stored, and right beside q
            step = (plain.step(b["q"], goal, env) - b["q"]).double().numpy()
            room = 0.5 * np.linalg.norm(goal.double().numpy() - q, axis=1) / np.linalg.norm(step, axis=1)
            scale = np.full(len(q), stride) if stride < 1 else np.clip(room, 1.0, stride)
            if stride > 1:  # far from the goal the whole stride, beside it the plain step: both cases are tested
                assert (scale == stride).any() if goal is b["q_goal"] else (scale == 1.0).all()
            want = clamp_to_limits(plain.robot, torch.from_numpy(q + scale[:, None] * step).float())
            assert torch.allclose(long.step(b["q"], goal, env), want, atol=1e-5)
    near = b["q"] + 0.01 * (b["q_goal"] - b["q"])
    assert torch.allclose(load_policy(path, compiled=False, stride=3.0).step(b["q"], near, env),
                          plain.step(b["q"], near, env), atol=1e-6)  # beside the goal: the trained step
    for bad in (0, -1.0, 5.0, "2"):
        with pytest.raises(ValueError, match="stride"):
            load_policy(path, stride=bad)
    with pytest.raises(ValueError, match="stride applies to the plain policy"):
        load_policy(path, stride=2.0, check=4)
