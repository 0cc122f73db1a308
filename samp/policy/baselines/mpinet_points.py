"""The robot and target parts of the MPiNet-style point cloud: points sampled on link surfaces, posed by FK.

MPiNet (Fishman et al., CoRL 2022) samples its robot points on the arm's surface at q_t and its target
points on the gripper posed at the goal end-effector pose. `SurfacePoints` holds such a sample: `count`
points drawn on the collision meshes of some links (area-weighted, seeded, so a checkpoint rebuilds the
same points), stored in their link frames and posed with `Robot.link_poses`.

Which links form "the gripper" is read from the robot's kinematics rather than named (robots are data):
`gripper_links` are the point links that move rigidly with the end-effector link (no arm joint between
them) other than the child link of the last arm joint, i.e. the hand and the fingers (held at their
planning opening) for the Panda. A robot with nothing mounted after its last arm joint uses that link.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["SurfacePoints", "gripper_links"]


def _last_arm_joint(robot, link: str) -> str | None:
    """The nearest arm joint (one of `robot.joint_names`) on the chain from `link` up to the root."""
    arm = set(robot.joint_names)
    while True:
        joint = robot.urdf.parent_joint(link)
        if joint is None:
            return None
        if joint.name in arm:
            return joint.name
        link = joint.parent


def gripper_links(robot) -> list[str]:
    """The point links of the gripper (see the module docstring), in `point_link_names` order."""
    last = _last_arm_joint(robot, robot.ee_link)
    if last is None:
        raise ValueError(f"robot {robot.name!r}: its end effector {robot.ee_link!r} moves with no arm joint")
    flange = robot.urdf.joints[last].child
    rigid = [name for name in robot.point_link_names if _last_arm_joint(robot, name) == last]
    return [name for name in rigid if name != flange] or [flange]


class SurfacePoints(nn.Module):
    """`count` points on the collision surfaces of `links`, drawn in proportion to each link's area.

    forward(poses (B, L, 4, 4) from `robot.link_poses(q)`) -> (B, count, 3) points in the base frame.
    """

    def __init__(self, robot, links: list[str], count: int, seed: int = 0):
        super().__init__()
        if count < 1 or not links:
            raise ValueError(f"need at least one point on at least one link, got count={count}, links={links}")
        unknown = [name for name in links if name not in robot.link_names]
        if unknown:
            raise ValueError(f"links {unknown} are not collision links of {robot.name!r}: {robot.link_names}")
        meshes = robot.link_meshes
        areas = np.array([meshes[name].area for name in links], dtype=np.float64)
        # Largest-remainder split of `count` by area: every point has a link, and the split is deterministic.
        share = count * areas / areas.sum()
        per_link = np.floor(share).astype(int)
        per_link[np.argsort(per_link - share)[: count - per_link.sum()]] += 1
        rng = np.random.default_rng(seed)
        xyz, link_index = [], []
        for name, k in zip(links, per_link):
            if k:
                pts, _ = _sample_surface(meshes[name], int(k), rng)
                xyz.append(pts)
                link_index.append(np.full(int(k), robot.link_names.index(name)))
        self.register_buffer("points", torch.from_numpy(np.concatenate(xyz)).to(robot.dtype), persistent=False)
        self.register_buffer("links", torch.from_numpy(np.concatenate(link_index)).long(), persistent=False)

    def forward(self, poses: torch.Tensor) -> torch.Tensor:
        T = poses[:, self.links]  # (B, count, 4, 4)
        return torch.einsum("bkij,kj->bki", T[..., :3, :3], self.points.to(T.dtype)) + T[..., :3, 3]


def _sample_surface(mesh, count: int, rng: np.random.Generator):
    import trimesh

    return trimesh.sample.sample_surface(mesh, count, seed=rng)
