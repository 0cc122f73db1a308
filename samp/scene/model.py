"""The scene model: obstacle primitives and meshes with poses, a target object, workspace bounds.

Poses are (position (3,), quaternion (x, y, z, w)) in the robot base frame, metres. Sizes are full
extents (box), radius and height along the local z axis (cylinder), radius (sphere).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import numpy as np

from samp.paths import resolve_asset

__all__ = ["DEFAULT_BOUNDS", "Box", "Cylinder", "MeshObstacle", "Obstacle", "Pose", "Scene", "Sphere", "check_bounds"]

# docs/design.md section 4: x, y in [-1, 1], z in [0.05, 1.25] m, as rows (min, max).
DEFAULT_BOUNDS = ((-1.0, -1.0, 0.05), (1.0, 1.0, 1.25))


def check_bounds(bounds) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Validate workspace bounds ((xmin, ymin, zmin), (xmax, ymax, zmax)) and return them as tuples."""
    arr = np.asarray(bounds, dtype=np.float64)
    if arr.shape != (2, 3) or not np.all(np.isfinite(arr)):
        raise ValueError(f"bounds must be ((xmin, ymin, zmin), (xmax, ymax, zmax)), got {bounds!r}")
    if np.any(arr[0] >= arr[1]):
        raise ValueError(f"bounds need min < max on every axis, got min {arr[0].tolist()} and max {arr[1].tolist()}")
    return tuple(map(float, arr[0])), tuple(map(float, arr[1]))


@dataclass(frozen=True)
class Pose:
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)  # x, y, z, w

    def __post_init__(self):
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        object.__setattr__(self, "quaternion", tuple(float(v) for v in self.quaternion))
        if len(self.position) != 3 or len(self.quaternion) != 4:
            raise ValueError(f"a pose needs 3 position and 4 quaternion values, got {self.position}, {self.quaternion}")
        norm = float(np.linalg.norm(self.quaternion))
        if abs(norm - 1.0) > 1e-6:
            raise ValueError(f"quaternion {self.quaternion} has norm {norm:.6f}; it must be a unit quaternion (x, y, z, w)")

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous transform, object frame -> base frame."""
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(self.quaternion).as_matrix()
        T[:3, 3] = self.position
        return T

    @staticmethod
    def from_xyz_yaw(x: float, y: float, z: float, yaw: float = 0.0) -> "Pose":
        return Pose((x, y, z), (0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2))))


def _positive(kind: str, name: str, **values) -> None:
    for key, v in values.items():
        arr = np.atleast_1d(np.asarray(v, dtype=np.float64))
        if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            raise ValueError(f"{kind} {name!r}: {key} must be positive, got {v}")


@dataclass(frozen=True)
class Box:
    name: str
    size: tuple[float, float, float]  # full extents along local x, y, z
    pose: Pose = Pose()
    kind = "box"

    def __post_init__(self):
        object.__setattr__(self, "size", tuple(float(v) for v in self.size))
        if len(self.size) != 3:
            raise ValueError(f"box {self.name!r}: size needs 3 values, got {self.size}")
        _positive("box", self.name, size=self.size)


@dataclass(frozen=True)
class Cylinder:
    name: str
    radius: float
    height: float  # along local z
    pose: Pose = Pose()
    kind = "cylinder"

    def __post_init__(self):
        _positive("cylinder", self.name, radius=self.radius, height=self.height)


@dataclass(frozen=True)
class Sphere:
    name: str
    radius: float
    pose: Pose = Pose()
    kind = "sphere"

    def __post_init__(self):
        _positive("sphere", self.name, radius=self.radius)


@dataclass(frozen=True)
class MeshObstacle:
    """Any trimesh-readable file. Signed distance needs a closed mesh: an open one is refused unless
    `convex_hull` is set, which replaces it by its convex hull (for the SDF and the simulator alike)."""

    name: str
    path: str  # pybullet_data://..., or a file path
    scale: float = 1.0
    pose: Pose = Pose()
    convex_hull: bool = False
    kind = "mesh"

    def __post_init__(self):
        _positive("mesh", self.name, scale=self.scale)

    def resolved_path(self) -> Path:
        return resolve_asset(self.path)

    def file_hash(self) -> str:
        from samp.paths import file_sha256

        return file_sha256(self.resolved_path())


Obstacle = Union[Box, Cylinder, Sphere, MeshObstacle]
_KINDS = {"box": Box, "cylinder": Cylinder, "sphere": Sphere, "mesh": MeshObstacle}


def _obstacle_to_dict(o: Obstacle) -> dict[str, Any]:
    d = {"kind": o.kind, **{k: getattr(o, k) for k in o.__dataclass_fields__ if k != "pose"}}
    d["pose"] = {"position": list(o.pose.position), "quaternion": list(o.pose.quaternion)}
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def _obstacle_from_dict(d: dict[str, Any]) -> Obstacle:
    d = dict(d)
    kind = d.pop("kind", None)
    if kind not in _KINDS:
        raise ValueError(f"unknown obstacle kind {kind!r}; expected one of {sorted(_KINDS)}")
    pose = d.pop("pose", None) or {}
    cls = _KINDS[kind]
    unknown = set(d) - set(cls.__dataclass_fields__)
    if unknown:
        raise ValueError(f"{kind} obstacle has unknown fields {sorted(unknown)}; valid: {sorted(cls.__dataclass_fields__)}")
    return cls(**d, pose=Pose(**pose))


@dataclass(frozen=True)
class Scene:
    """Obstacles, an optional target object (also an obstacle for collision), and workspace bounds."""

    name: str
    obstacles: tuple[Obstacle, ...] = ()
    target: Obstacle | None = None
    bounds: tuple[tuple[float, ...], tuple[float, ...]] = DEFAULT_BOUNDS
    meta: dict = field(default_factory=dict, compare=False)  # generator name, seed, parameters

    def __post_init__(self):
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        object.__setattr__(self, "bounds", check_bounds(self.bounds))
        names = [o.name for o in self.all_obstacles]
        if len(set(names)) != len(names):
            raise ValueError(f"scene {self.name!r}: obstacle names must be unique, got {names}")

    @property
    def all_obstacles(self) -> tuple[Obstacle, ...]:
        """Obstacles plus the target: everything the robot must not touch."""
        return self.obstacles + ((self.target,) if self.target is not None else ())

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "obstacles": [_obstacle_to_dict(o) for o in self.obstacles],
                "target": None if self.target is None else _obstacle_to_dict(self.target),
                "bounds": [list(self.bounds[0]), list(self.bounds[1])], "meta": dict(self.meta)}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "Scene":
        return Scene(name=d["name"], obstacles=tuple(_obstacle_from_dict(o) for o in d.get("obstacles", [])),
                     target=None if d.get("target") is None else _obstacle_from_dict(d["target"]),
                     bounds=d.get("bounds", DEFAULT_BOUNDS), meta=dict(d.get("meta", {})))

    def content_hash(self) -> str:
        """sha256 over the geometry (not the name or meta) and the contents of any mesh files (not their
        paths: the same cell read from another folder or machine is the same scene)."""
        geometry = {k: v for k, v in self.to_dict().items() if k not in ("name", "meta")}
        for o in [*geometry["obstacles"], geometry["target"]]:
            if o is not None and o["kind"] == "mesh":
                o.pop("path")
        h = hashlib.sha256(json.dumps(geometry, sort_keys=True).encode())
        for o in self.all_obstacles:
            if isinstance(o, MeshObstacle):
                h.update(o.file_hash().encode())
        return h.hexdigest()

    # Geometry queries live in samp.scene.sdf / samp.scene.grid; these are the public entry points.
    def sdf(self, points):
        """(..., 3) base-frame points (torch or numpy) -> (...) exact signed distance, metres (negative inside)."""
        from samp.scene.sdf import scene_sdf

        return scene_sdf(self, points)

    def anchor_grid(self, n_e: int, bounds=None, cache: bool = True):
        """(n_e, n_e, n_e) float32 tensor of exact signed distances at the anchors, indexed (x, y, z)."""
        from samp.scene.grid import anchor_grid

        return anchor_grid(self, n_e, bounds, cache=cache)
