"""A small URDF reader: the joint tree, joint limits and collision geometry, checked as they are read.

pytorch-kinematics has its own parser, but it rejects some valid files (the xArm's transmissions) and
warns about every tag it does not know, so it is handed a kinematics-only copy (`kinematic_xml`).

A URDF may come from anyone (`samp-robot add`, a scene file), so `parse_urdf` refuses with one
`ValueError` naming the file and the joint or link: a file over `MAX_URDF_BYTES` or with a DOCTYPE
(entity definitions, the "billion laughs"), more than `MAX_URDF_LINKS` links, a joint graph that is not
one tree (a cycle, two roots, a link with two parents, a joint to an undefined link), numbers that do not
parse or are not finite (origins, axes, limits, sizes), lower > upper, and mesh paths outside the URDF's
folder as written (or the package folders that `package://` is looked up in).
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Collision", "Joint", "MAX_URDF_BYTES", "MAX_URDF_LINKS", "URDFModel", "parse_urdf", "origin_matrix",
           "rpy_matrix", "resolve_mesh"]

MAX_URDF_BYTES = 8 * 2**20  # 8 MiB: pybullet_data's largest URDF has 34 kB, a xacro-expanded humanoid < 1 MB
# Most links read. pytorch-kinematics builds its chain recursively and in time quadratic in the joints, so
# a deep chain must stay well under Python's recursion limit (1000); real arms have tens of links.
MAX_URDF_LINKS = 512
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")  # what samp's kinematics reads
PACKAGE_SEARCH = 4  # package://pkg/x is looked up in the URDF's folder and its 3 parents (pybullet_data's layout)


def rpy_matrix(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw to a rotation matrix, R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def _floats(text: str | None, default: tuple[float, ...], what: str = "a number list") -> np.ndarray:
    """The finite numbers of a space-separated attribute (`default` when absent); ValueError saying what
    was found when one does not parse, is NaN or infinite, or (with a non-empty default) their count differs."""
    if text is None:
        return np.array(default, dtype=np.float64)
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        values = None
    if values is None or not np.isfinite(values).all() or (default and len(values) != len(default)):
        count = f"{len(default)} finite numbers" if len(default) > 1 else "a finite number" if default else "finite numbers"
        raise ValueError(f"{what} is {text!r}; expected {count}")
    return values


def _number(element: ET.Element, key: str, where: str, default: float | None = None) -> float | None:
    """One finite number attribute of `element` (`default` when absent)."""
    text = element.get(key)
    return default if text is None else float(_floats(text, (0.0,), f"{where} {key}")[0])


def origin_matrix(element: ET.Element | None, where: str = "<origin>") -> np.ndarray:
    """The 4x4 transform of an `<origin xyz rpy>` child of `element` (identity when absent)."""
    T = np.eye(4)
    origin = None if element is None else element.find("origin")
    if origin is not None:
        T[:3, :3] = rpy_matrix(_floats(origin.get("rpy"), (0.0, 0.0, 0.0), f"{where} <origin rpy>"))
        T[:3, 3] = _floats(origin.get("xyz"), (0.0, 0.0, 0.0), f"{where} <origin xyz>")
    return T


@dataclass
class Joint:
    name: str
    type: str  # revolute | continuous | prismatic | fixed
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


# --- mesh paths -------------------------------------------------------------------------------------------

def _inside(path: Path, folder: Path) -> bool:
    """Whether `path` names a file under `folder` as written (`..` collapsed). Symbolic links are followed
    afterwards: a link is something the owner of the folder put there (a shared mesh folder), where a
    path in the URDF is only text that anyone can write."""
    return Path(os.path.abspath(path)).is_relative_to(os.path.abspath(folder))


def resolve_mesh(filename: str, urdf_dir: Path) -> Path:
    """The file a URDF's mesh `filename` names: a relative path, `file://` or an absolute path inside the
    URDF's folder, or `package://pkg/rest` looked up as `rest` or `pkg/rest` in the URDF's folder and its
    parents (pybullet_data keeps the package folders beside the URDF). ValueError for a path that leaves
    those folders as written (`..`, an absolute path elsewhere); FileNotFoundError when missing."""
    urdf_dir = Path(urdf_dir)
    if not filename:
        raise ValueError("its filename is empty")
    if filename.startswith("package://"):
        rel = Path(filename[len("package://"):])
        if rel.is_absolute() or ".." in rel.parts:
            raise ValueError(f"package path {filename!r} leaves its package; name a file inside it")
        tail = Path(*rel.parts[1:]) if len(rel.parts) > 1 else None
        for base in [urdf_dir, *urdf_dir.parents][:PACKAGE_SEARCH]:
            for candidate in (base / rel, base / tail if tail is not None else None):
                if candidate is not None and candidate.is_file():
                    return candidate.resolve()
        raise FileNotFoundError(f"mesh {filename!r} was not found in {urdf_dir} or its {PACKAGE_SEARCH - 1} parents")
    path = Path(filename[len("file://"):] if filename.startswith("file://") else filename)
    path = path if path.is_absolute() else urdf_dir / path
    if not _inside(path, urdf_dir):
        raise ValueError(f"mesh path {filename!r} leads to {os.path.abspath(path)}, outside the URDF's folder {urdf_dir}; "
                         "keep meshes inside that folder (or name them package://PKG/...)")
    if not path.is_file():
        raise FileNotFoundError(f"mesh {filename!r} does not exist (looked for {path})")
    return path.resolve()


# --- reading ----------------------------------------------------------------------------------------------

def _read_xml(path: Path) -> ET.Element:
    """The root element of the URDF at `path`, after bounding its size and refusing a DOCTYPE: expat
    expands internal entities, so a few kB of nested ones can take gigabytes, and no URDF needs them."""
    size = path.stat().st_size
    if size > MAX_URDF_BYTES:
        raise ValueError(f"{path} has {size} bytes, over samp's limit for a URDF of {MAX_URDF_BYTES} "
                         "(samp.robot.urdf.MAX_URDF_BYTES); is it a URDF?")
    data = path.read_bytes()
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise ValueError(f"{path} declares a DOCTYPE or entities, which samp does not read in a URDF "
                         "(they can expand without bound); expand them (e.g. with xacro) and remove the declaration")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as err:
        raise ValueError(f"{path} is not a readable URDF: {err}") from None
    if root.tag != "robot":
        raise ValueError(f"{path} is not a URDF: its root element is <{root.tag}>, expected <robot>")
    return root


def _named(elements: list[ET.Element], what: str, path: Path) -> list[str]:
    """The `name` attributes of `elements`, each present and unique."""
    names = [e.get("name") for e in elements]
    for i, n in enumerate(names):
        if not n:
            raise ValueError(f"{path}: <{what}> number {i + 1} has no name; give every <{what}> a unique name")
    seen = set()
    for n in names:
        if n in seen:
            raise ValueError(f"{path}: two <{what}> elements are named {n!r}; {what} names must be unique")
        seen.add(n)
    return names


def _collision(element: ET.Element, urdf_dir: Path, where: str) -> Collision:
    geometry = element.find("geometry")
    if geometry is None or len(geometry) == 0:
        raise ValueError(f"{where} has a <collision> without <geometry>")
    shape = geometry[0]
    origin = origin_matrix(element, where)
    if shape.tag == "mesh":
        try:
            mesh_path = resolve_mesh(shape.get("filename", ""), urdf_dir)
        except ValueError as err:
            raise ValueError(f"{where}: collision mesh: {err}") from None
        except FileNotFoundError as err:
            raise FileNotFoundError(f"{where}: collision {err}") from None
        scale = _floats(shape.get("scale"), (1.0, 1.0, 1.0), f"{where} <mesh scale>")
        if not np.abs(scale).min() > 0:
            raise ValueError(f"{where} <mesh scale> is {shape.get('scale')!r}; expected three non-zero numbers")
        return Collision(origin, "mesh", mesh_path=mesh_path, scale=scale)
    sizes = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",)}
    if shape.tag not in sizes:
        raise ValueError(f"{where}: unsupported collision geometry <{shape.tag}>; expected mesh, box, cylinder or sphere")
    if shape.tag == "box":
        size = _floats(shape.get("size"), (0.0, 0.0, 0.0), f"{where} <box size>")
    else:
        size = np.array([_number(shape, key, f"{where} <{shape.tag}>", math.nan) for key in sizes[shape.tag]])
    if not (size > 0).all():  # also NaN: an attribute that is missing
        got = {key: shape.get(key) for key in sizes[shape.tag]}
        raise ValueError(f"{where} <{shape.tag}> has {got}; expected positive numbers for {', '.join(sizes[shape.tag])}")
    return Collision(origin, shape.tag, size=size)


def _joint(j: ET.Element, name: str, links: set[str], path: Path) -> Joint:
    where = f"{path}: joint {name!r}"
    kind = j.get("type")
    if kind not in JOINT_TYPES:
        raise ValueError(f"{where} has type {kind!r}; samp reads {', '.join(JOINT_TYPES)} joints")
    ends = {}
    for tag in ("parent", "child"):
        element = j.find(tag)
        link = None if element is None else element.get("link")
        if not link:
            raise ValueError(f"{where} has no <{tag} link=...>; every joint names its parent and child links")
        if link not in links:
            raise ValueError(f"{where} names {tag} link {link!r}, which is not a <link> of the file")
        ends[tag] = link
    if ends["parent"] == ends["child"]:
        raise ValueError(f"{where} joins link {ends['child']!r} to itself")
    axis_element = j.find("axis")
    axis = _floats(None if axis_element is None else axis_element.get("xyz"), (1.0, 0.0, 0.0), f"{where} <axis xyz>")
    with np.errstate(over="ignore"):
        norm = np.linalg.norm(axis)
    if kind != "fixed" and not 0 < norm < math.inf:  # 1e308 passes as finite but its length does not
        raise ValueError(f"{where} has axis {axis.tolist()}; a moving joint needs a non-zero axis of finite length")
    lower = upper = None
    limit = j.find("limit")
    # A revolute or prismatic joint without <limit> (URDF requires one) is read without a range: refused by
    # `samp-robot add` if it is an arm joint, and a cell URDF says that its joints must be fixed.
    if limit is not None:
        for key in ("effort", "velocity"):  # not used by samp, but pytorch-kinematics parses them
            _number(limit, key, f"{where} <limit>")
        bounds = (limit.get("lower"), limit.get("upper"))
        if None in bounds and bounds != (None, None):
            # the URDF spec reads a missing bound as 0, pybullet a missing upper as -1: ask, do not guess
            raise ValueError(f"{where} <limit> has only one of lower and upper ({bounds}); give both")
        if bounds != (None, None):  # none: a joint without a range (pybullet's "unlimited"), refused if in the arm
            lower, upper = (_number(limit, key, f"{where} <limit>") for key in ("lower", "upper"))
            if lower > upper and kind in ("revolute", "prismatic"):
                raise ValueError(f"{where} has lower limit {lower} above its upper limit {upper} (pybullet reads that "
                                 "as no limit; samp needs the joint's range): give it lower <= upper")
    return Joint(name, kind, ends["parent"], ends["child"], origin_matrix(j, where), axis, lower, upper)


def _root(path: Path, links: list[str], joints: dict[str, Joint]) -> str:
    """The one root of the joint tree, checked iteratively (deep chains must not recurse): every link has
    at most one parent joint, one link has none, and every link hangs from it (no cycle)."""
    parent_of: dict[str, str] = {}
    for j in joints.values():
        if j.child in parent_of:
            raise ValueError(f"{path}: link {j.child!r} is the child of joints {parent_of[j.child]!r} and {j.name!r}; "
                             "a URDF is a tree, each link has one parent joint")
        parent_of[j.child] = j.name
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        what = "no link without a parent joint: the joints form a cycle" if not roots else f"several: {roots}"
        raise ValueError(f"{path} must have exactly one root link, found {what}; join every link to one tree")
    children: dict[str, list[str]] = {}
    for j in joints.values():
        children.setdefault(j.parent, []).append(j.child)
    reached, stack = {roots[0]}, [roots[0]]
    while stack:
        for child in children.get(stack.pop(), []):
            reached.add(child)
            stack.append(child)
    unreached = [name for name in links if name not in reached]
    if unreached:
        cycle = [parent_of[name] for name in unreached]
        raise ValueError(f"{path}: joints {cycle} form a cycle (links {unreached} do not hang from the root "
                         f"{roots[0]!r}); a URDF is a tree")
    return roots[0]


def _kinematic_xml(robot: ET.Element, links: list[str], joints: dict[str, Joint]) -> str:
    """Kinematics-only copy for pytorch-kinematics: bare links plus joints with origin/axis/limit, with the
    URDF's defaults written out where its parser differs or fails: an absent axis is URDF's x (its parser
    would take z), and an <origin> or <axis> missing an attribute, or a <limit> missing effort or velocity
    (unused by samp, not required by pybullet), would stop its parser."""
    kin = ET.Element("robot", name=robot.get("name", "robot"))
    for name in links:
        ET.SubElement(kin, "link", name=name)
    defaults = {"origin": {"xyz": "0 0 0", "rpy": "0 0 0"}, "limit": {"effort": "0", "velocity": "0"}}
    for j in robot.findall("joint"):
        joint = joints[j.get("name")]
        kj = ET.SubElement(kin, "joint", name=joint.name, type=joint.type)
        for tag in ("origin", "parent", "child", "limit"):
            if j.find(tag) is not None:
                ET.SubElement(kj, tag, {**defaults.get(tag, {}), **j.find(tag).attrib})
        ET.SubElement(kj, "axis", xyz=" ".join(repr(float(v)) for v in joint.axis))
    return ET.tostring(kin, encoding="unicode")


def parse_urdf(path: Path) -> URDFModel:
    """Read and check (module docstring) the link tree, joints and collision elements of the URDF at `path`."""
    path = Path(path)
    robot = _read_xml(path)
    link_elements = robot.findall("link")
    if len(link_elements) > MAX_URDF_LINKS:
        raise ValueError(f"{path} has {len(link_elements)} links, over samp's limit of {MAX_URDF_LINKS} "
                         "(samp.robot.urdf.MAX_URDF_LINKS)")
    links = _named(link_elements, "link", path)
    joint_elements = robot.findall("joint")
    names = _named(joint_elements, "joint", path)
    joints = {name: _joint(j, name, set(links), path) for name, j in zip(names, joint_elements)}
    root = _root(path, links, joints)
    collisions = {name: [_collision(c, path.parent, f"{path}: link {name!r}") for c in link.findall("collision")]
                  for name, link in zip(links, link_elements)}
    return URDFModel(path=path, name=robot.get("name", path.stem), links=links, joints=joints,
                     collisions=collisions, root=root, kinematic_xml=_kinematic_xml(robot, links, joints))
