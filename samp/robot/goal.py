"""How far an arm's end effector is from a goal pose: the reach test of docs/design.md section 4, shared by the
evaluation (`samp.eval.checks`) and a policy's own `plan` (`samp.policy.plan`)."""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["ee_poses", "goal_errors"]


def ee_poses(robot, q) -> np.ndarray:
    """q (B, n) radians (numpy or torch) -> (B, 4, 4) float64 end-effector poses in the base frame."""
    with torch.no_grad():
        q = torch.as_tensor(np.asarray(q, dtype=np.float64) if not isinstance(q, torch.Tensor) else q)
        T = robot.fk(q.to(device=robot.device, dtype=robot.dtype))[robot.ee_link]
    return T.double().cpu().numpy()


def goal_errors(poses: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """End-effector poses (B, 4, 4) against goal poses (B, 4, 4) or one (4, 4) -> position error (B,)
    in metres and orientation error (B,) in degrees (the angle of the relative rotation)."""
    goal = np.broadcast_to(goal, poses.shape)
    pos = np.linalg.norm(poses[:, :3, 3] - goal[:, :3, 3], axis=1)
    relative = np.einsum("bji,bjk->bik", goal[:, :3, :3], poses[:, :3, :3])  # R_goal^T R
    cos = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return pos, np.degrees(np.arccos(cos))
