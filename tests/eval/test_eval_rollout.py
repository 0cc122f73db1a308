"""Problems from a dataset, the batched rollout engine, and the expert judged by the same code."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from samp.eval import (EnvBatch, Problem, StraightLinePolicy, dataset_grids, evaluate, load_planner,
                       problems_from_dataset, rollout)
from samp.eval.config import RolloutConfig

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


def test_the_experts_own_trajectories_succeed_without_collision(tiny_problems):
    ds, problems = tiny_problems
    assert {p.split for p in problems} == {"train", "val", "test"}
    result = evaluate(load_planner("expert"), problems)
    for split in ("train", "val", "test", "all"):
        m = result["metrics"][split]
        assert m["success_rate"] == 1.0 and m["reach_rate"] == 1.0, f"{split}: {m}"
        assert m["collision_rate"] == 0.0 and m["self_collision_rate"] == 0.0 and m["joint_limit_rate"] == 0.0, m
    for rec, p in zip(result["records"], problems):
        assert rec["position_error"] < 1e-9, "the expert's last waypoint is the goal"
        assert rec["solution_time"] == p.expert_time, "the expert's solution time is its planning time"
        assert rec["steps"] == 49


def test_problems_are_fixed_by_the_seed_and_spread_over_scenes(tiny_problems):
    ds, everything = tiny_problems
    a = problems_from_dataset(ds, "train", 2, seed=3)
    b = problems_from_dataset(ds, "train", 2, seed=3)
    assert [p.name for p in a] == [p.name for p in b]
    assert len(a) == 2 and all(p.split == "train" and p.robot == "panda" for p in a)
    assert len(problems_from_dataset(ds, "val", 50)) == 3, "a count above what the split has takes all of it"
    heldout = problems_from_dataset(ds, "heldout", 2, seed=1)  # the name before issue 17 reads as "val"
    assert [(p.name, p.split) for p in heldout] == [(p.name, "val") for p in problems_from_dataset(ds, "val", 2, seed=1)]
    for p in everything:  # each problem is its expert trajectory's start and goal, with the manifest's time
        np.testing.assert_array_equal(p.q_start, p.expert_trajectory[0])
        np.testing.assert_array_equal(p.q_goal, p.expert_trajectory[-1])
        index = int(p.name.rsplit("problem", 1)[1])
        assert p.expert_time == ds.manifest["scenes"][p.scene_index]["eval_planning_time"][index]
        assert p.scene_hash == ds.scene_hashes[p.scene_index] == p.scene.content_hash()
        assert p.expert_reason is None


def test_problems_are_the_stored_evaluation_problems_not_the_training_data(tiny_problems):
    """Every problem is one of the dataset's stored evaluation problems, with the expert's stored solution;
    compared by value, none is a demonstration the policy trains on."""
    ds, problems = tiny_problems
    assert len(problems) == len(ds.eval_problems) == 9
    stored = {(p["scene"], p["index"]): p for p in ds.eval_problems}
    demos = ds.trajectories.numpy()  # (N, 50, 7)
    for p in problems:
        record = stored[(p.scene_index, int(p.name.rsplit("problem", 1)[1]))]
        assert p.split == record["split"] == ds.scene_split[p.scene_index]
        np.testing.assert_array_equal(p.q_start, record["start"])
        np.testing.assert_array_equal(p.q_goal, record["goal"])
        np.testing.assert_array_equal(p.expert_trajectory, record["solution"])
        assert not ((demos[:, 0] == p.q_start).all(axis=1) & (demos[:, -1] == p.q_goal).all(axis=1)).any(), p.name
    assert not any(p.expert_trajectory is None for p in problems)
    assert ds.scene_indices("test") == [2] and {p.split for p in problems if p.scene_index == 2} == {"test"}


def test_a_failed_expert_plan_keeps_its_reason(tiny_problems):
    """A stored problem the expert failed comes back without a trajectory and with its reason, and the
    expert replayed on it fails with that reason."""
    import copy

    ds, _ = tiny_problems
    ds = copy.copy(ds)
    ds.eval_problems = [dict(p) for p in ds.eval_problems]
    reason = "planner timeout: RRTConnect found no exact solution in 5.0 s (OMPL: Timeout)"
    ds.eval_problems[0].update(success=False, solution=None, reason=reason)
    (p,) = [p for p in problems_from_dataset(ds, "train") if p.name.endswith("/problem0")]
    assert p.expert_trajectory is None and p.expert_reason == reason and p.expert_time is not None
    record = evaluate(load_planner("expert"), [p])["records"][0]
    assert record["termination"] == f"failed: {reason}" and not any(record["success"].values()), record["termination"]


def test_a_dataset_without_stored_evaluation_problems_is_refused(tiny_problems):
    import copy

    ds = copy.copy(tiny_problems[0])
    ds.has_eval_problems, ds.eval_problems = False, []
    with pytest.raises(ValueError, match=r"predates stored evaluation problems .*regenerate it with "
                                         r"`python -m samp.data generate dataset=tiny_eval`"):
        problems_from_dataset(ds, "val")
    with pytest.raises(ValueError, match=r"split must be one of \('train', 'val', 'test'\)"):
        problems_from_dataset(tiny_problems[0], "heldin")


def test_batched_and_one_at_a_time_rollouts_agree(tiny_problems, panda):
    _, problems = tiny_problems
    policy = StraightLinePolicy(panda, max_step=0.05)
    cfg = RolloutConfig()
    batched = rollout(policy, problems, cfg)
    single = rollout(policy, problems, RolloutConfig(batch_size=1))
    for a, b, p in zip(batched, single, problems):
        np.testing.assert_allclose(a.trajectory, b.trajectory, atol=1e-12)
        assert a.termination == b.termination == "reached"
        steps = np.linalg.norm(np.diff(a.trajectory, axis=0), axis=1)
        assert steps.max() <= 0.05 + 1e-12, "the straight-line policy moves at most max_step per step"
        assert len(a.step_times) == len(a.trajectory) - 1 and a.solution_time >= sum(a.step_times) - 1e-12
        assert a.position_error < cfg.position_tolerance


def _surface(robot, per_link: int = 300) -> dict:
    return {n: torch.as_tensor(trimesh.sample.sample_surface(m, per_link, seed=1)[0], dtype=torch.float64)
            for n, m in robot.link_meshes.items() if n != robot.base_link}


def test_rollout_collisions_agree_with_the_analytic_sdf(tiny_problems, panda):
    """Each straight-line rollout's collision flag against an oracle: the scene's analytic SDF at points
    on the exact link surfaces, at joint-space states 0.005 rad apart. Shallow contacts (< 2 mm) may
    fall between the oracle's surface samples, so only clear cases are compared."""
    ds, problems = tiny_problems
    result = evaluate(StraightLinePolicy(panda), problems)
    surface = _surface(panda)
    assert any(r["collision"] for r in result["records"]), "the straight line should hit something in these scenes"
    for rec, p in zip(result["records"], problems):
        traj = np.asarray(rec["trajectory"])
        dense = [traj[:1]] + [a + np.linspace(0, 1, max(1, int(np.ceil(np.linalg.norm(b - a) / 0.005))) + 1)[1:, None]
                              * (b - a) for a, b in zip(traj[:-1], traj[1:])]
        fk = panda.fk(torch.as_tensor(np.concatenate(dense)))
        worst = min(float(p.scene.sdf(pts @ fk[n][:, :3, :3].transpose(1, 2) + fk[n][:, None, :3, 3]).min())
                    for n, pts in surface.items())
        if worst < -0.002:
            assert rec["collision"], f"{p.name}: the oracle finds {-worst * 1000:.1f} mm of penetration"
        if not rec["collision"]:
            assert worst > -0.001, f"{p.name}: no collision reported, the oracle finds {-worst * 1000:.1f} mm"


class _Still:
    """A policy that never moves."""

    name, n_e = "still", None

    def __init__(self, robot):
        self.robot = robot

    def step(self, q, q_goal, env):
        return q.clone()


class _Wobble(_Still):
    """A policy that moves back and forth by 0.01 rad and never gets anywhere."""

    name = "wobble"

    def __init__(self, robot):
        super().__init__(robot)
        self.sign = 1.0

    def step(self, q, q_goal, env):
        self.sign = -self.sign
        return q + self.sign * 0.01


class _NaN(_Still):
    name = "nan"

    def step(self, q, q_goal, env):
        return torch.full_like(q, float("nan"))


def test_terminations_stall_max_steps_and_divergence(tiny_problems, panda):
    _, problems = tiny_problems
    cfg = RolloutConfig(max_steps=20, stall_steps=4)
    still = rollout(_Still(panda), problems[:2], cfg)
    assert [r.termination for r in still] == ["stalled"] * 2 and all(len(r.trajectory) == 5 for r in still)
    wobble = rollout(_Wobble(panda), problems[:2], cfg)
    assert [r.termination for r in wobble] == ["max_steps"] * 2 and all(len(r.trajectory) == 21 for r in wobble)
    nan = rollout(_NaN(panda), problems[:1], cfg)
    assert nan[0].termination == "diverged" and len(nan[0].trajectory) == 1
    rec = evaluate(_Wobble(panda), problems[:2], cfg)
    assert rec["metrics"]["all"]["reach_rate"] == 0.0 and rec["metrics"]["all"]["terminations"] == {"max_steps": 2}


class _Shape(_Still):
    name = "shape"

    def step(self, q, q_goal, env):
        return q[:, :3]


def test_a_policy_returning_the_wrong_shape_is_refused(tiny_problems, panda):
    with pytest.raises(ValueError, match=r"step must return a \(\d+, 7\) tensor"):
        rollout(_Shape(panda), tiny_problems[1][:2], RolloutConfig())


class _Probe(_Still):
    """Records what the engine hands to step."""

    name = "probe"

    def __init__(self, robot, n_e):
        super().__init__(robot)
        self.n_e, self.seen, self.resets = n_e, [], 0

    def reset(self, env):
        self.resets += 1

    def step(self, q, q_goal, env: EnvBatch):
        self.seen.append((env.grids, env.scene_index.clone(), env.problem_grids(), env.problem_bounds()))
        return q_goal.clone()  # jump to the goal: one step


def test_the_engine_hands_each_problem_its_scene_grid(tiny_problems, panda):
    ds, problems = tiny_problems
    probe = _Probe(panda, n_e=12)
    results = rollout(probe, problems, RolloutConfig(), dataset_grids(ds))
    assert probe.resets == 1 and len(probe.seen) == 1 and all(r.termination == "reached" for r in results)
    grids, index, per_problem, bounds = probe.seen[0]
    assert grids.shape == (3, 12, 12, 12), "one grid per distinct scene"
    for i, p in enumerate(problems):
        torch.testing.assert_close(per_problem[i], ds.grid(p.scene_index, 12).to(panda.dtype))
        torch.testing.assert_close(bounds[i], torch.tensor(p.scene.bounds, dtype=panda.dtype))
    exact = problems[0].scene.anchor_grid(12)  # the stored grid is the scene's exact SDF
    torch.testing.assert_close(ds.grid(problems[0].scene_index, 12), exact)


def test_problems_for_another_robot_are_refused(tiny_problems, robots):
    _, problems = tiny_problems
    with pytest.raises(ValueError, match="controls robot 'iiwa', but the problems were made for 'panda'"):
        evaluate(StraightLinePolicy(robots["iiwa"]), problems[:1])


def test_a_free_standing_problem_needs_a_valid_configuration(tiny_problems):
    scene = tiny_problems[1][0].scene
    with pytest.raises(ValueError, match="q_goal must be a finite"):
        Problem(scene, np.zeros(7), np.array([0.0, np.nan, 0, 0, 0, 0, 0]))


@pytest.mark.slow
def test_the_expert_planning_afresh_solves_its_own_problems(tiny_problems):
    """mode="plan" re-plans with OMPL (a float32 robot is given, as the CLI loads one): every stored problem,
    some with a start exactly at a joint limit, is solved again without collision."""
    from samp.robot import load_robot

    from dataclasses import replace

    from samp.sim import World

    _, problems = tiny_problems
    exact = load_robot("panda", dtype=torch.float64)
    limits = exact.joint_limits.numpy()
    # Starts exactly at a float64 joint limit (what float32 IK goals rounded inward are meant to plan from):
    # each stored problem's start with one joint moved onto a limit, where that is collision-free.
    at_limit = []
    for p in problems[3:]:
        with World(exact, p.scene) as world:
            for j in range(7):
                for bound in limits[j]:
                    q = p.q_start.copy()
                    q[j] = bound
                    if not world.in_collision(q[None])[0]:
                        at_limit.append(replace(p, q_start=q, name=f"{p.name}/joint{j}@{bound}"))
                        break
                else:
                    continue
                break
    assert len(at_limit) >= 2, "the test needs starts exactly at a joint limit"
    assert all(np.isin(p.q_start, limits).any() for p in at_limit)
    result = evaluate(load_planner("expert", robot=load_robot("panda"), mode="plan"), problems[3:] + at_limit)
    m = result["metrics"]["all"]
    assert m["success_rate"] == 1.0 and m["collision_rate"] == 0.0, [r["termination"] for r in result["records"]]
    assert all(r["solution_time"] > 0 for r in result["records"])
