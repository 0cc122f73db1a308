"""`SerialFK` (`Robot.link_poses` for serial arms) against pytorch-kinematics' general FK of every frame, in
float64 and float32, with gradients; and `transform_points` from given poses (both of its paths)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.robot import load_robot


def _q(robot, count: int, dtype) -> torch.Tensor:
    lo, hi = robot.joint_limits.to(dtype).T
    return lo + (hi - lo) * torch.rand(count, robot.dof, generator=torch.Generator().manual_seed(0), dtype=dtype)


@pytest.mark.parametrize("name", ["panda", "iiwa", "xarm6"])
@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_link_poses_equal_the_general_fk(name, dtype, tol, _isolated_cache):
    robot = load_robot(name, dtype=dtype)
    assert robot._serial is not None
    q = _q(robot, 32, dtype)
    general = robot.fk(q)  # pytorch-kinematics over every frame
    expected = torch.stack([general[link] for link in robot.link_names], dim=1)
    assert torch.allclose(robot.link_poses(q), expected, atol=tol, rtol=0)


@pytest.mark.parametrize("name", ["panda", "iiwa", "xarm6"])
def test_numpy_link_poses_and_ik_frames_equal_the_general_fk(name, _isolated_cache):
    """The collision checks' numpy FK (`Robot.link_poses_numpy`) and the IK's frames (`Robot.frames_fk`)."""
    robot = load_robot(name, dtype=torch.float64)
    q = _q(robot, 17, torch.float64)
    general = robot.fk(q)
    expected = torch.stack([general[link] for link in robot.link_names], dim=1).numpy()
    assert np.allclose(robot.link_poses_numpy(q.numpy()), expected, atol=1e-12, rtol=0)
    frames = (*robot.link_names[1:3], robot.ee_link)
    serial = robot.frames_fk(frames)
    assert serial is not None
    oracle = torch.stack([general[f] for f in frames], dim=1)
    assert torch.allclose(serial(q), oracle, atol=1e-12, rtol=0)
    assert np.allclose(serial.numpy(q.numpy()), oracle.numpy(), atol=1e-12, rtol=0)


def test_matrix_to_quaternion_matches_scipy():
    from scipy.spatial.transform import Rotation

    from samp.robot.bodies import matrix_to_quaternion

    R = np.concatenate([Rotation.random(500, random_state=0).as_matrix(),  # and each branch of the method:
                        np.diag([1.0, -1, -1])[None], np.diag([-1.0, 1, -1])[None], np.diag([-1.0, -1, 1])[None]])
    ours, theirs = matrix_to_quaternion(R), Rotation.from_matrix(R).as_quat()
    assert np.allclose(np.abs((ours * theirs).sum(axis=1)), 1.0, atol=1e-12)  # the same rotation (q ~ -q)
    assert np.allclose(Rotation.from_quat(ours).as_matrix(), R, atol=1e-12)
    from samp.sim.broadphase import quaternions  # the collision queries' compiled copy: the same method

    T = np.zeros((len(R), 4, 4))
    T[:, :3, :3], T[:, 3, 3] = R, 1.0
    np.testing.assert_allclose(quaternions(T[None])[0], ours, rtol=0, atol=1e-15)


@pytest.mark.parametrize("count", [3, 20])  # one gather per point (B <= 8), or one product per link run
def test_points_from_poses_and_their_gradient(count, _isolated_cache):
    robot = load_robot("panda", dtype=torch.float64)
    q = _q(robot, count, torch.float64).requires_grad_()
    fk = robot.fk(q)
    oracle = torch.stack([fk[robot.point_link_names[i]][:, :3, :3] @ robot.points[m] + fk[robot.point_link_names[i]][:, :3, 3]
                          for m, i in enumerate(robot.point_links.tolist())], dim=1)
    points = robot.transform_points(q, robot.link_poses(q))
    assert torch.allclose(points, oracle, atol=1e-12)
    (g,) = torch.autograd.grad(points.square().sum(), q)
    (g_oracle,) = torch.autograd.grad(oracle.square().sum(), q)
    assert torch.allclose(g, g_oracle, atol=1e-9)


@pytest.mark.parametrize("name", ["panda", "iiwa", "xarm6"])
def test_compiled_joint_motions_are_numpys_to_the_bit(name, _isolated_cache):
    """`SerialFK.numpy` builds the joint motions in one compiled pass: bit for bit numpy's elementwise Rodrigues
    expression (the IK's solutions, and with them every dataset's bytes, depend on each rounding), and the
    translation of a prismatic joint (none of the robots has one: joint 2 is taken as prismatic here)."""
    from samp.robot.serial import _joint_motions

    robot = load_robot(name, dtype=torch.float64)
    A, D, axes, K, K2, revolute, take = robot.serial_fk.numpy_constants()
    q = np.random.default_rng(1).uniform(-3.2, 3.2, (2000, robot.dof))
    c, s = np.cos(q)[..., None, None], np.sin(q)[..., None, None]
    expected = np.zeros((len(q), robot.dof, 4, 4))
    expected[..., :3, :3] = np.eye(3) + s * K + (1 - c) * K2
    expected[..., 3, 3] = 1.0
    got = _joint_motions(q, np.cos(q), np.sin(q), K, K2, revolute, axes)
    assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))
    prismatic = revolute.copy()
    prismatic[2] = False
    expected[:, 2, :3, :3] = np.eye(3)
    expected[:, 2, :3, 3] = axes[2] * q[:, 2, None]
    assert np.array_equal(_joint_motions(q, np.cos(q), np.sin(q), K, K2, prismatic, axes), expected)
