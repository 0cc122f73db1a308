"""Forward kinematics against pybullet's link world poses, and `.to()` across dtypes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import torch
from scipy.spatial.transform import Rotation

N_CONFIGS = 200


def _pybullet_link_poses(robot, qs: np.ndarray) -> dict[str, np.ndarray]:
    """link name -> (B, 4, 4) URDF link frames in the world, from pybullet with a fixed base at the origin."""
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(robot.urdf.path), useFixedBase=True, physicsClientId=client)
        joints = {pb.getJointInfo(body, j, physicsClientId=client)[1].decode(): j
                  for j in range(pb.getNumJoints(body, physicsClientId=client))}
        links = {pb.getJointInfo(body, j, physicsClientId=client)[12].decode(): j for j in joints.values()}
        for name in robot.cfg.gripper.joints:
            pb.resetJointState(body, joints[name], robot.cfg.gripper.opening, physicsClientId=client)
        out = {name: np.zeros((len(qs), 4, 4)) for name in links}
        for b, q in enumerate(qs):
            for name, value in zip(robot.joint_names, q):
                pb.resetJointState(body, joints[name], float(value), physicsClientId=client)
            for name, idx in links.items():
                state = pb.getLinkState(body, idx, computeForwardKinematics=True, physicsClientId=client)
                out[name][b, :3, :3] = Rotation.from_quat(state[5]).as_matrix()
                out[name][b, :3, 3] = state[4]
                out[name][b, 3, 3] = 1.0
        return out
    finally:
        pb.disconnect(client)


def random_configurations(robot, count: int, seed: int) -> torch.Tensor:
    lo, hi = robot.joint_limits.T
    g = torch.Generator().manual_seed(seed)
    return lo + (hi - lo) * torch.rand(count, robot.dof, generator=g, dtype=robot.dtype)


def test_fk_matches_pybullet(robot):
    q = random_configurations(robot, N_CONFIGS, seed=1)
    ours = robot.fk(q)
    theirs = _pybullet_link_poses(robot, q.numpy())
    assert set(robot.link_names) <= set(theirs) | {robot.urdf.root}
    for name, T_ref in theirs.items():
        T = ours[name].numpy()
        pos_err = np.linalg.norm(T[:, :3, 3] - T_ref[:, :3, 3], axis=1).max()
        R_rel = np.einsum("bji,bjk->bik", T[:, :3, :3], T_ref[:, :3, :3])
        rot_err = np.linalg.norm(Rotation.from_matrix(R_rel).as_rotvec(), axis=1).max()
        assert pos_err < 1e-5, f"{robot.name}/{name}: position error {pos_err:.2e} m, expected < 1e-5"
        assert rot_err < 1e-5, f"{robot.name}/{name}: rotation error {rot_err:.2e} rad, expected < 1e-5"


def test_fk_returns_base_frame_poses(robot):
    q = random_configurations(robot, 3, seed=2)
    fk = robot.fk(q)
    base = fk[robot.base_link]
    assert torch.allclose(base, torch.eye(4, dtype=robot.dtype).expand(3, 4, 4), atol=1e-12)
    assert fk[robot.ee_link].shape == (3, 4, 4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_to_moves_chain_and_buffers(robots, dtype):
    from samp.robot import load_robot

    robot = load_robot("panda", dtype=dtype)
    assert robot.points.dtype == dtype
    # Limits stay exact float64: a configuration exactly at a limit must not read as outside it.
    cfg = robot.cfg
    assert torch.equal(robot.joint_limits, torch.tensor([cfg.lower, cfg.upper], dtype=torch.float64).T)
    round_trip = load_robot("panda", dtype=dtype).to(torch.float32).to(torch.float64)
    assert torch.equal(round_trip.home, torch.tensor(cfg.home, dtype=torch.float64))
    q = random_configurations(robots["panda"], 5, seed=3)
    got = robot.transform_points(q.to(dtype)).double()
    want = robots["panda"].transform_points(q)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    err = (got - want).abs().max().item()
    assert err < tol, f"{dtype}: transform_points differs from float64 by {err:.2e}, expected < {tol}"
    robot.to(torch.float64)
    assert robot.dtype == torch.float64 and robot.chain.dtype == torch.float64


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_matches_cpu(robots):
    robot = robots["panda"]
    q = random_configurations(robot, 64, seed=5)
    want = robot.transform_points(q)
    from samp.robot import load_robot

    gpu = load_robot("panda", dtype=torch.float64).to("cuda")
    got = gpu.transform_points(q.cuda()).cpu()
    assert torch.allclose(got, want, atol=1e-10), f"CUDA differs from CPU by {(got - want).abs().max():.2e}"


def test_a_mounted_robot_reports_the_same_base_frame_poses(robots, tmp_path):
    """The Panda's URDF under an extra root link ("world", the arm mounted 0.3 m forward, 0.5 m up and turned
    0.7 rad): FK is in the base link's frame, so every pose equals the unmounted arm's. Every shipped robot has
    its base at the URDF root, where the base transform is the identity and a wrong side (T B^-1 instead of
    B^-1 T) would go unseen."""
    import pybullet_data
    import yaml

    from samp.paths import conf_dir
    from samp.robot import load_robot

    source = Path(pybullet_data.getDataPath()) / "franka_panda"
    text = (source / "panda.urdf").read_text()
    mount = ('<link name="world"/>\n  <joint name="mount" type="fixed"><parent link="world"/><child link="panda_link0"/>'
             '<origin xyz="0.3 0 0.5" rpy="0 0 0.7"/></joint>\n  <link name="panda_link0">')
    (tmp_path / "panda_mounted.urdf").write_text(text.replace('<link name="panda_link0">', mount, 1))
    (tmp_path / "meshes").symlink_to(source / "meshes")
    cfg = yaml.safe_load((conf_dir() / "robot" / "panda.yaml").read_text())
    cfg["urdf"] = str(tmp_path / "panda_mounted.urdf")
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(cfg))
    mounted, plain = load_robot(tmp_path / "robot.yaml", dtype=torch.float64), robots["panda"]
    q = random_configurations(plain, 4, seed=5)
    got, want = mounted.fk(q), plain.fk(q)
    for name in plain.link_names:
        torch.testing.assert_close(got[name], want[name], rtol=0, atol=1e-10, msg=lambda m: f"{name}: {m}")
    torch.testing.assert_close(mounted.transform_points(q), plain.transform_points(q), rtol=0, atol=1e-10)
