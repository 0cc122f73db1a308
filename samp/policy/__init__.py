"""Trainable planners: the SAMP network (pure torch), its losses and LightningModule, the baselines, the
base they share (`PolicySystemBase`), the planner interface the evaluation calls, and `load_policy`,
which rebuilds any of them from a checkpoint by its recorded kind."""

from samp.policy.interface import EnvBatch, PlannedTrajectory, StepPolicy, TrajectoryPlanner, clamp_to_limits
from samp.policy.losses import LossConfig, collision_loss, config_loss, match_loss
from samp.policy.network import PolicyConfig, SAMPNet, denormalize, normalize, sample_by_scene
from samp.policy.registry import load_policy, load_system, policy_kinds
from samp.policy.step import SAMPStepPolicy

__all__ = ["EnvBatch", "LossConfig", "PlannedTrajectory", "PolicyConfig", "SAMPNet", "SAMPStepPolicy", "StepPolicy",
           "TrajectoryPlanner", "clamp_to_limits", "collision_loss", "config_loss", "denormalize", "load_policy",
           "load_system", "match_loss", "normalize", "policy_kinds", "sample_by_scene"]
