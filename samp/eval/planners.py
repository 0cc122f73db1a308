"""What the evaluation can roll out or replay: the step-policy protocol, trajectory planners, and the
two planners that exist without training (a straight-line baseline and the expert).

Two kinds of planner are evaluated by the same checks and metrics:

* A **step policy** (`StepPolicy`) maps the current configurations to the next ones, one step at a time,
  for a whole batch of problems. The learned SAMP policy implements it; the rollout engine
  (`samp.eval.engine`) calls `step` until each problem reaches its goal, stalls or runs out of steps.
* A **trajectory planner** (`TrajectoryPlanner`) returns a whole trajectory per problem (the expert).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import torch

__all__ = ["EXPERT_VARIANTS", "EnvBatch", "ExpertPlanner", "PlannedTrajectory", "StepPolicy", "StraightLinePolicy",
           "TrajectoryPlanner", "clamp_to_limits"]

# Expert rows of the paper's Table I besides the expert itself, as overrides of the dataset's expert config,
# planned afresh (mode "plan"): the expert's path as planned, before simplification and smoothing; and the
# sampling planner alone (RRTConnect, no shortcutting, smoothing or straight-line shortcut), our counterpart
# of "cuRobo (sampling)".
EXPERT_VARIANTS = {
    "expert_raw": {"simplify": False, "smooth": False},
    "ompl_sampling": {"planner": "RRTConnect", "simplify": False, "smooth": False, "direct": False},
}


@dataclass
class EnvBatch:
    """The environments of a batch of problems, shared between problems of the same scene.

    Attributes:
        grids: (S, n_e, n_e, n_e) float anchor grids of the S scenes in the batch, indexed (x, y, z)
            (DESIGN section 4), on the policy's device; None when the policy asks for none (`n_e` None).
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
    `EnvBatch` -> q_next (B, n) radians. The policy keeps its output within the joint limits (DESIGN
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
    """A planner that answers a whole problem at once: `plan(problem) -> PlannedTrajectory`."""

    name: str

    def plan(self, problem) -> PlannedTrajectory: ...


def clamp_to_limits(robot, q: torch.Tensor) -> torch.Tensor:
    """q (B, n) -> q clamped into the robot's joint limits (same device and dtype)."""
    limits = robot.joint_limits.to(device=q.device, dtype=q.dtype)
    return torch.maximum(torch.minimum(q, limits[:, 1]), limits[:, 0])


class StraightLinePolicy:
    """Baseline step policy: move toward the goal in joint space, at most `max_step` radians (Euclidean
    norm of the joint change) per step, clamped into the joint limits. It ignores the environment, so it
    collides wherever the straight joint-space motion does: the floor a learned policy must beat, and a
    policy that exercises the rollout engine before any network exists.

    Args:
        robot: the `Robot`.
        max_step: radians per step (Euclidean over the joints); 0.05 covers a typical 3-4 rad problem in
            60-80 steps, inside the default 150.
        n_e: grid resolution to request from the engine although the policy ignores the grids (None:
            no grids); set it to time the engine's grid handling as a learned policy would see it.
    """

    def __init__(self, robot, max_step: float = 0.05, n_e: int | None = None):
        if not (np.isfinite(max_step) and max_step > 0):
            raise ValueError(f"max_step must be a positive number of radians, got {max_step!r}")
        if n_e is not None and (not isinstance(n_e, int) or n_e < 2):
            raise ValueError(f"n_e must be None or an integer >= 2, got {n_e!r}")
        self.robot, self.max_step, self.n_e = robot, float(max_step), n_e
        self.name = "straight"

    def step(self, q: torch.Tensor, q_goal: torch.Tensor, env: EnvBatch | None = None) -> torch.Tensor:
        delta = q_goal - q  # (B, n)
        norm = torch.linalg.vector_norm(delta, dim=1, keepdim=True)  # (B, 1)
        scale = torch.clamp(self.max_step / torch.clamp(norm, min=1e-12), max=1.0)
        return clamp_to_limits(self.robot, q + scale * delta)


class ExpertPlanner:
    """The expert as a trajectory planner.

    mode "replay" (default): the problem's stored expert trajectory and planning time (dataset problems),
    so the expert is judged by the same checks and metrics as a policy without planning again.
    mode "plan": plan afresh with `samp.expert.ExpertPlanner` (OMPL) in the problem's scene; the solution
    time is its planning time. `config` is an expert config (name, path or mapping), `seed` its seed,
    `name` its label in tables (e.g. an `EXPERT_VARIANTS` key).
    """

    def __init__(self, mode: str = "replay", robot=None, config=None, seed: int = 0, name: str = "expert"):
        if mode not in ("replay", "plan"):
            raise ValueError(f"expert mode must be 'replay' or 'plan', got {mode!r}")
        self.mode, self.robot, self.config, self.seed = mode, robot, config, int(seed)
        self.name = name
        self._planners: dict[str, object] = {}

    def plan(self, problem) -> PlannedTrajectory:
        if self.mode == "replay":
            if problem.expert_trajectory is None:
                raise ValueError(f"problem {problem.name or '(unnamed)'} has no expert trajectory to replay; take "
                                 "problems from a dataset (samp.eval.problems_from_dataset) or use mode='plan'")
            return PlannedTrajectory(problem.expert_trajectory, problem.expert_time)
        if self.robot is None:
            raise ValueError("the expert in mode 'plan' needs a robot: ExpertPlanner(mode='plan', robot=...)")
        from samp.eval.checks import exact_robot
        from samp.expert import ExpertPlanner as OMPLPlanner

        key = problem.scene.content_hash()
        if key not in self._planners:
            # float64: OMPL's bounds are the robot's limits, and a float32 limit rounds inward, which
            # refuses a start stored exactly at a limit (as the expert's own IK goals can be).
            self._planners[key] = OMPLPlanner(exact_robot(self.robot), problem.scene, self.config)
        result = self._planners[key].plan(problem.q_start, problem.q_goal, seed=self.seed)
        return PlannedTrajectory(result.trajectory if result.success else None, result.stats.get("planning_time"),
                                 result.reason)

    def close(self) -> None:
        for planner in self._planners.values():
            planner.close()
        self._planners.clear()
