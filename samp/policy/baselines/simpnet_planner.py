"""SIMPNet-style planning: a trained `SIMPNetSystem` as the sampler inside an OMPL planner, as a
`TrajectoryPlanner` (samp.policy.interface): `plan(problem) -> PlannedTrajectory`.

Per problem:
  1. the scene's anchor grid is encoded once, and the network, dropout on, is rolled out `rollouts`
     times from the start toward the goal and as many from the goal toward the start, `rollout_steps`
     steps each (one batched call per step): the learned proposals, a set of configurations around the
     paths the network expects;
  2. OMPL plans with the expert's machinery (`samp.expert.ExpertPlanner`: the same validity and motion
     checks, clearance, straight-line shortcut, simplification, resampling and dense final check) and
     the `planner` of this config, whose sampler is `LearnedSampler`: with probability
     `learned_fraction` a draw is a learned proposal (one within the requested distance of the state the
     planner grows from, else a step toward one of the nearest; anywhere for a free sample) plus Gaussian
     noise of `noise` rad, otherwise uniform, as OMPL's own sampler would draw it.

What ompl 2.0.1's Python bindings allow decides the planner: a Python sampler can only be installed as
the `ValidStateSampler` (`SpaceInformation.setValidStateSamplerAllocator`). The RRT family (RRT,
RRTConnect, RRT*) draws from the state space's `StateSampler`, whose allocator the bindings do not expose
(`setStateSamplerAllocator` is missing and a Python override of `allocDefaultStateSampler` is never
called), so the learned sampler cannot drive them. BKPIECE1, a bidirectional tree planner, grows both
trees through `ValidStateSampler.sampleNear`, so it is the default; PRM draws `sample` but grows its
roadmap in a second thread that deadlocks against Python callbacks (samp.expert.ompl_backend).

Solution time is the wall time of `plan` after the scene's World exists: the encoding, the proposals,
the planning and the post-processing.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass

import numpy as np
import torch

from samp.policy.baselines.mpnet import set_dropout
from samp.policy.baselines.mpnet_planner import SceneWorlds
from samp.policy.network import denormalize, normalize

__all__ = ["LearnedSampler", "SIMPNetPlanConfig", "SIMPNetPlanner", "learned_sampler"]


@dataclass
class SIMPNetPlanConfig:
    """How `SIMPNetPlanner` plans (`system.planning` in conf/system/simpnet.yaml). Radians, seconds."""

    planner: str = "BKPIECE1"  # an OMPL planner that draws from the valid-state sampler (module docstring)
    learned_fraction: float = 0.5  # share of sampler draws that are learned proposals
    rollouts: int = 8  # stochastic network rollouts from each end per problem
    rollout_steps: int = 50  # network steps of each rollout
    noise: float = 0.05  # Gaussian spread around a learned proposal (rad per joint)
    time_limit: float = 5.0  # per OMPL attempt
    attempts: int = 2
    direct: bool = True  # the expert's straight-line shortcut when the straight motion is valid
    simplify: bool = True  # the expert's post-processing (PathSimplifier)
    smooth: bool = True
    waypoints: int = 50
    seed: int = 0  # dropout and sampler draws are seeded per problem from this and the problem's name

    def __post_init__(self):
        if not 0.0 <= self.learned_fraction <= 1.0 or self.noise < 0:
            raise ValueError(f"SIMPNet planning: learned_fraction in [0, 1] and noise >= 0 expected, got "
                             f"{self.learned_fraction}, {self.noise}")
        if min(self.rollouts, self.rollout_steps, self.attempts, self.waypoints) < 1 or self.time_limit <= 0:
            raise ValueError("SIMPNet planning: rollouts, rollout_steps, attempts, waypoints >= 1 and time_limit > 0 "
                             f"expected, got {self.rollouts}, {self.rollout_steps}, {self.attempts}, {self.waypoints}, "
                             f"{self.time_limit}")


class LearnedSampler:
    """The learned proposal distribution, without OMPL: a pool of configurations (P, n) radians, joint
    limits (n, 2), the learned share and noise. `learned_sampler` wraps it as an OMPL ValidStateSampler."""

    def __init__(self, pool: np.ndarray, limits: np.ndarray, fraction: float, noise: float, rng: np.random.Generator):
        self.pool, self.lo, self.hi = pool, limits[:, 0], limits[:, 1]
        self.fraction, self.noise, self.rng = fraction, noise, rng
        self.drawn = {"learned": 0, "uniform": 0}

    def _near(self, q: np.ndarray) -> np.ndarray:
        return np.clip(q + self.rng.normal(0.0, self.noise, q.shape), self.lo, self.hi)

    def sample(self) -> np.ndarray:
        """(n,) a learned proposal with probability `fraction`, else uniform within the limits."""
        if self.rng.random() < self.fraction:
            self.drawn["learned"] += 1
            return self._near(self.pool[self.rng.integers(len(self.pool))])
        self.drawn["uniform"] += 1
        return self.rng.uniform(self.lo, self.hi)

    def sample_near(self, near: np.ndarray, distance: float, nearest: int = 8) -> np.ndarray:
        """(n,) within `distance` of `near` (joint-space Euclidean). With probability `fraction` a learned
        proposal: one of the proposals that close, or else a step of `distance` toward one of the `nearest`
        proposals (the planner's tree is pulled toward the learned paths); otherwise uniform in the box
        around `near`, pulled back onto the ball."""
        if self.rng.random() < self.fraction:
            self.drawn["learned"] += 1
            gap = np.linalg.norm(self.pool - near, axis=1)
            close = np.flatnonzero(gap <= distance)
            pick = self.rng.choice(close if len(close) else np.argsort(gap)[:nearest])
            step = self.pool[pick] - near
            if gap[pick] > distance:
                step *= distance / gap[pick]
            return self._near(near + step)
        self.drawn["uniform"] += 1
        step = self.rng.uniform(-distance, distance, near.shape)
        length = np.linalg.norm(step)
        if length > distance:
            step *= distance / length
        return np.clip(near + step, self.lo, self.hi)


def learned_sampler(learned: LearnedSampler, keep: list, tries: int = 10):
    """An allocator `si -> ompl.base.ValidStateSampler` drawing from `learned` (`plan_once(sampler=...)`);
    each draw is retried up to `tries` times until the state is valid. `keep` holds the samplers alive."""
    from ompl import base as ob

    def allocate(si):
        n = si.getStateDimension()

        class Sampler(ob.ValidStateSampler):
            def __init__(self):
                super().__init__(si)

            def _fill(self, state, draw) -> bool:
                for _ in range(tries):
                    q = draw()
                    for i in range(n):
                        state[i] = float(q[i])
                    if si.isValid(state):
                        return True
                return False

            def sample(self, state) -> bool:
                return self._fill(state, learned.sample)

            def sampleNear(self, state, near, distance) -> bool:
                centre = np.fromiter((near[i] for i in range(n)), dtype=np.float64, count=n)
                return self._fill(state, lambda: learned.sample_near(centre, float(distance)))

        sampler = Sampler()
        keep.append(sampler)
        return sampler

    return allocate


class SIMPNetPlanner(SceneWorlds):
    """A trained `SIMPNetSystem` as a trajectory planner (name "simpnet"). Keeps one `World` per scene;
    `close()` releases them. `drawn` counts the learned and uniform draws over every problem planned."""

    def __init__(self, system, cfg: SIMPNetPlanConfig | None = None, name: str = "simpnet"):
        from samp.expert import load_expert_config
        from samp.expert.ompl_backend import planner_class
        from samp.robot.precision import exact_robot

        system.fitted()
        self.system, self.cfg, self.name = system.eval(), cfg or SIMPNetPlanConfig(), name
        planner_class(self.cfg.planner)  # an unknown planner fails here
        set_dropout(system.net, True)  # stochastic proposals, as MPNet's dropout
        self.robot, self.n_e = system.robot, system.n_e
        self._exact = exact_robot(system.robot)
        c = self.cfg
        self._expert_cfg = load_expert_config(None)
        for key, value in {"planner": c.planner, "time_limit": c.time_limit, "attempts": c.attempts,
                           "direct": c.direct, "simplify": c.simplify, "smooth": c.smooth, "waypoints": c.waypoints}.items():
            setattr(self._expert_cfg, key, value)
        self._worlds: dict[str, object] = {}
        self.drawn = {"learned": 0, "uniform": 0}

    def proposals(self, grid: torch.Tensor, q_start: np.ndarray, q_goal: np.ndarray) -> np.ndarray:
        """(n_e, n_e, n_e) grid, start and goal (n,) radians -> (2 * rollouts * rollout_steps, n) radians:
        the states of the stochastic rollouts from each end toward the other."""
        c, system = self.cfg, self.system
        lim = system.limits
        ends = torch.as_tensor(np.stack([q_start, q_goal]), dtype=torch.float32, device=system.device)
        u = normalize(ends, lim).repeat_interleave(c.rollouts, dim=0)  # (2K, n): K from the start, K from the goal
        target = u.flip(0)  # each row heads for the other end
        with torch.no_grad():
            tokens = system.net.encode(grid[None].to(system.device, torch.float32)).expand(len(u), -1, -1)
            states = []
            for _ in range(c.rollout_steps):
                u = system.net(tokens, u, target)
                states.append(u)
        return denormalize(torch.cat(states), lim).double().cpu().numpy()

    def plan(self, problem):
        """problem: a `samp.eval.Problem` -> `PlannedTrajectory` ((W, n) radians or None, seconds, reason)."""
        from samp.expert import ExpertPlanner
        from samp.policy.interface import PlannedTrajectory

        world, grid = self._scene(problem)
        device = self.system.device
        seed = zlib.crc32(f"{self.cfg.seed}/{problem.name}".encode())
        t0 = time.perf_counter()
        with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
            torch.manual_seed(seed)
            pool = self.proposals(grid, problem.q_start, problem.q_goal)
        learned = LearnedSampler(pool, self._exact.joint_limits.numpy(), self.cfg.learned_fraction, self.cfg.noise,
                                 np.random.default_rng(seed))
        keep: list = []
        expert = ExpertPlanner(self._exact, problem.scene, self._expert_cfg, world=world,
                               sampler=learned_sampler(learned, keep))
        result = expert.plan(problem.q_start, problem.q_goal, seed=seed)
        elapsed = time.perf_counter() - t0
        for k, v in learned.drawn.items():
            self.drawn[k] += v
        return PlannedTrajectory(result.trajectory if result.success else None, elapsed, result.reason)
