"""The interface between planners and the evaluation that rolls them out (docs/design.md section 4).

Two kinds of planner are evaluated by the same checks and metrics:

* A **step policy** (`StepPolicy`) maps the current configurations to the next ones, one step at a time,
  for a whole batch of problems (SAMP, MPiNet). The rollout engine (`samp.eval.rollouts`) calls `step`
  until each problem reaches its goal, stalls or runs out of steps.
* A **trajectory planner** (`TrajectoryPlanner`) returns a whole trajectory per problem (the expert, MPNet).

It sits in the policy layer because policies implement it and the evaluation, a layer above, calls it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import torch

__all__ = ["EnvBatch", "PlannedTrajectory", "StepPolicy", "TrajectoryPlanner", "clamp_to_limits"]


@dataclass
class EnvBatch:
    """The environments of a batch of problems, shared between problems of the same scene.

    Attributes:
        grids: (S, n_e, n_e, n_e) float anchor grids of the S scenes in the batch, indexed (x, y, z)
            (docs/design.md section 4), on the policy's device; None when the policy asks for none (`n_e` None).
        bounds: (S, 2, 3) workspace bounds of each scene, rows (min, max), metres.
        scene_index: (B,) long, which of the S scenes each problem is in.

    Within one rollout `grids` is the same tensor object at every step (only `scene_index` shrinks as
    problems finish), so a policy may encode the environments once in `reset` and index the result.
    """

    grids: torch.Tensor | None
    bounds: torch.Tensor
    scene_index: torch.Tensor

    def subset(self, rows: torch.Tensor) -> "EnvBatch":
        """The environments of problems `rows` (indices into this batch); grids are shared, not copied."""
        return EnvBatch(self.grids, self.bounds, self.scene_index[rows])

    def problem_grids(self) -> torch.Tensor:
        """(B, n_e, n_e, n_e) one grid per problem (a copy: B x n_e^3 floats), for simple policies."""
        if self.grids is None:
            raise ValueError("this batch carries no grids: the policy's n_e is None")
        return self.grids[self.scene_index]

    def problem_bounds(self) -> torch.Tensor:
        """(B, 2, 3) bounds per problem."""
        return self.bounds[self.scene_index]


@runtime_checkable
class StepPolicy(Protocol):
    """A closed-loop motion policy, batched over problems.

    Attributes:
        robot: the samp `Robot` it controls; its device and dtype are the policy's (the engine hands
            `step` tensors of that device and dtype).
        n_e: anchors per axis of the environment grid the policy reads, or None if it reads none.
        name: a short label for tables and records.

    `step(q, q_goal, env)`: q (B, n) current and q_goal (B, n) goal configurations in radians, `env` an
    `EnvBatch` -> q_next (B, n) radians. The policy keeps its output within the joint limits (docs/design.md
    section 4: q_{t+1} = clamp(q_t + dq)); the engine does not clamp and records any violation. It is
    called under `torch.no_grad()`, and its wall time is the rollout's solution time.

    Optional `reset(env)`: called once per rollout batch before the first step, inside the timed
    region, e.g. to encode the environment grids once.
    """

    robot: object
    n_e: int | None
    name: str

    def step(self, q: torch.Tensor, q_goal: torch.Tensor, env: EnvBatch) -> torch.Tensor: ...


@dataclass
class PlannedTrajectory:
    """A trajectory planner's answer: (W, n) radians or None on failure, its wall time, and why it failed."""

    trajectory: np.ndarray | None
    solution_time: float | None
    reason: str = ""


@runtime_checkable
class TrajectoryPlanner(Protocol):
    """A planner that answers a whole problem at once: `plan(problem) -> PlannedTrajectory`. One that reads
    anchor grids takes them as `plan(problem, grids=None)` (a `(problem, n_e) -> grid` source, samp+check):
    the evaluation then hands it the grids of the section (exact or reconstructed)."""

    name: str

    def plan(self, problem) -> PlannedTrajectory: ...


def clamp_to_limits(robot, q: torch.Tensor) -> torch.Tensor:
    """q (B, n) -> q clamped into the robot's joint limits (same device and dtype)."""
    limits = robot.joint_limits.to(device=q.device, dtype=q.dtype)
    return torch.maximum(torch.minimum(q, limits[:, 1]), limits[:, 0])
