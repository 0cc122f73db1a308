"""Baseline neural planners trained and evaluated in SAMP's harness (issue 9, the paper's Table I):

* MPiNet-style policy (`MPiNetSystem`, `+experiment=mpinet`): PointNet++ over a labelled point cloud,
  joint steps, point-match plus hinge collision loss; rolled out as a step policy like SAMP.
* MPNet-style planner (`MPNetSystem`, `+experiment=mpnet`): obstacle encoder plus dropout MLP, planning
  by bidirectional rollout, lazy contraction and neural replanning; evaluated as a trajectory planner
  like the expert.

`load_policy(checkpoint)` (samp.policy) hands a baseline checkpoint to `planner_from_checkpoint`, so
`samp.eval.load_planner(run_dir)` and `python -m samp.eval run=RUN_DIR` work for these runs unchanged.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["BASELINES", "MPNetSystem", "MPiNetSystem", "planner_from_checkpoint"]

BASELINES = ("mpinet", "mpnet")


def __getattr__(name: str):
    if name == "MPiNetSystem":
        from samp.policy.baselines.mpinet_system import MPiNetSystem

        return MPiNetSystem
    if name == "MPNetSystem":
        from samp.policy.baselines.mpnet_system import MPNetSystem

        return MPNetSystem
    raise AttributeError(f"module 'samp.policy.baselines' has no attribute {name!r}")


def planner_from_checkpoint(checkpoint: str | Path | dict, **options):
    """A baseline checkpoint (path or loaded dict) -> its planner: an MPiNet `StepPolicy` or an MPNet
    `TrajectoryPlanner` (`options`: planning settings for MPNet, see `MPNetPlanConfig`)."""
    import torch

    from samp.policy.baselines.mpinet_system import MPiNetSystem
    from samp.policy.baselines.mpnet_system import MPNetSystem

    ckpt = checkpoint if isinstance(checkpoint, dict) else torch.load(checkpoint, map_location="cpu", weights_only=False)
    kind = (ckpt.get("baseline") or {}).get("kind")
    systems = {"mpinet": MPiNetSystem, "mpnet": MPNetSystem}
    if kind not in systems:
        raise ValueError(f"{checkpoint if not isinstance(checkpoint, dict) else 'the checkpoint'} is not a baseline "
                         f"checkpoint (kind {kind!r}; expected one of {sorted(systems)})")
    return systems[kind].from_checkpoint(ckpt).planner(**options)
