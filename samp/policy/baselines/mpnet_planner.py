"""MPNet-style planning with a trained `MPNetSystem` (after Qureshi et al., T-RO 2020, Algorithms 1-4),
as a `TrajectoryPlanner` (samp.policy.interface): `plan(problem) -> PlannedTrajectory`.

  1. Bidirectional rollout: two chains grow from the start and from the goal, one network step at a
     time and alternating, each toward the other chain's last state, until the straight segment between
     the two ends is collision-free (checked in `samp.sim.World`); the chains are then joined.
  2. Lazy states contraction: from each kept state, jump to the farthest later state reachable by a
     collision-free straight segment (at most `contract_tries` candidates per state).
  3. Feasibility and replanning: states in collision are dropped, every segment is checked, and each
     infeasible one is replaced by a new bidirectional rollout between its ends. Dropout stays active,
     so a retry proposes different states. After `replan_rounds` rounds or `time_limit` seconds it
     fails with the reason, or hands the problem to the OMPL expert (`fallback: ompl`, MPNet's hybrid).
The first round is step 3 applied to the one-segment path [start, goal], so steps 1 and 3 are the same
code. The returned path keeps its states and adds points on its segments up to about `waypoints`, so
the evaluation checks exactly the polyline that was planned.

Solution time is the wall time of `plan` after the scene's World and anchor grid exist (as the expert's
planning time excludes building its World, and a policy is handed its grid): network calls, the obstacle
encoding and every collision check count.
"""

from __future__ import annotations

import time
import zlib
from collections import Counter
from dataclasses import dataclass

import numpy as np
import torch

from samp.policy.baselines.mpnet import set_dropout
from samp.policy.network import denormalize, normalize

__all__ = ["MPNetPlanConfig", "MPNetPlanner", "SceneWorlds", "densify"]


@dataclass
class MPNetPlanConfig:
    """How `MPNetPlanner` plans (`system.planning` in conf/experiment/mpnet.yaml). Radians, metres, seconds."""

    max_steps: int = 100  # network steps of the first bidirectional rollout (both chains together)
    segment_steps: int = 40  # network steps when replanning one infeasible segment
    replan_rounds: int = 10  # replanning passes before giving up (MPNet: 10)
    contract_tries: int = 10  # farthest-first shortcut candidates tried per state in the contraction
    resolution: float = 0.02  # segment checks: joint-space spacing of the checked states (the expert's)
    margin: float = 0.005  # every checked state at least this far from obstacles (and no self-collision)
    dropout: bool = True  # dropout active while planning, as MPNet
    waypoints: int = 50  # the returned polyline gets about this many points (its states kept)
    time_limit: float = 10.0  # per problem, for the neural planner
    fallback: str = "none"  # none: fail with the reason | ompl: plan the problem with the OMPL expert instead
    fallback_time: float = 5.0  # the OMPL expert's time limit
    seed: int = 0  # dropout draws are seeded per problem from this and the problem's name

    def __post_init__(self):
        ints = (self.max_steps, self.segment_steps, self.contract_tries, self.waypoints)
        if min(ints) < 1 or self.replan_rounds < 0:
            raise ValueError(f"MPNet planning: max_steps, segment_steps, contract_tries, waypoints >= 1 and "
                             f"replan_rounds >= 0 expected, got {ints} and {self.replan_rounds}")
        if self.resolution <= 0 or self.margin < 0 or self.time_limit <= 0 or self.fallback_time <= 0:
            raise ValueError(f"MPNet planning: resolution, time_limit, fallback_time > 0 and margin >= 0 expected, got "
                             f"{self.resolution}, {self.time_limit}, {self.fallback_time}, {self.margin}")
        if self.fallback not in ("none", "ompl"):
            raise ValueError(f"MPNet planning: fallback must be 'none' or 'ompl', got {self.fallback!r}")


def densify(path: np.ndarray, count: int) -> np.ndarray:
    """(m, n) polyline -> (W, n), W >= max(count, m): every state of `path` kept, each segment cut into
    pieces in proportion to its joint-space length (at least one), so the polyline itself is unchanged.
    The pieces are whole numbers summing to at least count - 1 (largest remainders round up), so rounding
    never leaves the trajectory short of `count` waypoints."""
    path = np.asarray(path, dtype=np.float64)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)  # (m - 1,)
    total = seg.sum()
    if len(seg) == 0 or total <= 0:
        return path
    share = seg / total * max(count - 1, len(seg))  # (m - 1,) pieces per segment, fractional
    pieces = np.maximum(1, np.floor(share)).astype(int)
    short = max(count - 1, len(seg)) - int(pieces.sum())
    if short > 0:
        pieces[np.argsort(-(share - np.floor(share)), kind="stable")[:short]] += 1
    out = [path[:1]]
    for a, b, p in zip(path[:-1], path[1:], pieces):
        out.append(a + (np.arange(1, p + 1) / p)[:, None] * (b - a))
    return np.concatenate(out)


class SceneWorlds:
    """One collision `World` per scene for a planner with a float64 robot `_exact`, built on first use and
    kept (planning many problems in a scene reuses it); `close()` releases them."""

    _worlds: dict

    def close(self) -> None:
        for world in self._worlds.values():
            world.close()
        self._worlds.clear()

    def _world(self, scene):
        from samp.sim import World

        key = scene.content_hash()
        if key not in self._worlds:
            self._worlds[key] = World(self._exact, scene)
        return self._worlds[key]

    def _scene(self, problem) -> tuple:
        """The problem's collision World and anchor grid, refusing a scene with other workspace bounds."""
        bounds = [list(map(float, b)) for b in self.system.bounds]
        if [list(b) for b in problem.scene.bounds] != bounds:
            raise ValueError(f"the {self.name} planner was trained on workspace bounds {bounds}; scene "
                             f"{problem.scene.name!r} has {problem.scene.bounds}")
        return self._world(problem.scene), problem.scene.anchor_grid(self.n_e)


class MPNetPlanner(SceneWorlds):
    """A trained `MPNetSystem` as a trajectory planner (name "mpnet"). Keeps one `World` per scene;
    `close()` releases them. `outcomes` counts how problems ended (neural, fallback, failed)."""

    def __init__(self, system, cfg: MPNetPlanConfig | None = None, name: str = "mpnet"):
        from samp.robot.precision import exact_robot

        system.fitted()
        self.system, self.cfg, self.name = system.eval(), cfg or MPNetPlanConfig(), name
        set_dropout(system.net, self.cfg.dropout)
        self.robot, self.n_e = system.robot, system.n_e
        self._exact = exact_robot(system.robot)  # float64 limits for the World (and the OMPL fallback)
        self._lo, self._hi = self._exact.joint_limits.numpy().T
        self._worlds: dict[str, object] = {}
        self.outcomes: Counter = Counter()

    # ------------------------------------------------------------------ the pieces
    def _free(self, a: np.ndarray, b: np.ndarray, world) -> bool:
        """Is the straight segment a -> b clear (states every `resolution`, a itself excluded)? The
        states are checked every 8th first, so most blocked segments cost one small batch."""
        steps = max(1, int(np.ceil(np.linalg.norm(b - a) / self.cfg.resolution)))
        states = a + (np.arange(1, steps + 1) / steps)[:, None] * (b - a)  # (steps, n), ends at b
        coarse = np.zeros(steps, dtype=bool)
        coarse[::8], coarse[-1] = True, True
        for part in (states[coarse], states[~coarse]):
            if len(part) and world.in_collision(part, margin=self.cfg.margin).any():
                return False
        return True

    def _step(self, q: np.ndarray, toward: np.ndarray, code: torch.Tensor) -> np.ndarray:
        """One network step from q (n,) toward `toward` (n,) -> (n,) radians, within the joint limits."""
        lim = self.system.limits
        x = torch.as_tensor(np.stack([q, toward]), dtype=torch.float32, device=lim.device)  # (2, n)
        u = normalize(x, lim)
        out = denormalize(self.system.net(code, u[:1], u[1:]), lim)[0].double().cpu().numpy()
        return np.clip(out, self._lo, self._hi)

    def _connect(self, a, b, code, world, steps: int, deadline: float) -> list[np.ndarray] | None:
        """Bidirectional rollout between a and b: [a, ..., b] once the chain ends see each other, else None."""
        chains, side = ([a], [b]), 0
        for _ in range(steps):
            if self._free(chains[0][-1], chains[1][-1], world):
                return chains[0] + chains[1][::-1]
            if time.perf_counter() > deadline:
                return None
            chains[side].append(self._step(chains[side][-1], chains[1 - side][-1], code))
            side = 1 - side
        return chains[0] + chains[1][::-1] if self._free(chains[0][-1], chains[1][-1], world) else None

    def _contract(self, path: list[np.ndarray], world) -> list[np.ndarray]:
        """Lazy states contraction: from each kept state, the farthest later state it sees directly."""
        out, i, last = [path[0]], 0, len(path) - 1
        while i < last:
            nxt = i + 1
            if i + 2 <= last:  # candidates i+2 .. last, farthest first
                for j in np.unique(np.linspace(i + 2, last, self.cfg.contract_tries).round().astype(int))[::-1]:
                    if self._free(path[i], path[j], world):
                        nxt = int(j)
                        break
            out.append(path[nxt])
            i = nxt
        return out

    def _solve(self, start, goal, code, world, deadline: float) -> tuple[list[np.ndarray] | None, str]:
        cfg = self.cfg
        ends = world.in_collision(np.stack([start, goal]), margin=cfg.margin)
        if ends.any():
            which = " and ".join(n for n, bad in zip(("start", "goal"), ends) if bad)
            return None, f"{which} closer than {cfg.margin} m to an obstacle, in self-collision or outside the limits"
        path = [start, goal]
        for round_ in range(cfg.replan_rounds + 1):
            inner = world.in_collision(np.stack(path[1:-1]), margin=cfg.margin) if len(path) > 2 else []
            path = [path[0], *(p for p, bad in zip(path[1:-1], inner) if not bad), path[-1]]
            free = [self._free(a, b, world) for a, b in zip(path[:-1], path[1:])]
            if all(free):
                return path, ""
            if time.perf_counter() > deadline:
                return None, f"neural planner: time limit of {cfg.time_limit} s reached in round {round_}"
            steps = cfg.max_steps if round_ == 0 else cfg.segment_steps
            new = [path[0]]
            for i, ok in enumerate(free):
                if not ok:
                    mini = self._connect(path[i], path[i + 1], code, world, steps, deadline)
                    new += [] if mini is None else mini[1:-1]
                new.append(path[i + 1])
            path = self._contract(new, world)
        return None, f"neural planner: segments still infeasible after {cfg.replan_rounds} replanning rounds"

    def _fallback(self, problem, world) -> tuple[np.ndarray | None, str]:
        from samp.expert import ExpertPlanner, load_expert_config

        expert = ExpertPlanner(self._exact, problem.scene, load_expert_config(time_limit=self.cfg.fallback_time,
                                                                              attempts=1), world=world)
        result = expert.plan(problem.q_start, problem.q_goal, seed=self.cfg.seed)
        return result.trajectory, "" if result.success else f"OMPL fallback: {result.reason}"

    # ------------------------------------------------------------------ the planner protocol
    def plan(self, problem):
        """problem: a `samp.eval.Problem` -> `PlannedTrajectory` ((W, n) radians or None, seconds, reason)."""
        from samp.policy.interface import PlannedTrajectory

        world, grid = self._scene(problem)
        device = self.system.device
        t0 = time.perf_counter()
        with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []), torch.no_grad():
            torch.manual_seed(zlib.crc32(f"{self.cfg.seed}/{problem.name}".encode()))
            code = self.system.net.encode(grid[None].to(device, torch.float32))  # (1, L)
            path, reason = self._solve(problem.q_start, problem.q_goal, code, world, t0 + self.cfg.time_limit)
        outcome = "neural" if path is not None else "failed"
        if path is None and self.cfg.fallback == "ompl":
            path, reason = self._fallback(problem, world)
            outcome = "fallback" if path is not None else "failed"
        elapsed = time.perf_counter() - t0
        self.outcomes[outcome] += 1
        traj = None if path is None else densify(np.stack(path), self.cfg.waypoints)
        if traj is not None:
            traj[0], traj[-1] = problem.q_start, problem.q_goal
        return PlannedTrajectory(traj, elapsed, reason)
