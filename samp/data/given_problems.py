"""Problems a scene file gives (`problems_from_files`): its starts and goals, checked, to be planned by the expert.

A problem set gives each problem a start and a list of goal configurations (`goal_ik`, all reaching one goal
pose). Each becomes one `PlanningProblem` of kind "file":

* the start must be a state the expert can plan from: within the joint limits, `clearance` clear of every
  obstacle and free of self-collision (the checks every sampled start passes). A value beyond a limit by
  at most `LIMIT_SNAP` radians is a float32 rounding of the limit (files store 3.7525 as 3.7525000572) and
  is moved onto it; further is outside.
* the goal is the valid `goal_ik` configuration (the same checks) nearest to the start in joint space, as
  the expert picks among its own IK solutions (`goal_select: nearest`).

A problem whose start, or every goal, fails is skipped: it is kept with q_goal None and a reason that says
which check failed (`no valid start (...)`, `no valid goal (...)`), so the dataset's summary counts the
skipped problems by reason, and evaluation leaves them out (there is nothing to plan). The goal pose stored
with a problem is the robot's own end-effector pose at the goal (the file's pose may name another link).
"""

from __future__ import annotations

import numpy as np

__all__ = ["LIMIT_SNAP", "given_problems"]

LIMIT_SNAP = 1e-6  # radians; the float32 spacing near pi is 2.4e-7


def _snapped(q: np.ndarray, lim: np.ndarray) -> np.ndarray:
    """(B, n) configurations moved onto a joint limit where they pass it by at most LIMIT_SNAP."""
    lo, hi = lim[:, 0], lim[:, 1]
    q = np.where((q < lo) & (q >= lo - LIMIT_SNAP), lo, q)
    return np.where((q > hi) & (q <= hi + LIMIT_SNAP), hi, q)


def _failures(robot, world, q: np.ndarray, clearance: float) -> list[str]:
    """(B, n) -> per configuration "" (valid) or why not: "joint limits", "obstacles" or "self-collision"."""
    lim = robot.joint_limits.double().cpu().numpy()
    outside = ((q < lim[:, 0]) | (q > lim[:, 1])).any(axis=1)
    near = world.in_collision(q, margin=clearance, self_collision=False, joint_limits=False)
    hit = world.in_collision(q, margin=clearance, self_collision=True, joint_limits=False)
    return ["joint limits" if o else "obstacles" if n else "self-collision" if h else ""
            for o, n, h in zip(outside, near, hit)]


def _ee_pose(robot, q: np.ndarray) -> np.ndarray:
    import torch

    T = robot.fk(torch.as_tensor(q[None], dtype=robot.dtype, device=robot.device))[robot.ee_link]  # (1, 4, 4)
    return T[0].double().cpu().numpy()


def given_problems(robot, world, problems, cfg) -> list:
    """FileProblems (`samp.scene.worlds`) -> PlanningProblems for the expert (module docstring); ValueError
    when a problem's configurations do not have the robot's number of joints."""
    from samp.expert.problems import PlanningProblem, straight_line_blocked

    lim = robot.joint_limits.double().cpu().numpy()
    clear = f"{cfg.clearance} m"
    out = []
    for p in problems:
        if len(p.start) != robot.dof:
            raise ValueError(f"problem {p.where} gives {len(p.start)} joint values, robot {robot.name!r} has "
                             f"{robot.dof} joints")
        start, goals = _snapped(p.start[None], lim)[0], _snapped(p.goals, lim)
        why = _failures(robot, world, start[None], cfg.clearance)[0]
        if why:
            out.append(PlanningProblem(start, None, None, "file", f"no valid start ({why}): problem {p.where}'s start "
                                       f"fails the expert's check ({why}, clearance {clear})"))
            continue
        failures = _failures(robot, world, goals, cfg.clearance)
        valid = np.array([f == "" for f in failures])
        if not valid.any():
            counts = {f: failures.count(f) for f in sorted(set(failures))}
            main = max(counts, key=counts.get)
            why = (f"no valid goal ({main}): none of problem {p.where}'s {len(goals)} goal_ik configurations passes "
                   f"the expert's check (clearance {clear}); failed by {counts}")
            out.append(PlanningProblem(start, None, None, "file", why))
            continue
        candidates = goals[valid]
        goal = candidates[int(np.argmin(np.linalg.norm(candidates - start, axis=1)))].copy()
        out.append(PlanningProblem(start, goal, _ee_pose(robot, goal), "file",
                                   detour=straight_line_blocked(world, start, goal, cfg)))
    return out
