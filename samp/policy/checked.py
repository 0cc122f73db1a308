"""samp+check: several rollouts of a step policy in one batch, and the one the scene's anchor grid says is
clear (after Neural MP's sample-and-check; docs/design.md section 4).

Candidate 0 is the plain rollout. Candidates 1 to `noisy` are the policy's own rollouts with noise: they head
for the goal from the start, and each step gets Gaussian noise of `step_noise` radians per joint (seeded by
the problem's name) while the candidate is farther than `finish` radians from the goal and within the first
third of `max_steps`, so they explore around the plain rollout's path (as Neural MP samples its own rollouts).
Every other candidate first heads for a via configuration drawn around the midpoint of start and goal (normal,
`spread` radians per joint, seeded by the problem's name), and from there (within `via_reach` radians of it,
or after a third of `max_steps`) for the goal. All candidates step together, one policy call per step. After
each step the new segment of every candidate is checked against the anchor grid: the grid's SDF, trilinear at
the robot points posed at `substeps` configurations along the segment, must stay above `margin` metres (a
candidate's clearance is the smallest value read so far). Goals often lie close to surfaces (a target in a
cabinet), where the grid reads less than the margin at the goal itself: where a segment lies within `finish`
radians of the goal, it must only keep the goal's own reading less `goal_slack` when that is lower. A
candidate that stalls within `finish` radians of the goal configuration ends on the straight segment to it
when the grid says that segment is clear too (the learned policy tends to stop a few centimetres short of
goals close to surfaces). The first candidate to reach the goal with a clear record is the answer. A candidate
that fails the check steps on to the goal all the same, and when none reaches it clear, the answer is the one
that reached it with the most slack, its least clearance less what each segment had to keep (the plain rollout
on ties, or when none reached it).

The check reads the same anchor grid the policy reads, so obstacles cost grid samples, not collision queries:
the scene's exact SDF at n_e anchors by default, or the grid the evaluation's section hands to `plan`
(`grids`, a `(problem, n_e) -> grid` source): with `grid_source=reconstructed` both the policy and the check
see the grid reconstructed from the cameras, never the exact one. `n_e` gives the check a grid of its own
resolution from the same source. A robot point outside the grid's bounds (below its lowest anchors, near
the table top) reads the border value less its distance to the bounds, a lower bound of a signed distance.
With `self_collision` (the default) a checked configuration is also unclear where the robot touches itself:
its own convex parts in a simulator world without obstacles, the check the evaluation makes (the planner
knows the robot's geometry, as the expert does).
Its solution time is the whole call: encoding, steps and checks (fetching or reconstructing the grid is not
timed, as for the rollout engine's step policies).
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass

import numpy as np
import torch

from samp.policy.interface import EnvBatch, PlannedTrajectory, clamp_to_limits
from samp.robot.goal import ee_poses, goal_errors
from samp.scene.grid import sample_grid

__all__ = ["CheckConfig", "CheckedPolicy"]

FINISH_RESOLUTION = 0.02  # rad between the checked states of a finishing segment (the evaluation's substep_resolution)


@dataclass
class CheckConfig:
    """How many candidates, how they spread, and what counts as clear (radians, metres)."""

    candidates: int = 8  # rollouts per problem, the plain one included
    noisy: int = 0  # of them, the policy's own rollouts with noise on its steps (the rest: via configurations)
    step_noise: float = 0.05  # std of the noise on a noisy candidate's step (rad per joint)
    spread: float = 0.6  # std of the via configurations around the start-goal midpoint, per joint
    via_reach: float = 0.15  # a candidate turns to the goal within this of its via configuration ...
    margin: float = 0.01  # clear: the grid's SDF at every robot point stays above this
    goal_slack: float | None = 0.005  # within `finish` of the goal, reading no less than the goal itself less this
    # (metres) is clear too (goals lie close to surfaces); None: `margin` everywhere
    substeps: int = 3  # configurations checked per step (the step's end included)
    self_collision: bool = True  # a checked configuration where the robot touches itself is not clear
    n_e: int | None = None  # anchors per axis of the grid the check reads, from the policy's grid source; None: its n_e
    finish: float = 0.5  # a candidate that stalls this close to the goal (rad) ends on a straight checked segment
    max_steps: int = 150
    position_tolerance: float = 0.02
    orientation_tolerance: float = 15.0
    stall_threshold: float = 1e-3
    stall_steps: int = 10
    seed: int = 0

    def __post_init__(self):
        if not (isinstance(self.candidates, int) and self.candidates >= 1):
            raise ValueError(f"check.candidates must be an integer >= 1, got {self.candidates!r}")
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"check.substeps must be an integer >= 1, got {self.substeps!r}")
        if self.finish < 0:
            raise ValueError(f"check.finish must be >= 0 radians (0: no straight finish), got {self.finish}")
        if not (isinstance(self.noisy, int) and 0 <= self.noisy < self.candidates):
            raise ValueError(f"check.noisy must be an integer in [0, candidates - 1 = {self.candidates - 1}] (candidate "
                             f"0 is the plain rollout), got {self.noisy!r}")
        if self.step_noise < 0:
            raise ValueError(f"check.step_noise must be >= 0 radians, got {self.step_noise}")
        if self.n_e is not None and not (isinstance(self.n_e, int) and self.n_e >= 2):
            raise ValueError(f"check.n_e must be null (the policy's own anchors) or an integer >= 2 (anchors per "
                             f"axis of the grid the check reads), got {self.n_e!r}")
        if self.goal_slack is not None and not self.goal_slack >= 0:
            raise ValueError(f"check.goal_slack must be null or >= 0 metres, got {self.goal_slack!r}")
        if self.spread < 0 or self.via_reach <= 0:
            raise ValueError(f"check.spread must be >= 0 and check.via_reach > 0 radians, got {self.spread}, "
                             f"{self.via_reach}")


class CheckedPolicy:
    """A `TrajectoryPlanner` around a `SAMPStepPolicy` (`plan(problem) -> PlannedTrajectory`)."""

    def __init__(self, policy, config: CheckConfig | None = None, name: str = "samp+check"):
        self.policy, self.cfg, self.name = policy, config or CheckConfig(), name
        self.robot, self.n_e = policy.robot, policy.n_e
        self.chosen: dict[str, int] = {"plain": 0, "noisy": 0, "via": 0, "unclear": 0, "unreached": 0}
        self._free = None  # the robot alone in a simulator world, for the self-collision check (made on first use)

    def close(self) -> None:
        """Release the self-collision check's simulator client (made again if `plan` is called later)."""
        if self._free is not None:
            self._free.close()
            self._free = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may already be gone
            pass

    def _self_hits(self, qs: torch.Tensor) -> np.ndarray:
        """(C, n) configurations -> (C,) bool: the robot touches itself (collision links that are not excluded
        as neighbours), by the robot's convex parts in a world without obstacles: the evaluation's check."""
        if self._free is None:
            from samp.scene import Scene
            from samp.sim import World

            self._free = World(self.robot, Scene(name="no_obstacles"))
        return self._free.in_collision(qs, margin=0.0, self_collision=True, joint_limits=False)

    def _vias(self, start: torch.Tensor, goal: torch.Tensor, key: str) -> torch.Tensor:
        """(K, n) the targets of the first leg: the goal for candidate 0 and the noisy ones, via configurations
        for the others."""
        K = self.cfg.candidates
        g = torch.Generator().manual_seed(zlib.crc32(f"{self.cfg.seed}/{key}".encode()))
        noise = torch.randn(K, len(start), generator=g, dtype=torch.float64).to(start)
        vias = clamp_to_limits(self.robot, (start + goal) / 2 + self.cfg.spread * noise)
        vias[:self.cfg.noisy + 1] = goal
        return vias

    def _clearance(self, grid: torch.Tensor, bounds, q0: torch.Tensor, q1: torch.Tensor,
                   substeps: int | None = None) -> torch.Tensor:
        """(R,) the smallest grid SDF at the robot points over `substeps` configurations from q0 to q1 (R, n);
        -inf where the robot touches itself at one of them (`self_collision`).

        A point outside the grid's bounds reads the border value less its distance to the bounds: a signed
        distance changes by at most that much, so the table top below the grid's lowest anchors is not read
        as clear."""
        s = substeps or self.cfg.substeps
        t = torch.arange(1, s + 1, dtype=q0.dtype, device=q0.device) / s
        qs = (q0[:, None] + t[None, :, None] * (q1 - q0)[:, None]).reshape(-1, q0.shape[1])  # (R s, n)
        points = self.robot.transform_points(qs).reshape(-1, 3)  # (R s M, 3)
        lo, hi = (torch.as_tensor(b, dtype=points.dtype, device=points.device) for b in bounds)
        outside = torch.maximum(lo - points, points - hi).clamp(min=0).norm(dim=1)
        d = (sample_grid(grid, points, bounds) - outside.to(grid.dtype)).view(len(q0), -1).amin(dim=1)
        if self.cfg.self_collision:
            hit = torch.as_tensor(self._self_hits(qs).reshape(len(q0), s).any(axis=1), device=d.device)
            d = d.masked_fill(hit, -float("inf"))
        return d

    def _near_margin(self, grid: torch.Tensor, bounds, goal: torch.Tensor) -> float:
        """The clearance a segment within `finish` radians of the goal must keep: `margin`, or less where the goal
        itself reads less (its reading less `goal_slack`): a goal close to a surface is reached close to it."""
        if self.cfg.goal_slack is None:
            return self.cfg.margin
        at_goal = float(self._clearance(grid, bounds, goal[None], goal[None], 1)[0])
        return min(self.cfg.margin, at_goal - self.cfg.goal_slack) if np.isfinite(at_goal) else self.cfg.margin

    def _slack(self, grid: torch.Tensor, bounds, q0: torch.Tensor, q1: torch.Tensor, goal: torch.Tensor,
               near: float) -> np.ndarray:
        """(R,) each segment's clearance less what it must keep: `near` where both its ends lie within `finish`
        radians of the goal, else `margin` (above 0: clear)."""
        close = torch.maximum((q0 - goal).norm(dim=1), (q1 - goal).norm(dim=1)) < self.cfg.finish
        keep = np.where(close.cpu().numpy(), near, self.cfg.margin)
        return self._clearance(grid, bounds, q0, q1).double().cpu().numpy() - keep

    def _finishes(self, grid: torch.Tensor, bounds, q: torch.Tensor, goal: torch.Tensor, slack: float,
                  near: float) -> bool:
        """Whether a candidate stalled at q (clear so far: `slack` > 0) ends on the straight segment to the goal:
        within `finish` radians of it, and the segment's clearance above `near` at sub-steps of at most
        FINISH_RESOLUTION."""
        dist = float((goal - q).norm())
        if self.cfg.finish <= 0 or dist > self.cfg.finish or slack <= 0:
            return False
        steps = max(1, int(np.ceil(dist / FINISH_RESOLUTION)))
        return float(self._clearance(grid, bounds, q[None], goal[None], steps)[0]) > near

    def _grid_env(self, problem, grids) -> EnvBatch:
        """The one-scene `EnvBatch` both the policy and the check read: the scene's exact anchor grid, or
        `grids(problem, n_e)` (the evaluation's grid source), after checking the scene's bounds."""
        if grids is None:
            return self.policy._environment(problem.scene)
        bounds = np.asarray(self.policy.system.bounds, dtype=np.float64)
        if not np.allclose(np.asarray(problem.scene.bounds, dtype=np.float64), bounds, atol=1e-9):
            raise ValueError(f"scene {problem.scene.name!r} has workspace bounds {problem.scene.bounds}; the policy "
                             f"was trained on {self.policy.system.bounds}")
        return self.policy._environment(grids(problem, self.n_e))

    def _check_grid(self, problem, grids, env1: EnvBatch) -> torch.Tensor:
        """The grid the check reads: the policy's own, or at `n_e` anchors from the same source (the scene's
        exact grid, or `grids(problem, n_e)`)."""
        n_e = self.cfg.n_e
        if n_e is None or n_e == self.n_e:
            return env1.grids[0]
        grid = problem.scene.anchor_grid(n_e, self.policy.system.bounds) if grids is None else grids(problem, n_e)
        return torch.as_tensor(grid).to(device=env1.grids.device, dtype=env1.grids.dtype)

    def plan(self, problem, grids=None) -> PlannedTrajectory:
        """problem: a `samp.eval.Problem` (its scene, q_start, q_goal) -> the chosen trajectory.
        grids: None (the scene's exact anchor grid) or a grid source `(problem, n_e) -> (n_e, n_e, n_e)`,
        the grid the policy steps on and the candidates are checked against."""
        cfg, robot, policy = self.cfg, self.robot, self.policy
        dev, dt = robot.device, robot.dtype
        env1 = self._grid_env(problem, grids)  # before the clock, as the rollout engine fetches grids untimed
        grid = self._check_grid(problem, grids, env1)
        t0 = time.perf_counter()
        K = cfg.candidates
        env = EnvBatch(env1.grids, env1.bounds, torch.zeros(K, dtype=torch.long, device=dev))
        bounds = policy.system.bounds
        start = torch.as_tensor(np.asarray(problem.q_start), dtype=dt, device=dev)
        goal = torch.as_tensor(np.asarray(problem.q_goal), dtype=dt, device=dev)
        goal_pose = ee_poses(robot, np.asarray(problem.q_goal, dtype=np.float64)[None])
        targets = self._vias(start, goal, problem.name or "")
        heading_goal = torch.zeros(K, dtype=torch.bool, device=dev)
        heading_goal[:cfg.noisy + 1] = True
        noisy = torch.zeros(K, dtype=torch.bool, device=dev)
        noisy[1:cfg.noisy + 1] = True
        shake = torch.Generator().manual_seed(zlib.crc32(f"{cfg.seed}/noise/{problem.name or ''}".encode()))
        q = start.repeat(K, 1)
        path = [q.double().cpu().numpy()]
        near = self._near_margin(grid, bounds, goal)
        slack = self._slack(grid, bounds, q, q, goal, near)  # so far, the least clearance less what it must keep
        done = np.zeros(K, dtype=bool)
        reached = np.zeros(K, dtype=bool)
        finished = np.zeros(K, dtype=bool)  # reached by the straight segment after a stall
        still = np.zeros(K, dtype=int)
        ends = np.full(K, -1)
        chosen = None
        with torch.inference_mode():
            policy.reset(env)
            for step in range(cfg.max_steps):
                active = torch.as_tensor(np.flatnonzero(~done), device=dev)
                q_next = q.clone()
                q_next[active] = policy.step(q[active], targets[active], env.subset(active))
                if cfg.noisy and step < cfg.max_steps // 3:  # the noisy candidates explore on their way out
                    running = torch.as_tensor(~done, device=dev)  # a finished candidate keeps its end
                    far = noisy & running & ((q_next - goal).norm(dim=1) > cfg.finish)
                    kick = cfg.step_noise * torch.randn(K, len(start), generator=shake, dtype=torch.float64)
                    q_next = torch.where(far[:, None], clamp_to_limits(robot, q_next + kick.to(q_next)), q_next)
                slack = np.minimum(slack, self._slack(grid, bounds, q, q_next, goal, near))
                moved = (q_next - q).norm(dim=1).cpu().numpy()
                q = q_next
                q_np = q.double().cpu().numpy()
                path.append(q_np)
                turn = (~heading_goal) & (((q - targets).norm(dim=1) < cfg.via_reach) | (step >= cfg.max_steps // 3))
                targets[turn], heading_goal[turn] = goal, True
                pos, rot = goal_errors(ee_poses(robot, q_np), goal_pose)
                hg = heading_goal.cpu().numpy()
                for k in np.flatnonzero(~done):
                    still[k] = still[k] + 1 if moved[k] < cfg.stall_threshold else 0
                    if hg[k] and pos[k] < cfg.position_tolerance and rot[k] < cfg.orientation_tolerance:
                        done[k], reached[k], ends[k] = True, True, step + 1
                    elif (still[k] >= cfg.stall_steps and hg[k]) or not np.isfinite(q_np[k]).all():
                        done[k], ends[k] = True, step + 1
                        if still[k] >= cfg.stall_steps and self._finishes(grid, bounds, q[k], goal, slack[k], near):
                            reached[k] = finished[k] = True
                winners = np.flatnonzero(reached & (slack > 0))
                if len(winners):
                    chosen = int(winners[0])
                    break
                if done.all():
                    break
        if chosen is not None:
            self.chosen["plain" if chosen == 0 else "noisy" if chosen <= cfg.noisy else "via"] += 1
        else:  # none reached the goal clear: the one that reached it with the most slack (plain on ties)
            reachers = np.flatnonzero(reached)
            chosen = int(reachers[np.argmax(slack[reachers])]) if len(reachers) else 0
            self.chosen["unclear" if reached[chosen] else "unreached"] += 1
        end = ends[chosen] if ends[chosen] >= 0 else len(path) - 1
        trajectory = np.stack([p[chosen] for p in path[:end + 1]]
                              + ([np.asarray(problem.q_goal, dtype=np.float64)] if finished[chosen] else []))
        return PlannedTrajectory(trajectory, time.perf_counter() - t0,
                                 "" if reached[chosen] else "no candidate reached the goal")
