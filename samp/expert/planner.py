"""The expert planner: OMPL in joint space, post-processed into verified 50-waypoint trajectories.

`ExpertPlanner(robot, scene, cfg).plan(q_start, q_goal, seed)`:
  1. rejects a start or goal outside the joint limits or closer than `clearance` to an obstacle (or in
     self-collision), with the reason; one within `LIMIT_TOLERANCE` (1e-6 rad, rounding) beyond a limit is
     moved onto it first, since OMPL's bounds check tolerates nothing and would refuse it as "invalid
     bounds" after spending every attempt;
  2. takes the straight joint-space motion when it is valid (the shortest path; it also sidesteps
     AORRTC's zero-length-path error on such problems in ompl 2.0.1), otherwise plans with the
     configured OMPL planner (states `clearance` clear of obstacles, motions checked every `resolution`
     radians) and simplifies and smooths the path;
  3. resamples it to `waypoints` configurations uniform in joint-space arc length, first and last
     exactly q_start and q_goal, and checks every segment densely (`resolution`) with `check_margin`.
A timeout or a failed dense check is retried with the next seed, up to `attempts`; what still fails
comes back as a `PlanResult` with success False and the reason, never dropped.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from samp.expert.config import ExpertConfig, load_expert_config
from samp.expert.ompl_backend import ANYTIME, plan_once, planner_class
from samp.expert.seeding import derive_seed
from samp.expert.trajectory import ee_path_length, first_invalid_segment, joint_path_length, resample, segment_states

__all__ = ["ExpertPlanner", "PlanResult", "derive_seed", "make_planner", "plan_scene"]


@dataclass
class PlanResult:
    """One planning problem's outcome. On success `trajectory` is (waypoints, n) radians and `reason` is ""."""

    success: bool
    trajectory: np.ndarray | None
    reason: str
    # planning_time (s), attempts, joint_path_length (rad), motion_checks (of the attempts not stopped by the
    # clock, whose counts depend on the machine's speed), ...
    stats: dict = field(default_factory=dict)
    q_start: np.ndarray | None = None  # (n,)
    q_goal: np.ndarray | None = None  # (n,)

    def to_record(self) -> dict:
        """JSON-ready summary (no trajectory): success, reason, start, goal, stats."""
        as_list = lambda a: None if a is None else np.asarray(a).tolist()  # noqa: E731
        return {"success": self.success, "reason": self.reason, "q_start": as_list(self.q_start),
                "q_goal": as_list(self.q_goal), "stats": dict(self.stats)}


def _as_config(q, n: int, name: str) -> np.ndarray | None:
    if q is None:
        return None
    if hasattr(q, "detach"):
        q = q.detach().cpu().numpy()
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (n,) or not np.all(np.isfinite(q)):
        raise ValueError(f"{name} must be a finite ({n},) configuration in radians, got shape {q.shape}")
    return q


class ExpertPlanner:
    """OMPL expert for one robot in one scene. Owns a `World` unless one is passed; use as a context
    manager or call `close()`."""

    backend = "ompl"

    def __init__(self, robot, scene, cfg: ExpertConfig | dict | str | None = None, world=None, sampler=None):
        """sampler: None, or `sampler(si) -> ompl.base.ValidStateSampler` for every attempt (`plan_once`)."""
        from samp.sim import World

        self.cfg = cfg if isinstance(cfg, ExpertConfig) else load_expert_config(cfg)
        if self.cfg.backend != "ompl":
            raise ValueError(f"ExpertPlanner is the OMPL backend, but the config asks for backend {self.cfg.backend!r}; "
                             "use samp.expert.make_planner to pick the backend from the config")
        planner_class(self.cfg.planner)  # an unknown name fails here, before any work
        self.robot, self.scene, self.sampler = robot, scene, sampler
        self._owns_world = world is None
        self.world = World(robot, scene) if world is None else world

    def __enter__(self) -> "ExpertPlanner":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._owns_world:
            self.world.close()

    def valid(self, q: np.ndarray) -> np.ndarray:
        """q (B, n) -> (B,) bool: within limits, clear of obstacles by `clearance`, no self-collision."""
        return ~self.world.in_collision(q, margin=self.cfg.clearance)

    def endpoint_problem(self, q: np.ndarray | None, name: str) -> str:
        """Why q (n,) cannot be a start or goal ("" if it can)."""
        from samp.sim.world import LIMIT_TOLERANCE

        if q is None:
            return f"no valid {name}"
        if self.world.outside_limits(q[None])[0]:
            lim = self.robot.joint_limits.double().cpu().numpy()
            beyond = np.maximum(lim[:, 0] - q, q - lim[:, 1])  # (n,) radians past the nearer limit
            bad = [self.robot.joint_names[j] for j in np.flatnonzero(beyond > LIMIT_TOLERANCE)]
            return (f"{name} outside the joint limits at {bad}: {float(beyond.max()):.3g} rad beyond (only "
                    f"{LIMIT_TOLERANCE:g} rad of rounding is moved onto a limit)")
        if self.valid(q[None])[0]:
            return ""
        d = float(self.world.min_distance(q[None])[0])
        if d < 0:
            return f"{name} in collision: penetrates an obstacle by {-d:.4f} m"
        if d < self.cfg.clearance:
            return f"{name} in collision: {d:.4f} m from an obstacle, closer than the clearance {self.cfg.clearance} m"
        return f"{name} in collision: self-collision"

    def plan(self, q_start, q_goal, seed: int = 0, straight_free: bool | None = None) -> PlanResult:
        """Plan from q_start (n,) to q_goal (n,) radians; reproducible for a given seed. `straight_free`:
        whether the straight motion is valid, when the caller has checked it already with the same clearance
        and resolution (`samp.expert.problems.straight_line_blocked`; a sampled problem's `detour`); None:
        checked here."""
        t0, cfg, n = time.perf_counter(), self.cfg, self.robot.dof
        q_start, q_goal = _as_config(q_start, n, "q_start"), _as_config(q_goal, n, "q_goal")
        stats = {"planner": cfg.planner, "backend": self.backend, "seed": int(seed), "attempts": 0, "direct": False,
                 "solve_time": 0.0, "simplify_time": 0.0, "motion_checks": 0}

        def finish(success: bool, traj: np.ndarray | None, reason: str) -> PlanResult:
            stats["planning_time"] = time.perf_counter() - t0
            if traj is not None:
                stats["joint_path_length"] = joint_path_length(traj)
                stats["ee_path_length"] = ee_path_length(self.robot, traj)
            return PlanResult(success, traj if success else None, reason, stats, q_start, q_goal)

        reason = self.endpoint_problem(q_start, "start") or self.endpoint_problem(q_goal, "goal")
        if reason:
            return finish(False, None, reason)
        clipped = self._onto_limits(q_start), self._onto_limits(q_goal)
        stats["endpoint_clip"] = float(max(np.abs(clipped[0] - q_start).max(), np.abs(clipped[1] - q_goal).max()))
        q_start, q_goal = clipped  # what is planned between, returned, and the trajectory's first and last waypoint
        if straight_free is None and cfg.direct:
            straight_free = bool(self.valid(segment_states(np.stack([q_start, q_goal]), cfg.resolution)[0]).all())
        direct = cfg.direct and bool(straight_free)
        valid = _remembering(self.valid)  # OMPL asks about many states again (tree nodes, path vertices)
        for attempt in range(cfg.attempts):
            stats["attempts"] = attempt + 1
            path, reason = self._attempt(q_start, q_goal, derive_seed(seed, attempt), direct, stats, valid)
            if path is None:
                continue
            traj = resample(path, cfg.waypoints)
            traj[0], traj[-1] = q_start, q_goal
            k = first_invalid_segment(self.world, traj, cfg.resolution, cfg.check_margin)
            if k is None:
                return finish(True, traj, "")
            reason = (f"dense check failed at segment {k}: a state between waypoints {k} and {k + 1} is closer than "
                      f"{cfg.check_margin} m to an obstacle or in self-collision")
            direct = False  # the straight motion passed at `resolution` but not densely: plan around it
        return finish(False, None, reason)

    def _onto_limits(self, q: np.ndarray) -> np.ndarray:
        """q (n,) within LIMIT_TOLERANCE of the limits -> q on or within them. A configuration stored from a
        float32 computation can sit a rounding error (~1e-8 rad) beyond a limit: the World accepts it, OMPL's
        `satisfiesBounds` does not."""
        lim = self.robot.joint_limits.double().cpu().numpy()
        return np.clip(q, lim[:, 0], lim[:, 1])

    def _attempt(self, q_start, q_goal, seed: int, direct: bool, stats: dict, valid) -> tuple[np.ndarray | None, str]:
        """One attempt with the validity function `valid`: (path (m, n), "") or (None, reason)."""
        stats["direct"] = direct
        if direct:
            return np.stack([q_start, q_goal]), ""
        out = plan_once(self.robot, self.cfg, valid, q_start, q_goal, seed, self.sampler)
        stats["solve_time"] += out.solve_time
        stats["simplify_time"] += out.simplify_time
        cfg = self.cfg
        gave_up = bool(cfg.planner in ANYTIME and cfg.max_checks and out.motion_checks >= cfg.max_checks)
        if out.solved or gave_up:
            # An attempt stopped by the clock made as many checks as the machine's speed allowed: counting them
            # would make the stored statistics, and so the dataset's bytes and id, differ from run to run.
            stats["motion_checks"] += out.motion_checks
        if out.solved:
            return out.path, ""
        if gave_up:
            return None, f"planner gave up: {cfg.planner} found no solution in {cfg.max_checks} motion checks (OMPL: {out.status})"
        return None, f"planner timeout: {cfg.planner} found no exact solution in {cfg.time_limit} s (OMPL: {out.status})"


def _remembering(valid):
    """`valid` ((B, n) -> (B,) bool, a function of each row alone) that answers a configuration it was asked
    about before from memory, keyed by its exact bytes: the same answers, fewer collision queries. One per
    planning problem, so the memory lives as long as the problem (about a quarter of OMPL's queries, and
    most of its single-state ones, repeat a state of the same problem)."""
    seen: dict[bytes, bool] = {}

    def remembered(q: np.ndarray) -> np.ndarray:
        q = np.ascontiguousarray(q, dtype=np.float64)
        keys = [row.tobytes() for row in q]
        new = [i for i, key in enumerate(keys) if key not in seen]
        if new:
            for i, ok in zip(new, valid(q[new]).tolist()):
                seen[keys[i]] = ok
        return np.fromiter((seen[key] for key in keys), dtype=bool, count=len(keys))

    return remembered


def make_planner(robot, scene, cfg: ExpertConfig | dict | str | None = None, world=None):
    """The planner of `cfg.backend`: `ExpertPlanner` (ompl, the only backend; `load_expert_config` refuses
    `curobo`, planned work described in `samp.expert.curobo`)."""
    cfg = cfg if isinstance(cfg, ExpertConfig) else load_expert_config(cfg)
    return ExpertPlanner(robot, scene, cfg, world)


def plan_scene(robot, scene, count: int, seed: int, cfg: ExpertConfig | dict | str | None = None,
               progress: bool = False) -> list[PlanResult]:
    """Sample `count` problems in `scene` (`samp.expert.problems.sample_problems`) and plan each; a problem
    without a valid goal is a failed `PlanResult` with its reason. Seeded: same seed, same results."""
    from samp.console import Progress
    from samp.expert.problems import sample_problems

    cfg = cfg if isinstance(cfg, ExpertConfig) else load_expert_config(cfg)
    with make_planner(robot, scene, cfg) as planner:
        problems = sample_problems(robot, scene, count, seed, cfg, world=getattr(planner, "world", None))
        results = []
        bar = Progress(len(problems), f"expert {scene.name}", unit="traj", enabled=progress)
        for i, problem in enumerate(problems):
            if problem.q_goal is None:
                result = PlanResult(False, None, problem.reason, {"planner": cfg.planner, "backend": cfg.backend,
                                                                  "attempts": 0, "planning_time": 0.0}, problem.q_start)
            else:
                result = planner.plan(problem.q_start, problem.q_goal, seed=derive_seed(seed, i),
                                      straight_free=None if problem.detour is None else not problem.detour)
            result.stats.update(goal_kind=problem.kind, goal_pose=None if problem.goal_pose is None else problem.goal_pose.tolist())
            results.append(result)
            bar.update()
        bar.close()
    return results
