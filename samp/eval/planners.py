"""The two planners that exist without training: a straight-line baseline and the expert (replayed or
planned afresh). The protocols they implement (`StepPolicy`, `TrajectoryPlanner`, `EnvBatch`) are
defined in `samp.policy.interface` and re-exported here.
"""

from __future__ import annotations

import numpy as np
import torch

from samp.policy.interface import EnvBatch, PlannedTrajectory, StepPolicy, TrajectoryPlanner, clamp_to_limits

__all__ = ["EXPERT_VARIANTS", "EnvBatch", "ExpertTrajectoryPlanner", "PlannedTrajectory", "StepPolicy", "StraightLinePolicy",
           "TrajectoryPlanner", "clamp_to_limits"]

# Expert rows of the paper's Table I besides the expert itself, as overrides of the dataset's expert config,
# planned afresh (mode "plan"): the expert's path as planned, before simplification and smoothing; and the
# sampling planner alone (RRTConnect, no shortcutting, smoothing or straight-line shortcut), our counterpart
# of "cuRobo (sampling)".
EXPERT_VARIANTS = {
    "expert_raw": {"simplify": False, "smooth": False},
    "ompl_sampling": {"planner": "RRTConnect", "simplify": False, "smooth": False, "direct": False},
}


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
        if n_e is not None:
            from samp.scene.grid import check_n_e

            n_e = check_n_e(n_e)
        self.robot, self.max_step, self.n_e = robot, float(max_step), n_e
        self.name = "straight"

    def step(self, q: torch.Tensor, q_goal: torch.Tensor, env: EnvBatch | None = None) -> torch.Tensor:
        delta = q_goal - q  # (B, n)
        norm = torch.linalg.vector_norm(delta, dim=1, keepdim=True)  # (B, 1)
        scale = torch.clamp(self.max_step / torch.clamp(norm, min=1e-12), max=1.0)
        return clamp_to_limits(self.robot, q + scale * delta)


class ExpertTrajectoryPlanner:
    """The expert (`samp.expert.ExpertPlanner`) as a `TrajectoryPlanner` for the evaluation.

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
            if problem.expert_trajectory is None and problem.expert_reason:  # the expert failed on it when stored
                return PlannedTrajectory(None, problem.expert_time, problem.expert_reason)
            if problem.expert_trajectory is None:
                raise ValueError(f"problem {problem.name or '(unnamed)'} has no expert trajectory to replay; take "
                                 "problems from a dataset (samp.eval.problems_from_dataset) or use mode='plan'")
            return PlannedTrajectory(problem.expert_trajectory, problem.expert_time)
        if self.robot is None:
            raise ValueError("the expert in mode 'plan' needs a robot: ExpertTrajectoryPlanner(mode='plan', robot=...)")
        from samp.expert import ExpertPlanner
        from samp.robot.precision import exact_robot

        key = problem.scene.content_hash()
        if key not in self._planners:
            # float64: OMPL's bounds are the robot's limits, and a float32 limit rounds inward, which
            # refuses a start stored exactly at a limit (as the expert's own IK goals can be).
            self._planners[key] = ExpertPlanner(exact_robot(self.robot), problem.scene, self.config)
        result = self._planners[key].plan(problem.q_start, problem.q_goal, seed=self.seed)
        return PlannedTrajectory(result.trajectory if result.success else None, result.stats.get("planning_time"),
                                 result.reason)

    def close(self) -> None:
        for planner in self._planners.values():
            planner.close()
        self._planners.clear()
