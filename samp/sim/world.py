"""`World`: a robot and a scene in one pybullet DIRECT client, for batched collision and distance queries.

The robot is samp's own convex parts posed by samp's FK (`LinkBodies`), not pybullet's URDF loader, so
the simulator collides exactly the geometry that robot points and the robot SDF are built on. Obstacles
(the scene's obstacles and its target) are static bodies at their poses: primitives as pybullet
primitives, each closed body of a mesh obstacle as a convex hull when it is convex (or `convex_hull`
is set) and as a static concave triangle mesh otherwise.

A query takes q (B, n): one batched FK gives every link pose, a numpy broadphase compares the parts'
axis-aligned boxes with the obstacles' (a lower bound on each pair's distance), and pybullet's
getClosestPoints runs only on the pairs the broadphase cannot rule out, with bodies posed only for the
configurations that have such pairs.

Collision margins (measured with sphere and polytope probes against analytic distances and exact
polytope distances from NNLS, pybullet 3.2.7): pybullet grows every shape except the sphere by a 1 mm
margin. A GEOM_MESH (convex hull or concave triangle mesh) is the exact shape grown by a 1 mm sphere, so
its reported distance is exactly 1 mm short. GEOM_BOX and GEOM_CYLINDER are first shrunk by the margin
and then grown by it: faces are exact but edges and corners are rounded (a corner reads up to
(sqrt(3) - 1) mm = 0.73 mm too far, a cylinder rim 0.41 mm), an error that depends on the feature.
So boxes and cylinders are built 1 mm larger (half extents, radius and half height), which makes every
non-sphere shape the exact shape grown by 1 mm; after adding 1 mm back per such shape in a pair, the
probes agree with the exact distance to within 1e-5 m (box, mesh) and 1.1e-5 m (cylinder rim).
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from samp.scene.model import Scene
from samp.sim.broadphase import part_gaps, quaternions, serial_link_poses
from samp.sim.obstacles import ObstacleBody, make_obstacle
from samp.robot.bodies import MESH_MARGIN, LinkBodies
from samp.console import import_pybullet

pb = import_pybullet()  # without its build-time banner

__all__ = ["World", "DEFAULT_MAX_DISTANCE", "LIMIT_TOLERANCE"]

DEFAULT_MAX_DISTANCE = 1.0  # metres: min_distance searches no farther and reports at most this
LIMIT_TOLERANCE = 1e-6  # radians: a float32 round trip of a limit (~5e-8 rad) is not a violation
SHELL = 0.02  # metres: first search radius beyond the box gap for a concave mesh
# metres: a self pair whose parts' boxes are this far apart in either part's own link frame is not asked of
# pybullet: a hundred times the error of its distances (~1e-5 m, module docstring), so its answer there is surely
# "no penetration" and skipping the call changes no outcome.
SELF_SLACK = 1e-3
GROUPED_FROM = 12  # configurations per query from which part boxes are computed per group of equal-size parts


def _box_gap(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray) -> np.ndarray:
    """Euclidean distance between axis-aligned boxes, (..., 3) corners broadcast -> (...); 0 if they overlap."""
    return np.linalg.norm(np.maximum(np.maximum(lo_a - hi_b, lo_b - hi_a), 0.0), axis=-1)


class World:
    """A robot among a scene's obstacles in a pybullet DIRECT client.

    Args:
        robot: the `Robot`; its base link is fixed (mounted on the table) and never checked against obstacles.
        scene: the `Scene`; its obstacles and its target are all obstacles.
        max_distance: metres; `min_distance` searches no farther and reports at most this.

    Use as a context manager (`with World(robot, scene) as world:`) or call `close()`.
    """

    def __init__(self, robot, scene: Scene, max_distance: float = DEFAULT_MAX_DISTANCE):
        if not (np.isfinite(max_distance) and max_distance > 0):
            raise ValueError(f"max_distance must be a positive number of metres, got {max_distance!r}")
        self.robot, self.scene, self.max_distance = robot, scene, float(max_distance)
        self._renderer = None  # depth cameras: a samp.sim.camera.Renderer, made on the first capture
        self.client: int | None = pb.connect(pb.DIRECT)
        try:
            self.links = LinkBodies(robot, client=self.client)
            self.obstacles = [body for o in scene.all_obstacles for body in make_obstacle(o, self.client)]
        except BaseException:
            self.close()
            raise
        boxes = np.array([pb.getAABB(o.body, physicsClientId=self.client) for o in self.obstacles]).reshape(-1, 2, 3)
        self._obstacle_lo, self._obstacle_hi = boxes[:, 0], boxes[:, 1]  # (K, 3) each, conservative
        self._parts = [part for name in robot.link_names for part in robot.geometry[name].parts]
        # every part's vertices (3, V) padded to the longest with copies of its first vertex, for one product
        size = max(len(part.vertices) for part in self._parts)
        self._vertices_t = np.stack([np.concatenate([part.vertices, np.repeat(part.vertices[:1], size - len(part.vertices),
                                                                              axis=0)]).T for part in self._parts])
        self._local_lo, self._local_hi = self._vertices_t.min(axis=2), self._vertices_t.max(axis=2)  # (P, 3) each
        counts = np.array([len(part.vertices) for part in self._parts])  # equal-size parts, unpadded: big batches
        self._part_groups = [(g, np.ascontiguousarray(self._vertices_t[g, :, :counts[g[0]]]))
                             for g in (np.flatnonzero(counts == c) for c in np.unique(counts))]
        base = robot.link_names.index(robot.base_link) if robot.base_link in robot.link_names else -1
        self._moving = np.flatnonzero(self.links.part_links != base)  # parts checked against obstacles
        self._self_pairs = self._allowed_part_pairs()  # (S, 2)
        self._self_pair_parts = np.zeros((len(self._self_pairs), len(self._parts)), dtype=np.float32)  # (S, P) 0/1
        self._self_pair_parts[np.arange(len(self._self_pairs))[:, None], self._self_pairs] = 1.0
        limits = robot.joint_limits.double().cpu().numpy()
        self._lower, self._upper = limits[:, 0] - LIMIT_TOLERANCE, limits[:, 1] + LIMIT_TOLERANCE
        # the compiled broadphase (samp.sim.broadphase) for a serial arm; the numpy one otherwise
        serial = robot.serial_fk
        self.compiled = serial is not None
        if self.compiled:
            self._fk_constants = serial.numpy_constants()
            self._part_arrays = (np.ascontiguousarray(self.links.part_links, dtype=np.int64),
                                 np.ascontiguousarray(self._vertices_t), counts.astype(np.int64),
                                 self._moving.astype(np.int64), self._obstacle_lo.reshape(-1, 3).copy(),
                                 self._obstacle_hi.reshape(-1, 3).copy(), self._self_pairs.astype(np.int64),
                                 self._local_lo.copy(), self._local_hi.copy())

    def _allowed_part_pairs(self) -> np.ndarray:
        """(S, 2) indices of part pairs on different links whose link pair is not excluded."""
        names = self.robot.link_names
        skip = {frozenset(p) for p in self.robot.self_collision_exclude}
        links = self.links.part_links
        pairs = [(i, j) for i in range(len(links)) for j in range(i + 1, len(links))
                 if links[i] != links[j] and frozenset((names[links[i]], names[links[j]])) not in skip]
        return np.array(pairs, dtype=int).reshape(-1, 2)

    # ----------------------------------------------------------------- lifetime
    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect the pybullet client (and the cameras' renderer); safe to call more than once."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None

    @property
    def closed(self) -> bool:
        return self.client is None

    # ----------------------------------------------------------------- queries
    def in_collision(self, q, margin: float = 0.0, self_collision: bool = True,
                     joint_limits: bool = True) -> np.ndarray:
        """q (B, n) radians (torch or numpy) -> (B,) bool.

        True where a non-base link is closer than `margin` metres to an obstacle (margin 0: penetration),
        where two collision links that are not excluded touch (if `self_collision`), or where q is
        outside the joint limits by more than LIMIT_TOLERANCE (if `joint_limits`).
        """
        q, margin = self._check_q(q), self._check_margin(margin)
        hit = self._outside(q) if joint_limits else np.zeros(len(q), dtype=bool)
        T, gaps, touch = self._broadphase(q, self_collision)
        near = gaps <= margin  # (B, Pm, K) candidate part-obstacle pairs
        todo = np.flatnonzero(~hit & (near.any(axis=(1, 2)) | touch.any(axis=1)))
        if len(todo) == 0:
            return hit
        pos, quat = self._pose_arrays(T[todo])  # (b, L, 3), (b, L, 4)
        near, touch = near[todo], touch[todo]
        # the parts each configuration's candidate pairs query: only those are posed
        need = np.zeros((len(todo), len(self._parts)), dtype=bool)
        need[:, self._moving] = near.any(axis=2)
        need |= (touch.astype(np.float32) @ self._self_pair_parts) > 0
        jo, io, ko = np.nonzero(near)  # candidate (configuration, moving part, obstacle) triples, by configuration
        js, ss = np.nonzero(touch)
        o_cut = np.searchsorted(jo, np.arange(len(todo) + 1)).tolist()
        s_cut = np.searchsorted(js, np.arange(len(todo) + 1)).tolist()
        obstacle_pairs = np.stack([self._moving[io], ko], axis=1).tolist()
        ss = ss.tolist()
        for j, b in enumerate(todo.tolist()):
            self.links.place(pos[j], quat[j], np.flatnonzero(need[j]).tolist())
            hit[b] = (self._obstacle_hit(T[b], obstacle_pairs[o_cut[j]:o_cut[j + 1]], margin)
                      or self._self_hit(ss[s_cut[j]:s_cut[j + 1]]))
        return hit

    def min_distance(self, q) -> np.ndarray:
        """q (B, n) radians -> (B,) smallest signed distance in metres between the robot's non-base links
        and any obstacle, exact to ~1e-5 m when positive and capped at `max_distance` (also the value
        with no obstacles). Negative values are penetration depths: pybullet's for convex pairs and for
        parts crossing a concave mesh's surface; minus the depth of the deepest vertex for a part that
        lies wholly inside a closed concave mesh."""
        q = self._check_q(q)
        T, gaps, _ = self._broadphase(q, self_collision=False)
        gaps = gaps.reshape(len(q), len(self._moving) * len(self.obstacles))  # (B, Pm * K)
        pos, quat = self._pose_arrays(T)  # (B, L, 3), (B, L, 4)
        return np.array([self._nearest(T[b], gaps[b], (pos[b], quat[b])) for b in range(len(q))],
                        dtype=np.float64).reshape(len(q))

    def outside_limits(self, q) -> np.ndarray:
        """q (B, n) -> (B,) bool: some joint is outside its limits by more than LIMIT_TOLERANCE."""
        return self._outside(self._check_q(q))

    def _outside(self, q: np.ndarray) -> np.ndarray:
        return ((q < self._lower) | (q > self._upper)).any(axis=1)

    # ----------------------------------------------------------------- depth cameras
    def depth_images(self, cameras, q=None, seed: int | None = None) -> list:
        """Render a camera set (`samp.sim.camera.load_camera_set`: a CameraSet, a conf/camera name or a
        YAML path) with the robot at q (n,) radians (default: its home configuration) -> one
        `DepthImage` per camera; noise seeded by `seed` (default: the set's seed)."""
        from samp.sim.camera import Renderer, load_camera_set

        if self.client is None:
            raise RuntimeError("this World is closed; create a new World(robot, scene) to render it")
        q = self.robot.home.cpu().numpy() if q is None else self._check_q(np.asarray(q, dtype=np.float64)[None])[0]
        if self._renderer is None:
            self._renderer = Renderer(self.robot, self.scene)
        return self._renderer.capture(load_camera_set(cameras), q, seed)

    def capture(self, cameras, q=None, seed: int | None = None) -> list:
        """`depth_images` back-projected: one `samp.sim.scan.Scan` per camera, base frame, the robot's
        own pixels removed from the points (their rays kept as free space)."""
        return [image.scan() for image in self.depth_images(cameras, q, seed)]

    # ----------------------------------------------------------------- validation
    def _check_q(self, q) -> np.ndarray:
        """(B, n) torch or numpy -> (B, n) float64 numpy."""
        if self.client is None:
            raise RuntimeError("this World is closed; create a new World(robot, scene) to query it")
        if isinstance(q, torch.Tensor):
            q = q.detach().cpu().double().numpy()
        try:
            q = np.asarray(q, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise TypeError(f"q must be a (B, n) torch tensor or numpy array of radians, got {type(q).__name__}") from e
        n = self.robot.dof
        if q.ndim != 2 or q.shape[1] != n:
            hint = "; use q[None] for one configuration" if q.ndim == 1 else ""
            raise ValueError(f"q must have shape (B, {n}) for {self.robot.name}'s joints {self.robot.joint_names}, "
                             f"got {tuple(q.shape)}{hint}")
        if not np.isfinite(q).all():
            bad = np.flatnonzero(~np.isfinite(q).all(axis=1)).tolist()
            raise ValueError(f"q must be finite, got NaN or inf in configurations {bad}")
        return q

    @staticmethod
    def _check_margin(margin) -> float:
        if not (np.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be a non-negative number of metres, got {margin!r}")
        return float(margin)

    # ----------------------------------------------------------------- broadphase
    def _broadphase(self, q: np.ndarray, self_collision: bool, compiled: bool | None = None):
        """q (B, n) -> link poses T (B, L, 4, 4), box gaps (B, Pm, K) of the moving parts to the obstacles, and
        the candidate self pairs (B, S) (all False unless `self_collision`): compiled for a serial arm
        (`samp.sim.broadphase`), else in numpy; `compiled` forces one (the tests compare them)."""
        if self.compiled if compiled is None else compiled:
            T = serial_link_poses(q, *self._fk_constants)
            return (T, *part_gaps(T, *self._part_arrays, bool(self_collision), SELF_SLACK))
        T = self.links.link_poses(q)
        lo, hi = self._part_boxes(T)
        touch = (self._self_gaps(lo, hi) <= 0.0) & self_collision
        return T, self._obstacle_gaps(lo, hi), self._apart_in_link_frames(T, touch)

    def _pose_arrays(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`LinkBodies.pose_arrays`, the quaternions compiled when the broadphase is."""
        if not self.compiled:
            return self.links.pose_arrays(T)
        return T[..., :3, 3], quaternions(np.ascontiguousarray(T))

    def _part_boxes(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """T (B, L, 4, 4) -> the parts' exact world AABBs, lo and hi (B, P, 3)."""
        Tp = T[:, self.links.part_links]  # (B, P, 4, 4)
        if len(T) < GROUPED_FROM:  # one product over the padded vertices: fewest numpy calls
            rotated = Tp[..., :3, :3] @ self._vertices_t  # (B, P, 3, V); matmul: einsum took 25x longer
            return rotated.min(axis=3) + Tp[..., :3, 3], rotated.max(axis=3) + Tp[..., :3, 3]
        R, t = Tp[..., :3, :3], Tp[..., :3, 3]
        lo, hi = np.empty(t.shape), np.empty(t.shape)
        for parts, vertices in self._part_groups:  # no padding (panda: 1354 vertices instead of 11 x 260)
            rotated = R[:, parts] @ vertices  # the same products, value for value
            lo[:, parts], hi[:, parts] = rotated.min(axis=3) + t[:, parts], rotated.max(axis=3) + t[:, parts]
        return lo, hi

    def _obstacle_gaps(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(B, P, 3) part boxes -> (B, Pm, K) box gaps of the moving parts to each obstacle."""
        m = self._moving
        return _box_gap(lo[:, m, None], hi[:, m, None], self._obstacle_lo, self._obstacle_hi)

    def _self_gaps(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(B, P, 3) part boxes -> (B, S) box gaps of the allowed part pairs."""
        a, b = self._self_pairs.T
        return _box_gap(lo[:, a], hi[:, a], lo[:, b], hi[:, b])

    def _apart_in_link_frames(self, T: np.ndarray, touch: np.ndarray) -> np.ndarray:
        """touch (B, S) with the pairs removed whose boxes, in the link frame of one part of the pair, are
        more than SELF_SLACK apart: a separating axis, so the convex parts cannot touch. The world boxes of
        parts on neighbouring links overlap for most configurations (e.g. link 6 and the hand); in a link's
        own frame its box fits tightly."""
        j, s = np.nonzero(touch)
        if len(j) == 0:
            return touch
        a, b = self._self_pairs[s].T
        Ta, Tb = T[j, self.links.part_links[a]], T[j, self.links.part_links[b]]  # (m, 4, 4)
        gap = self._frame_gap(Ta, Tb, a, b)
        rest = np.flatnonzero(gap <= SELF_SLACK)  # not yet apart: try the other part's frame
        gap[rest] = np.maximum(gap[rest], self._frame_gap(Tb[rest], Ta[rest], b[rest], a[rest]))
        touch = touch.copy()
        touch[j[gap > SELF_SLACK], s[gap > SELF_SLACK]] = False
        return touch

    def _frame_gap(self, Ta: np.ndarray, Tb: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(m,) box gaps between parts a (m,) posed at Ta (m, 4, 4) and parts b posed at Tb, in b's link frame."""
        Rt = np.swapaxes(Tb[:, :3, :3], 1, 2)  # base -> b's link frame
        v = (Rt @ Ta[:, :3, :3]) @ self._vertices_t[a]  # (m, 3, V)
        shift = (Rt @ (Ta[:, :3, 3] - Tb[:, :3, 3])[..., None])[..., 0]  # (m, 3)
        return _box_gap(v.min(axis=2) + shift, v.max(axis=2) + shift, self._local_lo[b], self._local_hi[b])

    # ----------------------------------------------------------------- narrowphase (bodies posed)
    def _obstacle_hit(self, T: np.ndarray, pairs: list, margin: float) -> bool:
        """pairs: candidate [part, obstacle] pairs of one configuration posed at T (L, 4, 4)."""
        return any(self._distance(T, i, k, margin) < margin for i, k in pairs)

    def _self_hit(self, pairs: list) -> bool:
        """pairs: candidate part pairs (indices into the allowed pairs) of the posed configuration; True if
        one pair penetrates."""
        bodies, client = self.links.part_bodies, self.client
        for s in pairs:
            a, b = self._self_pairs[s]
            points = pb.getClosestPoints(bodies[a], bodies[b], 0.0, physicsClientId=client)
            if min((p[8] for p in points), default=np.inf) + 2 * MESH_MARGIN < 0.0:
                return True
        return False

    def _nearest(self, T: np.ndarray, gaps: np.ndarray, placement: tuple[np.ndarray, np.ndarray]) -> float:
        """Branch and bound over one configuration's part-obstacle pairs, gaps (Pm * K,): visit pairs by
        increasing gap and stop at the first positive gap at least the best distance found. (A positive
        gap bounds a pair's distance from below; overlapping boxes, gap 0, bound nothing, as the pair may
        penetrate to any depth, so they are always visited.) T (L, 4, 4) and `placement` (positions
        (L, 3), quaternions (L, 4)) pose the links; bodies are placed only if a pair needs pybullet."""
        best, posed, K = self.max_distance, False, len(self.obstacles)
        for flat in np.argsort(gaps, kind="stable"):
            if gaps[flat] > 0.0 and gaps[flat] >= best:
                break
            if not posed:
                self.links.place(*placement)
                posed = True
            i, k = divmod(int(flat), K)
            best = min(best, self._search(T, self._moving[i], k, gaps[flat], max(best, 0.0)))
        return best

    def _search(self, T: np.ndarray, part: int, k: int, gap: float, limit: float) -> float:
        """`_distance` within `limit`, for a concave mesh in growing shells from the box gap: pybullet
        returns a point for every triangle within the limit (on the test bunny this saves 40% of the time)."""
        if self.obstacles[k].mesh is not None:
            reach = gap + SHELL
            while reach < limit:
                if (d := self._distance(T, part, k, reach)) < np.inf:
                    return d
                reach *= 4
        return self._distance(T, part, k, limit)

    def _distance(self, T: np.ndarray, part: int, k: int, limit: float) -> float:
        """Exact signed distance between posed part `part` and obstacle k; inf if it exceeds `limit`."""
        o = self.obstacles[k]
        points = pb.getClosestPoints(self.links.part_bodies[part], o.body, limit, physicsClientId=self.client)
        d = min((p[8] for p in points), default=np.inf) + MESH_MARGIN + o.inflation
        if o.mesh is not None and d >= 0.0:
            # pybullet sees only the triangles of a concave mesh: a part inside it, clear of the surface,
            # reads as free. One vertex decides (no crossing was found); the reverse, the mesh inside
            # the part, needs no test: its triangles then overlap the solid part and pybullet reports it.
            local = self._part_vertices_in(T, part, o)  # (V, 3)
            if o.mesh.contains(local[:1])[0]:
                # Minus the depth of the part's deepest vertex, as the scene SDF measures it (trimesh:
                # positive inside); a lower bound on the depth needed to separate them.
                return -float(trimesh.proximity.signed_distance(o.mesh, local).max())
        return d if d <= limit else np.inf

    def _part_vertices_in(self, T: np.ndarray, part: int, o: ObstacleBody) -> np.ndarray:
        """(V, 3) vertices of part `part`, posed by T (L, 4, 4), in the frame of obstacle o."""
        link_pose = T[self.links.part_links[part]]
        world = self._parts[part].vertices @ link_pose[:3, :3].T + link_pose[:3, 3]  # (V, 3) base frame
        return (world - o.pose[:3, 3]) @ o.pose[:3, :3]
