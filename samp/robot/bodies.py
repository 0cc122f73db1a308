"""The robot's collision links as pybullet bodies built from samp's convex parts: the robot's own
bodies for self-collision checks, and the robot side of `samp.sim.World`.

pybullet's own URDF loader keeps only part of some multi-object OBJ files (for the xArm's V-HACD meshes
it collided with one body of each link in a check against trimesh), so collision queries use bodies
made from exactly the geometry that robot points and the robot SDF are built on.

Distances here are exact: pybullet inflates every GEOM_MESH by a 1 mm collision margin (measured, see
`MESH_MARGIN`), and `pair_distance` adds it back.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

from samp.console import import_pybullet

pb = import_pybullet()  # without its build-time banner

__all__ = ["LinkBodies", "MESH_MARGIN", "matrix_to_quaternion"]

# pybullet models a GEOM_MESH (convex hull or concave triangle mesh) as the exact shape grown by a 1 mm
# sphere (its collision margin), so getClosestPoints reports 1 mm less per mesh than the exact distance;
# measured against exact polytope distances (NNLS) to 1e-6 m (see samp/sim/world.py for the full probe).
MESH_MARGIN = 0.001


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions x, y, z, w, from the largest of the four
    candidate components (Shepperd's method, as scipy's `Rotation.from_matrix` does for a rotation)."""
    R = np.asarray(R, dtype=np.float64)
    m = R.reshape(-1, 3, 3)
    d = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]], axis=1)  # (N, 4)
    k = d.argmax(axis=1)
    q = np.empty((len(m), 4))
    i = k < 3  # a diagonal entry is largest: component k first
    if i.any():
        ki = k[i]
        kj, kk = (ki + 1) % 3, (ki + 2) % 3
        mi, rows = m[i], np.arange(int(i.sum()))
        qi = np.empty((len(mi), 4))
        qi[rows, ki] = 1 - d[i, 3] + 2 * mi[rows, ki, ki]
        qi[rows, kj] = mi[rows, kj, ki] + mi[rows, ki, kj]
        qi[rows, kk] = mi[rows, kk, ki] + mi[rows, ki, kk]
        qi[:, 3] = mi[rows, kk, kj] - mi[rows, kj, kk]
        q[i] = qi
    t = ~i  # the trace is largest
    if t.any():
        mt = m[t]
        q[t] = np.stack([mt[:, 2, 1] - mt[:, 1, 2], mt[:, 0, 2] - mt[:, 2, 0], mt[:, 1, 0] - mt[:, 0, 1],
                         1 + d[t, 3]], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(*R.shape[:-2], 4)


class LinkBodies:
    """Static pybullet bodies for each collision link (one per convex part), posed by `set_q`.

    Args:
        robot: the `Robot` whose `geometry` the bodies are made of.
        client: a pybullet client to build in; by default a DIRECT client of its own, closed by `close`.

    Attributes:
        bodies: link name -> body ids of its convex parts.
        part_bodies, part_links: (P,) body id and index into `robot.link_names` of every part, flattened.
    Use as a context manager; a client it opened is closed on exit.
    """

    def __init__(self, robot, client: int | None = None):
        self.robot = robot
        self._owns_client = client is None
        self.client = pb.connect(pb.DIRECT) if client is None else client
        # createCollisionShapeArray takes no vertex lists, so each convex part is a body of its own.
        self.bodies: dict[str, list[int]] = {name: [self._part_body(part) for part in robot.geometry[name].parts]
                                             for name in robot.link_names}
        self.part_bodies = [body for bodies in self.bodies.values() for body in bodies]
        self.part_links = np.array([li for li, bodies in enumerate(self.bodies.values()) for _ in bodies])

    def _part_body(self, part) -> int:
        shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=part.vertices.tolist(), physicsClientId=self.client)
        return pb.createMultiBody(0, shape, physicsClientId=self.client)

    def __enter__(self) -> "LinkBodies":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._owns_client and self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None

    def link_poses(self, q) -> np.ndarray:
        """q (B, n) radians -> (B, L, 4, 4) float64 base-frame poses of `robot.link_names`, one batched FK
        (in numpy for a serial arm: a collision query's few configurations cost torch more in overhead)."""
        if isinstance(q, torch.Tensor):
            q = q.detach().cpu().double().numpy()
        return self.robot.link_poses_numpy(np.asarray(q, dtype=np.float64))

    @staticmethod
    def pose_arrays(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., L, 4, 4) link poses -> positions (..., L, 3) and unit quaternions (..., L, 4) x, y, z, w
        as pybullet expects (`matrix_to_quaternion`, vectorised: scipy costs ~50 us per call)."""
        return T[..., :3, 3], matrix_to_quaternion(T[..., :3, :3])

    def place(self, pos: np.ndarray, quat: np.ndarray, parts=None) -> None:
        """Pose the part bodies (all, or the indices `parts`) from their links' positions (L, 3) and
        quaternions (L, 4)."""
        pos, quat = pos.tolist(), quat.tolist()
        bodies, links = self.part_bodies, self.part_links
        for i in range(len(bodies)) if parts is None else parts:
            li = links[i]
            pb.resetBasePositionAndOrientation(bodies[i], pos[li], quat[li], physicsClientId=self.client)

    def set_poses(self, T: np.ndarray) -> None:
        """Pose every part body from its link's pose, T (L, 4, 4) in `robot.link_names` order."""
        self.place(*self.pose_arrays(T))

    def set_q(self, q: np.ndarray) -> None:
        """Pose every link body for one configuration q (n,) radians."""
        self.set_poses(self.link_poses(np.asarray(q)[None])[0])

    def pair_distance(self, a: str, b: str, max_distance: float = 0.0) -> float:
        """Exact signed distance between two link bodies (negative: penetrating), or inf beyond max_distance."""
        d = min((p[8] for ba in self.bodies[a] for bb in self.bodies[b]
                 for p in pb.getClosestPoints(ba, bb, max_distance, physicsClientId=self.client)),
                default=float("inf")) + 2 * MESH_MARGIN
        return d if d <= max_distance else float("inf")

    def colliding_pairs(self, exclude=()) -> list[tuple[str, str]]:
        """Link pairs in contact at the current pose, except the excluded ones (order-free)."""
        skip = {frozenset(p) for p in exclude}
        return [(a, b) for a, b in itertools.combinations(self.bodies, 2)
                if frozenset((a, b)) not in skip and self.pair_distance(a, b) < 0.0]
