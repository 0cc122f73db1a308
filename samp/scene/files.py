"""Scenes from files: a user's own cell, given as data rather than drawn by a generator.

Two formats (docs/robots-and-scenes.md, "Scenes from files"):

* **samp's scene file**, JSON or YAML: what `Scene.to_dict` writes (`examples/scene_and_grid.py` saves one).
  `obstacles` lists boxes, cylinders, spheres and meshes with poses in the robot's base frame; `target`
  (optional) is the object the "target" goals approach; `bounds` and `name` are optional (the default
  workspace, the file's stem). A mesh's `path` may be relative to the scene file.
* **a URDF of the cell**: every link's `<collision>` elements become obstacles, posed through the joints
  from the root link, whose frame is the robot's base frame. All joints must be fixed (a cell does not
  move). A link named `target` becomes the scene's target.

* **a cuRobo-style world** or **a problem set** (robometrics' layout of MotionBenchMaker's problems), YAML
  or JSON, told apart from samp's scene file by their top-level keys (`samp.scene.worlds`). A problem set
  holds many scenes: `FILE#TYPE/INDEX` names the scene of problem INDEX of TYPE, and `scene_refs` lists
  one reference per distinct scene. These layouts carry no bounds: the scene gets the default workspace.

A reference may also be a folder (its scene files, sorted by name) or a glob (`worlds/*.yaml`, sorted);
`scene_refs` expands either into one reference per scene.

A scene's identity is `Scene.content_hash()`: its geometry and its mesh files' contents, not its name or
where the files lie, exactly as for generated scenes.
"""

from __future__ import annotations

import glob
import json
import re
from functools import lru_cache
from pathlib import Path

import numpy as np

from samp.scene.model import DEFAULT_BOUNDS, Box, Cylinder, MeshObstacle, Pose, Scene, Sphere
from samp.scene.worlds import FileProblem, problem_groups, world_kind, world_obstacles
from samp.yaml_files import YamlFileError

__all__ = ["SCENE_FILE_SUFFIXES", "file_problems", "load_scene_file", "resolve_scene_file", "scene_refs",
           "split_ref"]

SCENE_FILE_SUFFIXES = (".json", ".yaml", ".yml", ".urdf")
TARGET_LINK = "target"
MAX_SCENE_FILE_BYTES = 64 << 20  # a scene file is a description, not data: larger is refused before reading
PART = re.compile(r"#([^#/]+/[0-9]+)$")  # `FILE#TYPE/INDEX`: one problem's scene in a problem set
GLOB_CHARS = set("*?[")


class SceneFileError(ValueError):
    """A scene file that cannot be parsed; the message names it."""


def split_ref(ref: str) -> tuple[str, str | None]:
    """`set.yaml#bookshelf/3` -> ("set.yaml", "bookshelf/3"); a reference without a part -> (ref, None)."""
    match = PART.search(str(ref))
    if match is None or Path(str(ref)).is_file():
        return str(ref), None
    return str(ref)[:match.start()], match.group(1)


def resolve_scene_file(ref: str) -> Path:
    """A scene file reference -> its path: absolute, `pybullet_data://...`, or relative to the config folders
    (`conf_dir()`, the user's folders of SAMP_CONFIG_PATH first), then to the project folder."""
    from samp.paths import PYBULLET_DATA_SCHEME, conf_dir, project_dir, resolve_asset

    ref, part = split_ref(ref)
    with_part = lambda p: p if part is None else Path(f"{p}#{part}")  # noqa: E731
    if ref.startswith(PYBULLET_DATA_SCHEME) or Path(ref).expanduser().is_absolute():
        return with_part(resolve_asset(ref))
    tried = [conf_dir() / ref, project_dir() / ref]
    for path in tried:
        if path.is_file():
            return with_part(path.resolve())
    raise FileNotFoundError(f"scene file {ref!r} not found; looked for {' and '.join(map(str, tried))}. Give an "
                            "absolute path, or put the file in a folder of SAMP_CONFIG_PATH or the project folder")


def scene_refs(ref: str) -> list[str]:
    """One reference per scene that `ref` stands for: a folder -> its scene files (not its subfolders),
    sorted by name; a glob -> its matches, sorted; a problem set -> `FILE#TYPE/INDEX` per distinct scene;
    a scene file -> [ref]. Relative references are looked up as `resolve_scene_file` does and stay relative
    (so a spec's hash does not depend on where the project lies). ValueError when nothing matches."""
    from samp.paths import conf_dir, project_dir

    ref = str(ref)
    if split_ref(ref)[1] is not None:
        return [ref]
    absolute = Path(ref).expanduser().is_absolute()
    bases = [Path("/")] if absolute else [conf_dir(), project_dir()]
    for base in bases:
        target = Path(ref).expanduser() if absolute else base / ref
        if GLOB_CHARS & set(ref):
            found = sorted(Path(p) for p in glob.glob(str(target)) if Path(p).suffix.lower() in SCENE_FILE_SUFFIXES
                           and Path(p).is_file())
            if not found:
                continue
        elif target.is_dir():
            found = sorted(p for p in target.iterdir() if p.suffix.lower() in SCENE_FILE_SUFFIXES and p.is_file())
        elif target.is_file():
            found = [target]
        else:
            continue
        if not found:
            raise ValueError(f"scene files {ref!r}: {target} holds no scene files ({', '.join(SCENE_FILE_SUFFIXES)})")
        if GLOB_CHARS & set(ref):
            shown = [str(p) if absolute else str(p.relative_to(base)) for p in found]
        else:
            shown = [ref] if target.is_file() else [str(Path(ref) / p.name) for p in found]
        try:
            return [r for path, shown_ref in zip(found, shown) for r in _problem_refs(path, shown_ref)]
        except (YamlFileError, SceneFileError):
            raise
        except ValueError as err:
            raise ValueError(f"scene file {ref}: {err}") from None
    if GLOB_CHARS & set(ref):
        raise ValueError(f"scene files {ref!r}: the pattern matches no file in {' or '.join(map(str, bases))}")
    return [ref]  # resolve_scene_file says where it looked


def _problem_refs(path: Path, ref: str) -> list[str]:
    """[ref], or `ref#TYPE/INDEX` per distinct scene when `path` holds a problem set."""
    if path.suffix.lower() == ".urdf" or world_kind(_parsed(path)) != "problems":
        return [ref]
    return [f"{ref}#{key}" for key in _groups(path)]


def load_scene_file(path: str | Path, name: str | None = None) -> Scene:
    """The scene described by a scene file (samp's JSON/YAML, a cuRobo-style world, one scene of a problem
    set as `FILE#TYPE/INDEX`) or a cell URDF; ValueError naming the file and what is wrong with it."""
    file, part = split_ref(str(path))
    path = _checked(Path(file))
    try:
        if path.suffix.lower() == ".urdf":
            scene = _from_urdf(path, name or path.stem)
        else:
            scene = _from_data(path, name, part)
    except (KeyError, TypeError) as err:
        raise ValueError(f"scene file {path}: {type(err).__name__} {err}; see docs/robots-and-scenes.md for the "
                         "format") from None
    except (YamlFileError, SceneFileError):  # name the scene file already
        raise
    except ValueError as err:
        raise ValueError(f"scene file {path}: {err}") from None
    return scene


def file_problems(path: str | Path) -> list[FileProblem]:
    """The problems a scene file gives for its scene: those of `FILE#TYPE/INDEX`'s scene in a problem set
    (every problem with the same obstacles), else none."""
    file, part = split_ref(str(path))
    path = _checked(Path(file))
    if path.suffix.lower() == ".urdf" or world_kind(_parsed(path)) != "problems":
        return []
    try:
        return list(_groups(path)[_group_key(path, part)][1])
    except (YamlFileError, SceneFileError):
        raise
    except ValueError as err:
        raise ValueError(f"scene file {path}: {err}") from None


def _checked(path: Path) -> Path:
    if path.suffix.lower() not in SCENE_FILE_SUFFIXES:
        raise ValueError(f"scene file {path}: unknown format {path.suffix!r}; expected one of {SCENE_FILE_SUFFIXES}")
    if not path.is_file():
        raise FileNotFoundError(f"scene file {path} does not exist")
    if path.stat().st_size > MAX_SCENE_FILE_BYTES:
        raise ValueError(f"scene file {path} holds {path.stat().st_size} bytes, more than the {MAX_SCENE_FILE_BYTES} "
                         "a scene description may have; keep meshes in their own files and name them")
    return path


def _parsed(path: Path):
    """The file's contents, parsed once per version of the file (a problem set is read for every scene)."""
    stat = path.stat()
    return _parse(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=8)
def _parse(path: str, mtime_ns: int, size: int):
    from samp.yaml_files import load_yaml

    path = Path(path)
    if path.suffix.lower() == ".json":
        try:
            return json.loads(path.read_text())
        except RecursionError:  # the C scanner stops at Python's recursion limit, not with a ValueError
            raise SceneFileError(f"scene file {path}: its JSON nests deeper than Python's recursion limit; a scene "
                                 "is a flat list of obstacles") from None
        except json.JSONDecodeError as err:
            raise SceneFileError(f"scene file {path} is not valid JSON: {err}") from None
    # aliases, nesting and size bounded (an alias bomb would otherwise never finish loading)
    return load_yaml(path, "scene file", max_bytes=MAX_SCENE_FILE_BYTES)


def _groups(path: Path) -> dict:
    stat = path.stat()
    return _problem_groups(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=8)
def _problem_groups(path: str, mtime_ns: int, size: int) -> dict:
    return problem_groups(_parse(path, mtime_ns, size), Path(path).parent)


def _group_key(path: Path, part: str | None) -> str:
    """The key of the scene that problem `part` ("TYPE/INDEX") of a problem set belongs to."""
    groups = _groups(path)
    if part is None:
        if len(groups) == 1:
            return next(iter(groups))
        raise ValueError(f"a problem set of {len(groups)} scenes; name one as FILE#TYPE/INDEX (e.g. "
                         f"{path.name}#{next(iter(groups))}), or list the file in a dataset spec, which takes each")
    for key, (_, problems) in groups.items():
        if any(p.where == part for p in problems):
            return key
    raise ValueError(f"no problem {part!r}; it holds {', '.join(sorted({k.split('/')[0] for k in groups}))} with "
                     f"{sum(len(p) for _, p in groups.values())} problems in all")


def _from_data(path: Path, name: str | None, part: str | None) -> Scene:
    data = _parsed(path)
    kind = world_kind(data)
    if part is not None and kind != "problems":
        raise ValueError(f"#{part} names a problem of a problem set, but the file holds "
                         f"{'a world' if kind == 'world' else 'one scene'}; drop the #{part}")
    if kind is None:
        return _from_description(path, data, name or path.stem)
    if kind == "world":
        obstacles, source = world_obstacles(data, path.parent), "world"
    else:  # named by its group, whichever of the group's problems named it
        part = _group_key(path, part)
        obstacles, source = _groups(path)[part][0], f"problem set {part}"
        name = name or f"{path.stem}_{part.replace('/', '_')}"
    return Scene(name=name or path.stem, obstacles=tuple(obstacles), bounds=DEFAULT_BOUNDS,
                 meta={"source": source, "file": path.name})


def _from_description(path: Path, data, name: str) -> Scene:
    if not isinstance(data, dict):
        raise ValueError(f"expected a mapping with `obstacles` (and optionally `target`, `bounds`, `name`), got "
                         f"{type(data).__name__}")
    unknown = sorted(set(data) - {"name", "obstacles", "target", "bounds", "meta"})
    if unknown:
        raise ValueError(f"unknown keys {unknown}; valid: name, obstacles, target, bounds, meta (samp's scene file), "
                         "or only cuboid, cylinder, sphere, capsule, mesh (a cuRobo-style world), or problem type -> "
                         "list of problems with obstacles, start and goal_ik (a problem set)")

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
