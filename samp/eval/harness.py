"""`evaluate(planner, problems)`: roll out or replay, check in pybullet, and compute the metrics per split.

Step policies are rolled out in batches (`samp.eval.rollouts`); trajectory planners (the expert) answer
each problem; both trajectories then go through the same checks (`samp.eval.checks`) and the same
metric code (`samp.eval.metrics`), so the policy and the expert are compared on equal terms.
"""

from __future__ import annotations

import inspect
from dataclasses import asdict, replace

import numpy as np

from samp.console import Progress
from samp.eval.checks import TrajectoryChecker, ee_poses, exact_robot, goal_errors, polyline_length
from samp.eval.config import RolloutConfig, rollout_config
from samp.eval.rollouts import RolloutResult, rollout
from samp.eval.metrics import reached_within, summarize
from samp.eval.names import ALL_SPLITS
from samp.eval.planners import StepPolicy, TrajectoryPlanner
from samp.eval.problems import GridSource, Problem

__all__ = ["evaluate", "planner_name", "reads_grids", "resolve_robot"]


def planner_name(planner) -> str:
    return str(getattr(planner, "name", type(planner).__name__))


def resolve_robot(planner, problems: list[Problem], robot=None):
    """The robot to check with: `robot`, else the planner's, else the one the problems name. Refuses a
    planner for another robot than the problems were made for."""
    from samp.robot import load_robot

    robot = robot or getattr(planner, "robot", None)
    wanted = {p.robot for p in problems if p.robot}
    if len(wanted) > 1:
        raise ValueError(f"the problems were made for different robots {sorted(wanted)}; evaluate them separately")
    if robot is None:
        if not wanted:
            raise ValueError("no robot to evaluate with: the planner has none and the problems name none; "
                             "pass evaluate(..., robot=load_robot(NAME))")
        robot = load_robot(next(iter(wanted)))
    if wanted and robot.name not in wanted:
        raise ValueError(f"planner {planner_name(planner)!r} controls robot {robot.name!r}, but the problems were made "
                         f"for {sorted(wanted)[0]!r}; evaluate it on a dataset of its own robot")
    n = {len(p.q_start) for p in problems}
    if n != {robot.dof}:
        raise ValueError(f"robot {robot.name!r} has {robot.dof} joints but the problems have {sorted(n)}")
    return robot


def reads_grids(planner) -> bool:
    """Whether a trajectory planner reads anchor grids: its `plan` takes `grids` (a `GridSource`), as
    samp+check does; the evaluation then hands it the section's grids (exact or reconstructed)."""
    try:
        return "grids" in inspect.signature(planner.plan).parameters
    except (TypeError, ValueError):  # a builtin or C callable: no signature to read, so no grids
        return False


def _plan_all(planner, problems: list[Problem], robot, bar=None, grids: GridSource | None = None
              ) -> list[RolloutResult | None]:
    """Answers of a trajectory planner as rollout results (None where it failed), goal errors at the end.
    A planner that reads grids (`reads_grids`) plans on `grids`, the section's source."""
    out = []
    extra = {"grids": grids} if grids is not None and reads_grids(planner) else {}
    for p in problems:
        if bar is not None:
            bar.update()
        answer = planner.plan(p, **extra)
        if answer.trajectory is None:
            out.append(RolloutResult(np.asarray(p.q_start)[None], f"failed: {answer.reason}", answer.solution_time,
                                     [], None, None))
            continue
        traj = np.asarray(answer.trajectory, dtype=np.float64)
        pos, rot = goal_errors(ee_poses(robot, traj[-1:]), ee_poses(robot, p.q_goal[None]))
        out.append(RolloutResult(traj, "planned", answer.solution_time, [], float(pos[0]), float(rot[0])))
    return out


def _rollout_batches(policy, problems: list[Problem], cfg: RolloutConfig, grids, checker_robot,
                     bar) -> list[RolloutResult]:
    """`rollout` one batch of `cfg.batch_size` at a time, so that progress can be shown between batches;
    the batches are numbered as `rollout` numbers them."""
    size = cfg.batch_size or len(problems)
    out: list[RolloutResult] = []
    for k, i in enumerate(range(0, len(problems), size)):
        batch = rollout(policy, problems[i:i + size], replace(cfg, batch_size=None), grids, checker_robot)
        out += [replace(r, batch=k) for r in batch]
        bar.update(len(batch))
    return out


def _records(planner, problems: list[Problem], results: list[RolloutResult], checker: TrajectoryChecker,
             cfg: RolloutConfig, bar=None) -> list[dict]:
    robot = checker.robot
    records: list[dict | None] = [None] * len(problems)
    by_scene: dict[str, list[int]] = {}
    for i, p in enumerate(problems):
        by_scene.setdefault(p.scene.content_hash(), []).append(i)
    for rows in by_scene.values():
        valid = [i for i in rows if results[i].position_error is not None]  # planner failures carry no path
        checks = dict(zip(valid, checker.check(problems[rows[0]].scene, [results[i].trajectory for i in valid])))
        if bar is not None:
            bar.update(len(rows))
        for i in rows:
            p, r = problems[i], results[i]
            c = checks.get(i) or {"collision": False, "first_collision_step": None, "collision_depth": 0.0,
                                  "first_collision_state": None, "self_collision": False,
                                  "first_self_collision_step": None, "joint_limit_violation": False,
                                  "first_limit_step": None, "checked_states": 0}
            failed = r.position_error is None
            reached = reached_within(r.position_error, r.orientation_error, cfg)
            violation = c["collision"] or c["self_collision"] or c["joint_limit_violation"]
            records[i] = {
                "planner": planner_name(planner), "problem": p.name, "split": p.split, "scene": p.scene.name,
                "scene_index": p.scene_index, "termination": r.termination, "steps": len(r.trajectory) - 1,
                "reached": reached, "success": {k: v and not violation for k, v in reached.items()},
                "position_error": r.position_error, "orientation_error": r.orientation_error, **c,
                "path_length": None if failed else polyline_length(ee_poses(robot, r.trajectory)[:, :3, 3]),
                "joint_path_length": None if failed else float(np.linalg.norm(np.diff(r.trajectory, axis=0), axis=1).sum()),
                "solution_time": r.solution_time, "step_times": list(r.step_times),
                "inference_time": float(np.mean(r.step_times)) if r.step_times else None,
                "batch": None if r.batch_time is None else r.batch,  # None: answered alone (a trajectory planner)
                "batch_time": r.solution_time if r.batch_time is None else r.batch_time,
                # one problem at a time: a trajectory planner always answers so; a step policy for the
                # problems `_time_one_at_a_time` rolls out again alone
                "solution_time_b1": r.solution_time if r.batch_time is None else None, "step_times_b1": [],
                "q_start": p.q_start.tolist(), "q_goal": p.q_goal.tolist(), "trajectory": r.trajectory.tolist(),
            }
    return records


def timed_rows(count: int, total: int) -> list[int]:
    """`count` problem indices spread evenly over `total` (all of them when count >= total)."""
    if count >= total:
        return list(range(total))
    return sorted({int(round(i)) for i in np.linspace(0, total - 1, count)})


def _time_one_at_a_time(policy, problems: list[Problem], records: list[dict], cfg: RolloutConfig, grids,
                        checker_robot) -> None:
    """Roll `cfg.timed_problems` problems out again alone (B = 1) and put their solution and step times in
    their records: the per-problem latency the paper's tables report, apart from the batched outcomes."""
    single = replace(cfg, batch_size=1)
    for i in timed_rows(cfg.timed_problems, len(problems)):
        (alone,) = rollout(policy, [problems[i]], single, grids, checker_robot)
        records[i]["solution_time_b1"], records[i]["step_times_b1"] = alone.solution_time, list(alone.step_times)


def evaluate(planner, problems: list[Problem], config: RolloutConfig | dict | None = None, *, robot=None,
             grids: GridSource | None = None, progress_s: float | None = None) -> dict:
    """Evaluate `planner` on `problems` with the definitions of docs/design.md section 4.

    Args:
        planner: a `StepPolicy` (rolled out in batches) or a `TrajectoryPlanner` (e.g. `load_planner("expert")`).
        problems: `Problem`s; metrics are given per `problem.split` and pooled under "all".
        config: a `RolloutConfig` or a mapping of its keys (max_steps, tolerances, sub-steps, stall, batch_size).
        robot: the robot to check with (default: the planner's, else the one the problems name).
        grids: where a policy's anchor grids come from (default: each scene's exact `anchor_grid`); also handed
            to a trajectory planner whose `plan` takes `grids` (samp+check), so it steps and checks on them.
        progress_s: show progress (rollout batches, plans, checks) on stderr: a bar on a terminal, else a
            line every `progress_s` seconds and one per phase at its end; None: silent.
    Returns:
        {"planner": name, "metrics": {split: metrics, ..., "all": metrics}, "records": [one per problem],
         "config": the rollout config as a dict}. A step policy's outcomes come from batched rollouts
        (`config.batch_size`); `config.timed_problems` of the problems are also rolled out alone for the
        B = 1 solution and step times (`solution_time_b1`, `step_time_b1` in the metrics).
    """
    cfg = rollout_config(config)
    problems = list(problems)
    if not problems:
        raise ValueError("no problems to evaluate; take some with samp.eval.problems_from_dataset(ds, split, count)")
    if not all(isinstance(p, Problem) for p in problems):
        raise TypeError("problems must be samp.eval.Problem instances")
    is_policy, is_planner = isinstance(planner, StepPolicy), isinstance(planner, TrajectoryPlanner)
    if not (is_policy or is_planner):
        raise TypeError(f"{type(planner).__name__} is neither a StepPolicy (robot, n_e, name, step) nor a "
                        "TrajectoryPlanner (name, plan); see samp.eval.planners")
    checker_robot = exact_robot(resolve_robot(planner, problems, robot))
    splits: dict[str, list[int]] = {}
    for i, p in enumerate(problems):
        splits.setdefault(p.split, []).append(i)
    records: list[dict | None] = [None] * len(problems)
    name = planner_name(planner)
    with TrajectoryChecker(checker_robot, cfg.substep_resolution) as checker:
        for split, rows in splits.items():  # one split at a time: its batch timings are its own
            subset = [problems[i] for i in rows]
            with Progress(len(subset), f"  {name} {split}: {'rollouts' if is_policy else 'plans'}", "problem",
                          every_s=progress_s or 0.0, enabled=progress_s is not None) as bar:
                results = _rollout_batches(planner, subset, cfg, grids, checker_robot, bar) if is_policy else \
                    _plan_all(planner, subset, checker_robot, bar, grids)
            with Progress(len(subset), f"  {name} {split}: checks", "problem", every_s=progress_s or 0.0,
                          enabled=progress_s is not None) as bar:
                checked = _records(planner, subset, results, checker, cfg, bar)
            for i, rec in zip(rows, checked):
                if rec["batch"] is not None:  # batches are numbered per split: make them unique over all
                    rec["batch"] = f"{problems[i].split}/{rec['batch']}"
                records[i] = rec
    if is_policy:
        _time_one_at_a_time(planner, problems, records, cfg, grids, checker_robot)
    metrics = {split: summarize([records[i] for i in rows], cfg) for split, rows in splits.items()}
    metrics[ALL_SPLITS] = summarize(records, cfg)
    return {"planner": planner_name(planner), "metrics": metrics, "records": records, "config": asdict(cfg)}
