"""pybullet side of samp: the World of a robot in a scene, simulated depth cameras and what they produce.

    from samp.sim import World
    with World(robot, scene) as world:
        world.in_collision(q), world.min_distance(q)      # q (B, n) radians -> (B,) bool, (B,) metres

`LinkBodies` (a robot's own link bodies) lives in `samp.robot.bodies` and is re-exported here. Names are
imported on first use, so that `samp.sim.scan` (plain dataclasses) stays light for `samp.perception`.
"""

from samp import lazy_exports

__getattr__, __all__ = lazy_exports(__name__, {"LinkBodies": "samp.robot.bodies", "World": "samp.sim.world"})
