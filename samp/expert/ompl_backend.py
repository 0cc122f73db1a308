"""OMPL glue (ompl 2.x Python bindings): joint space, batched motion checks, seeding, one planning attempt.

States are checked in batches: a Python `MotionValidator` interpolates a motion at the configured
resolution and sends its states through the batched validity function in coarse-to-fine chunks, so an
invalid motion is usually rejected by its first chunk. Only the two-state `checkMotion` is provided;
the planners in `PLANNERS` (and `PathSimplifier`) use nothing else.

Seeding: OMPL derives every RNG's seed from one global seed generator. `RNG.setSeed` re-seeds that
generator even after sampling has begun (it then logs an error that only RNGs created earlier keep
their streams). Each attempt builds its space, planner and simplifier afresh after `seed_ompl`, so
every RNG it uses descends from the attempt's seed and the attempt is reproducible.
"""

from __future__ import annotations

import functools
import math
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["ANYTIME", "PLANNERS", "OMPLOutcome", "available_planners", "ompl_log_level", "plan_once", "planner_class",
           "seed_ompl"]

# Planners checked to run (and repeat by seed) with the Python validity and motion checks; anytime ones
# refine until a limit. BKPIECE1 grows its trees from the valid-state sampler (the SIMPNet-style planner's
# learned sampler goes there). PRM is left out: it grows its roadmap in a second thread, whose callbacks into
# Python deadlock against the solving thread (ompl 2.0.1).
PLANNERS = ("RRTConnect", "AORRTC", "RRTstar", "RRT", "InformedRRTstar", "BITstar", "BKPIECE1")
ANYTIME = frozenset({"AORRTC", "RRTstar", "InformedRRTstar", "BITstar"})
FIRST_CHUNK = 8  # states in the first chunk of a motion check; later chunks grow fourfold


def _ompl():
    try:
        from ompl import base as ob, geometric as og, util as ou
    except ImportError as err:  # a hard dependency, but say how to get it
        raise ImportError(f"the OMPL expert needs the `ompl` Python bindings (>= 2.0): pip install 'ompl>=2.0' ({err})") from err
    return ob, og, ou


def available_planners() -> list[str]:
    """Names accepted as `planner`: those in PLANNERS that this OMPL build provides."""
    _, og, _ = _ompl()
    return [name for name in PLANNERS if hasattr(og, name)]


def planner_class(name: str):
    """The `ompl.geometric` planner class called `name`; ValueError naming the available ones otherwise."""
    available = available_planners()
    if name not in available:
        raise ValueError(f"unknown planner {name!r}; available planners: {', '.join(available)}")
    return getattr(_ompl()[1], name)


def seed_ompl(seed: int) -> None:
    """Re-seed OMPL's seed generator (any int), quietly; see the module docstring."""
    with ompl_log_level("none"):
        _ompl()[2].RNG.setSeed(int(seed) % (2**32 - 1) + 1)  # OMPL refuses 0


@contextmanager
def ompl_log_level(level: str):
    """Set OMPL's log level ("debug" | "info" | "warn" | "error" | "none") inside the block."""
    _, _, ou = _ompl()
    previous = ou.getLogLevel()
    ou.setLogLevel(getattr(ou, f"LOG_{level.upper()}"))
    try:
        yield
    finally:
        ou.setLogLevel(previous)


@functools.lru_cache(maxsize=1024)
def _coarse_to_fine(steps: int) -> np.ndarray:
    """Indices 1..steps ordered coarse to fine: the end point first, then by halving strides
    (indices with more trailing zero bits first, as a 1D van der Corput sequence). Read-only: one array per
    `steps`, shared by every motion of that many steps."""
    k = np.arange(1, steps + 1)
    order = k[np.argsort(-(k & -k), kind="stable")]
    out = np.concatenate([[steps], order[order != steps]])
    out.setflags(write=False)
    return out


@dataclass
class OMPLOutcome:
    """One planning attempt."""

    solved: bool  # an exact solution
    path: np.ndarray | None  # (m, n) after simplification and smoothing
    status: str  # OMPL's planner status
    solve_time: float  # seconds in the planner
    simplify_time: float  # seconds in simplification and smoothing
    motion_checks: int


def _state_array(state, n: int) -> np.ndarray:
    return np.fromiter((state[i] for i in range(n)), dtype=np.float64, count=n)


def _make_motion_validator(ob, space, n: int, valid: Callable[[np.ndarray], np.ndarray], resolution: float):
    # The validator is built on a SpaceInformation of its own over the same space, not on the setup's: the
    # binding keeps a validator's SpaceInformation alive, and the setup's holds the validator, so using it
    # would make a reference cycle through C++ that Python's collector cannot break. Every attempt would
    # then leak its setup, and each worker process would print nanobind's "leaked instance" report at exit.
    # checkMotion below never reads the validator's SpaceInformation.
    owner = ob.SpaceInformation(space)

    class BatchMotionValidator(ob.MotionValidator):
        """checkMotion(s1, s2): s1 is valid (OMPL's contract); s2 and the states between are checked."""

        def __init__(self):
            super().__init__(owner)
            self.count = 0

        def checkMotion(self, s1, s2, *last_valid):
            if last_valid:
                raise NotImplementedError("checkMotion with lastValid is not supported; use a planner in PLANNERS")
            self.count += 1
            a, b = _state_array(s1, n), _state_array(s2, n)
            steps = max(1, math.ceil(float(np.linalg.norm(b - a)) / resolution))
            t = _coarse_to_fine(steps) / steps  # (steps,)
            start, size = 0, FIRST_CHUNK
            while start < steps:
                chunk = t[start:start + size, None]
                if not valid(a + chunk * (b - a)).all():
                    return False
                start, size = start + size, size * 4
            return True

    return BatchMotionValidator()


def _setup(robot, valid: Callable[[np.ndarray], np.ndarray], resolution: float):
    """SimpleSetup over the robot's joint limits with batched validity and motion checks."""
    ob, og, _ = _ompl()
    n = robot.dof
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i, (lo, hi) in enumerate(robot.joint_limits.double().cpu().tolist()):
        bounds.setLow(i, lo)
        bounds.setHigh(i, hi)
    space.setBounds(bounds)
    space.setLongestValidSegmentFraction(min(1.0, resolution / space.getMaximumExtent()))
    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(lambda s: bool(valid(_state_array(s, n)[None])[0]))
    si = ss.getSpaceInformation()
    mv = _make_motion_validator(ob, space, n, valid, resolution)
    si.setMotionValidator(mv)
    return ss, space, si, mv


def _to_state(space, q: np.ndarray):
    state = space.allocState()
    for i, v in enumerate(q):
        state[i] = float(v)
    return state


def plan_once(robot, cfg, valid: Callable[[np.ndarray], np.ndarray], q_start: np.ndarray, q_goal: np.ndarray,
              seed: int, sampler: Callable | None = None) -> OMPLOutcome:
    """One seeded attempt: plan with `cfg.planner` from q_start (n,) to q_goal (n,), then simplify/smooth.

    valid: (B, n) -> (B,) bool, True for configurations the robot may occupy.
    sampler: None, or `sampler(si) -> ompl.base.ValidStateSampler`, installed with
        `SpaceInformation.setValidStateSamplerAllocator` (a learned sampler: samp.policy.baselines.simpnet_planner).
        Only the planners that draw from the valid-state sampler use it: in ompl 2.0.1's Python bindings
        BKPIECE1 (`sampleNear`, to grow its trees) and PRM (`sample`); the RRT family draws from the space's
        `StateSampler`, which the bindings do not let Python replace.
    """
    with ompl_log_level(cfg.log_level):
        return _plan_once(robot, cfg, valid, q_start, q_goal, seed, sampler)


def _plan_once(robot, cfg, valid, q_start, q_goal, seed, sampler=None) -> OMPLOutcome:
    ob, og, _ = _ompl()
    cls = planner_class(cfg.planner)
    seed_ompl(seed)
    ss, space, si, mv = _setup(robot, valid, cfg.resolution)
    if sampler is not None:
        si.setValidStateSamplerAllocator(sampler)
    # Path length explicitly: AORRTC reports zero-cost paths without an objective (ompl 2.0.1).
    ss.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
    ss.setPlanner(cls(si))
    ss.setStartAndGoalStates(_to_state(space, q_start), _to_state(space, q_goal))
    budget = cfg.max_checks if cfg.planner in ANYTIME else 0
    deadline = time.perf_counter() + cfg.time_limit
    ptc = ob.PlannerTerminationCondition(
        lambda: time.perf_counter() >= deadline or (budget > 0 and mv.count >= budget))
    t0 = time.perf_counter()
    status = ss.solve(ptc)
    solve_time = time.perf_counter() - t0
    if not ss.haveExactSolutionPath():
        return OMPLOutcome(False, None, str(status), solve_time, 0.0, mv.count)
    path = ss.getSolutionPath()
    t0 = time.perf_counter()
    if cfg.simplify and path.getStateCount() > 2:  # a straight start-goal motion cannot get shorter
        og.PathSimplifier(si).simplifyMax(path)
    if cfg.smooth and path.getStateCount() > 2:
        og.PathSimplifier(si).smoothBSpline(path)
    states = np.stack([_state_array(path.getState(k), robot.dof) for k in range(path.getStateCount())])
    return OMPLOutcome(True, states, str(status), solve_time, time.perf_counter() - t0, mv.count)
