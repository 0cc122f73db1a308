"""A small URDF reader: the joint tree, joint limits and collision geometry.

pytorch-kinematics has its own parser, but it rejects some valid files (the xArm's transmissions) and
warns about every tag it does not know, so it is handed a kinematics-only copy (`kinematic_xml`).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Collision", "Joint", "URDFModel", "parse_urdf", "origin_matrix", "rpy_matrix"]


def rpy_matrix(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw to a rotation matrix, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def _floats(text: str | None, default: tuple[float, ...]) -> np.ndarray:
    return np.array([float(v) for v in text.split()] if text else default, dtype=np.float64)


def origin_matrix(element: ET.Element | None) -> np.ndarray:
    """The 4x4 transform of an `<origin xyz rpy>` child of `element` (identity when absent)."""
    T = np.eye(4)
    origin = None if element is None else element.find("origin")
    if origin is not None:
        T[:3, :3] = rpy_matrix(_floats(origin.get("rpy"), (0.0, 0.0, 0.0)))
        T[:3, 3] = _floats(origin.get("xyz"), (0.0, 0.0, 0.0))
    return T


@dataclass
class Joint:
    name: str
    type: str  # revolute | continuous | prismatic | fixed | ...
    parent: str
    child: str
    origin: np.ndarray = field(default_factory=lambda: np.eye(4))  # parent link -> joint frame
    axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    lower: float | None = None
    upper: float | None = None


@dataclass
class Collision:
    """One `<collision>` element: its pose in the link frame and its geometry."""

    origin: np.ndarray  # (4, 4)
    kind: str  # mesh | box | cylinder | sphere
    mesh_path: Path | None = None
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    size: np.ndarray | None = None  # box (3,), cylinder (radius, length), sphere (radius,)


@dataclass
class URDFModel:
    path: Path
    name: str
    links: list[str]
    joints: dict[str, Joint]
    collisions: dict[str, list[Collision]]
    root: str
    kinematic_xml: str

    @property
    def movable_joints(self) -> list[str]:
        return [j.name for j in self.joints.values() if j.type != "fixed"]

    def parent_joint(self, link: str) -> Joint | None:
        return next((j for j in self.joints.values() if j.child == link), None)

    def asset_files(self) -> list[Path]:
        """The URDF and every collision mesh it uses, in a stable order."""
        meshes = {c.mesh_path for cs in self.collisions.values() for c in cs if c.mesh_path}
        return [self.path, *sorted(meshes)]


def _resolve_mesh(filename: str, urdf_dir: Path) -> Path:
    """Resolve `package://pkg/rest`, `file://...` or a relative path against the URDF's folder and,
    for `package://`, its parents (pybullet_data keeps the package folders beside the URDF)."""
    if filename.startswith("file://"):
        return Path(filename[len("file://"):])
    rel = filename[len("package://"):] if filename.startswith("package://") else filename
    if Path(rel).is_absolute():
        return Path(rel)
    for base in [urdf_dir, *urdf_dir.parents][:4]:
        candidate = base / rel
        if candidate.is_file():
            return candidate.resolve()
        # package://<pkg>/x may mean <urdf_dir>/x when the package is the URDF's own folder
        tail = Path(*Path(rel).parts[1:]) if len(Path(rel).parts) > 1 else None
        if tail is not None and (base / tail).is_file():
            return (base / tail).resolve()
    raise FileNotFoundError(f"mesh {filename!r} of {urdf_dir} was not found next to the URDF or its parents")


def _parse_collision(element: ET.Element, urdf_dir: Path) -> Collision:
    geometry = element.find("geometry")
    if geometry is None or len(geometry) == 0:
        raise ValueError("a <collision> element has no <geometry>")
    shape = geometry[0]
    origin = origin_matrix(element)
    if shape.tag == "mesh":
        return Collision(origin, "mesh", mesh_path=_resolve_mesh(shape.get("filename", ""), urdf_dir),
                         scale=_floats(shape.get("scale"), (1.0, 1.0, 1.0)))
    if shape.tag == "box":
        return Collision(origin, "box", size=_floats(shape.get("size"), ()))
    if shape.tag == "cylinder":
        return Collision(origin, "cylinder", size=np.array([float(shape.get("radius")), float(shape.get("length"))]))
    if shape.tag == "sphere":
        return Collision(origin, "sphere", size=np.array([float(shape.get("radius"))]))
    raise ValueError(f"unsupported collision geometry <{shape.tag}>; expected mesh, box, cylinder or sphere")


def parse_urdf(path: Path) -> URDFModel:
    """Read the link tree, joints and collision elements of the URDF at `path`."""
    tree = ET.parse(path)
    robot = tree.getroot()
    if robot.tag != "robot":
        raise ValueError(f"{path} is not a URDF: its root element is <{robot.tag}>, expected <robot>")
    links = [link.get("name") for link in robot.findall("link")]
    collisions = {
        link.get("name"): [_parse_collision(c, path.parent) for c in link.findall("collision")]
        for link in robot.findall("link")
    }
    joints = {}
    for j in robot.findall("joint"):
        limit = j.find("limit")
        lower = upper = None
        if limit is not None and limit.get("lower") is not None:
            lower, upper = float(limit.get("lower")), float(limit.get("upper"))
        axis = j.find("axis")
        joints[j.get("name")] = Joint(j.get("name"), j.get("type"), j.find("parent").get("link"),
                                      j.find("child").get("link"), origin_matrix(j),
                                      _floats(None if axis is None else axis.get("xyz"), (1.0, 0.0, 0.0)), lower, upper)
    children = {j.child for j in joints.values()}
    roots = [name for name in links if name not in children]
    if len(roots) != 1:
        raise ValueError(f"{path} must have exactly one root link, found {roots}")

    # Kinematics-only copy for pytorch-kinematics: bare links plus joints with origin/axis/limit.
    kin = ET.Element("robot", name=robot.get("name", "robot"))
    for name in links:
        ET.SubElement(kin, "link", name=name)
    for j in robot.findall("joint"):
        kj = ET.SubElement(kin, "joint", name=j.get("name"), type=j.get("type"))
        for tag in ("origin", "parent", "child", "axis", "limit"):
            if j.find(tag) is not None:
                ET.SubElement(kj, tag, dict(j.find(tag).attrib))
    return URDFModel(path=path, name=robot.get("name", path.stem), links=links, joints=joints,
                     collisions=collisions, root=roots[0], kinematic_xml=ET.tostring(kin, encoding="unicode"))
