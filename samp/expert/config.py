"""The expert's settings as data: the schema of `conf/expert/*.yaml` and its loader.

Angles are radians, lengths metres, times seconds. `ExpertConfig` holds the planner settings, with
`ik` (damped-least-squares IK) and `problems` (start and goal sampling) as sub-nodes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, ValidationError

from samp.paths import conf_dir

LOG_LEVELS = ("debug", "info", "warn", "error", "none")

__all__ = ["ExpertConfig", "IKConfig", "ProblemConfig", "available_expert_configs", "load_expert_config"]


@dataclass
class IKConfig:
    """Batched damped-least-squares IK (`samp.expert.ik.solve_ik`)."""

    seeds: int = 32  # random initial configurations per target pose, solved in parallel
    iterations: int = 100  # fixed budget; every seed runs all of them
    restarts: int = 1  # times within the budget that seeds still far from their target are redrawn
    damping: float = 0.05  # lambda of (J J^T + lambda^2 I)
    max_step: float = 0.3  # largest joint change per iteration (radians), for stability far from a solution
    position_tolerance: float = 0.001  # a seed has converged within this (metres) ...
    rotation_tolerance: float = 0.0087  # ... and this (radians, 0.5 degrees)
    candidates: int = 8  # converged seeds per target checked for collisions (at most)


@dataclass
class ProblemConfig:
    """How starts and goals are drawn in a scene (`samp.expert.problems`)."""

    target_fraction: float = 0.5  # share of goals that are pre-grasp poses at the scene's target
    approach_offset: float = 0.10  # pre-grasp point: this far from the target's centre, above or in front
    approach_clearance: float = 0.04  # the approach corridor must be this far from every obstacle ...
    approach_depth: float = 0.2  # ... from the pre-grasp point out to this much further (hand and wrist)
    approach_axis: list[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])  # in the ee frame, out of the gripper
    radius: list[float] = field(default_factory=lambda: [0.25, 0.85])  # workspace goals: distance from the base axis
    position_clearance: float = 0.05  # workspace goal points at least this far from obstacles
    max_tilt: float = 1.75  # workspace goals: approach axis within this angle of straight down (100 degrees)
    poses_per_goal: int = 4  # poses drawn (and solved) per goal and round
    goal_rounds: int = 4  # rounds of fresh poses for goals whose IK found no collision-free solution
    goal_select: str = "nearest"  # among a goal's free IK solutions: nearest to the start (joint space) or random
    start: str = "chain"  # chain: each start is the previous goal; random: collision-free at random
    start_batch: int = 256  # random configurations drawn per round when looking for a free start
    start_rounds: int = 20


@dataclass
class ExpertConfig:
    """Expert planner settings (`samp.expert.planner.ExpertPlanner`)."""

    backend: str = "ompl"  # ompl (the only backend; curobo is planned work, samp.expert.curobo)
    planner: str = "RRTConnect"  # an OMPL geometric planner; see samp.expert.ompl_backend.PLANNERS
    time_limit: float = 5.0  # per attempt
    attempts: int = 3  # a failed attempt (timeout, dense check) is retried with the next seed
    max_checks: int = 1000  # per attempt, motion checks before an anytime planner stops (deterministic budget)
    resolution: float = 0.02  # motion-check step, joint-space Euclidean distance (radians)
    clearance: float = 0.015  # planning: every state at least this far from obstacles
    check_margin: float = 0.005  # final dense check of the 50-waypoint trajectory: at least this far
    direct: bool = True  # take the straight joint-space motion when it is valid, without planning
    simplify: bool = True  # OMPL PathSimplifier.simplifyMax (shortcutting, no time limit: deterministic)
    smooth: bool = True  # OMPL PathSimplifier.smoothBSpline
    waypoints: int = 50
    log_level: str = "warn"  # OMPL's log level while planning: debug | info | warn | error | none
    ik: IKConfig = field(default_factory=IKConfig)
    problems: ProblemConfig = field(default_factory=ProblemConfig)


def available_expert_configs() -> list[str]:
    return sorted(p.stem for p in (conf_dir() / "expert").glob("*.yaml"))


def load_expert_config(source: str | Path | DictConfig | dict[str, Any] | ExpertConfig | None = None,
                       **overrides) -> ExpertConfig:
    """A validated `ExpertConfig` from a name in `conf/expert/` (default: "default"), a YAML path, a
    mapping (e.g. the `expert` node of a composed Hydra config) or an `ExpertConfig`. Keyword arguments
    override top-level keys (`load_expert_config(planner="AORRTC", time_limit=2.0)`)."""
    if isinstance(source, ExpertConfig):
        raw = OmegaConf.structured(source)
    elif isinstance(source, (dict, DictConfig)):
        raw = OmegaConf.create(source) if isinstance(source, dict) else source
    else:
        text = "default" if source is None else str(source)
        path = Path(text)
        if path.suffix not in (".yaml", ".yml"):
            path = conf_dir() / "expert" / f"{text}.yaml"
            if not path.is_file():
                raise ValueError(f"unknown expert config {text!r}; available: {', '.join(available_expert_configs())} "
                                 "(or pass the path of a YAML file)")
        elif not path.is_file():
            raise FileNotFoundError(f"expert config {path} does not exist")
        from samp.yaml_files import load_config  # aliases and size bounded (a user's file)

        raw = load_config(path, "expert config")
    try:
        merged = OmegaConf.merge(OmegaConf.structured(ExpertConfig), raw, OmegaConf.create(overrides))
        OmegaConf.resolve(merged)
    except (ConfigKeyError, ValidationError) as err:
        first = str(err.msg if hasattr(err, "msg") else err).splitlines()[0]
        raise ValueError(f"invalid expert config: {first} (key {err.full_key!r}). Valid keys: "
                         f"{', '.join(ExpertConfig.__dataclass_fields__)}; ik: {', '.join(IKConfig.__dataclass_fields__)}; "
                         f"problems: {', '.join(ProblemConfig.__dataclass_fields__)}; see conf/expert/default.yaml") from None
    cfg: ExpertConfig = OmegaConf.to_object(merged)
    _check(cfg)
    return cfg


def _require(ok: bool, key: str, expected: str, got) -> None:
    if not ok:
        raise ValueError(f"expert config: {key} must be {expected}, got {got!r}")


def _check(cfg: ExpertConfig) -> None:
    if cfg.backend == "curobo":
        from samp.expert.curobo import NOT_IMPLEMENTED

        raise ValueError(f"expert config: backend 'curobo' {NOT_IMPLEMENTED}")
    _require(cfg.backend == "ompl", "backend", "'ompl'", cfg.backend)
    _require(cfg.log_level in LOG_LEVELS, "log_level", " | ".join(LOG_LEVELS), cfg.log_level)
    _require(cfg.time_limit > 0, "time_limit", "positive (seconds)", cfg.time_limit)
    _require(cfg.attempts >= 1, "attempts", ">= 1", cfg.attempts)
    _require(cfg.max_checks >= 0, "max_checks", ">= 0 (0: time limit only)", cfg.max_checks)
    _require(0 < cfg.resolution <= 0.5, "resolution", "in (0, 0.5] radians", cfg.resolution)
    _require(cfg.clearance >= 0 and cfg.check_margin >= 0, "clearance and check_margin", "non-negative metres",
             (cfg.clearance, cfg.check_margin))
    _require(cfg.check_margin <= cfg.clearance, "check_margin", f"<= clearance ({cfg.clearance})", cfg.check_margin)
    _require(cfg.waypoints >= 2, "waypoints", ">= 2", cfg.waypoints)
    ik, pr = cfg.ik, cfg.problems
    _require(ik.seeds >= 1 and ik.iterations >= 1 and ik.candidates >= 1, "ik.seeds, ik.iterations, ik.candidates",
             ">= 1", (ik.seeds, ik.iterations, ik.candidates))
    _require(0 <= ik.restarts < ik.iterations, "ik.restarts", f"in [0, iterations={ik.iterations})", ik.restarts)
    _require(ik.damping >= 0 and ik.max_step > 0, "ik.damping / ik.max_step", ">= 0 / > 0", (ik.damping, ik.max_step))
    _require(0 <= pr.target_fraction <= 1, "problems.target_fraction", "in [0, 1]", pr.target_fraction)
    _require(len(pr.approach_axis) == 3 and math.hypot(*pr.approach_axis) > 0, "problems.approach_axis",
             "a non-zero 3-vector", pr.approach_axis)
    _require(len(pr.radius) == 2 and 0 <= pr.radius[0] < pr.radius[1], "problems.radius", "[min, max] with 0 <= min < max",
             pr.radius)
    _require(0 < pr.max_tilt <= math.pi, "problems.max_tilt", "in (0, pi]", pr.max_tilt)
    _require(pr.goal_select in ("nearest", "random"), "problems.goal_select", "'nearest' or 'random'", pr.goal_select)
    _require(pr.start in ("chain", "random"), "problems.start", "'chain' or 'random'", pr.start)
    _require(pr.approach_offset > 0 and pr.approach_depth >= 0 and pr.approach_clearance >= 0,
             "problems.approach_offset / approach_depth / approach_clearance", "> 0 / >= 0 / >= 0",
             (pr.approach_offset, pr.approach_depth, pr.approach_clearance))
    _require(pr.poses_per_goal >= 1 and pr.goal_rounds >= 1 and pr.start_batch >= 1 and pr.start_rounds >= 1,
             "problems.poses_per_goal, goal_rounds, start_batch, start_rounds", ">= 1", (pr.poses_per_goal, pr.goal_rounds, pr.start_batch, pr.start_rounds))
