"""Checks in float64 on the CPU, whatever precision and device a policy runs in."""

from __future__ import annotations

import torch

__all__ = ["exact_robot"]


def exact_robot(robot):
    """The robot itself if it is float64 on the CPU, else a float64 CPU copy (the policy's robot may be
    float32 on a GPU; checks and goal errors are done in float64).

    A float32 round trip rounds the joint limits (by up to ~1e-7 rad, inward or outward), so the copy
    takes them, and `home`, from the robot's config again: a configuration stored exactly at a limit
    must stay within it (the World allows 1e-6 rad, but OMPL's bounds allow nothing)."""
    if robot.dtype == torch.float64 and robot.device.type == "cpu":
        return robot
    import copy

    exact = copy.deepcopy(robot).to(device="cpu", dtype=torch.float64)
    cfg = exact.cfg
    exact.joint_limits.copy_(torch.tensor([cfg.lower, cfg.upper], dtype=torch.float64).T)
    exact.home.copy_(torch.tensor(cfg.home, dtype=torch.float64))
    return exact
