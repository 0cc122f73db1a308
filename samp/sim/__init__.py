"""pybullet side of samp: bodies built from samp's own geometry (the World comes with the scene model)."""

from samp.sim.bodies import LinkBodies

__all__ = ["LinkBodies"]
