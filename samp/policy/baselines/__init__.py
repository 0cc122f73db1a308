"""Baseline neural planners trained and evaluated in SAMP's harness (the paper's Table I):

* MPiNet-style policy (`MPiNetSystem`, `experiment=mpinet`): PointNet++ over a labelled point cloud,
  joint steps, point-match plus hinge collision loss; rolled out as a step policy like SAMP.
* MPNet-style planner (`MPNetSystem`, `experiment=mpnet`): obstacle encoder plus dropout MLP, planning
  by bidirectional rollout, lazy contraction and neural replanning; evaluated as a trajectory planner
  like the expert.

Both derive from `samp.policy.base.PolicySystemBase`, which registers their kind, so
`samp.policy.load_policy(checkpoint)` and `python -m samp.eval run=RUN_DIR` load them like SAMP. A new
baseline is a network module here, a `<name>_system.py` module with its system class (found by
`samp.policy.registry` without being listed), and an experiment config.
"""

from __future__ import annotations

__all__ = ["MPNetSystem", "MPiNetSystem"]


def __getattr__(name: str):
    if name == "MPiNetSystem":
        from samp.policy.baselines.mpinet_system import MPiNetSystem

        return MPiNetSystem
    if name == "MPNetSystem":
        from samp.policy.baselines.mpnet_system import MPNetSystem

        return MPNetSystem
    raise AttributeError(f"module 'samp.policy.baselines' has no attribute {name!r}")
