"""MPiNet-style policy: network shapes, the labelled cloud, the hinge collision loss against hand-computed
values, a loss that falls on a small set, checkpoints that reload to identical outputs, and rollouts
through the evaluation's step-policy interface."""

from __future__ import annotations

import pytest
import torch

from samp.policy.baselines.mpinet import LABELS, MPiNetConfig, MPiNetNet, labelled_cloud
from samp.policy.baselines.mpinet_system import MPiNetSystem, hinge_collision_loss

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

SMALL = {"robot_points": 48, "obstacle_points": 64, "target_points": 16,
         "levels": [{"centres": 32, "radius": 0.15, "neighbours": 8, "widths": [16, 32]}],
         "global_widths": [32, 64], "config_hidden": [16], "decoder_hidden": [64]}


@pytest.fixture(scope="module")
def dm(tiny_datamodule):
    return tiny_datamodule(16)


def _system(dm, **kw) -> MPiNetSystem:
    system = MPiNetSystem(robot="panda", model=SMALL, **kw)
    system.bind(dm.binding)
    return system


@pytest.mark.parametrize("batch", [1, 5])
def test_network_output_shape_and_range(batch):
    torch.manual_seed(0)
    net = MPiNetNet(MPiNetConfig(**SMALL))
    xyz, labels = labelled_cloud(torch.rand(batch, 48, 3), torch.rand(batch, 64, 3), torch.rand(batch, 16, 3))
    assert xyz.shape == (batch, 128, 3) and labels.shape == (batch, 128, len(LABELS))
    u = net(torch.rand(batch, 7) * 2 - 1, xyz, labels)
    assert u.shape == (batch, 7) and (u.abs() <= 1).all()
    with pytest.raises(ValueError, match="expects u_t"):
        net(torch.zeros(batch, 6), xyz, labels)


def test_labels_mark_robot_obstacle_and_target_points():
    _, labels = labelled_cloud(torch.zeros(2, 3, 3), torch.zeros(2, 4, 3), torch.zeros(2, 1, 3))
    want = torch.tensor([0, 0, 0, 1, 1, 1, 1, 2])
    assert torch.equal(labels[0].argmax(-1), want) and torch.equal(labels.sum(-1), torch.ones(2, 8))


def test_hinge_collision_loss_matches_hand_computed_values():
    # A linear field sdf = z - 0.5 is reproduced exactly by trilinear interpolation.
    bounds = ((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0))
    z = torch.linspace(0.0, 1.0, 5)
    grid = (z - 0.5).expand(5, 5, 5).clone()[None]  # (1, x, y, z)
    heights = torch.tensor([0.5, 0.51, 0.55, 0.48])  # sdf 0, 0.01, 0.05, -0.02
    points = torch.stack([torch.zeros(4), torch.zeros(4), heights], dim=-1)[None]  # (1, 4, 3)
    got = hinge_collision_loss(points, grid, torch.zeros(1, dtype=torch.long), bounds, 0.03)
    want = (0.03 + 0.02 + 0.0 + 0.05) / 4
    assert abs(float(got) - want) < 1e-6, f"expected {want}, got {float(got)}"


def test_losses_combine_with_mpinet_weights_and_fall_on_a_small_set(dm):
    torch.manual_seed(0)
    system = _system(dm).train()
    batch = dm.train_samples[torch.arange(16)]
    losses = system._losses(batch)
    assert set(losses) == {"match", "coll", "loss"}
    assert torch.allclose(losses["loss"], losses["match"] + 5.0 * losses["coll"])
    opt = torch.optim.Adam(system.net.parameters(), lr=1e-3)
    first = float(losses["loss"].detach())
    for _ in range(40):
        loss = system._losses(batch)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < first / 3, f"loss {first} -> {float(loss.detach())}"


def test_checkpoint_reloads_and_rolls_out(dm, tiny, tmp_path):
    import pytorch_lightning as pl

    from samp.data import open_dataset
    from samp.eval import evaluate, problems_from_dataset
    from samp.policy import load_policy

    system = _system(dm)
    trainer = pl.Trainer(max_steps=2, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    trainer.fit(system, datamodule=dm)
    path = tmp_path / "mpinet.ckpt"
    trainer.save_checkpoint(path)
    policy = load_policy(path)  # the SAMP entry point recognises the baseline's checkpoint
    assert policy.name == "mpinet" and policy.n_e == 16
    system.eval()
    b = dm.train_samples[torch.arange(4)]
    with torch.no_grad():
        want = system.predict(b["q"], b["q_goal"], system.obstacles[b["scene"]])
        got = policy.system.predict(b["q"], b["q_goal"], policy.system.obstacle_points(dm.grids, dm.bounds)[b["scene"]])
    assert torch.equal(want, got)
    problems = problems_from_dataset(open_dataset(tiny[0]), "heldout", 2)
    result = evaluate(policy, problems, {"max_steps": 5})
    assert result["planner"] == "mpinet" and len(result["records"]) == 2
    assert all(r["steps"] <= 5 and r["inference_time"] > 0 for r in result["records"])


def test_rollout_refuses_grids_of_another_resolution(dm):
    from samp.eval import EnvBatch

    policy = _system(dm).planner()
    env = EnvBatch(torch.zeros(1, 8, 8, 8), torch.tensor([dm.bounds], dtype=torch.float32), torch.zeros(1, dtype=torch.long))
    with pytest.raises(ValueError, match="reads grids at n_e = 16"):
        policy.reset(env)


def test_target_points_are_the_gripper_posed_at_the_goal_end_effector_pose():
    from samp.policy.baselines.mpinet_points import SurfacePoints, gripper_links
    from samp.robot import load_robot

    robot = load_robot("panda")
    assert gripper_links(robot) == ["panda_hand", "panda_leftfinger", "panda_rightfinger"]
    target = SurfacePoints(robot, gripper_links(robot), 64, seed=1)
    g = torch.Generator().manual_seed(0)
    lo, hi = robot.joint_limits.float().T
    q = lo + (hi - lo) * torch.rand(3, robot.dof, generator=g)
    points = target(robot.link_poses(q))  # (3, 64, 3)
    ee = robot.fk(q)[robot.ee_link]  # (3, 4, 4)
    local = torch.einsum("bji,bkj->bki", ee[:, :3, :3], points - ee[:, None, :3, 3])  # in the end-effector frame
    assert torch.allclose(local[0], local[1], atol=1e-5) and torch.allclose(local[0], local[2], atol=1e-5), \
        f"gripper points should be rigid in the end-effector frame; spread {float((local - local[:1]).abs().max()):.2e} m"
    assert float(local.norm(dim=-1).max()) < 0.2, "gripper points should lie within 20 cm of the end effector"


def test_untrained_policy_stands_still_and_goal_config_needs_the_goal(dm):
    system = _system(dm).eval()
    b = dm.train_samples[torch.arange(4)]
    with torch.no_grad():
        q_next = system.predict(b["q"], b["q_goal"], system.obstacles[b["scene"]])
    assert torch.allclose(q_next, b["q"], atol=1e-5), "the zero-initialised decoder should predict no step"
    net = MPiNetNet(MPiNetConfig(**{**SMALL, "goal_config": True}))
    xyz, labels = labelled_cloud(torch.rand(2, 48, 3), torch.rand(2, 64, 3), torch.rand(2, 16, 3))
    assert net(torch.zeros(2, 7), xyz, labels, torch.zeros(2, 7)).shape == (2, 7)
    with pytest.raises(ValueError, match="reads the goal configuration"):
        net(torch.zeros(2, 7), xyz, labels)
