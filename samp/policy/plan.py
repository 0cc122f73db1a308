"""One call to plan with a trained step policy, outside the evaluation (docs/design.md section 8):

    policy = load_policy(run_dir)
    result = policy.plan(scene, q_start, q_goal)      # or an (n_e, n_e, n_e) anchor grid instead of a scene
    result.trajectory, result.reached, result.solution_time

The rollout steps the policy until the end effector is within the goal tolerances (2 cm and 15 degrees by
default, as the evaluation's), until it stalls (moves less than `stall_threshold` rad for `stall_steps`
steps) or after `max_steps` steps. It does not check collisions: that is the evaluation's job
(`samp.eval.evaluate`), which also rolls many problems out in batches.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from samp.policy.interface import EnvBatch
from samp.robot.goal import ee_poses, goal_errors

__all__ = ["PlanResult", "Plannable"]


@dataclass
class PlanResult:
    """A planned motion: the trajectory (T, n) radians from q_start, how it ended, and where the time went."""

    trajectory: np.ndarray
    reached: bool
    termination: str  # reached | stalled | max_steps | diverged
    position_error: float  # final, metres
    orientation_error: float  # final, degrees
    solution_time: float  # seconds in the policy: the scene's encoding and every step
    setup_time: float  # seconds of that in encoding the scene (once per scene)
    step_times: list[float]  # seconds per step

    @property
    def steps(self) -> int:
        return len(self.trajectory) - 1


def _configuration(q, n: int, what: str) -> np.ndarray:
    q = np.asarray(q.detach().cpu() if isinstance(q, torch.Tensor) else q, dtype=np.float64).reshape(-1)
    if q.shape != (n,) or not np.isfinite(q).all():
        raise ValueError(f"{what} must be {n} finite joint angles in radians, got {q.tolist()}")
    return q


class Plannable:
    """`plan` for a `StepPolicy` whose system knows its grid resolution and bounds (`system.n_e`,
    `system.bounds`): SAMP and MPiNet."""

    def _environment(self, scene_or_grid) -> EnvBatch:
        system, robot = self.system, self.robot
        if hasattr(scene_or_grid, "anchor_grid"):  # a samp.scene.Scene
            bounds = np.asarray(system.bounds, dtype=np.float64)
            if not np.allclose(np.asarray(scene_or_grid.bounds, dtype=np.float64), bounds, atol=1e-9):
                raise ValueError(f"the scene's workspace bounds {scene_or_grid.bounds} are not the policy's "
                                 f"{system.bounds}")
            grid = scene_or_grid.anchor_grid(self.n_e)
        else:
            grid = torch.as_tensor(scene_or_grid)
            if tuple(grid.shape) != (self.n_e,) * 3:
                raise ValueError(f"the policy reads ({self.n_e}, {self.n_e}, {self.n_e}) anchor grids over its bounds "
                                 f"{system.bounds}; got a grid of shape {tuple(grid.shape)}. Pass a samp Scene instead "
                                 "to have its grid computed")
        return EnvBatch(grid[None].to(device=robot.device, dtype=robot.dtype),
                        torch.tensor([system.bounds], dtype=robot.dtype, device=robot.device),
                        torch.zeros(1, dtype=torch.long, device=robot.device))

    def plan(self, scene_or_grid, q_start, q_goal, *, max_steps: int = 150, position_tolerance: float = 0.02,
             orientation_tolerance: float = 15.0, stall_threshold: float = 1e-3, stall_steps: int = 10) -> PlanResult:
        """Roll the policy out from `q_start` towards `q_goal` (radians, (n,)) in a scene.

        Args:
            scene_or_grid: a `samp.scene.Scene` (its exact anchor grid at the policy's n_e, disk-cached), or
                an (n_e, n_e, n_e) anchor grid over the policy's workspace bounds (e.g. reconstructed
                from a depth camera, `samp.perception`).
        """
        robot, n = self.robot, self.robot.dof
        start, goal = _configuration(q_start, n, "q_start"), _configuration(q_goal, n, "q_goal")
        env = self._environment(scene_or_grid)
        goal_pose = ee_poses(robot, goal[None])
        sync = torch.cuda.synchronize if robot.device.type == "cuda" else (lambda: None)
        q = torch.as_tensor(start[None], dtype=robot.dtype, device=robot.device)
        q_goal_t = torch.as_tensor(goal[None], dtype=robot.dtype, device=robot.device)
        t0 = time.perf_counter()
        self.reset(env)
        sync()
        setup = time.perf_counter() - t0
        trajectory, step_times, still, termination = [start], [], 0, "max_steps"
        pos, rot = goal_errors(ee_poses(robot, start[None]), goal_pose)
        if pos[0] < position_tolerance and rot[0] < orientation_tolerance:
            termination, max_steps = "reached", 0
        for _ in range(max_steps):
            t0 = time.perf_counter()
            q_next = self.step(q, q_goal_t, env)
            sync()
            step_times.append(time.perf_counter() - t0)
            if not torch.isfinite(q_next).all():
                termination = "diverged"
                break
            q_np = q_next[0].double().cpu().numpy()
            still = still + 1 if np.linalg.norm(q_np - trajectory[-1]) < stall_threshold else 0
            trajectory.append(q_np)
            q = q_next
            pos, rot = goal_errors(ee_poses(robot, q_np[None]), goal_pose)
            if pos[0] < position_tolerance and rot[0] < orientation_tolerance:
                termination = "reached"
                break
            if still >= stall_steps:
                termination = "stalled"
                break
        return PlanResult(np.stack(trajectory), termination == "reached", termination, float(pos[0]), float(rot[0]),
                          setup + sum(step_times), setup, step_times)
