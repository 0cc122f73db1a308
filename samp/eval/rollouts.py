"""The batched rollout engine: every problem of a batch steps together through a `StepPolicy` in torch.

From q_0 = q_start the engine calls `policy.step` on the problems still running, and after each step
ends a problem when its end-effector is within the goal tolerance (reached), when it has moved less than
`stall_threshold` for `stall_steps` steps in a row (stalled), when the policy returns NaN or inf
(diverged; the last finite configuration is kept), or after `max_steps` steps. A problem keeps running
after a collision: collisions are found afterwards on the executed trajectory (`samp.eval.checks`), so
reaching and colliding are judged independently, as docs/design.md section 4 defines them.

Timing: each `step` call (and `reset`, if the policy has one) is timed with the device synchronised;
a problem's solution time is the wall time of the calls it took part in. With `batch_size` 1 that is
its own planning latency; in a batch it is the batch's latency (the per-problem share is smaller), and
the batch's size / `batch_time` is the batched throughput.
Goal checks and collision checks are not timed: they are the simulator's work, not the planner's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import torch

from samp.eval.checks import ee_poses, exact_robot, goal_errors
from samp.eval.config import RolloutConfig
from samp.eval.planners import EnvBatch
from samp.eval.problems import GridSource, Problem, scene_grids

__all__ = ["RolloutResult", "rollout"]


@dataclass
class RolloutResult:
    """One problem's rollout: the executed trajectory (steps + 1, n) radians, why it ended, and times."""

    trajectory: np.ndarray
    termination: str  # reached | stalled | max_steps | diverged
    solution_time: float | None  # seconds in reset + the step calls this problem took part in
    step_times: list[float]  # seconds per step call
    position_error: float | None  # final, metres (None: a planner that gave no trajectory)
    orientation_error: float | None  # final, degrees
    batch: int = 0  # which rollout batch it was in
    batch_time: float | None = None  # seconds the policy spent on that whole batch (throughput = size / time)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _environments(policy, problems: list[Problem], grid_source: GridSource) -> EnvBatch:
    """One entry per distinct scene (by geometry), grids on the policy's device and dtype."""
    robot = policy.robot
    keys, first, index = {}, [], []
    for p in problems:
        key = p.scene.content_hash()
        if key not in keys:
            keys[key] = len(first)
            first.append(p)
        index.append(keys[key])
    bounds = torch.tensor([p.scene.bounds for p in first], dtype=robot.dtype, device=robot.device)  # (S, 2, 3)
    grids = None
    n_e = getattr(policy, "n_e", None)
    if n_e is not None:
        grids = torch.stack([grid_source(p, n_e) for p in first]).to(device=robot.device, dtype=robot.dtype)
    return EnvBatch(grids, bounds, torch.tensor(index, dtype=torch.long, device=robot.device))


def _check_output(q_next, rows: int, n: int, name: str) -> None:
    if not isinstance(q_next, torch.Tensor) or tuple(q_next.shape) != (rows, n):
        got = tuple(q_next.shape) if isinstance(q_next, torch.Tensor) else type(q_next).__name__
        raise ValueError(f"policy {name!r}: step must return a ({rows}, {n}) tensor of configurations, got {got}")


class _Progress:
    """Per-problem state of one rollout batch, updated after every step (numpy, float64, on the CPU)."""

    def __init__(self, start: np.ndarray, goal_T: np.ndarray, cfg: RolloutConfig, checker_robot):
        B, n = start.shape
        self.cfg, self.robot, self.goal_T = cfg, checker_robot, goal_T
        self.traj = np.empty((cfg.max_steps + 1, B, n))  # (T + 1, B, n)
        self.traj[0] = start
        self.length = np.ones(B, dtype=int)
        self.still = np.zeros(B, dtype=int)
        self.solve = np.zeros(B)
        self.step_times: list[list[float]] = [[] for _ in range(B)]
        self.pos_err, self.rot_err = goal_errors(ee_poses(checker_robot, start), goal_T)
        self.term = np.where(self._within(self.pos_err, self.rot_err), "reached", "").astype(object)
        self.active = self.term == ""

    def _within(self, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
        return (pos < self.cfg.position_tolerance) & (rot < self.cfg.orientation_tolerance)

    def timed(self, idx: np.ndarray, dt: float) -> None:
        self.solve[idx] += dt
        for b in idx:
            self.step_times[b].append(dt)

    def advance(self, t: int, idx: np.ndarray, finite: np.ndarray, q_np: np.ndarray) -> None:
        """Step t's finite results q_np (b, n) for problems idx[finite]; end the reached, stalled, diverged."""
        self.term[idx[~finite]], self.active[idx[~finite]] = "diverged", False
        ok = idx[finite]
        moved = np.linalg.norm(q_np - self.traj[t - 1, ok], axis=1)
        self.traj[t, ok], self.length[ok] = q_np, t + 1
        self.still[ok] = np.where(moved < self.cfg.stall_threshold, self.still[ok] + 1, 0)
        pos, rot = goal_errors(ee_poses(self.robot, q_np), self.goal_T[ok])
        self.pos_err[ok], self.rot_err[ok] = pos, rot
        reached = self._within(pos, rot)
        self.term[ok[reached]], self.active[ok[reached]] = "reached", False
        stalled = ok[~reached & (self.still[ok] >= self.cfg.stall_steps)]
        self.term[stalled], self.active[stalled] = "stalled", False

    def results(self) -> list[RolloutResult]:
        self.term[self.active] = "max_steps"
        return [RolloutResult(self.traj[:self.length[b], b].copy(), str(self.term[b]), float(self.solve[b]),
                              self.step_times[b], float(self.pos_err[b]), float(self.rot_err[b]))
                for b in range(len(self.length))]


def _rollout_batch(policy, problems: list[Problem], cfg: RolloutConfig, checker_robot,
                   grid_source: GridSource) -> list[RolloutResult]:
    robot, name = policy.robot, getattr(policy, "name", type(policy).__name__)
    device, dtype = robot.device, robot.dtype
    start_np, goal_np = np.stack([p.q_start for p in problems]), np.stack([p.q_goal for p in problems])  # (B, n)
    state = _Progress(start_np, ee_poses(checker_robot, goal_np), cfg, checker_robot)
    env = _environments(policy, problems, grid_source)
    q = torch.as_tensor(start_np, dtype=dtype, device=device)
    goal = torch.as_tensor(goal_np, dtype=dtype, device=device)
    with torch.no_grad():
        if hasattr(policy, "reset"):
            t0 = time.perf_counter()
            policy.reset(env)
            _sync(device)
            state.solve += time.perf_counter() - t0
        for t in range(1, cfg.max_steps + 1):
            idx = np.flatnonzero(state.active)
            if len(idx) == 0:
                break
            rows = torch.as_tensor(idx, device=device)
            t0 = time.perf_counter()
            q_next = policy.step(q[rows], goal[rows], env.subset(rows))
            _sync(device)
            state.timed(idx, time.perf_counter() - t0)
            _check_output(q_next, len(idx), robot.dof, name)
            finite = torch.isfinite(q_next).all(dim=1)
            q[rows[finite]] = q_next[finite].to(dtype)
            state.advance(t, idx, finite.cpu().numpy(), q_next[finite].double().cpu().numpy())
    return state.results()


def rollout(policy, problems: list[Problem], cfg: RolloutConfig, grid_source: GridSource | None = None,
            checker_robot=None) -> list[RolloutResult]:
    """Roll `policy` out on `problems` in batches of `cfg.batch_size` (None: all at once).

    Args:
        policy: a `StepPolicy`.
        problems: the problems, in order; results come back in the same order.
        grid_source: (problem, n_e) -> (n_e, n_e, n_e) grid, for policies with `n_e`; default: the scene's
            exact anchor grid (`scene.anchor_grid`, disk-cached).
        checker_robot: a float64 CPU robot for goal checks (default: a copy of the policy's robot).
    """
    if not problems:
        return []
    n = policy.robot.dof
    bad = [p.name or str(i) for i, p in enumerate(problems) if len(p.q_start) != n]
    if bad:
        raise ValueError(f"problems {bad[:5]} have {len(problems[0].q_start)} joints but the policy's robot "
                         f"{policy.robot.name!r} has {n}")
    checker_robot = checker_robot or exact_robot(policy.robot)
    size = cfg.batch_size or len(problems)
    out: list[RolloutResult] = []
    for k, i in enumerate(range(0, len(problems), size)):
        batch = _rollout_batch(policy, problems[i:i + size], cfg, checker_robot, grid_source or scene_grids)
        wall = max(r.solution_time for r in batch)  # every call of the batch had its longest-running problem in it
        out += [replace(r, batch=k, batch_time=wall) for r in batch]
    return out
