"""A trained SAMP policy as a `samp.eval.StepPolicy`, and `load_policy(checkpoint)` for the evaluation."""

from __future__ import annotations

from pathlib import Path

import torch

__all__ = ["SAMPStepPolicy", "load_policy"]


class SAMPStepPolicy:
    """Rolls out a `PolicySystem`: `reset` encodes the batch's scene grids once, `step` predicts q_{t+1}.

    The grids must be at the policy's n_e and share the workspace bounds the policy was trained with.
    """

    def __init__(self, system, name: str = "samp"):
        self.system, self.robot, self.name = system, system.robot, name
        self.n_e = system.hparams.n_e
        if self.n_e is None:
            raise ValueError("this policy was never fitted to a dataset (its n_e is unknown); train it first")
        self._features = None

    def reset(self, env) -> None:
        bounds = torch.as_tensor(self.system.hparams.bounds, dtype=env.bounds.dtype, device=env.bounds.device)
        if not torch.allclose(env.bounds, bounds.expand_as(env.bounds), atol=1e-9):
            raise ValueError(f"the policy was trained on workspace bounds {self.system.hparams.bounds}; these scenes "
                             f"have {env.bounds.tolist()}")
        if env.grids is None or tuple(env.grids.shape[1:]) != (self.n_e,) * 3:
            raise ValueError(f"the policy reads grids at n_e = {self.n_e}; got "
                             f"{None if env.grids is None else tuple(env.grids.shape)}")
        with torch.no_grad():
            self._features = self.system.encode(env.grids.to(self.system.device, torch.float32))

    def step(self, q: torch.Tensor, q_goal: torch.Tensor, env) -> torch.Tensor:
        if self._features is None:
            self.reset(env)
        with torch.no_grad():
            return self.system.predict(q, q_goal, self._features, env.scene_index, self.system.hparams.bounds)


def load_policy(checkpoint: str | Path, run_dir: str | Path | None = None, **options) -> SAMPStepPolicy:
    """A `SAMPStepPolicy` from a policy checkpoint (the run folder is not needed: the checkpoint is whole).
    A baseline's checkpoint (MPiNet, MPNet) gives that baseline's planner (`samp.policy.baselines`)."""
    from samp.policy.system import PolicySystem

    # Memory-mapped: only the record's keys are read here, not the weights.
    if "baseline" in torch.load(checkpoint, map_location="cpu", weights_only=False, mmap=True):
        from samp.policy.baselines import planner_from_checkpoint

        return planner_from_checkpoint(checkpoint, **options)
    if options:
        raise ValueError(f"load_policy takes no options, got {sorted(options)}")
    return SAMPStepPolicy(PolicySystem.from_checkpoint(checkpoint).eval())
