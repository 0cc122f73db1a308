"""Scene obstacles as static pybullet bodies for `samp.sim.World`: primitives as pybullet primitives (boxes and
cylinders grown by pybullet's 1 mm margin, see `samp.sim.world`'s docstring), each closed body of a mesh
obstacle as a convex hull or a static concave triangle mesh."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from samp.console import import_pybullet
from samp.robot.bodies import MESH_MARGIN
from samp.scene.model import Box, Cylinder, MeshObstacle, Obstacle as SceneObstacle, Sphere
from samp.scene.sdf import obstacle_parts

pb = import_pybullet()  # without its build-time banner

__all__ = ["ObstacleBody", "make_obstacle"]


@dataclass(frozen=True)
class ObstacleBody:
    """One static pybullet body of an obstacle and what its distance needs to become exact."""

    name: str  # the scene obstacle's name (a mesh obstacle of several bodies has one entry per body)
    body: int
    inflation: float  # pybullet's margin around this shape, added back to every distance
    mesh: trimesh.Trimesh | None  # a closed non-convex body, which pybullet sees only as its surface
    pose: np.ndarray  # (4, 4) obstacle frame -> base frame


def _mesh_shape(body: trimesh.Trimesh, convex: bool, client: int) -> int:
    """A convex hull (vertices only), or a static concave triangle mesh."""
    if convex:
        return pb.createCollisionShape(pb.GEOM_MESH, vertices=body.vertices.tolist(), physicsClientId=client)
    return pb.createCollisionShape(pb.GEOM_MESH, vertices=body.vertices.tolist(), indices=body.faces.ravel().tolist(),
                                   flags=pb.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=client)


def _obstacle_shapes(o: SceneObstacle, client: int) -> list[tuple[int, float, trimesh.Trimesh | None]]:
    """pybullet collision shapes of one obstacle: (shape id, inflation, closed concave body or None) each."""
    kw = dict(physicsClientId=client)
    if isinstance(o, Box):  # grown by the margin: see samp.sim.world's docstring
        half = np.asarray(o.size) / 2 + MESH_MARGIN
        return [(pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half.tolist(), **kw), MESH_MARGIN, None)]
    if isinstance(o, Cylinder):  # along local z, as ours; grown by the margin
        return [(pb.createCollisionShape(pb.GEOM_CYLINDER, radius=o.radius + MESH_MARGIN,
                                         height=o.height + 2 * MESH_MARGIN, **kw), MESH_MARGIN, None)]
    if isinstance(o, Sphere):  # pybullet's sphere is all margin: exact
        return [(pb.createCollisionShape(pb.GEOM_SPHERE, radius=o.radius, **kw), 0.0, None)]
    if isinstance(o, MeshObstacle):  # one body per closed part, as the scene SDF sees it
        shapes = []
        for part in obstacle_parts(o):
            convex = o.convex_hull or part.is_convex
            shapes.append((_mesh_shape(part, convex, client), MESH_MARGIN, None if convex else part))
        return shapes
    raise TypeError(f"unknown obstacle type {type(o).__name__}; expected Box, Cylinder, Sphere or MeshObstacle")


def make_obstacle(o: SceneObstacle, client: int) -> list[ObstacleBody]:
    """The static pybullet bodies of one scene obstacle, posed, with what their distances need."""
    bodies = []
    for shape, inflation, mesh in _obstacle_shapes(o, client):
        if shape < 0:
            raise RuntimeError(f"pybullet could not build a collision shape for obstacle {o.name!r} ({o.kind})")
        body = pb.createMultiBody(0, shape, basePosition=o.pose.position, baseOrientation=o.pose.quaternion,
                                  physicsClientId=client)
        bodies.append(ObstacleBody(o.name, body, inflation, mesh, o.pose.matrix()))
    return bodies
