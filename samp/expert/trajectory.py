"""Trajectory post-processing: arc-length resampling, dense segment checks, path lengths.

A trajectory is an (W, n) array of joint configurations in radians, executed as straight joint-space
segments between consecutive waypoints.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["ee_path_length", "first_invalid_segment", "joint_path_length", "resample", "segment_states"]


def _check_path(path, name: str = "path") -> np.ndarray:
    path = np.asarray(path, dtype=np.float64)
    if path.ndim != 2 or len(path) < 1:
        raise ValueError(f"{name} must be a (W, n) array of configurations, got shape {path.shape}")
    if not np.all(np.isfinite(path)):
        raise ValueError(f"{name} contains NaN or inf")
    return path


def resample(path, count: int) -> np.ndarray:
    """path (m, n) polyline -> (count, n) waypoints uniform in joint-space (Euclidean) arc length.

    The first and last waypoints are the path's end points exactly; the others lie on the polyline.
    A zero-length path gives `count` copies of its first configuration.
    """
    path = _check_path(path)
    if count < 2:
        raise ValueError(f"count must be >= 2 waypoints, got {count}")
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])  # (m,)
    if s[-1] <= 0.0:
        return np.repeat(path[:1], count, axis=0)
    targets = np.linspace(0.0, s[-1], count)
    out = np.stack([np.interp(targets, s, path[:, j]) for j in range(path.shape[1])], axis=1)  # (count, n)
    out[0], out[-1] = path[0], path[-1]
    return out


def segment_states(traj, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """traj (W, n) -> states (C, n) along every segment no farther apart than `resolution` (joint-space
    Euclidean, radians), both ends included, and (C,) the index of the segment each state checks
    (waypoint 0 belongs to segment 0)."""
    traj = _check_path(traj, "trajectory")
    if not resolution > 0:
        raise ValueError(f"resolution must be positive radians, got {resolution}")
    states, owner = [traj[:1]], [np.zeros(1, dtype=int)]
    for k in range(len(traj) - 1):
        steps = max(1, int(np.ceil(np.linalg.norm(traj[k + 1] - traj[k]) / resolution)))
        t = np.arange(1, steps + 1)[:, None] / steps  # (steps, 1), ends at the next waypoint
        states.append(traj[k] + t * (traj[k + 1] - traj[k]))
        owner.append(np.full(steps, k))
    return np.concatenate(states), np.concatenate(owner)


def first_invalid_segment(world, traj, resolution: float, margin: float) -> int | None:
    """The first segment k (between waypoints k and k+1) with a state closer than `margin` to an
    obstacle, in self-collision or outside the joint limits, or None if every segment is valid.
    All states are checked in one batch through `world.in_collision`."""
    states, owner = segment_states(traj, resolution)
    bad = np.flatnonzero(world.in_collision(states, margin=margin))
    return None if len(bad) == 0 else int(owner[bad[0]])


def joint_path_length(traj) -> float:
    """(W, n) -> sum of joint-space Euclidean segment lengths, radians."""
    traj = _check_path(traj, "trajectory")
    return float(np.linalg.norm(np.diff(traj, axis=0), axis=1).sum())


def ee_path_length(robot, traj) -> float:
    """(W, n) -> sum over segments of the end-effector displacement between waypoints, metres."""
    traj = _check_path(traj, "trajectory")
    with torch.no_grad():
        p = robot.fk(torch.as_tensor(traj, dtype=robot.dtype, device=robot.device))[robot.ee_link][:, :3, 3]
    return float(torch.linalg.norm(p[1:] - p[:-1], dim=-1).sum())
