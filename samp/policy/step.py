"""A trained SAMP policy as a `StepPolicy` (samp.policy.interface) for rollouts."""

from __future__ import annotations

import torch

from samp.policy.plan import Plannable

__all__ = ["SAMPStepPolicy"]


class SAMPStepPolicy(Plannable):
    """Rolls out a `PolicySystem`: `reset` encodes the batch's scene grids once, `step` predicts q_{t+1};
    `plan(scene, q_start, q_goal)` does both for one problem (`samp.policy.plan`).

    The grids must be at the policy's n_e and share the workspace bounds the policy was trained with.
    """

    def __init__(self, system, name: str = "samp"):
        system.fitted()
        self.system, self.robot, self.name, self.n_e = system, system.robot, name, system.n_e
        self._features = None
        # What depends only on the robot and the robot SDF's weights is built now, outside any timed step.
        system.robot_sdf.self_distances(system.robot_sdf_tables)

    def reset(self, env) -> None:
        self.system.check_env(env)
        with torch.no_grad():
            self._features = self.system.encode(env.grids.to(self.system.device, torch.float32))

    def step(self, q: torch.Tensor, q_goal: torch.Tensor, env) -> torch.Tensor:
        if self._features is None:
            self.reset(env)
        with torch.inference_mode():
            return self.system.predict(q, q_goal, self._features, env.scene_index, self.system.bounds,
                                       near=self.system.robot_sdf_pairs == "near")
