"""Batched DLS IK: reachable poses (from FK of random configurations) are reached within 1 mm and 1 degree,
joint limits hold, the geometric Jacobian matches finite differences, and a seeded generator repeats."""

from __future__ import annotations

import math

import pytest
import torch

from samp.expert import IKConfig, solve_ik
from samp.expert.ik import geometric_jacobian, pose_errors, rotation_angle

TARGETS = 24


def _random_q(robot, count: int, seed: int) -> torch.Tensor:
    lo, hi = robot.joint_limits.unbind(-1)
    g = torch.Generator().manual_seed(seed)
    return lo + torch.rand(count, robot.dof, generator=g, dtype=torch.float64) * (hi - lo)


def test_reachable_poses_are_reached_within_limits(robot):
    targets = robot.fk(_random_q(robot, TARGETS, seed=1))[robot.ee_link]  # (K, 4, 4), reachable by construction
    result = solve_ik(robot, targets, IKConfig(seeds=16), generator=torch.Generator().manual_seed(0))
    assert result.q.shape == (TARGETS, 16, robot.dof)
    lo, hi = robot.joint_limits.unbind(-1)
    assert bool(((result.q >= lo) & (result.q <= hi)).all()), "IK left the joint limits"
    solved = result.converged.any(dim=1)
    assert bool(solved.all()), f"{int((~solved).sum())} of {TARGETS} reachable poses unsolved for {robot.name}"
    # Independent re-check of every converged solution by FK.
    q = result.q[result.converged]  # (C, n)
    pose = targets[:, None].expand(-1, 16, 4, 4)[result.converged]
    pos_err, rot_err = pose_errors(robot.fk(q)[robot.ee_link], pose)
    assert float(pos_err.max()) < 1e-3, f"position error {float(pos_err.max()):.2e} m, expected < 1 mm"
    assert float(rot_err.max()) < math.radians(1.0), f"rotation error {math.degrees(float(rot_err.max())):.3f} deg, expected < 1"


def test_same_generator_seed_same_solutions(robots):
    robot = robots["panda"]
    targets = robot.fk(_random_q(robot, 4, seed=2))[robot.ee_link]
    a = solve_ik(robot, targets, IKConfig(seeds=4, iterations=30), generator=torch.Generator().manual_seed(5))
    b = solve_ik(robot, targets, IKConfig(seeds=4, iterations=30), generator=torch.Generator().manual_seed(5))
    c = solve_ik(robot, targets, IKConfig(seeds=4, iterations=30), generator=torch.Generator().manual_seed(6))
    assert torch.equal(a.q, b.q)
    assert not torch.equal(a.q, c.q)


def test_initial_configuration_seeds_the_search(robots):
    robot = robots["panda"]
    q = _random_q(robot, 3, seed=3)
    targets = robot.fk(q)[robot.ee_link]
    result = solve_ik(robot, targets, IKConfig(seeds=2, iterations=1), generator=torch.Generator().manual_seed(0),
                      q_init=q[:, None])
    assert bool(result.converged[:, 0].all()), "a seed at the solution must stay there"
    assert torch.allclose(result.q[:, 0], q, atol=1e-9)


def test_jacobian_matches_finite_differences(robot):
    q = _random_q(robot, 3, seed=4)
    T, J = geometric_jacobian(robot, q)  # (B, 4, 4), (B, 6, n)
    eps = 1e-6
    for j in range(robot.dof):
        dq = torch.zeros_like(q)
        dq[:, j] = eps
        Tp, Tm = robot.fk(q + dq)[robot.ee_link], robot.fk(q - dq)[robot.ee_link]
        lin = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * eps)
        dR = (Tp[:, :3, :3] - Tm[:, :3, :3]) / (2 * eps) @ T[:, :3, :3].transpose(1, 2)  # skew(omega)
        ang = torch.stack([dR[:, 2, 1], dR[:, 0, 2], dR[:, 1, 0]], dim=1)
        assert torch.allclose(J[:, :3, j], lin, atol=1e-6), f"linear column {j}: {J[:, :3, j]} vs {lin}"
        assert torch.allclose(J[:, 3:, j], ang, atol=1e-6), f"angular column {j}: {J[:, 3:, j]} vs {ang}"


def test_rotation_angle_is_exact():
    from scipy.spatial.transform import Rotation

    R = torch.from_numpy(Rotation.from_rotvec([[0.0, 0.0, 0.3], [1.0, 2.0, 2.0]]).as_matrix())
    got = rotation_angle(torch.eye(3, dtype=torch.float64).expand(2, 3, 3), R)
    assert torch.allclose(got, torch.tensor([0.3, 3.0], dtype=torch.float64), atol=1e-9), got


def test_bad_targets_are_refused(robots):
    with pytest.raises(ValueError, match=r"\(K, 4, 4\)"):
        solve_ik(robots["panda"], torch.eye(4), generator=torch.Generator())
