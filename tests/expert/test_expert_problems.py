"""Problem sampling: goals reach their poses, starts and goals are free, chaining, seeding, goal kinds."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from samp.expert import load_expert_config, sample_problems
from samp.expert.ik import pose_errors
from samp.expert.problems import target_approaches
from samp.scene import generate_scene
from samp.sim import World

COUNT = 6


@pytest.fixture(scope="module")
def setup(robots):
    robot, scene, cfg = robots["panda"], generate_scene("tabletop", seed=0, num_obstacles=[3, 3]), load_expert_config()
    with World(robot, scene) as world:
        yield robot, scene, cfg, world, sample_problems(robot, scene, COUNT, seed=3, cfg=cfg, world=world)


def test_goals_reach_their_poses(setup):
    robot, _, _, _, problems = setup
    assert all(p.q_goal is not None for p in problems), [p.reason for p in problems]
    q = torch.from_numpy(np.stack([p.q_goal for p in problems]))
    pos, rot = pose_errors(robot.fk(q)[robot.ee_link], torch.from_numpy(np.stack([p.goal_pose for p in problems])))
    assert float(pos.max()) < 1e-3 and float(rot.max()) < math.radians(1.0), (pos, rot)


def test_starts_and_goals_are_free_and_within_limits(setup):
    _, _, cfg, world, problems = setup
    q = np.concatenate([np.stack([p.q_start for p in problems]), np.stack([p.q_goal for p in problems])])
    assert not world.in_collision(q, margin=cfg.clearance).any()
    assert not world.outside_limits(q).any()


def test_starts_chain_from_the_previous_goal(setup):
    problems = setup[4]
    for previous, problem in zip(problems[:-1], problems[1:]):
        assert np.array_equal(problem.q_start, previous.q_goal)


def test_goal_kinds(setup):
    robot, scene, cfg, _, problems = setup
    kinds = [p.kind for p in problems]
    assert set(kinds) == {"target", "workspace"}, kinds
    assert all(not (a == b == "target") for a, b in zip(kinds[:-1], kinds[1:])), f"two target goals in a row: {kinds}"
    centre = np.asarray(scene.target.pose.position)
    axis = np.asarray(cfg.problems.approach_axis)
    for p in problems:
        position, approach = p.goal_pose[:3, 3], p.goal_pose[:3, :3] @ axis
        if p.kind == "target":  # pre-grasp: offset from the centre, gripper pointing at it
            offset = centre - position
            assert np.linalg.norm(offset) == pytest.approx(cfg.problems.approach_offset)
            np.testing.assert_allclose(approach, offset / np.linalg.norm(offset), atol=1e-9)
        else:
            r = np.hypot(*position[:2])
            assert cfg.problems.radius[0] <= r <= cfg.problems.radius[1]
            assert scene.sdf(position[None])[0] >= cfg.problems.position_clearance
            assert math.acos(np.clip(-approach[2], -1, 1)) <= cfg.problems.max_tilt + 1e-9


def test_same_seed_same_problems(setup):
    robot, scene, cfg, world, problems = setup
    again = sample_problems(robot, scene, COUNT, seed=3, cfg=cfg, world=world)
    other = sample_problems(robot, scene, COUNT, seed=4, cfg=cfg, world=world)
    for a, b in zip(problems, again):
        assert np.array_equal(a.q_start, b.q_start) and np.array_equal(a.q_goal, b.q_goal) and a.kind == b.kind
    assert not np.array_equal(problems[0].q_goal, other[0].q_goal)


def test_unreachable_goals_are_reported(robots):
    robot, scene = robots["panda"], generate_scene("tabletop", seed=0, num_obstacles=[3, 3])
    cfg = load_expert_config({"ik": {"seeds": 4, "iterations": 20},
                              "problems": {"target_fraction": 0.0, "radius": [1.2, 1.4], "goal_rounds": 1,
                                           "poses_per_goal": 1, "start": "random"}})
    problems = sample_problems(robot, scene, 2, seed=0, cfg=cfg)
    assert all(p.q_goal is None and p.reason.startswith("no valid goal") for p in problems), [p.reason for p in problems]
    assert all(p.q_start is not None for p in problems)


def test_shelf_targets_are_approached_from_the_front():
    cfg = load_expert_config().problems
    for seed in range(4):
        offsets = target_approaches(generate_scene("shelf", seed=seed), cfg)
        assert len(offsets) > 0 and np.allclose(offsets[:, 2], 0.0), f"seed {seed}: {offsets}"


def test_ik_limits_are_rounded_inward(robots):
    """A float32 robot's IK clamps to its limits rounded inward, so a configuration clamped onto a limit is,
    in float64, within the exact limit (by less than one float32 step); a float64 robot's are exact."""
    from samp.expert.ik import limits_inward
    from samp.robot import load_robot

    exact = robots["panda"].joint_limits
    lo, hi = limits_inward(robots["panda"])
    assert torch.equal(lo, exact[:, 0]) and torch.equal(hi, exact[:, 1])
    lo, hi = limits_inward(load_robot("panda"))  # float32
    assert lo.dtype == hi.dtype == torch.float32
    assert (lo.double() >= exact[:, 0]).all() and (hi.double() <= exact[:, 1]).all()
    ulp = torch.finfo(torch.float32).eps * exact.abs().amax(dim=1)  # (n,) one float32 step near the limits
    assert ((lo.double() - exact[:, 0]) <= ulp).all() and ((exact[:, 1] - hi.double()) <= ulp).all()
    rounded = exact.float().double()  # rounded to nearest: some limit moves outward (the old refusals)
    assert ((rounded[:, 0] < exact[:, 0]) | (rounded[:, 1] > exact[:, 1])).any(), "the test needs an outward rounding"
