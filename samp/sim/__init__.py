"""pybullet side of samp: bodies built from samp's own geometry, and the World of a robot in a scene."""

from samp.sim.bodies import LinkBodies
from samp.sim.world import World

__all__ = ["LinkBodies", "World"]
