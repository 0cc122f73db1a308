"""samp+check's protocol, fast and against oracles: it checks candidates on the grid it is given (the
evaluation's section grids, reconstructed ones included, never the scene's exact grid behind them), it
prefers a clear candidate to an unclear one, and it never answers a candidate whose clearance is below its
margin as clear.

The policy is a stand-in whose steps are known (a straight joint-space step towards its target), so which
candidate is clear is decided by the grid alone. The clearance oracle uses a linear field f(p) = b - d . p
as the grid: trilinear interpolation reproduces a linear field exactly, so the check's clearance of a path
is the field's minimum over the robot points along it, computed here without the grid. A point outside the
bounds reads the field at the nearest point of the bounds less its distance to them (the check's lower
bound for a signed distance)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from samp.eval.problems import Problem
from samp.policy.checked import CheckConfig, CheckedPolicy
from samp.policy.interface import clamp_to_limits
from samp.policy.plan import Plannable
from samp.scene.grid import anchor_points
from samp.scene.model import DEFAULT_BOUNDS, Box, Pose, Scene

N_E = 12
MARGIN = 0.05


class LinePolicy(Plannable):
    """A step policy that ignores its grid: at most 0.1 rad (Euclidean) per step towards its target. It keeps
    the grids it was reset with, to show which grid samp+check handed it."""

    def __init__(self, robot, n_e: int = N_E):
        self.robot, self.n_e, self.name = robot, n_e, "line"
        self.system = SimpleNamespace(bounds=DEFAULT_BOUNDS)
        self.seen: list[torch.Tensor] = []

    def reset(self, env) -> None:
        self.seen.append(env.grids[0].clone())

    def step(self, q, target, env):
        delta = target - q
        norm = delta.norm(dim=1, keepdim=True).clamp(min=1e-12)
        return clamp_to_limits(self.robot, q + torch.clamp(0.1 / norm, max=1.0) * delta)


@pytest.fixture(scope="module")
def panda(robots):
    return robots["panda"]


@pytest.fixture(scope="module")
def problem(panda):
    home = panda.home.double().numpy()
    goal = home + np.array([1.5, 0.4, 0.0, 0.5, 0.0, 0.0, 0.0])
    return Problem(Scene("empty"), home, goal, name="linear-field")


def _field(d, b: float):
    """The source of the linear grid f(p) = b - d . p at the anchors (float32, as stored grids are)."""
    grid = (b - anchor_points(N_E, DEFAULT_BOUNDS) @ torch.tensor(d, dtype=torch.float64)).float()
    return lambda problem, n_e: grid


def _clearance(robot, trajectory: np.ndarray, d, b: float, substeps: int = 3, bounds=DEFAULT_BOUNDS) -> float:
    """The oracle: min of b - d . p over the robot points at the start and `substeps` configurations per step,
    a point outside `bounds` taken at the nearest point inside less its distance to it."""
    q = torch.as_tensor(trajectory, dtype=torch.float64)
    t = torch.arange(1, substeps + 1, dtype=torch.float64) / substeps
    states = torch.cat([q[:1], (q[:-1, None] + t[None, :, None] * (q[1:] - q[:-1])[:, None]).reshape(-1, q.shape[1])])
    lo, hi = (torch.tensor(v, dtype=torch.float64) for v in bounds)
    points = robot.transform_points(states)
    inside = torch.maximum(torch.minimum(points, hi), lo)
    return float((b - inside @ torch.tensor(d, dtype=torch.float64) - (points - inside).norm(dim=-1)).min())


def _plain_extent(panda, problem, d) -> float:
    """min of -d . p along the plain rollout (candidate 0 alone, the goal straight ahead)."""
    alone = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=1, margin=MARGIN))
    trajectory = alone.plan(problem, grids=_field(d, 100.0)).trajectory
    return _clearance(panda, trajectory, d, 0.0), trajectory


@pytest.mark.parametrize("d", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)])
def test_a_candidate_below_the_margin_is_never_answered_as_clear(panda, problem, d):
    """The field is set so that the plain rollout's clearance is 0.02 m, inside (0, margin): it must not win.
    Whatever is answered as clear (plain or via) has the oracle's clearance above the margin; otherwise the
    answer, counted unclear, is below the margin and no nearer the obstacle than the plain rollout."""
    extent, plain = _plain_extent(panda, problem, d)
    b = 0.02 - extent
    assert _clearance(panda, plain, d, b) == pytest.approx(0.02)
    # the margin everywhere (goal_slack: null); near a goal that reads less, see the goal_slack test below
    checked = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=8, margin=MARGIN, goal_slack=None))
    answer = checked.plan(problem, grids=_field(d, b)).trajectory
    got = _clearance(panda, answer, d, b)
    assert checked.chosen["plain"] == 0, f"the plain rollout (clearance 0.02 < margin {MARGIN}) was taken as clear"
    if checked.chosen["via"]:
        assert got > MARGIN, f"a detour answered as clear has clearance {got:.4f} <= margin {MARGIN}"
    else:
        assert checked.chosen == {"plain": 0, "noisy": 0, "via": 0, "unclear": 1, "unreached": 0}, checked.chosen
        assert 0.02 - 1e-4 <= got < MARGIN


def test_a_clear_candidate_is_picked_over_an_unclear_one(panda, problem):
    """With the field along -y, the plain rollout passes 0.02 m from the zero level (unclear) while a detour
    stays clear: that detour is the answer, its oracle clearance above the margin, and it reaches the goal."""
    d = (0.0, -1.0, 0.0)
    extent, plain = _plain_extent(panda, problem, d)
    b = 0.02 - extent
    checked = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=8, margin=MARGIN))
    result = checked.plan(problem, grids=_field(d, b))
    assert checked.chosen == {"plain": 0, "noisy": 0, "via": 1, "unclear": 0, "unreached": 0}, checked.chosen
    assert _clearance(panda, result.trajectory, d, b) > MARGIN
    assert not np.array_equal(result.trajectory[: len(plain)], plain[: len(result.trajectory)])
    from samp.robot.goal import ee_poses, goal_errors

    pos, rot = goal_errors(ee_poses(panda, result.trajectory[-1:]), ee_poses(panda, problem.q_goal[None]))
    assert result.reason == "" and pos[0] < 0.02 and rot[0] < 15.0, "the detour answered must reach the goal"
    clear = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=8, margin=MARGIN))
    assert np.array_equal(clear.plan(problem, grids=_field(d, b + 1.0)).trajectory, plain), \
        "with every candidate clear, the plain rollout (the first to reach) is the answer"
    assert clear.chosen["plain"] == 1


@pytest.fixture(scope="module")
def blocked(panda):
    """A problem whose straight joint-space line passes through a box (around the end effector halfway),
    the scene with the box, and the same scene without it: a reconstruction that missed the box."""
    home = panda.home.double().numpy()
    start, goal = home + [-0.9, 0, 0, 0, 0, 0, 0], home + [0.9, 0, 0, 0, 0, 0, 0]
    from samp.eval.checks import ee_poses

    centre = ee_poses(panda, ((start + goal) / 2)[None])[0, :3, 3]
    scene = Scene("boxed", (Box("box", (0.25, 0.25, 0.25), Pose(tuple(float(v) for v in centre))),))
    far = Box("far", (0.05, 0.05, 0.05), Pose((-0.9, -0.9, 0.1)))  # a scene's SDF needs one obstacle
    return Problem(scene, start, goal, name="boxed", robot="panda"), Scene("boxed-missed", (far,))


def test_near_the_goal_clear_means_no_nearer_than_the_goal_itself(panda, problem):
    """A goal close to a surface: along +y the plain rollout reads least at its end, set to 0.02 m, below the
    margin (the goal itself reads a little less), and above the margin wherever it is `finish` or more from the
    goal. With `goal_slack` (the default) the plain rollout is clear: near the goal it must keep the goal's own
    reading less the slack, not the margin. With `goal_slack: null` it is not. Far from the goal the margin
    still holds: 4 cm lower, the same rollout is unclear."""
    d = (0.0, 1.0, 0.0)
    extent, plain = _plain_extent(panda, problem, d)
    b = 0.02 - extent
    at_goal = _clearance(panda, problem.q_goal[None], d, b)  # the rollout stops within 2 cm of it, reading 0.02 m
    assert 0.005 < at_goal <= 0.02 + 1e-9, f"the goal must read less than the rollout and more than the slack: {at_goal}"
    far = plain[: int(np.argmax(np.linalg.norm(plain - problem.q_goal, axis=1) < CheckConfig().finish))]
    assert len(far) > 1 and _clearance(panda, far, d, b) > MARGIN + 0.03
    outcomes = {}
    for label, slack, shift in (("slack", 0.005, 0.0), ("margin only", None, 0.0), ("lower", 0.005, 0.04)):
        checked = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=1, margin=MARGIN, goal_slack=slack))
        checked.plan(problem, grids=_field(d, b - shift))
        outcomes[label] = "plain" if checked.chosen["plain"] else "unclear" if checked.chosen["unclear"] else "?"
    assert outcomes == {"slack": "plain", "margin only": "unclear", "lower": "unclear"}, outcomes
    with pytest.raises(ValueError, match="goal_slack"):
        CheckConfig(goal_slack=-0.01)


def test_when_no_candidate_is_clear_the_one_with_the_most_clearance_is_answered(panda, problem):
    """With a margin no candidate can keep (1 m, everywhere: no goal slack, so the slack ranks as the clearance),
    none is clear: the answer is the candidate that reached the goal with the most clearance: by the oracle
    (the candidates that reach it, rebuilt here) the largest, here a detour's, which stays farther from the zero
    level than the plain rollout. With every candidate the plain rollout (noisy ones without noise), the plain
    rollout."""
    d = (0.0, -1.0, 0.0)
    extent, plain = _plain_extent(panda, problem, d)
    b = 0.02 - extent
    checked = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=8, margin=1.0, goal_slack=None))
    answer = checked.plan(problem, grids=_field(d, b)).trajectory
    assert checked.chosen == {"plain": 0, "noisy": 0, "via": 0, "unclear": 1, "unreached": 0}, checked.chosen
    best = max(_clearance(panda, candidate, d, b) for candidate in _candidates(panda, problem, 8))
    assert _clearance(panda, answer, d, b) == pytest.approx(best, abs=1e-4) and best > 0.02 + 0.01
    alike = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=4, noisy=3, step_noise=0.0, margin=1.0,
                                                         goal_slack=None))
    assert np.array_equal(alike.plan(problem, grids=_field(d, b)).trajectory, plain), "ties go to the plain rollout"


def _candidates(robot, problem, count: int) -> list[np.ndarray]:
    """The oracle's candidates: LinePolicy's rollouts rebuilt here, each heading for its first-leg target (the goal
    for the plain one, the seeded via configuration for the others) and for the goal once within `via_reach` of
    it or after a third of the step budget, until the end effector is within the tolerances of the goal's."""
    from samp.robot.goal import ee_poses, goal_errors

    cfg = CheckConfig(candidates=count)
    start, goal = (torch.as_tensor(q, dtype=robot.dtype) for q in (problem.q_start, problem.q_goal))
    vias = CheckedPolicy(LinePolicy(robot), cfg)._vias(start, goal, problem.name)
    goal_pose, line, out = ee_poses(robot, problem.q_goal[None]), LinePolicy(robot), []
    for k in range(count):
        q, target, path = start[None], vias[k:k + 1], [start.numpy()]
        for step in range(cfg.max_steps):
            q = line.step(q, target, None)
            path.append(q[0].numpy())
            if not torch.equal(target, goal[None]) and ((q - target).norm() < cfg.via_reach or step >= cfg.max_steps // 3):
                target = goal[None]
            pos, rot = goal_errors(ee_poses(robot, q.numpy()), goal_pose)
            if torch.equal(target, goal[None]) and pos[0] < cfg.position_tolerance and rot[0] < cfg.orientation_tolerance:
                out.append(np.stack(path))
                break
    return out


def test_samp_check_checks_on_the_grid_it_is_given_not_the_exact_one(panda, blocked):
    """On the exact grid the box blocks the plain rollout; on a reconstruction that missed the box the plain
    rollout is clear and is the answer. The policy steps on that grid too (the one it was reset with)."""
    problem, missed = blocked
    exact = CheckedPolicy(LinePolicy(panda, 16), CheckConfig(candidates=4))
    exact.plan(problem)
    assert exact.chosen["plain"] == 0, "the exact grid must see the box on the straight path"
    asked = []

    def reconstructed(p, n_e):
        asked.append((p.name, n_e))
        return missed.anchor_grid(n_e)

    policy = LinePolicy(panda, 16)
    checked = CheckedPolicy(policy, CheckConfig(candidates=4))
    checked.plan(problem, grids=reconstructed)
    assert asked == [("boxed", 16)], asked
    assert checked.chosen["plain"] == 1, f"the check read the exact grid, not the reconstruction: {checked.chosen}"
    assert torch.equal(policy.seen[-1].float(), missed.anchor_grid(16).float()), "the policy stepped on another grid"


def test_the_evaluation_hands_samp_check_its_section_grids(panda, blocked):
    """`evaluate(..., grids=source)` passes the section's grid source to a planner whose plan takes grids."""
    from samp.eval.harness import evaluate, reads_grids

    problem, missed = blocked
    asked = []

    def source(p, n_e):
        asked.append(n_e)
        return missed.anchor_grid(n_e)

    checked = CheckedPolicy(LinePolicy(panda, 16), CheckConfig(candidates=2))
    assert reads_grids(checked) and not reads_grids(SimpleNamespace(plan=lambda problem: None))
    result = evaluate(checked, [problem], {"timed_problems": 0}, grids=source)
    assert asked == [16] and checked.chosen["plain"] == 1
    assert result["records"][0]["collision"], "collisions are still checked against the true scene"


def test_points_beyond_the_grid_read_less_than_its_border(panda, problem):
    """Bounds that end above the arm's lower links (z from 0.5 m): on a grid that reads 0.3 m everywhere, those
    points are up to 0.42 m below the bounds, so the check must see the plain rollout as unclear (it read the
    border's 0.3 m before), with the oracle's clearance below the margin; with bounds from the table up the
    same grid is clear."""
    (lo, hi), flat = DEFAULT_BOUNDS, lambda p, n_e: torch.full((N_E, N_E, N_E), 0.3)
    results = {}
    for z0 in (0.5, lo[2]):
        bounds = ((lo[0], lo[1], z0), hi)
        policy = LinePolicy(panda)
        policy.system = SimpleNamespace(bounds=bounds)
        checked = CheckedPolicy(policy, CheckConfig(candidates=1, margin=MARGIN))
        boxed = Problem(Scene("empty", bounds=bounds), problem.q_start, problem.q_goal, name=problem.name)
        trajectory = checked.plan(boxed, grids=flat).trajectory
        results[z0] = checked.chosen, _clearance(panda, trajectory, (0.0, 0.0, 0.0), 0.3, bounds=bounds)
    (below, low_clear), (inside, inside_clear) = results[0.5], results[lo[2]]
    assert below["unclear"] == 1 and low_clear < MARGIN, (below, low_clear)
    assert inside["plain"] == 1 and inside_clear == pytest.approx(0.3), (inside, inside_clear)


def test_the_check_reads_a_finer_grid_from_the_same_source(panda, blocked):
    """`n_e` gives the check its own grid, asked of the section's source (or the scene's exact grid): a source
    whose 16-anchor grid missed the box but whose 24-anchor grid has it makes the plain rollout unclear,
    while the policy still steps on the 16-anchor grid."""
    problem, missed = blocked
    asked = []

    def source(p, n_e):
        asked.append(n_e)
        return (missed if n_e == 16 else p.scene).anchor_grid(n_e)

    policy = LinePolicy(panda, 16)
    checked = CheckedPolicy(policy, CheckConfig(candidates=1, n_e=24))
    checked.plan(problem, grids=source)
    assert asked == [16, 24] and checked.chosen == {"plain": 0, "noisy": 0, "via": 0, "unclear": 1, "unreached": 0}
    assert torch.equal(policy.seen[-1].float(), missed.anchor_grid(16).float()), "the policy stepped on another grid"
    exact = CheckedPolicy(LinePolicy(panda, 16), CheckConfig(candidates=1, n_e=24))
    exact.plan(problem)
    assert exact.chosen["unclear"] == 1, "without a source the check reads the scene's exact grid at n_e"
    with pytest.raises(ValueError, match="check.n_e"):
        CheckConfig(n_e=1)


def test_noisy_candidates_are_the_policys_own_rollouts_shaken(panda, problem):
    """Candidates from the policy itself (`noisy`): without noise each one is the plain rollout, step for step
    (so none can be clear where the plain one is not); with noise (seeded) one leaves its path, and the one
    answered as clear has the oracle's clearance above the margin and reaches the goal."""
    d = (0.0, -1.0, 0.0)
    extent, plain = _plain_extent(panda, problem, d)
    b = 0.02 - extent  # the plain rollout's clearance is 0.02 m, inside the margin
    still = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=4, noisy=3, step_noise=0.0, margin=MARGIN))
    answer = still.plan(problem, grids=_field(d, b)).trajectory
    assert still.chosen == {"plain": 0, "noisy": 0, "via": 0, "unclear": 1, "unreached": 0}
    assert np.array_equal(answer, plain)
    shaken = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=8, noisy=7, step_noise=0.1, margin=MARGIN))
    answer = shaken.plan(problem, grids=_field(d, b)).trajectory
    assert shaken.chosen == {"plain": 0, "noisy": 1, "via": 0, "unclear": 0, "unreached": 0}, shaken.chosen
    assert _clearance(panda, answer, d, b) > MARGIN and not np.array_equal(answer[:len(plain)], plain[:len(answer)])
    from samp.robot.goal import ee_poses, goal_errors

    pos, _ = goal_errors(ee_poses(panda, answer[-1:]), ee_poses(panda, problem.q_goal[None]))
    assert pos[0] < 0.02


@pytest.mark.parametrize("bad", [{"candidates": 4, "noisy": 4}, {"candidates": 4, "noisy": -1},
                                 {"candidates": 4, "noisy": 2, "step_noise": -0.1}])
def test_bad_noisy_settings_are_refused(bad):
    with pytest.raises(ValueError, match="noisy|step_noise"):
        CheckConfig(**bad)


def _self_hits(robot, trajectory: np.ndarray, substeps: int = 3) -> np.ndarray:
    """The oracle: the evaluation's self-collision check (the robot alone in a simulator world) at the start and
    `substeps` configurations per step, the ones samp+check checks."""
    from samp.eval.checks import TrajectoryChecker

    q = torch.as_tensor(trajectory, dtype=torch.float64)
    t = torch.arange(1, substeps + 1, dtype=torch.float64) / substeps
    states = torch.cat([q[:1], (q[:-1, None] + t[None, :, None] * (q[1:] - q[:-1])[:, None]).reshape(-1, q.shape[1])])
    checker = TrajectoryChecker(robot)
    try:
        return checker._free_world().in_collision(states.numpy(), self_collision=True, joint_limits=False)
    finally:
        checker.close()


def test_a_candidate_where_the_robot_touches_itself_is_not_clear(panda):
    """An empty scene (every grid value 1 m) and a straight joint-space path on which the arm folds into itself
    midway (the evaluation's check says so): with `self_collision` off the plain rollout is answered as clear;
    with it on (the default) it is not, and the detour answered touches itself nowhere it was checked."""
    home = panda.home.double().numpy()
    lo, hi = panda.joint_limits.double().numpy().T
    d = np.array([-0.33, 0.273, 0.616, -0.079, 1.17, 1.181, 1.942])
    problem = Problem(Scene("empty"), np.clip(home - d, lo, hi), np.clip(home + d, lo, hi), name="folds")
    flat = lambda p, n_e: torch.ones((N_E, N_E, N_E))  # noqa: E731
    blind = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=8, self_collision=False))
    plain = blind.plan(problem, grids=flat).trajectory
    assert blind.chosen["plain"] == 1 and _self_hits(panda, plain).any(), "the plain path must fold into itself"
    checked = CheckedPolicy(LinePolicy(panda), CheckConfig(candidates=8))
    answer = checked.plan(problem, grids=flat).trajectory
    checked.close()
    assert checked.chosen["plain"] == 0, f"a path where the robot touches itself was taken as clear: {checked.chosen}"
    # a detour (seeded by the problem's name) goes round the fold
    assert checked.chosen["via"] == 1 and not _self_hits(panda, answer).any(), checked.chosen
