"""Link collision geometry as unions of convex parts.

Each `<collision>` element becomes convex parts in the link frame: a mesh that splits into watertight
bodies (a convex decomposition such as V-HACD output) gives one convex hull per body; any other mesh
(open or single-bodied, like the Panda's and iiwa's collision meshes) gives the convex hull of all its
vertices, which is also what pybullet collides with for a mesh on a moving link. Convex parts make
signed distances exact and the inside test a half-space test, and one geometry then serves robot
points, the robot SDF and the simulator alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from samp.meshes import load_mesh
from samp.robot.urdf import Collision

__all__ = ["LinkGeometry", "link_geometry"]


@dataclass
class LinkGeometry:
    """A link's collision geometry in its own frame."""

    name: str
    parts: list[trimesh.Trimesh]  # convex, watertight
    mesh: trimesh.Trimesh  # the parts concatenated (each part welded and closed)

    def __post_init__(self):
        # Half-space form of every part: inside iff normals @ x - offsets < 0 for all faces.
        self._planes = [(p.face_normals.copy(), np.einsum("fj,fj->f", p.face_normals, p.triangles[:, 0]))
                        for p in self.parts]

    @property
    def area(self) -> float:
        return float(self.mesh.area)

    def inside_depth(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) link-frame points -> (N,) min over parts of the part's largest face-plane value:
        negative inside the link (minus the exact depth for a single part), positive outside (a lower
        bound on the distance)."""
        depth = np.full(len(points), np.inf)
        for normals, offsets in self._planes:
            depth = np.minimum(depth, (points @ normals.T - offsets).max(axis=1))
        return depth

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N,) unsigned distance to the link surface (exact outside the link)."""
        _, dist, _ = trimesh.proximity.closest_point(self.mesh, points)
        return dist


def _primitive(c: Collision) -> trimesh.Trimesh:
    if c.kind == "box":
        return trimesh.creation.box(extents=c.size)
    if c.kind == "cylinder":
        return trimesh.creation.cylinder(radius=c.size[0], height=c.size[1], sections=32)
    return trimesh.creation.icosphere(subdivisions=3, radius=c.size[0])


def _convex_parts(c: Collision) -> list[trimesh.Trimesh]:
    if c.kind != "mesh":
        parts = [_primitive(c)]
    else:
        loaded = load_mesh(c.mesh_path, solid=True)  # checked: bounded, not empty, not flat
        loaded.merge_vertices()
        loaded.apply_transform(np.diag([*c.scale, 1.0]))
        bodies = [b for b in loaded.split(only_watertight=False) if len(b.vertices) >= 4]
        if len(bodies) > 1 and all(b.is_watertight for b in bodies):
            parts = [b.convex_hull for b in bodies]
        else:
            parts = [loaded.convex_hull]
    for part in parts:
        part.apply_transform(c.origin)
    return parts


def link_geometry(name: str, collisions: list[Collision]) -> LinkGeometry:
    parts = [p for c in collisions for p in _convex_parts(c)]
    # Parts are not welded to each other: vertices they share would make the union non-manifold.
    mesh = trimesh.util.concatenate(parts)
    return LinkGeometry(name=name, parts=parts, mesh=mesh)


