"""A trained SAMP policy as a `StepPolicy` (samp.policy.interface) for rollouts."""

from __future__ import annotations

import torch

from samp.policy.interface import clamp_to_limits
from samp.policy.network import denormalize
from samp.policy.plan import Plannable

__all__ = ["SAMPStepPolicy"]


class SAMPStepPolicy(Plannable):
    """Rolls out a `PolicySystem`: `reset` encodes the batch's scene grids once, `step` predicts q_{t+1};
    `plan(scene, q_start, q_goal)` does both for one problem (`samp.policy.plan`).

    The grids must be at the policy's n_e and share the workspace bounds the policy was trained with.

    `compiled`: on a CPU, compute what the network reads (robot points, robot SDF, scene features, normalised
    configurations) in one compiled call (`samp.policy.compiled`), where the system allows it (a serial arm,
    robot_sdf_pairs=near); None (the default) does so wherever it is allowed, False keeps the torch path. The
    two agree to float32 rounding.

    `stride`: each step moves up to `stride` times the network's predicted step (clamped to the joint limits):
    fewer steps, so less time per problem, at a cost in success that the evaluation measures (1: as trained).
    Near the goal the stride shrinks, to no more than half the joint-space distance left and no less than the
    predicted step: a fixed stride overshoots a goal closer than the stretched step and oscillates about it.
    """

    def __init__(self, system, name: str = "samp", compiled: bool | None = None, stride: float = 1.0):
        from samp.policy.compiled import StepInputs, compiled_step_available

        system.fitted()
        if not (isinstance(stride, (int, float)) and 0 < stride <= 4):
            raise ValueError(f"stride must be a number in (0, 4] (times the predicted step; 1: as trained), "
                             f"got {stride!r}")
        self.system, self.robot, self.name, self.n_e = system, system.robot, name, system.n_e
        self.stride = float(stride)
        self._features = None
        # What depends only on the robot and the robot SDF's weights is built now, outside any timed step.
        system.robot_sdf.self_distances(system.robot_sdf_tables)
        use = compiled_step_available(system) if compiled is None else compiled
        self._inputs = StepInputs(system) if use else None  # StepInputs refuses a system it cannot serve

    @property
    def compiled(self) -> bool:
        """Whether steps take the compiled inputs (`samp.policy.compiled`) or the torch path."""
        return self._inputs is not None

    def reset(self, env) -> None:
        self.system.check_env(env)
        with torch.no_grad():
            self._features = self.system.encode(env.grids.to(self.system.device, torch.float32))
        if self._inputs is not None:
            self._inputs.set_features(self._features)

    def step(self, q: torch.Tensor, q_goal: torch.Tensor, env) -> torch.Tensor:
        if self._features is None:
            self.reset(env)
        with torch.inference_mode():
            if self._inputs is None:
                q_next = self.system.predict(q, q_goal, self._features, env.scene_index, self.system.bounds,
                                             near=self.system.robot_sdf_pairs == "near")
            else:
                u = self.system.net.head(*self._inputs(q, q_goal, env.scene_index))  # head skips a branch it lacks
                q_next = denormalize(u, self.system.limits)
            if self.stride == 1.0:
                return q_next
            return clamp_to_limits(self.robot, q + self.scale(q, q_goal, q_next) * (q_next - q))

    def scale(self, q: torch.Tensor, q_goal: torch.Tensor, q_next: torch.Tensor) -> torch.Tensor:
        """(B, 1) how many predicted steps each row moves: `stride`, but no more than half the joint-space
        distance left to the goal and no less than one step (a stride below 1 is taken as it is)."""
        step = torch.linalg.vector_norm(q_next - q, dim=1, keepdim=True).clamp_min(1e-12)
        room = 0.5 * torch.linalg.vector_norm(q_goal - q, dim=1, keepdim=True)
        return (room / step).clamp(max=self.stride).clamp(min=min(1.0, self.stride))
