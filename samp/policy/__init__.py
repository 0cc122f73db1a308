"""The SAMP motion policy: network (pure torch), losses, and (in system.py) its LightningModule."""

from samp.policy.losses import LossConfig, collision_loss, config_loss, match_loss
from samp.policy.network import PolicyConfig, SAMPNet, denormalize, normalize, sample_by_scene
from samp.policy.step import SAMPStepPolicy, load_policy

__all__ = ["LossConfig", "PolicyConfig", "SAMPNet", "SAMPStepPolicy", "collision_loss", "config_loss", "denormalize",
           "load_policy", "match_loss", "normalize", "sample_by_scene"]
