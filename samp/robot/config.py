"""The robot description as data: the schema of `conf/robot/*.yaml` and its loader."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, ValidationError

from samp.paths import conf_dir

__all__ = ["GripperConfig", "PointsConfig", "RobotConfig", "available_robots", "load_robot_config"]


@dataclass
class GripperConfig:
    """Gripper joints held at one opening (metres for prismatic fingers) during planning."""

    joints: list[str] = field(default_factory=list)
    opening: float = 0.0


@dataclass
class PointsConfig:
    """Robot points P on shells around the moving links (docs/design.md section 4)."""

    count: int = 1024
    offsets: list[float] = field(default_factory=lambda: [0.001, 0.03, 0.06])
    jitter: float = 0.4  # tangential jitter, as a fraction of the shell offset
    tolerance: float = 0.1  # kept when |distance to own link - offset| <= tolerance * offset
    seed: int = 0


@dataclass
class RobotConfig:
    name: str = "???"
    urdf: str = "???"  # pybullet_data://..., an absolute path, or a path relative to the YAML file
    base_link: str = "???"
    ee_link: str = "???"
    joints: list[str] = field(default_factory=list)  # arm joints, in the order of q
    lower: list[float] = field(default_factory=list)  # joint limits (radians), one per arm joint
    upper: list[float] = field(default_factory=list)
    gripper: GripperConfig = field(default_factory=GripperConfig)
    collision_links: list[str] = field(default_factory=list)
    point_links: list[str] = field(default_factory=list)  # moving links that carry robot points
    home: list[float] = field(default_factory=list)  # a collision-free configuration; points are checked there
    self_collision_exclude: list[list[str]] = field(default_factory=list)
    points: PointsConfig = field(default_factory=PointsConfig)
    source_dir: Optional[str] = None  # set by the loader: folder of the YAML file


def available_robots() -> list[str]:
    return sorted(p.stem for p in (conf_dir() / "robot").glob("*.yaml"))


def load_robot_config(name_or_path: str | Path | DictConfig | dict[str, Any]) -> RobotConfig:
    """A validated `RobotConfig` from a robot name in `conf/robot/`, a YAML path, or a mapping
    (for example the `robot` node of a composed Hydra config)."""
    source_dir = str(conf_dir() / "robot")  # relative asset paths in a mapping resolve as in conf/robot/
    if isinstance(name_or_path, (dict, DictConfig)):
        raw = OmegaConf.create(name_or_path) if isinstance(name_or_path, dict) else name_or_path
    else:
        text = str(name_or_path)
        path = Path(text)
        if path.suffix not in (".yaml", ".yml"):
            path = conf_dir() / "robot" / f"{text}.yaml"
            if not path.is_file():
                raise ValueError(f"unknown robot {text!r}; available robots: {', '.join(available_robots())} "
                                 "(or pass the path of a robot YAML file)")
        elif not path.is_file():
            raise FileNotFoundError(f"robot config {path} does not exist")
        from samp.yaml_files import load_config  # aliases and size bounded (a user's file)

        raw = load_config(path, "robot config")
        source_dir = str(path.resolve().parent)
    schema = OmegaConf.structured(RobotConfig)
    try:
        merged = OmegaConf.merge(schema, raw)
        OmegaConf.resolve(merged)
    except (ConfigKeyError, ValidationError) as err:
        valid = ", ".join(f.name for f in RobotConfig.__dataclass_fields__.values() if f.name != "source_dir")
        first = str(err.msg if hasattr(err, "msg") else err).splitlines()[0]
        raise ValueError(f"invalid robot config {name_or_path if isinstance(name_or_path, (str, Path)) else ''}: "
                         f"{first} (key {err.full_key!r}). Valid keys: {valid}; see conf/robot/panda.yaml") from None
    cfg: RobotConfig = OmegaConf.to_object(merged)
    if cfg.source_dir is None:
        cfg.source_dir = source_dir
    _check(cfg)
    return cfg


def _check(cfg: RobotConfig) -> None:
    missing = [k for k in ("name", "urdf", "base_link", "ee_link") if getattr(cfg, k) == "???"]
    if missing:
        raise ValueError(f"robot config {cfg.name!r} lacks required keys: {missing}")
    n = len(cfg.joints)
    if n == 0:
        raise ValueError(f"robot {cfg.name!r} lists no arm joints under `joints`")
    for key in ("lower", "upper", "home"):
        if len(getattr(cfg, key)) != n:
            raise ValueError(f"robot {cfg.name!r}: `{key}` has {len(getattr(cfg, key))} values, expected {n} (one per joint)")
    bad = [(j, lo, hi) for j, lo, hi in zip(cfg.joints, cfg.lower, cfg.upper) if not lo < hi]
    if bad:
        raise ValueError(f"robot {cfg.name!r}: lower limit must be below upper limit, got {bad}")
    outside = [(j, q) for j, q, lo, hi in zip(cfg.joints, cfg.home, cfg.lower, cfg.upper) if not lo <= q <= hi]
    if outside:
        raise ValueError(f"robot {cfg.name!r}: home configuration outside the joint limits at {outside}")
    for pair in cfg.self_collision_exclude:
        if len(pair) != 2:
            raise ValueError(f"robot {cfg.name!r}: each self_collision_exclude entry is a pair of links, got {pair}")
    p = cfg.points
    if p.count <= 0 or not p.offsets or min(p.offsets) <= 0:
        raise ValueError(f"robot {cfg.name!r}: points.count must be positive and points.offsets positive, got {p}")
