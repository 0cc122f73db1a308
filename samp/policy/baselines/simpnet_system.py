"""The SIMPNet-style sampler's LightningModule: the `SIMPNetNet` trained exactly as MPNet's network (the
next configuration of a demonstration, with a `reverse_fraction` of each batch stepped backwards so the
sampler also grows a tree from the goal; squared error in normalised joint space), on the same samples as
SAMP. Only the network and the planner differ from `MPNetSystem`.
"""

from __future__ import annotations

from samp.policy.base import DEFAULT_OPTIMIZER, PolicySystemBase
from samp.policy.baselines.mpnet_system import MPNetSystem
from samp.policy.baselines.simpnet import SIMPNetConfig, SIMPNetNet

__all__ = ["SIMPNetSystem"]


class SIMPNetSystem(MPNetSystem, kind="simpnet"):
    """Args:
        robot: robot name. model: SIMPNetConfig fields (dof comes from the robot).
        reverse_fraction: share of each training batch stepped backwards along its trajectory.
        planning: SIMPNetPlanConfig fields, the planner's defaults (`samp.policy.baselines.simpnet_planner`).
        optimizer, scheduler: `_partial_` config nodes (conf/optimizer/; default lr 1e-3, as MPNet's).
    """

    def __init__(self, robot: str = "panda", model: dict | None = None, reverse_fraction: float = 0.5,
                 planning: dict | None = None, optimizer: dict | None = None, scheduler: dict | None = None):
        if not 0.0 <= reverse_fraction <= 1.0:
            raise ValueError(f"reverse_fraction must be in [0, 1], got {reverse_fraction}")
        PolicySystemBase.__init__(self, robot, optimizer or {**DEFAULT_OPTIMIZER, "lr": 1e-3}, scheduler)
        from samp.policy.baselines.simpnet_planner import SIMPNetPlanConfig

        # Named explicitly: Lightning finds a constructor's arguments only through super() calls, and this one
        # skips MPNetSystem's constructor (it builds the MPNet network).
        self.save_hyperparameters({"robot": robot, "model": model, "reverse_fraction": reverse_fraction,
                                   "planning": planning, "optimizer": optimizer, "scheduler": scheduler})
        self.net_cfg = SIMPNetConfig(**{**(model or {}), "dof": self.robot.dof})
        self.net = SIMPNetNet(self.net_cfg)
        SIMPNetPlanConfig(**(planning or {}))  # a bad planner setting fails before training, not after

    def planner(self, **options):
        """The trained sampler inside OMPL as a `TrajectoryPlanner`; options override the planning defaults."""
        from samp.policy.baselines.simpnet_planner import SIMPNetPlanConfig, SIMPNetPlanner

        return SIMPNetPlanner(self, SIMPNetPlanConfig(**{**(self.hparams.planning or {}), **options}))
