"""Scenes from files: a user's own cell, given as data rather than drawn by a generator.

Two formats (docs/robots-and-scenes.md, "Scenes from files"):

* **samp's scene file**, JSON or YAML: what `Scene.to_dict` writes (`examples/scene_and_grid.py` saves one).
  `obstacles` lists boxes, cylinders, spheres and meshes with poses in the robot's base frame; `target`
  (optional) is the object the "target" goals approach; `bounds` and `name` are optional (the default
  workspace, the file's stem). A mesh's `path` may be relative to the scene file.
* **a URDF of the cell**: every link's `<collision>` elements become obstacles, posed through the joints
  from the root link, whose frame is the robot's base frame. All joints must be fixed (a cell does not
  move). A link named `target` becomes the scene's target.

A scene's identity is `Scene.content_hash()`: its geometry and its mesh files' contents, not its name or
where the files lie, exactly as for generated scenes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from samp.scene.model import DEFAULT_BOUNDS, Box, Cylinder, MeshObstacle, Pose, Scene, Sphere
from samp.yaml_files import YamlFileError

__all__ = ["SCENE_FILE_SUFFIXES", "load_scene_file", "resolve_scene_file"]

SCENE_FILE_SUFFIXES = (".json", ".yaml", ".yml", ".urdf")
TARGET_LINK = "target"
MAX_SCENE_FILE_BYTES = 64 << 20  # a scene file is a description, not data: larger is refused before reading


def resolve_scene_file(ref: str) -> Path:
    """A scene file reference -> its path: absolute, `pybullet_data://...`, or relative to the config folders
    (`conf_dir()`, the user's folders of SAMP_CONFIG_PATH first), then to the project folder."""
    from samp.paths import PYBULLET_DATA_SCHEME, conf_dir, project_dir, resolve_asset

    if ref.startswith(PYBULLET_DATA_SCHEME) or Path(ref).expanduser().is_absolute():
        return resolve_asset(ref)
    tried = [conf_dir() / ref, project_dir() / ref]
    for path in tried:
        if path.is_file():
            return path.resolve()
    raise FileNotFoundError(f"scene file {ref!r} not found; looked for {' and '.join(map(str, tried))}. Give an "
                            "absolute path, or put the file in a folder of SAMP_CONFIG_PATH or the project folder")


def load_scene_file(path: str | Path, name: str | None = None) -> Scene:
    """The scene described by a scene file (JSON/YAML) or a cell URDF; ValueError naming the file and what
    is wrong with it."""
    path = Path(path)
    if path.suffix.lower() not in SCENE_FILE_SUFFIXES:
        raise ValueError(f"scene file {path}: unknown format {path.suffix!r}; expected one of {SCENE_FILE_SUFFIXES}")
    if not path.is_file():
        raise FileNotFoundError(f"scene file {path} does not exist")
    if path.stat().st_size > MAX_SCENE_FILE_BYTES:
        raise ValueError(f"scene file {path} holds {path.stat().st_size} bytes, more than the {MAX_SCENE_FILE_BYTES} "
                         "a scene description may have; keep meshes in their own files and name them")
    name = name or path.stem
    try:
        if path.suffix.lower() == ".urdf":
            scene = _from_urdf(path, name)
        else:
            scene = _from_description(path, name)
    except (KeyError, TypeError) as err:
        raise ValueError(f"scene file {path}: {type(err).__name__} {err}; see docs/robots-and-scenes.md for the "
                         "format") from None
    except YamlFileError:  # names the scene file already
        raise
    except ValueError as err:
        raise ValueError(f"scene file {path}: {err}") from None
    return scene


def _from_description(path: Path, name: str) -> Scene:
    from samp.yaml_files import load_yaml

    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text())
        except RecursionError:  # the C scanner stops at Python's recursion limit, not with a ValueError
            raise ValueError("its JSON nests deeper than Python's recursion limit; a scene is a flat list of "
                             "obstacles") from None
    else:  # aliases, nesting and size bounded (an alias bomb would otherwise never finish loading)
        data = load_yaml(path, "scene file", max_bytes=MAX_SCENE_FILE_BYTES)
    if not isinstance(data, dict):
        raise ValueError(f"expected a mapping with `obstacles` (and optionally `target`, `bounds`, `name`), got "
                         f"{type(data).__name__}")
    unknown = sorted(set(data) - {"name", "obstacles", "target", "bounds", "meta"})
    if unknown:
        raise ValueError(f"unknown keys {unknown}; valid: name, obstacles, target, bounds, meta")

    def absolute(o: dict) -> dict:  # mesh paths relative to the scene file
        if isinstance(o, dict) and o.get("kind") == "mesh" and "path" in o:
            ref = str(o["path"])
            if "://" not in ref and not Path(ref).expanduser().is_absolute():
                o = {**o, "path": str((path.parent / ref).resolve())}
        return o

    described = {"name": data.get("name") or name, "obstacles": [absolute(o) for o in data.get("obstacles") or []],
                 "target": None if data.get("target") is None else absolute(data["target"]),
                 "bounds": data.get("bounds") or DEFAULT_BOUNDS,
                 "meta": {**(data.get("meta") or {}), "source": "file", "file": path.name}}
    scene = Scene.from_dict(described)
    for o in scene.all_obstacles:
        if isinstance(o, MeshObstacle):
            o.resolved_path()  # a missing mesh is an error now, not at the first distance query
    return scene


def _from_urdf(path: Path, name: str) -> Scene:
    from scipy.spatial.transform import Rotation

    from samp.robot.urdf import parse_urdf

    model = parse_urdf(path)
    moving = model.movable_joints
    if moving:
        raise ValueError(f"a cell URDF must have fixed joints only; {moving} move. Describe the arm as a robot "
                         "(python -m samp.robot add), the cell as a scene")
    world = {model.root: np.eye(4)}  # link -> (4, 4) pose in the root (= robot base) frame
    pending = list(model.joints.values())
    while pending:
        ready = [j for j in pending if j.parent in world]
        if not ready:
            raise ValueError(f"joints {[j.name for j in pending]} do not hang from the root link {model.root!r}")
        for j in ready:
            world[j.child] = world[j.parent] @ j.origin
            pending.remove(j)
    obstacles, target = [], None
    for link in model.links:
        for k, c in enumerate(model.collisions.get(link, [])):
            pose_m = world[link] @ c.origin
            pose = Pose(tuple(pose_m[:3, 3]), tuple(Rotation.from_matrix(pose_m[:3, :3]).as_quat()))
            label = link if len(model.collisions[link]) == 1 else f"{link}_{k}"
            obstacle = _collision_obstacle(label, c, pose)
            if link == TARGET_LINK:
                if target is not None:
                    raise ValueError(f"the {TARGET_LINK!r} link must have one <collision>, it has several")
                target = obstacle
            else:
                obstacles.append(obstacle)
    if not obstacles and target is None:
        raise ValueError("no link has a <collision> element: the cell would be empty")
    return Scene(name=name, obstacles=tuple(obstacles), target=target, bounds=DEFAULT_BOUNDS,
                 meta={"source": "urdf", "file": path.name})


def _collision_obstacle(label: str, c, pose: Pose):
    if c.kind == "box":
        return Box(label, tuple(c.size), pose)
    if c.kind == "cylinder":
        return Cylinder(label, float(c.size[0]), float(c.size[1]), pose)
    if c.kind == "sphere":
        return Sphere(label, float(c.size[0]), pose)
    scale = np.asarray(c.scale, dtype=float)
    if not np.allclose(scale, scale[0]):
        raise ValueError(f"link {label!r}: mesh scale {scale.tolist()} is not uniform; samp's meshes take one "
                         "scale factor (rescale the mesh file instead)")
    return MeshObstacle(label, str(c.mesh_path), float(scale[0]), pose)
