"""The world layout other motion-planning projects share, read as samp scenes (and their problems).

Two layouts, detected by their keys (`world_kind`):

* **a world**: a mapping whose keys are among `cuboid`, `cylinder`, `sphere`, `capsule` and `mesh` (cuRobo's
  `WorldConfig` layout). Each maps obstacle names to entries; every pose is `[x, y, z, qw, qx, qy, qz]` in
  the robot's base frame (scalar first, where samp's `Pose` puts it last).
* **a problem set**: a mapping of problem type -> list of problems, each a mapping with `obstacles` (a
  world, as above), `start` (a joint configuration) and `goal_ik` (joint configurations that reach the
  goal), optionally `goal_pose`, `collision_buffer_ik` and `world_frame` (the layout robometrics ships
  MotionBenchMaker's and MpiNets' problems in). Problems whose obstacles are identical share one scene.

How each entry becomes samp obstacles (docs/robots-and-scenes.md, "Scenes from files"):

| key | samp obstacle |
|---|---|
| cuboid: `dims`, `pose` | Box (full extents, as samp's) |
| cylinder: `radius`, `height`, `pose` | Cylinder (centred on its pose, axis local z, as samp's) |
| sphere: `radius`, `pose` or `position` | Sphere |
| capsule: `radius`, `base`, `tip`, `pose` | a Cylinder from `base` to `tip` and a Sphere at each end (exactly the capsule) |
| mesh: `file_path`, `scale`, `pose` | MeshObstacle (path relative to the file; one scale factor) |

`color`, `texture`, `texture_id` and `material` only style a viewer, and are read past. Any other key, a
quaternion whose norm is further than `QUATERNION_TOLERANCE` from 1, and a size that is not finite and
positive are refused, naming the entry; `samp.scene.files` adds the file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from samp.scene.model import Box, Cylinder, MeshObstacle, Pose, Sphere

__all__ = ["FileProblem", "PROBLEM_KEYS", "QUATERNION_TOLERANCE", "WORLD_KEYS", "problem_groups", "world_kind",
           "world_obstacles"]

WORLD_KEYS = ("cuboid", "cylinder", "sphere", "capsule", "mesh")
STYLE_KEYS = {"color", "texture", "texture_id", "material"}  # a viewer's business, not geometry
ENTRY_KEYS = {"cuboid": {"dims", "pose"}, "cylinder": {"radius", "height", "pose"},
              "sphere": {"radius", "pose", "position"}, "capsule": {"radius", "base", "tip", "pose"},
              "mesh": {"file_path", "scale", "pose"}}
PROBLEM_KEYS = {"obstacles", "start", "goal_ik", "goal_pose", "collision_buffer_ik", "world_frame"}
# Files written from float32 carry quaternions whose norm is off by ~1e-7; a norm further from 1 than this
# is a typo or a different convention, not rounding, and is refused rather than quietly renormalised.
QUATERNION_TOLERANCE = 1e-3
SHORTEST_CAPSULE = 1e-9  # metres; a capsule with base and tip closer than this is a sphere


@dataclass(frozen=True)
class FileProblem:
    """One problem a file gives: a start and the goal configurations that solve it (radians)."""

    start: np.ndarray  # (n,)
    goals: np.ndarray  # (m, n), m >= 1
    where: str  # "TYPE/INDEX" in its file, for messages and records


def world_kind(data) -> str | None:
    """"world", "problems" or None (not this module's layout) for a file's parsed contents."""
    if not isinstance(data, dict) or not data:
        return None
    if set(data) <= set(WORLD_KEYS):
        return "world"
    if all(isinstance(v, list) and v and all(isinstance(p, dict) and "obstacles" in p for p in v)
           for v in data.values()):
        return "problems"
    return None


def _numbers(value, count: int | None, what: str) -> np.ndarray:
    if value is None:
        raise ValueError(f"{what} is missing")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be numbers, got {value!r}") from None
    if arr.ndim != (0 if count is None else 1) or (count is not None and len(arr) != count):
        raise ValueError(f"{what} must be {'a number' if count is None else f'{count} numbers'}, got {value!r}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite, got {value!r}")
    return arr


def _size(value, count: int | None, what: str) -> np.ndarray:
    arr = _numbers(value, count, what)
    if np.any(arr <= 0):
        raise ValueError(f"{what} must be positive, got {value!r}")
    return arr


def _pose(value, what: str) -> Pose:
    """`[x, y, z, qw, qx, qy, qz]` -> Pose (quaternion x, y, z, w), renormalised within the tolerance."""
    arr = _numbers(value, 7, f"{what}: pose [x, y, z, qw, qx, qy, qz]")
    norm = float(np.linalg.norm(arr[3:]))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise ValueError(f"{what}: quaternion (qw, qx, qy, qz) {arr[3:].tolist()} has norm {norm:.6f}; a unit "
                         f"quaternion is needed (norm within {QUATERNION_TOLERANCE} of 1)")
    qw, qx, qy, qz = arr[3:] / norm
    return Pose(tuple(arr[:3]), (qx, qy, qz, qw))


def _axis_rotation(u: np.ndarray) -> np.ndarray:
    """(3, 3) rotation taking the z axis onto the unit vector u (a half turn about x when u is -z)."""
    from scipy.spatial.transform import Rotation

    c = float(u[2])
    if c > 1.0 - 1e-12:
        return np.eye(3)
    if c < -1.0 + 1e-12:
        return Rotation.from_rotvec([np.pi, 0.0, 0.0]).as_matrix()
    axis = np.cross([0.0, 0.0, 1.0], u)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.arccos(c)).as_matrix()


def _capsule(name: str, radius: float, base: np.ndarray, tip: np.ndarray, pose: Pose) -> list:
    """A capsule as a cylinder along its segment and a sphere at each end (their union is the capsule)."""
    from scipy.spatial.transform import Rotation

    T = pose.matrix()
    ends = T[:3, :3] @ np.stack([base, tip]).T + T[:3, 3:4]  # (3, 2) base-frame end points
    spheres = [Sphere(f"{name}_base", radius, Pose(tuple(ends[:, 0]))),
               Sphere(f"{name}_tip", radius, Pose(tuple(ends[:, 1])))]
    length = float(np.linalg.norm(tip - base))
    if length < SHORTEST_CAPSULE:
        return spheres[:1]
    R = T[:3, :3] @ _axis_rotation((tip - base) / length)
    centre = Pose(tuple(ends.mean(axis=1)), tuple(Rotation.from_matrix(R).as_quat()))
    shaft = Cylinder(f"{name}_shaft", radius, length, centre)
    return [shaft, *spheres]


def _entry(kind: str, name: str, entry, folder: Path) -> list:
    what = f"{kind} {name!r}"
    if not isinstance(entry, dict):
        raise ValueError(f"{what}: expected a mapping of its keys, got {type(entry).__name__}")
    unknown = sorted(set(entry) - ENTRY_KEYS[kind] - STYLE_KEYS)
    if unknown:
        raise ValueError(f"{what}: unknown keys {unknown}; valid: {sorted(ENTRY_KEYS[kind])} (and "
                         f"{sorted(STYLE_KEYS)}, read past)")
    if kind == "sphere":
        if ("pose" in entry) == ("position" in entry):
            raise ValueError(f"{what}: give its centre as `pose` or as `position`, exactly one of them")
        pose = (_pose(entry["pose"], what) if "pose" in entry else
                Pose(tuple(_numbers(entry["position"], 3, f"{what}: position"))))
        return [Sphere(name, float(_size(entry.get("radius"), None, f"{what}: radius")), pose)]
    if "pose" not in entry:
        raise ValueError(f"{what}: `pose` [x, y, z, qw, qx, qy, qz] is missing")
    pose = _pose(entry["pose"], what)
    if kind == "cuboid":
        return [Box(name, tuple(_size(entry.get("dims"), 3, f"{what}: dims")), pose)]
    if kind == "cylinder":
        return [Cylinder(name, float(_size(entry.get("radius"), None, f"{what}: radius")),
                         float(_size(entry.get("height"), None, f"{what}: height")), pose)]
    if kind == "capsule":
        return _capsule(name, float(_size(entry.get("radius"), None, f"{what}: radius")),
                        _numbers(entry.get("base"), 3, f"{what}: base"), _numbers(entry.get("tip"), 3, f"{what}: tip"),
                        pose)
    return [_mesh(name, entry, pose, folder, what)]


def _mesh(name: str, entry: dict, pose: Pose, folder: Path, what: str) -> MeshObstacle:
    ref = entry.get("file_path")
    if not isinstance(ref, str) or not ref:
        raise ValueError(f"{what}: `file_path` must name a mesh file, got {ref!r}")
    scale = _size(entry.get("scale", 1.0), None if np.ndim(entry.get("scale", 1.0)) == 0 else 3, f"{what}: scale")
    if not np.allclose(scale, np.ravel(scale)[0]):
        raise ValueError(f"{what}: scale {scale.tolist()} is not uniform; samp's meshes take one scale factor "
                         "(rescale the mesh file instead)")
    if "://" not in ref and not Path(ref).expanduser().is_absolute():
        ref = str((folder / ref).resolve())
    mesh = MeshObstacle(name, ref, float(np.ravel(scale)[0]), pose)
    mesh.resolved_path()  # a missing mesh is an error now, not at the first distance query
    return mesh


def world_obstacles(world, folder: Path, where: str = "") -> list:
    """A world mapping (module docstring) -> samp obstacles in file order. A name used under two keys
    (`cube0` as a cuboid and as a cylinder) is qualified by its key (`cylinder_cube0`); mesh paths are
    relative to `folder`. ValueError naming `where` and the entry otherwise."""
    prefix = f"{where}: " if where else ""
    if not isinstance(world, dict):
        raise ValueError(f"{prefix}obstacles must be a mapping of {', '.join(WORLD_KEYS)}, got {type(world).__name__}")
    unknown = sorted(set(world) - set(WORLD_KEYS))
    if unknown:
        raise ValueError(f"{prefix}unknown keys {unknown}; a world holds {', '.join(WORLD_KEYS)}")
    names = [str(n) for kind in WORLD_KEYS for n in (world.get(kind) or {})]
    obstacles = []
    for kind in WORLD_KEYS:
        entries = world.get(kind) or {}
        if not isinstance(entries, dict):
            raise ValueError(f"{prefix}{kind} must map obstacle names to entries, got {type(entries).__name__}")
        for name, entry in entries.items():
            label = str(name) if names.count(str(name)) == 1 else f"{kind}_{name}"
            try:
                obstacles += _entry(kind, label, entry, folder)
            except ValueError as err:
                raise ValueError(f"{prefix}{err}") from None
    return obstacles


def _problem(p: dict, where: str) -> FileProblem:
    unknown = sorted(set(p) - PROBLEM_KEYS)
    if unknown:
        raise ValueError(f"problem {where}: unknown keys {unknown}; valid: {sorted(PROBLEM_KEYS)}")
    for key in ("start", "goal_ik"):
        if key not in p:
            raise ValueError(f"problem {where}: `{key}` is missing")
    if not isinstance(p["start"], list) or not p["start"]:
        raise ValueError(f"problem {where}: start must be a joint configuration (a list of numbers), got "
                         f"{p['start']!r}")
    start = _numbers(p["start"], len(p["start"]), f"problem {where}: start")
    goals = p["goal_ik"]
    if not isinstance(goals, list) or not goals:
        raise ValueError(f"problem {where}: goal_ik must list at least one joint configuration, got {goals!r}")
    goals = np.stack([_numbers(g, len(start), f"problem {where}: goal_ik[{k}]") for k, g in enumerate(goals)])
    return FileProblem(start, goals, where)


def problem_groups(data: dict, folder: Path) -> dict[str, tuple[list, list[FileProblem]]]:
    """A problem set (module docstring) -> {"TYPE/INDEX": (obstacles, problems)}, one entry per distinct
    obstacle set, keyed by its first problem, in file order; the problems of that entry are every problem
    with those obstacles."""
    groups: dict[str, tuple[list, list[FileProblem]]] = {}
    first: dict[str, str] = {}  # the obstacles, as canonical JSON -> the key of its group
    for kind, problems in data.items():
        for i, p in enumerate(problems):
            where = f"{kind}/{i}"
            problem = _problem(p, where)
            same = json.dumps(p["obstacles"], sort_keys=True, default=str)
            if same not in first:
                first[same] = where
                groups[where] = (world_obstacles(p["obstacles"], folder, f"problem {where}"), [])
            groups[first[same]][1].append(problem)
    return groups
