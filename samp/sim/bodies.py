"""The robot's collision links as pybullet bodies built from samp's convex parts.

pybullet's own URDF loader keeps only part of some multi-object OBJ files (for the xArm's V-HACD meshes
it collided with one body of each link in a check against trimesh), so collision queries use bodies
made from exactly the geometry that robot points and the robot SDF are built on.
"""

from __future__ import annotations

import itertools

import numpy as np
import pybullet as pb
import torch
from scipy.spatial.transform import Rotation

__all__ = ["LinkBodies"]


class LinkBodies:
    """Static pybullet bodies for each collision link (one per convex part), posed by `set_q`.

    Use as a context manager; the DIRECT client is closed on exit.
    """

    def __init__(self, robot):
        self.robot = robot
        self.client = pb.connect(pb.DIRECT)
        # createCollisionShapeArray takes no vertex lists, so each convex part is a body of its own.
        self.bodies: dict[str, list[int]] = {
            name: [pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_MESH, vertices=part.vertices.tolist(),
                                                                 physicsClientId=self.client),
                                      physicsClientId=self.client) for part in geom.parts]
            for name, geom in robot.geometry.items()
        }

    def __enter__(self) -> "LinkBodies":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None

    def set_q(self, q: np.ndarray) -> None:
        """Pose every link body for one configuration q (n,) radians."""
        with torch.no_grad():
            fk = self.robot.fk(torch.as_tensor(np.asarray(q)[None], dtype=self.robot.dtype))
        for name, bodies in self.bodies.items():
            T = fk[name][0].double().numpy()
            quat = Rotation.from_matrix(T[:3, :3]).as_quat()  # x, y, z, w as pybullet expects
            for body in bodies:
                pb.resetBasePositionAndOrientation(body, T[:3, 3].tolist(), quat.tolist(), physicsClientId=self.client)

    def pair_distance(self, a: str, b: str, max_distance: float = 0.0) -> float:
        """Signed distance between two link bodies (negative: penetrating), or inf beyond max_distance."""
        return min((p[8] for ba in self.bodies[a] for bb in self.bodies[b]
                    for p in pb.getClosestPoints(ba, bb, max_distance, physicsClientId=self.client)),
                   default=float("inf"))

    def colliding_pairs(self, exclude=()) -> list[tuple[str, str]]:
        """Link pairs in contact at the current pose, except the excluded ones (order-free)."""
        skip = {frozenset(p) for p in exclude}
        return [(a, b) for a, b in itertools.combinations(self.bodies, 2)
                if frozenset((a, b)) not in skip and self.pair_distance(a, b) < 0.0]
