"""Simulated depth cameras: models, camera sets from YAML (`conf/camera/`), rendering with pybullet's CPU
renderer (ER_TINY_RENDERER, DIRECT mode), and depth images back-projected into base-frame point clouds.

Conventions. Intrinsics are pinhole, in pixels, in the OpenCV sense: fx, fy focal lengths, (cx, cy) the
principal point with the centre of the first pixel at (0, 0); `fov` is the vertical field of view in
degrees (square pixels, centred principal point). A camera pose is given as eye/target/up or as a 4x4
camera -> base transform with optical axes (x right, y down, z forward). pybullet wants OpenGL
matrices (camera looking down -z, y up, column-major); `gl_view` and `gl_projection` build them from the
above, so one model serves rendering and back-projection.

Depth. pybullet returns the OpenGL depth buffer b in [0, 1]; the distance along the optical axis is
z = far * near / (far - (far - near) * b) (inverting the perspective divide of the projection matrix);
b = 1 (far plane) means no surface. A pixel (u, v) at depth z is the point ((u - cx) z / fx,
(v - cy) z / fy, z) in the camera frame.

Rendering uses a DIRECT client of its own with exact visual shapes: the World's collision boxes are
grown by pybullet's 1 mm margin, and pybullet draws collision-only primitives but not collision-only
convex meshes, so its collision bodies cannot be rendered faithfully. Robot pixels are found with the
segmentation mask (the body id of each pixel) and removed from the cloud; their rays still show the
space in front of the robot free.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from samp.scene.model import Box, Cylinder, MeshObstacle, Scene, Sphere
from samp.sim.scan import DepthView, Scan
from samp.console import import_pybullet

pb = import_pybullet()  # without its build-time banner

__all__ = ["Camera", "CameraSet", "DepthImage", "Renderer", "back_project", "camera_set", "linear_depth",
           "load_camera_set", "robot_volume"]

GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # optical axes (x right, y down, z fwd) -> OpenGL (y up, z back)
MAX_SIDE = 8192  # pixels per side of a camera image: far above any depth sensor, far below what pybullet survives


@dataclass
class Camera:
    """One depth camera. Lengths in metres, angles in degrees, intrinsics in pixels.

    Give either `fov` or `fx` (`fy` defaults to fx, cx/cy to the image centre), and either `eye` and
    `target` (with `up`) or `pose` (4x4 camera -> base, optical axes). Noise: Gaussian `depth_noise`
    (standard deviation, metres, on the depth of every pixel) and a `dropout` fraction of pixels that
    return nothing.
    """

    name: str
    width: int
    height: int
    fov: float | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    near: float = 0.1
    far: float = 5.0
    eye: list[float] | None = None
    target: list[float] | None = None
    up: list[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])
    pose: list[list[float]] | None = None
    depth_noise: float = 0.0
    dropout: float = 0.0

    def __post_init__(self):
        where = f"camera {self.name!r}"
        if not (isinstance(self.width, int) and isinstance(self.height, int) and self.width >= 1 and self.height >= 1):
            raise ValueError(f"{where}: width and height must be positive integers (pixels), "
                             f"got {self.width}, {self.height}")
        if max(self.width, self.height) > MAX_SIDE:  # before pybullet, which crashes on a huge image
            raise ValueError(f"{where}: {self.width} x {self.height} pixels is larger than the {MAX_SIDE} pixels a "
                             f"side allowed; give width and height <= {MAX_SIDE}")
        if (self.fov is None) == (self.fx is None):
            both = "both" if self.fov is not None else "neither"
            raise ValueError(f"{where}: give either fov (vertical, degrees) or fx (pixels), not {both}")
        if self.fov is not None and not 0 < self.fov < 180:
            raise ValueError(f"{where}: fov must be in (0, 180) degrees, got {self.fov}")
        if not 0 < self.near < self.far:
            raise ValueError(f"{where}: need 0 < near < far (metres), got near {self.near}, far {self.far}")
        if (self.pose is None) == (self.eye is None or self.target is None):
            raise ValueError(f"{where}: give either eye and target (with up) or a 4x4 pose, not both or neither")
        if not (self.depth_noise >= 0 and 0 <= self.dropout < 1):
            raise ValueError(f"{where}: depth_noise must be >= 0 metres and dropout in [0, 1), got "
                             f"{self.depth_noise}, {self.dropout}")
        self.pose_matrix()  # validates the pose

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels."""
        fy = self.height / 2 / np.tan(np.radians(self.fov) / 2) if self.fov is not None else (self.fy or self.fx)
        fx = fy if self.fov is not None else self.fx
        cx = (self.width - 1) / 2 if self.cx is None else self.cx
        cy = (self.height - 1) / 2 if self.cy is None else self.cy
        return float(fx), float(fy), float(cx), float(cy)

    def pose_matrix(self) -> np.ndarray:
        """(4, 4) camera -> base transform, optical axes (x right, y down, z forward)."""
        if self.pose is not None:
            T = np.asarray(self.pose, dtype=np.float64)
            if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]) or \
                    not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
                raise ValueError(f"camera {self.name!r}: pose must be a 4x4 rigid transform, got {T.tolist()}")
            return T
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (self.eye, self.target, self.up))
        forward = target - eye
        right = np.cross(forward, up)
        if np.linalg.norm(forward) < 1e-9 or np.linalg.norm(right) < 1e-9 * np.linalg.norm(forward):
            raise ValueError(f"camera {self.name!r}: eye and target must differ and up must not be parallel to "
                             f"the view direction (eye {self.eye}, target {self.target}, up {self.up})")
        forward, right = forward / np.linalg.norm(forward), right / np.linalg.norm(right)
        T = np.eye(4)
        T[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)  # columns: x, y (down), z
        T[:3, 3] = eye
        return T

    def gl_view(self) -> np.ndarray:
        """(4, 4) OpenGL view matrix: base -> camera with y up and z backwards."""
        return np.linalg.inv(self.pose_matrix() @ GL_FROM_CV)

    def gl_projection(self) -> np.ndarray:
        """(4, 4) OpenGL projection matrix of the pinhole intrinsics, for pybullet's TinyRenderer.

        TinyRenderer shades pixel (u, v) (row v from the top) with the scene at normalised device
        coordinates (2 u / W - 1, 1 - 2 (v + 1) / H), a corner of the pixel rather than its centre
        (measured: oblique planes back-project exactly, to 2e-5 m, only with this offset; half a pixel
        off they are 1-4 cm out at 2 m). So the principal point is shifted to put those samples on the
        pinhole model's pixel centres."""
        fx, fy, cx, cy = self.intrinsics
        W, H, n, f = self.width, self.height, self.near, self.far
        P = np.zeros((4, 4))
        P[0, 0], P[0, 2] = 2 * fx / W, 1 - 2 * cx / W
        P[1, 1], P[1, 2] = 2 * fy / H, 2 * (cy + 1) / H - 1
        P[2, 2], P[2, 3], P[3, 2] = -(f + n) / (f - n), -2 * f * n / (f - n), -1.0
        return P


@dataclass
class CameraSet:
    """Named cameras and the seed of their noise."""

    name: str
    cameras: list[Camera]
    seed: int = 0


def camera_set(name: str, cameras: Sequence[dict], common: dict | None = None, seed: int = 0) -> CameraSet:
    """A `CameraSet` from plain data: each camera's keys over the `common` ones (the YAML form)."""
    valid = list(Camera.__dataclass_fields__)
    built = []
    for i, c in enumerate(cameras or []):
        merged = {**(common or {}), **dict(c)}
        merged.setdefault("name", f"camera{i}")
        unknown = sorted(set(merged) - set(valid))
        if unknown:
            raise ValueError(f"camera set {name!r}, camera {merged['name']!r}: unknown keys {unknown}; valid: {valid}")
        built.append(Camera(**merged))
    if not built:
        raise ValueError(f"camera set {name!r} has no cameras; list them under `cameras:`")
    return CameraSet(name, built, int(seed))


def load_camera_set(ref: "str | Path | dict | CameraSet") -> CameraSet:
    """A camera set: itself, a mapping (the YAML form), a name in `conf/camera/`, or a YAML path."""
    if isinstance(ref, CameraSet):
        return ref
    if isinstance(ref, dict):
        data = dict(ref)
    else:
        from omegaconf import OmegaConf

        from samp.paths import conf_dir

        folder = conf_dir() / "camera"
        path = Path(ref) if str(ref).endswith((".yaml", ".yml")) else folder / f"{ref}.yaml"
        if not path.is_file():
            names = sorted(p.stem for p in folder.glob("*.yaml"))
            raise FileNotFoundError(f"no camera set {str(ref)!r}: {path} does not exist; give a YAML path or one of {names}")
        from samp.yaml_files import load_config  # aliases and size bounded (a user's file)

        data = OmegaConf.to_container(load_config(path, "camera set"), resolve=True)
        data.setdefault("name", path.stem)
    data.pop("_target_", None)
    unknown = sorted(set(data) - {"name", "cameras", "common", "seed"})
    if unknown:
        raise ValueError(f"camera set {data.get('name')!r}: unknown keys {unknown}; valid: name, cameras, common, seed")
    return camera_set(**data)


def linear_depth(buffer, near: float, far: float) -> np.ndarray:
    """OpenGL depth buffer values in [0, 1] (...) -> depth along the optical axis in metres (...)."""
    b = np.asarray(buffer, dtype=np.float64)
    return far * near / (far - (far - near) * b)


def back_project(depth: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) depths along the optical axis -> (H, W, 3) points in the base frame."""
    fx, fy, cx, cy = camera.intrinsics
    v, u = np.mgrid[0:depth.shape[0], 0:depth.shape[1]]
    local = np.stack([(u - cx) * depth / fx, (v - cy) * depth / fy, depth], axis=-1)  # (H, W, 3) camera frame
    T = camera.pose_matrix()
    return local @ T[:3, :3].T + T[:3, 3]


@dataclass
class DepthImage:
    """One rendered image. depth (H, W) metres along the optical axis (NaN: dropped pixel, exactly `far`:
    no surface); robot (H, W) bool: the pixel shows the robot."""

    camera: Camera
    depth: np.ndarray
    robot: np.ndarray

    def scan(self) -> Scan:
        """The `Scan`: obstacle pixels as hits; no-return and robot pixels as free rays; dropped pixels
        nothing."""
        points = back_project(np.nan_to_num(self.depth, nan=self.camera.far), self.camera).reshape(-1, 3)
        valid = ~np.isnan(self.depth).ravel()
        miss = (self.depth >= self.camera.far).ravel()
        robot = self.robot.ravel()
        pose = self.camera.pose_matrix()
        return Scan(points[valid & ~miss & ~robot], origin=pose[:3, 3], free_ends=points[valid & (miss | robot)],
                    name=self.camera.name, view=DepthView(self.depth, self.camera.intrinsics, pose))


def _visual_shapes(o, client: int) -> list[int]:
    """Exact visual shapes of one obstacle, in its own frame."""
    from samp.scene.sdf import obstacle_parts

    kw = dict(physicsClientId=client)
    if isinstance(o, Box):
        return [pb.createVisualShape(pb.GEOM_BOX, halfExtents=(np.asarray(o.size) / 2).tolist(), **kw)]
    if isinstance(o, Cylinder):
        return [pb.createVisualShape(pb.GEOM_CYLINDER, radius=o.radius, length=o.height, **kw)]
    if isinstance(o, Sphere):
        return [pb.createVisualShape(pb.GEOM_SPHERE, radius=o.radius, **kw)]
    if isinstance(o, MeshObstacle):
        return [_mesh_visual(part, client) for part in obstacle_parts(o)]
    raise TypeError(f"unknown obstacle type {type(o).__name__}; expected Box, Cylinder, Sphere or MeshObstacle")


def _mesh_visual(mesh, client: int) -> int:
    return pb.createVisualShape(pb.GEOM_MESH, vertices=mesh.vertices.tolist(), indices=mesh.faces.ravel().tolist(),
                                physicsClientId=client)


def _link_poses(robot, q: np.ndarray) -> np.ndarray:
    """q (n,) -> (L, 4, 4) float64 poses of `robot.link_names`."""
    with torch.no_grad():
        fk = robot.fk(torch.as_tensor(np.asarray(q)[None], dtype=robot.dtype, device=robot.device))
        return torch.stack([fk[name][0] for name in robot.link_names]).double().cpu().numpy()


class Renderer:
    """A scene and a robot drawn with exact visual shapes in a pybullet DIRECT client of its own."""

    def __init__(self, robot, scene: Scene):
        self.robot, self.scene = robot, scene
        self.client: int | None = pb.connect(pb.DIRECT)
        kw = dict(physicsClientId=self.client)
        for o in scene.all_obstacles:
            for shape in _visual_shapes(o, self.client):
                if shape < 0:
                    raise RuntimeError(f"pybullet could not build a visual shape for obstacle {o.name!r} ({o.kind})")
                pb.createMultiBody(0, -1, shape, basePosition=o.pose.position, baseOrientation=o.pose.quaternion, **kw)
        self._parts = [(li, pb.createMultiBody(0, -1, _mesh_visual(part, self.client), **kw))
                       for li, name in enumerate(robot.link_names) for part in robot.geometry[name].parts]
        self.robot_bodies = np.array([body for _, body in self._parts])

    def close(self) -> None:
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None

    def pose_robot(self, q) -> None:
        """Place the robot's parts at configuration q (n,) radians."""
        from scipy.spatial.transform import Rotation

        T = _link_poses(self.robot, q)
        quat = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # (L, 4) x, y, z, w
        for li, body in self._parts:
            pb.resetBasePositionAndOrientation(body, T[li, :3, 3].tolist(), quat[li].tolist(), physicsClientId=self.client)

    def render(self, camera: Camera, rng: np.random.Generator | None = None) -> DepthImage:
        """One depth image at the current robot pose, with the camera's noise drawn from `rng`."""
        if self.client is None:
            raise RuntimeError("this Renderer is closed")
        _, _, _, buffer, seg = pb.getCameraImage(
            camera.width, camera.height, camera.gl_view().T.ravel().tolist(), camera.gl_projection().T.ravel().tolist(),
            renderer=pb.ER_TINY_RENDERER, physicsClientId=self.client)
        shape = (camera.height, camera.width)
        seg = np.reshape(seg, shape)
        hit = seg >= 0  # -1: no body (the buffer then reads 1 - 2^-24, not exactly the far plane)
        depth = np.where(hit, linear_depth(np.reshape(buffer, shape), camera.near, camera.far), camera.far)
        robot = np.isin(seg, self.robot_bodies)
        if rng is not None and (camera.depth_noise > 0 or camera.dropout > 0):
            depth = np.where(hit, depth + rng.normal(0.0, camera.depth_noise, shape), depth)
            depth[rng.random(shape) < camera.dropout] = np.nan
        return DepthImage(camera, depth, robot)

    def capture(self, cameras: CameraSet, q, seed: int | None = None) -> list[DepthImage]:
        """Every camera's image with the robot at q (n,); noise seeded by `seed` (default the set's)."""
        self.pose_robot(q)
        base = cameras.seed if seed is None else seed
        return [self.render(c, np.random.default_rng([base, i])) for i, c in enumerate(cameras.cameras)]


def robot_volume(robot, q, margin: float) -> Callable[[np.ndarray], np.ndarray]:
    """A test of the space the robot fills at q (n,): (N, 3) base-frame points -> (N,) bool, True within
    `margin` metres of a link's convex parts (a face-plane test, so slightly more near corners)."""
    T = _link_poses(robot, q)
    geometry = [robot.geometry[name] for name in robot.link_names]
    boxes = []
    for Tl, g in zip(T, geometry):
        world = g.mesh.vertices @ Tl[:3, :3].T + Tl[:3, 3]
        boxes.append((world.min(axis=0) - margin, world.max(axis=0) + margin))

    def inside(points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=np.float64)
        out = np.zeros(len(points), dtype=bool)
        for Tl, g, (lo, hi) in zip(T, geometry, boxes):
            near = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1) & ~out)
            if len(near):
                local = (points[near] - Tl[:3, 3]) @ Tl[:3, :3]
                out[near[g.inside_depth(local) < margin]] = True
        return out

    return inside

