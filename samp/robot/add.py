"""`python -m samp.robot add urdf=PATH name=NAME`: a robot config (`robot/NAME.yaml`) written from a URDF.

What is read from the URDF and what is chosen (docs/design.md, "Robot config"):

* base_link: the URDF's root link (or, when it is a bare frame, the first link with collision geometry
  fixed below it) unless `base=` names another link fixed to the root;
* ee_link: unless `ee=` names one, the tip of the longest chain of movable joints below the base; where
  that chain splits into equally long branches (a gripper's fingers) it ends at the link before the split;
* joints: the movable joints from base_link to ee_link, with the URDF's limits (a continuous joint gets
  `CONTINUOUS_RANGE`); other movable joints are held at 0, or at the opening for a detected gripper
  (prismatic joints below the end effector with one shared range: held open);
* collision_links: the links below the base (itself included) with collision geometry; point_links: those
  of them that an arm joint moves;
* self_collision_exclude: `samp.robot.self_collision.propose_exclusions` over `samples` random configurations;
* home: the middle of the limits when it is free of self-collision (exclusions left out), else the free
  sample nearest to it; checked again on the robot as written.
"""

from __future__ import annotations

import math
import os
import textwrap
from pathlib import Path

import numpy as np
import yaml

from samp.robot.config import GripperConfig, PointsConfig, RobotConfig
from samp.robot.urdf import URDFModel, parse_urdf

__all__ = ["CONTINUOUS_RANGE", "propose_robot", "robot_yaml", "write_robot"]

CONTINUOUS_RANGE = (-math.pi, math.pi)  # limits given to a continuous joint: one full turn


def _children(urdf: URDFModel, link: str) -> list:
    return [j for j in urdf.joints.values() if j.parent == link]


def _link(urdf: URDFModel, name: str, what: str) -> str:
    if name not in urdf.links:
        raise ValueError(f"{what} {name!r} is not a link of {urdf.path}; its links are: {', '.join(urdf.links)}")
    return name


def _movable_depths(urdf: URDFModel) -> dict[str, int]:
    """link -> the most movable joints on a path down from it, leaves first (a loop, not recursion: a URDF
    may be a chain deeper than Python's recursion limit)."""
    depth: dict[str, int] = {}
    for link in reversed(_subtree(urdf, urdf.root)):  # every child before its parent
        depth[link] = max(((j.type != "fixed") + depth[j.child] for j in _children(urdf, link)), default=0)
    return depth


def default_ee(urdf: URDFModel, base: str) -> str:
    """The tip of the longest chain of movable joints below `base`, or the link where it splits evenly."""
    link, depth = base, _movable_depths(urdf)
    while True:
        scored = [((j.type != "fixed") + depth[j.child], j) for j in _children(urdf, link)]
        best = max((s for s, _ in scored), default=0)
        top = [j for s, j in scored if s == best]
        if best == 0 or len(top) > 1:
            return link
        link = top[0].child


def arm_joints(urdf: URDFModel, base: str, ee: str) -> list:
    """The movable joints from `base` to `ee`, base first; ValueError when `ee` is not below `base`."""
    path, link = [], ee
    while link != base:
        joint = urdf.parent_joint(link)
        if joint is None:
            raise ValueError(f"end-effector link {ee!r} is not below the base link {base!r} in {urdf.path}; "
                             f"pick links on one chain (links: {', '.join(urdf.links)})")
        path.append(joint)
        link = joint.parent
    joints = [j for j in reversed(path) if j.type != "fixed"]
    if not joints:
        raise ValueError(f"no movable joint between base {base!r} and end effector {ee!r} in {urdf.path}")
    unsupported = [f"{j.name} ({j.type})" for j in joints if j.type not in ("revolute", "continuous", "prismatic")]
    if unsupported:
        raise ValueError(f"arm joints must be revolute, continuous or prismatic; {urdf.path} has {unsupported}")
    return joints


def _subtree(urdf: URDFModel, link: str) -> list[str]:
    """`link` and every link below it, depth first in the URDF's joint order (parents before children)."""
    out, stack = [], [link]
    while stack:
        out.append(stack.pop())
        stack.extend(reversed([j.child for j in _children(urdf, out[-1])]))
    return out


def _limits(joint) -> tuple[float, float]:
    if joint.type == "continuous":
        return CONTINUOUS_RANGE
    if joint.lower is None or joint.upper is None or not joint.lower < joint.upper:
        raise ValueError(f"joint {joint.name!r} ({joint.type}) has no usable <limit lower upper> in the URDF "
                         f"(got {joint.lower}, {joint.upper}); add its limits to the URDF")
    return joint.lower, joint.upper


def _gripper(urdf: URDFModel, ee: str) -> GripperConfig:
    """Prismatic joints below the end effector sharing one range are a gripper, held open; else none."""
    below = [urdf.parent_joint(link) for link in _subtree(urdf, ee)[1:]]
    movable = [j for j in below if j.type != "fixed"]
    if movable and all(j.type == "prismatic" and j.lower is not None for j in movable) \
            and len({(j.lower, j.upper) for j in movable}) == 1:
        return GripperConfig(joints=[j.name for j in movable], opening=float(movable[0].upper))
    return GripperConfig()


def _base(urdf: URDFModel, base: str | None) -> str:
    """`base` checked, or by default the root, or, when the root is a bare frame (a `world` without
    collision geometry), the first link fixed below it that has some: the base is mounted on the table and
    never checked against obstacles (samp.sim.World), so it must be the link that touches the table."""
    if not base:
        base = urdf.root
        while not urdf.collisions[base] and len(kids := _children(urdf, base)) == 1 and kids[0].type == "fixed":
            base = kids[0].child
        return base
    base = _link(urdf, base, "base link")
    link = base
    while (joint := urdf.parent_joint(link)) is not None:
        if joint.type != "fixed":
            raise ValueError(f"base link {base!r} moves with joint {joint.name!r}; the base must be fixed to the "
                             f"URDF's root {urdf.root!r}")
        link = joint.parent
    return base


def urdf_reference(urdf: Path, yaml_dir: Path) -> str:
    """How the YAML names its URDF: `pybullet_data://...` under pybullet_data; a path relative to the YAML's
    folder when the URDF lies in the project that holds the config folder (`yaml_dir` is CONF/robot, the
    project CONF's parent: docs/bring-your-own.md puts robots/ beside conf/), so the project can be
    committed and moved; else the absolute path."""
    import pybullet_data

    from samp.paths import PYBULLET_DATA_SCHEME

    urdf = urdf.resolve()
    data = Path(pybullet_data.getDataPath()).resolve()
    if urdf.is_relative_to(data):
        return PYBULLET_DATA_SCHEME + urdf.relative_to(data).as_posix()
    project = yaml_dir.resolve().parent.parent
    if project != Path(project.anchor) and urdf.is_relative_to(project):
        return Path(os.path.relpath(urdf, yaml_dir.resolve())).as_posix()
    return str(urdf)


def propose_robot(urdf_path: Path, name: str, yaml_dir: Path, base: str | None = None, ee: str | None = None,
                  samples: int = 1000, seed: int = 0) -> tuple[RobotConfig, dict]:
    """The robot config for the URDF at `urdf_path` (module docstring), and notes for the YAML's comments:
    `continuous` (joint names), `held` (movable joints not in the arm), `home` (how it was found),
    `free_share` (share of samples free of self-collision with the exclusions)."""
    from samp.robot.self_collision import propose_exclusions

    if not urdf_path.is_file():
        raise FileNotFoundError(f"URDF {urdf_path} does not exist")
    urdf = parse_urdf(urdf_path.resolve())  # checked as it is read: one line naming the file and the joint
    base = _base(urdf, base)
    ee = _link(urdf, ee, "end-effector link") if ee else default_ee(urdf, base)
    joints = arm_joints(urdf, base, ee)
    lower, upper = (list(v) for v in zip(*(_limits(j) for j in joints)))
    gripper = _gripper(urdf, ee)
    collision = [link for link in _subtree(urdf, base) if urdf.collisions[link]]
    if not collision:
        raise ValueError(f"no link below {base!r} in {urdf_path} has <collision> geometry; samp needs it for robot "
                         "points, the robot SDF and collision checks")
    arm = {j.name for j in joints}
    points = [link for link in collision if _moved(urdf, link, base, arm)]
    mid = [(lo + hi) / 2 for lo, hi in zip(lower, upper)]
    cfg = RobotConfig(name=name, urdf=str(urdf_path.resolve()), base_link=base, ee_link=ee,
                      joints=[j.name for j in joints], lower=lower, upper=upper, gripper=gripper,
                      collision_links=collision, point_links=[], home=mid, source_dir=str(yaml_dir))
    draft = _collision_only(cfg)
    report = propose_exclusions(draft, samples=samples, seed=seed)
    cfg.self_collision_exclude = report.rows
    cfg.home, how = _home(draft, report, np.array(mid))
    cfg.point_links, cfg.points = points, PointsConfig()
    cfg.urdf = urdf_reference(urdf_path, yaml_dir)
    held = [j.name for j in urdf.joints.values() if j.type != "fixed" and j.name not in arm and j.name not in gripper.joints]
    notes = {"continuous": [j.name for j in joints if j.type == "continuous"], "held": held, "home": how,
             "free_share": float(report.free.mean()) if len(report.free) else float("nan"), "samples": samples}
    return cfg, notes


def _collision_only(cfg: RobotConfig):
    """A `Robot` without robot points (they are drawn at the home, which is not chosen yet), float64."""
    from samp.robot.model import Robot

    class Draft(Robot):
        def _robot_points(self):
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)

    return Draft(cfg).double()


def _moved(urdf: URDFModel, link: str, base: str, arm: set[str]) -> bool:
    while link != base:
        joint = urdf.parent_joint(link)
        if joint.name in arm:
            return True
        link = joint.parent
    return False


def _home(robot, report, mid: np.ndarray) -> tuple[list[float], str]:
    """The middle of the limits (to 1e-6 rad) when free of self-collision, else the free sample nearest to
    it (to 1e-4 rad); rounded inside the limits and checked as rounded."""
    from samp.robot.bodies import LinkBodies

    lo, hi = robot.joint_limits.double().cpu().numpy().T
    with LinkBodies(robot) as bodies:
        def free(q):
            bodies.set_q(q)
            return not bodies.colliding_pairs(exclude=report.rows)

        middle = np.clip(np.round(mid, 6), lo, hi)
        if free(middle):
            return [float(v) for v in middle], "the middle of the joint limits"
        order = np.argsort(np.linalg.norm(report.samples - mid, axis=1))
        for i in order[report.free[order]]:
            q = np.clip(np.round(report.samples[i], 4), lo, hi)
            if free(q):
                return [float(v) for v in q], "the sampled configuration free of self-collision nearest the middle of the limits"
    raise ValueError(f"robot {robot.name!r}: the middle of the limits is in self-collision and none of the "
                     f"{len(report.samples)} random configurations is free; raise samples= or check the URDF's collision geometry")


def _flow(value) -> str:
    """One YAML value on one line (a list in flow style)."""
    return yaml.safe_dump(value, default_flow_style=True, width=100_000).removesuffix("...\n").strip()


def _entry(key: str, value, width: int = 110) -> str:
    """`key: value`, a long list wrapped between items with its items aligned (as in conf/robot/*.yaml)."""
    text = f"{key}: {_flow(value)}"
    if len(text) <= width or not isinstance(value, list):
        return text
    return textwrap.fill(", ".join(_flow(v) for v in value) + "]", width, initial_indent=f"{key}: [",
                         subsequent_indent=" " * (len(key) + 3), break_long_words=False, break_on_hyphens=False)


def _comment(text: str) -> list[str]:
    return textwrap.wrap(text, 108, initial_indent="# ", subsequent_indent="# ")


def robot_yaml(cfg: RobotConfig, notes: dict, urdf_path: Path) -> str:
    """The YAML text of `cfg`, in the layout of conf/robot/panda.yaml, with comments saying what was chosen."""
    lines = [*_comment(f"{cfg.name}: written by `python -m samp.robot add` from {urdf_path.name}. Joints, limits "
                       "and links are the URDF's; edit this file to change them (see conf/robot/panda.yaml).")]
    if notes["continuous"]:
        lines += _comment(f"Continuous joints {', '.join(notes['continuous'])} are limited to one turn, "
                          f"[{CONTINUOUS_RANGE[0]:.6f}, {CONTINUOUS_RANGE[1]:.6f}] rad.")
    if notes["held"]:
        lines += _comment(f"Movable joints outside the arm, held at 0: {', '.join(notes['held'])}.")
    lines += [_entry(k, getattr(cfg, k)) for k in ("name", "urdf", "base_link", "ee_link", "joints", "lower", "upper")]
    if cfg.gripper.joints:
        lines += ["gripper:  # prismatic fingers below the end effector, held open during planning",
                  f"  joints: {_flow(cfg.gripper.joints)}", f"  opening: {_flow(cfg.gripper.opening)}"]
    lines += [_entry("collision_links", cfg.collision_links), _entry("point_links", cfg.point_links),
              f"# home: {notes['home']}, free of self-collision.", _entry("home", cfg.home),
              *_comment(f"Adjacent links, and links touching in 95% or more of {notes['samples']} random "
                        f"configurations; with them left out, {notes['free_share']:.0%} of those configurations "
                        "are free of self-collision."),
              "self_collision_exclude:" + ("" if cfg.self_collision_exclude else " []")]
    lines += [f"  - {_flow(pair)}" for pair in cfg.self_collision_exclude]
    p = cfg.points
    lines += ["points:", f"  count: {p.count}", f"  offsets: {_flow(list(p.offsets))}", f"  jitter: {p.jitter}",
              f"  tolerance: {p.tolerance}", f"  seed: {p.seed}"]
    return "\n".join(lines) + "\n"


def write_robot(text: str, path: Path) -> None:
    """Write `text` to `path` atomically (a reader never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


# --- the command ------------------------------------------------------------------------------------------

ADD_KEYS = ("urdf", "name", "base", "ee", "out", "samples", "seed", "force")
ADD_OPTIONS = """  urdf=PATH      the robot's URDF (meshes as package://, relative or absolute paths)
  name=NAME      the robot's name: writes OUT/robot/NAME.yaml; robot=NAME then selects it
  base=LINK      the fixed base link (default: the URDF's root link)
  ee=LINK        the end-effector link (default: the tip of the longest chain of movable joints)
  out=DIR        the config folder (default: the first folder of $SAMP_CONFIG_PATH, else ./conf)
  samples=1000   random configurations for the self-collision exclusions and the home
  seed=0         their seed
  force=false    replace an existing OUT/robot/NAME.yaml, or shadow one of samp's own robots"""


def _int(opts: dict, key: str, default: int, minimum: int) -> int:
    try:
        value = int(opts.get(key, default))
    except ValueError:
        raise ValueError(f"{key}={opts[key]!r} is not an integer") from None
    if value < minimum:
        raise ValueError(f"{key}={value} must be at least {minimum}")
    return value


def _flag(opts: dict, key: str) -> bool:
    value = str(opts.get(key, "false")).lower()
    if value not in ("true", "false"):
        raise ValueError(f"{key}={opts[key]!r}: say {key}=true or {key}=false")
    return value == "true"


def default_out() -> Path:
    """The first folder of `$SAMP_CONFIG_PATH`, else `./conf` in the current folder."""
    from samp.paths import config_path

    folders = config_path()
    return folders[0] if folders else Path.cwd() / "conf"


def _packaged_robots() -> list[str]:
    from samp.paths import packaged_conf_dir

    return sorted(p.stem for p in (packaged_conf_dir() / "robot").glob("*.yaml"))


def _checked(path: Path):
    """Load the YAML at `path` through the normal loader and check its home for self-collision."""
    import torch

    from samp.robot import load_robot
    from samp.robot.bodies import LinkBodies

    try:
        robot = load_robot(path, dtype=torch.float64)
    except RuntimeError as err:  # robot points that cannot be placed around the home found
        raise ValueError(f"the robot written to {path} does not load: {err}") from None
    with LinkBodies(robot) as bodies:
        bodies.set_q(robot.home.numpy())
        hits = bodies.colliding_pairs(exclude=robot.self_collision_exclude)
    if hits:
        raise ValueError(f"the home of the robot written to {path} is in self-collision ({hits}); set home by hand")
    return robot


def next_steps(name: str, out: Path) -> list[str]:
    """The shell commands that train the new robot's robot SDF and a smoke policy, shell-quoted; prefixed
    with SAMP_CONFIG_PATH when `out` is not already where samp finds configs."""
    import shlex

    from samp.paths import conf_dir

    found = conf_dir() / "robot" / f"{name}.yaml"
    here = found.is_file() and found.resolve() == (out / "robot" / f"{name}.yaml").resolve()
    current = os.environ.get("SAMP_CONFIG_PATH")
    env = "" if here else "SAMP_CONFIG_PATH=" + shlex.quote(str(out.resolve()) + (f"{os.pathsep}{current}" if current else "")) + " "
    q = shlex.quote
    return [f"{env}python -m samp.robot show robot={q(name)}",
            f"{env}python -m samp.train experiment=robot_sdf_quick robot={q(name)}",
            f"{env}python -m samp.data generate dataset=smoke dataset.robot={q(name)} dataset.name={q(name + '_smoke')}",
            f"{env}python -m samp.train experiment=quickstart robot={q(name)} datamodule.dataset={q(name + '_smoke')} "
            "evaluation.benchmark=null"]


def add_robot(args: list[str], summary) -> Path:
    """`python -m samp.robot add ...` (module docstring): write, load, check and summarise the new robot."""
    from samp.cli import parse_options
    from samp.paths import check_name

    _, opts, _ = parse_options(args, ADD_KEYS, command="add")
    missing = [k for k in ("urdf", "name") if not opts.get(k)]
    if missing:
        raise ValueError(f"add needs {' and '.join(f'{k}=...' for k in missing)}: "
                         "python -m samp.robot add urdf=PATH name=NAME")
    name, force = check_name(opts["name"], "robot name"), _flag(opts, "force")
    samples, seed = _int(opts, "samples", 1000, 1), _int(opts, "seed", 0, 0)
    out = Path(opts["out"]).expanduser() if opts.get("out") else default_out()
    path = (out / "robot" / f"{name}.yaml").absolute()
    if name in _packaged_robots() and not force:
        raise ValueError(f"robot name {name!r} is one of samp's own robots ({', '.join(_packaged_robots())}); "
                         "pick another name=, or pass force=true to shadow it")
    if path.exists() and not force:
        raise ValueError(f"{path} already exists; pass force=true to replace it, or pick another name=")
    urdf = Path(opts["urdf"]).expanduser().absolute()
    cfg, notes = propose_robot(urdf, name, path.parent, opts.get("base"), opts.get("ee"), samples, seed)
    draft = path.with_name(f".{name}.draft.yaml")  # hidden: not a robot of the folder until it is checked
    write_robot(robot_yaml(cfg, notes, urdf), draft)
    try:
        robot = _checked(draft)
    except Exception:
        draft.unlink()
        raise
    draft.replace(path)
    print(summary(robot))
    print(f"\nwrote {path}\nnext: look at it, train its robot SDF, then a smoke policy on a small dataset of its own:")
    print("\n".join(f"  {line}" for line in next_steps(name, out)))
    return path
