"""Planning problems in a scene: goal end-effector poses, their IK solutions, and starts.

Goals are of two kinds (`ProblemConfig.target_fraction` sets the mix):
  * "target": a pre-grasp pose at the scene's target object, `approach_offset` from its centre above it
    (gripper pointing down) or in front of it on the base's side (gripper pointing at it, for shelves),
    among the approach points that are `approach_clearance` clear of obstacles, with a random rotation
    about the approach axis (chained problems never have two target goals in a row);
  * "workspace": a point uniform in the scene bounds at a distance in `radius` from the base axis and
    `position_clearance` clear of obstacles, with the approach axis uniform in a cone of half-angle
    `max_tilt` around straight down and a random rotation about it.
Each goal gets `poses_per_goal` poses per round, solved by batched IK (`samp.expert.ik`) to
configurations clear of obstacles by the planner's clearance; the goal is the solution nearest to the
start (`goal_select`). A goal without one gets fresh poses for up to `goal_rounds` rounds and otherwise
stays unsolved with its reason. Starts are the previous goal (`start: chain`) or random collision-free
configurations. Everything is drawn from `seed`: the same seed gives the same problems. Every start and
goal lies within the robot's exact (float64) joint limits, whatever the robot's dtype (IK clamps to the
limits rounded inward, `samp.expert.ik.limits_inward`), so the expert's OMPL bounds accept all of them.
With `detour_share` > 0, that share of the problems gets a goal whose straight joint-space line from the
start is blocked (`straight_line_blocked`), so the expert must plan around obstacles; every problem records
whether its line is blocked (`PlanningProblem.detour`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from samp.expert.config import ExpertConfig, ProblemConfig, load_expert_config
from samp.expert.ik import solve_ik

__all__ = ["PlanningProblem", "ik_goals", "random_free_configs", "sample_problems", "straight_line_blocked",
           "target_approaches", "target_poses", "workspace_poses"]

POSITION_DRAWS = 64  # candidate points per wanted workspace position and round of rejection sampling
CORRIDOR_POINTS = 5  # points checked along a target approach corridor
FACING = 0.5  # a horizontal approach direction must be within 60 degrees of pointing at the base axis
IK_BATCH = 4096  # configurations solved together (poses x seeds), to bound memory
DETOUR_ROUNDS = 4  # rounds of fresh goal poses for a problem that must need a detour
DETOUR_STREAM = 0xDE70  # key of the seed stream of detour choices


@dataclass
class PlanningProblem:
    """One start/goal pair. q_goal is None when no valid goal was found; `reason` says why."""

    q_start: np.ndarray  # (n,) radians
    q_goal: np.ndarray | None  # (n,) radians
    goal_pose: np.ndarray | None  # (4, 4) end-effector pose in the base frame that q_goal reaches
    kind: str  # "target" | "workspace"
    reason: str = ""
    detour: bool | None = None  # the straight joint-space line from start to goal is not valid (None: no goal)


def _frames(axes: np.ndarray, yaw: np.ndarray, approach_axis) -> np.ndarray:
    """axes (K, 3) unit approach directions (base frame), yaw (K,) -> (K, 3, 3) end-effector rotations
    whose `approach_axis` (ee frame) points along `axes`, rotated by `yaw` about it."""
    helper = np.where(np.abs(axes[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])  # (K, 3) not parallel
    x = np.cross(helper, axes)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(axes, x)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x, y = c * x + s * y, -s * x + c * y
    frame = np.stack([x, y, axes], axis=2)  # (K, 3, 3), columns x, y, z = approach
    to_z, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [np.asarray(approach_axis, dtype=np.float64)])
    return frame @ to_z.as_matrix()  # maps the ee approach axis onto frame's z


def _poses(positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    T = np.tile(np.eye(4), (len(positions), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = rotations, positions
    return T


def _approach_directions(scene) -> np.ndarray:
    """(A, 3) unit candidate directions from the target's centre to a pre-grasp point: straight up, and
    horizontally toward the base axis, both radially and along the target's own horizontal axes that
    face the base (a target in a shelf is aligned with its cubby, which may not face the base squarely)."""
    centre = np.asarray(scene.target.pose.position)
    toward_base = -np.array([centre[0], centre[1], 0.0])
    candidates = [np.array([0.0, 0.0, 1.0])]
    r = float(np.linalg.norm(toward_base))
    if r > 1e-6:
        toward_base /= r
        axes = scene.target.pose.matrix()[:3, :3]
        for axis in (toward_base, *axes[:, :2].T, *(-axes[:, :2].T)):
            flat = np.array([axis[0], axis[1], 0.0])
            if np.linalg.norm(flat) > 1e-6:
                flat /= np.linalg.norm(flat)
                if flat @ toward_base > FACING and all(np.linalg.norm(flat - c) > 1e-3 for c in candidates):
                    candidates.append(flat)
    return np.stack(candidates)


def target_approaches(scene, cfg: ProblemConfig) -> np.ndarray:
    """(A, 3) free approach offsets from the target's centre (`_approach_directions` x `approach_offset`):
    those whose corridor, from the pre-grasp point out to a further `approach_depth` (where the hand and
    wrist will be), is `approach_clearance` clear of obstacles. The corridor rules out an approach from
    above inside a shelf's cubby."""
    if scene.target is None:
        raise ValueError(f"scene {scene.name!r} has no target; use target_fraction 0 or a scene with a target")
    centre = np.asarray(scene.target.pose.position)
    directions = _approach_directions(scene)  # (A, 3)
    steps = cfg.approach_offset + np.linspace(0.0, cfg.approach_depth, CORRIDOR_POINTS)  # (C,)
    corridor = centre + directions[:, None] * steps[None, :, None]  # (A, C, 3)
    free = (np.asarray(scene.sdf(corridor.reshape(-1, 3))).reshape(corridor.shape[:2]) >= cfg.approach_clearance).all(1)
    return directions[free] * cfg.approach_offset


def target_poses(scene, count: int, cfg: ProblemConfig, rng: np.random.Generator) -> np.ndarray:
    """(count, 4, 4) pre-grasp poses at the scene's target; ValueError if it has no free approach."""
    approaches = target_approaches(scene, cfg)
    if len(approaches) == 0:
        raise ValueError(f"scene {scene.name!r}: no pre-grasp point {cfg.approach_offset} m above or in front of the "
                         f"target is {cfg.approach_clearance} m clear of obstacles")
    offsets = approaches[rng.integers(len(approaches), size=count)]  # (count, 3)
    axes = -offsets / np.linalg.norm(offsets, axis=1, keepdims=True)  # the gripper points at the target
    rotations = _frames(axes, rng.uniform(-np.pi, np.pi, size=count), cfg.approach_axis)
    return _poses(np.asarray(scene.target.pose.position) + offsets, rotations)


def workspace_poses(scene, count: int, cfg: ProblemConfig, rng: np.random.Generator, max_rounds: int = 20) -> np.ndarray:
    """(count, 4, 4) poses spread over the reachable workspace (see the module docstring)."""
    lo, hi = np.asarray(scene.bounds[0]), np.asarray(scene.bounds[1])
    found = []
    for _ in range(max_rounds):
        p = rng.uniform(lo, hi, size=(POSITION_DRAWS * count, 3))
        r = np.hypot(p[:, 0], p[:, 1])
        p = p[(r >= cfg.radius[0]) & (r <= cfg.radius[1])]
        found.extend(p[np.asarray(scene.sdf(p)) >= cfg.position_clearance])
        if len(found) >= count:
            break
    if len(found) < count:
        raise ValueError(f"scene {scene.name!r}: found only {len(found)} of {count} workspace points within radius "
                         f"{cfg.radius} m of the base axis and {cfg.position_clearance} m clear of obstacles")
    positions = np.stack(found[:count])
    cos_tilt = rng.uniform(np.cos(cfg.max_tilt), 1.0, size=count)  # uniform on the spherical cap
    phi = rng.uniform(-np.pi, np.pi, size=count)
    sin_tilt = np.sqrt(1.0 - cos_tilt ** 2)
    axes = np.stack([sin_tilt * np.cos(phi), sin_tilt * np.sin(phi), -cos_tilt], axis=1)
    return _poses(positions, _frames(axes, rng.uniform(-np.pi, np.pi, size=count), cfg.approach_axis))


def ik_goals(robot, world, poses: np.ndarray, cfg: ExpertConfig, generator: torch.Generator,
             rng: np.random.Generator, outcomes: list | None = None) -> list[np.ndarray]:
    """poses (K, 4, 4) -> K arrays (m_k, n) of IK solutions `cfg.clearance` clear of obstacles and free of
    self-collision, from up to `ik.candidates` converged seeds per pose (in random order); m_k may be 0.
    With `outcomes`, one entry per pose is appended to it: "ok", or why m_k is 0 (`GOAL_FAILURES`)."""
    chunk = max(1, IK_BATCH // cfg.ik.seeds)
    q, converged = [], []
    for a in range(0, len(poses), chunk):
        result = solve_ik(robot, torch.as_tensor(poses[a:a + chunk], dtype=robot.dtype), cfg.ik, generator=generator)
        q.append(result.q.cpu().double().numpy())  # (k, S, n)
        converged.append(result.converged.cpu().numpy())  # (k, S)
    q, converged = np.concatenate(q), np.concatenate(converged)
    picks = [rng.permutation(np.flatnonzero(row))[:cfg.ik.candidates] for row in converged]
    flat = np.array([(k, s) for k, row in enumerate(picks) for s in row], dtype=int).reshape(-1, 2)
    free = ~world.in_collision(q[flat[:, 0], flat[:, 1]], margin=cfg.clearance) if len(flat) else np.zeros(0, bool)
    kept = flat[free]
    if outcomes is not None:
        outcomes.extend(_goal_outcomes(world, q, flat, free, len(poses), cfg.clearance))
    return [q[k, kept[kept[:, 0] == k, 1]] for k in range(len(poses))]


# Why a goal pose gave no usable IK solution, the key of its problem's reason (shown by `samp.data show`).
GOAL_FAILURES = {"ik": "IK failed", "obstacles": "goal in collision", "self": "self-collision or joint limits"}


def _goal_outcomes(world, q: np.ndarray, flat: np.ndarray, free: np.ndarray, count: int, clearance: float) -> list[str]:
    """Per pose: "ok"; "ik" when no IK seed converged (the pose is out of the arm's reach, or the IK
    budget too small); "obstacles" when every converged solution is within `clearance` of an obstacle;
    "self" when some are clear of obstacles but all are in self-collision or outside the joint limits.
    The second check runs only for the poses without a free solution."""
    out = ["ik"] * count
    for k in np.unique(flat[:, 0]).tolist():
        mine = flat[:, 0] == k
        if free[mine].any():
            out[k] = "ok"
        else:
            clear = ~world.in_collision(q[k, flat[mine, 1]], margin=clearance, self_collision=False, joint_limits=False)
            out[k] = "self" if clear.any() else "obstacles"
    return out


def random_free_configs(robot, world, count: int, rng: np.random.Generator, clearance: float,
                        cfg: ProblemConfig | None = None) -> np.ndarray:
    """(count, n) configurations uniform within the joint limits and `clearance` clear of obstacles
    (and free of self-collision)."""
    cfg = cfg or ProblemConfig()
    lim = robot.joint_limits.double().cpu().numpy()
    found: list[np.ndarray] = []
    if count == 0:
        return np.zeros((0, robot.dof))
    for _ in range(cfg.start_rounds):
        q = rng.uniform(lim[:, 0], lim[:, 1], size=(max(cfg.start_batch, count), robot.dof))
        found.extend(q[~world.in_collision(q, margin=clearance)])
        if len(found) >= count:
            return np.stack(found[:count])
    raise ValueError(f"found only {len(found)} of {count} collision-free configurations (clearance {clearance} m) in "
                     f"{cfg.start_rounds} rounds of {cfg.start_batch}; the scene may leave the robot little room")


def _goal_poses(scene, kinds: np.ndarray, cfg: ProblemConfig, rng: np.random.Generator) -> np.ndarray:
    poses = np.empty((len(kinds), 4, 4))
    is_target = kinds == "target"
    if is_target.any():
        poses[is_target] = target_poses(scene, int(is_target.sum()), cfg, rng)
    if (~is_target).any():
        poses[~is_target] = workspace_poses(scene, int((~is_target).sum()), cfg, rng)
    return poses


def sample_problems(robot, scene, count: int, seed: int, cfg: ExpertConfig | None = None,
                    world=None, detour_share: float = 0.0) -> list[PlanningProblem]:
    """`count` seeded problems in `scene`; see the module docstring. A goal without a collision-free IK
    solution after `goal_rounds` rounds gives a problem with q_goal None and its reason.

    detour_share: the share of problems (round(share * count), at positions drawn from a stream of their
    own) whose goal is chosen so that the straight joint-space line from the start is not valid, i.e. the
    expert must plan a detour (`straight_line_blocked`): among the goal's IK solutions, the first in
    `goal_select` order whose line is blocked, else from up to `DETOUR_ROUNDS` rounds of fresh poses of
    the same kind; a problem that finds none keeps the usual goal. The other problems are drawn as usual
    (some of them need a detour too). Every problem records whether it needs one (`detour`)."""
    if not 0.0 <= detour_share <= 1.0:
        raise ValueError(f"detour_share must be in [0, 1], got {detour_share}")
    from samp.sim import World

    cfg = cfg if isinstance(cfg, ExpertConfig) else load_expert_config(cfg)
    if count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    own = world is None
    world = World(robot, scene) if own else world
    try:
        return _sample(robot, scene, world, count, int(seed), cfg, float(detour_share))
    finally:
        if own:
            world.close()


def _solve_goals(robot, scene, world, kinds: np.ndarray, cfg: ExpertConfig, generator, rng):
    """Per goal: (m, n) free IK solutions and (m, 4, 4) the poses they reach, over up to `goal_rounds`
    rounds of `poses_per_goal` fresh poses for the goals still without one."""
    pc, n, P = cfg.problems, robot.dof, cfg.problems.poses_per_goal
    found = [(np.zeros((0, n)), np.zeros((0, 4, 4))) for _ in kinds]
    tally = [dict.fromkeys(GOAL_FAILURES, 0) for _ in kinds]  # per goal: its poses' failures, for its reason
    pending = np.arange(len(kinds))
    for _ in range(pc.goal_rounds):
        if len(pending) == 0:
            break
        owner = np.repeat(pending, P)  # (len(pending) * P,) goal of each pose
        poses = _goal_poses(scene, kinds[owner], pc, rng)
        outcomes: list[str] = []
        solved = ik_goals(robot, world, poses, cfg, generator, rng, outcomes)
        for i, why in zip(owner, outcomes):
            if why != "ok":
                tally[i][why] += 1
        for i, pose, q in zip(owner, poses, solved):
            qs, ps = found[i]
            found[i] = (np.concatenate([qs, q]), np.concatenate([ps, np.repeat(pose[None], len(q), axis=0)]))
        pending = np.array([i for i in pending if len(found[i][0]) == 0], dtype=int)
    return found, tally


def _no_goal_reason(counts: dict[str, int], kind: str, clearance: float) -> str:
    """Why a goal has no valid configuration: the commonest failure of its poses first (before the colon,
    so that a dataset's summary counts problems by it), then every count and what to change."""
    main = max(counts, key=counts.get)
    return (f"no valid goal ({GOAL_FAILURES[main]}): of {sum(counts.values())} sampled {kind} poses, IK failed for "
            f"{counts['ik']} (out of the arm's reach? check the scene's workspace against the robot, or raise "
            f"ik.seeds), every solution was within {clearance} m of an obstacle for {counts['obstacles']}, and in "
            f"self-collision or outside the joint limits for {counts['self']}")


def straight_line_blocked(world, q_start: np.ndarray, q_goal: np.ndarray, cfg: ExpertConfig) -> bool:
    """True when the straight joint-space motion from q_start to q_goal has a state (every `resolution`
    radians) closer than `clearance` to an obstacle or in self-collision: the expert's `direct` check fails."""
    from samp.expert.ompl_backend import FIRST_CHUNK, _coarse_to_fine
    from samp.expert.trajectory import segment_states

    states = segment_states(np.stack([q_start, q_goal]), cfg.resolution)[0]  # (C, n), the start first
    order = np.concatenate([_coarse_to_fine(len(states) - 1), [0]]) if len(states) > 1 else np.zeros(1, int)
    start, size = 0, FIRST_CHUNK  # coarse to fine in growing chunks: a blocked line usually stops early
    while start < len(order):
        if world.in_collision(states[order[start:start + size]], margin=cfg.clearance).any():
            return True
        start, size = start + size, size * 4
    return False


def _detour_goal(robot, scene, world, start, kind: str, candidates, cfg: ExpertConfig, drng, generator):
    """(q_goal, pose) whose straight line from `start` is blocked, from `candidates` ((m, n), (m, 4, 4)) or
    from up to DETOUR_ROUNDS rounds of fresh poses of `kind` (drawn with drng and `generator`), or None."""
    pc = cfg.problems
    qs, poses = candidates
    for _ in range(DETOUR_ROUNDS + 1):
        order = (np.argsort(np.linalg.norm(qs - start, axis=1), kind="stable") if pc.goal_select == "nearest"
                 else drng.permutation(len(qs)))
        for j in order.tolist():
            if straight_line_blocked(world, start, qs[j], cfg):
                return qs[j].copy(), poses[j]
        fresh = _goal_poses(scene, np.full(pc.poses_per_goal, kind), pc, drng)
        solved = ik_goals(robot, world, fresh, cfg, generator, drng)
        qs = np.concatenate(solved)
        poses = np.concatenate([np.repeat(p[None], len(q), axis=0) for p, q in zip(fresh, solved)])
    return None


def _sample(robot, scene, world, count: int, seed: int, cfg: ExpertConfig,
            detour_share: float = 0.0) -> list[PlanningProblem]:
    pc = cfg.problems
    rng = np.random.default_rng(seed)
    generator = torch.Generator().manual_seed(int(rng.integers(2**62)))
    with_target = scene.target is not None and pc.target_fraction > 0 and len(target_approaches(scene, pc)) > 0
    kinds = _goal_kinds(count, with_target, pc, rng)
    found, tally = _solve_goals(robot, scene, world, kinds, cfg, generator, rng)
    valid = np.array([len(q) > 0 for q, _ in found], dtype=bool)
    chained = np.zeros(count, dtype=bool)
    if pc.start == "chain":
        chained[1:] = valid[:-1]
    randoms = iter(random_free_configs(robot, world, int((~chained).sum()), rng, cfg.clearance, pc))
    # Detours from streams of their own: detour_share 0 leaves every other draw as it was.
    drng = np.random.default_rng([seed, DETOUR_STREAM])
    dgen = torch.Generator().manual_seed(int(drng.integers(2**62)))
    wanted = drng.permutation(count) < round(detour_share * count) if detour_share > 0 else np.zeros(count, bool)
    problems: list[PlanningProblem] = []
    for i in range(count):
        start = problems[-1].q_goal if chained[i] else next(randoms)
        if not valid[i]:
            problems.append(PlanningProblem(start, None, None, str(kinds[i]),
                                            _no_goal_reason(tally[i], str(kinds[i]), cfg.clearance)))
            continue
        chosen = _detour_goal(robot, scene, world, start, str(kinds[i]), found[i], cfg, drng, dgen) if wanted[i] else None
        if chosen is None:
            j = _select(found[i][0], start, pc.goal_select, rng)
            chosen = found[i][0][j].copy(), found[i][1][j]
        problems.append(PlanningProblem(start, chosen[0], chosen[1], str(kinds[i]),
                                        detour=straight_line_blocked(world, start, chosen[0], cfg)))
    return problems


def _goal_kinds(count: int, with_target: bool, pc: ProblemConfig, rng: np.random.Generator) -> np.ndarray:
    """(count,) "target" | "workspace". Chained problems never put two target goals in a row (the second
    would start at the same pre-grasp point): a target follows a workspace goal with probability
    p / (1 - p), which keeps the share of targets at p = target_fraction (at most 1/2)."""
    u = rng.random(count)
    if not with_target:
        return np.full(count, "workspace")
    if pc.start != "chain":
        return np.where(u < pc.target_fraction, "target", "workspace")
    p_after_workspace = min(1.0, pc.target_fraction / max(1e-12, 1.0 - pc.target_fraction))
    kinds, previous = [], "workspace"
    for i in range(count):
        p = pc.target_fraction if i == 0 else (0.0 if previous == "target" else p_after_workspace)
        previous = "target" if u[i] < p else "workspace"
        kinds.append(previous)
    return np.array(kinds)


def _select(candidates: np.ndarray, start: np.ndarray, how: str, rng: np.random.Generator) -> int:
    """Index of one of the (m, n) candidate goals: the nearest to start (n,) in joint space, or a random one."""
    if how == "nearest":
        return int(np.argmin(np.linalg.norm(candidates - start, axis=1)))
    return int(rng.integers(len(candidates)))
