"""A trained SAMP policy outside the evaluation: a few real training steps, `load_policy(run_dir)`, `step`
against the network fed by the generic robot-SDF query (an independent path), `plan` replayed step by
step and judged by the float64 robot, the policy's refusals, `examples/plan.py`, and the device option."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from samp.eval.checks import ee_poses, exact_robot, goal_errors
from samp.policy import load_policy
from samp.policy.interface import EnvBatch
from samp.policy.network import denormalize, normalize
from samp.policy.system import PolicySystem

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

REPO = Path(__file__).resolve().parents[2]
SMALL_NET = {"channels": 2, "env_hidden": [32], "point_hidden": [16, 32], "config_hidden": [16], "fusion_hidden": [32]}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory, tiny_datamodule, robots, small_robot_sdf):
    """A run folder holding a checkpoint of a SAMP policy trained for a few steps (real Lightning fit)."""
    import pytorch_lightning as pl

    dm = tiny_datamodule(8)
    payload = small_robot_sdf(robots["panda"], spread=True)
    system = PolicySystem(robot="panda", robot_sdf_payload=payload, model=SMALL_NET)
    system.bind(dm.binding)
    trainer = pl.Trainer(max_steps=3, accelerator="cpu", logger=False, enable_checkpointing=False,
                         enable_progress_bar=False, enable_model_summary=False)
    trainer.fit(system, dm)
    folder = tmp_path_factory.mktemp("run")
    trainer.save_checkpoint(folder / "checkpoints" / "last.ckpt")
    return folder


def _problem(policy, seed: int = 0):
    from samp.expert import sample_problems
    from samp.scene import generate_scene

    scene = generate_scene("tabletop", seed=11, bounds=policy.system.bounds)
    exact = exact_robot(policy.robot)
    return scene, next(p for p in sample_problems(exact, scene, 10, seed=seed) if p.q_goal is not None)


def test_step_is_the_network_fed_by_the_generic_robot_sdf_query(run_dir):
    policy = load_policy(run_dir, robot_sdf_tables=0)
    system = policy.system
    scene, problem = _problem(policy)
    env = policy._environment(scene)
    policy.reset(env)
    g = torch.Generator().manual_seed(0)
    lo, hi = system.robot.joint_limits.float().T
    q, q_goal = (lo + (hi - lo) * torch.rand(2, 5, 7, generator=g)).unbind(0)
    got = policy.step(q, q_goal, EnvBatch(env.grids, env.bounds, torch.zeros(5, dtype=torch.long)))
    with torch.no_grad():  # the oracle: FK of every frame and the robot SDF's culled query of arbitrary points
        points = system.robot.transform_points(q)
        d = system.robot_sdf.query(points, q)
        features = system.net.encode_scenes(env.grids)
        u = system.net(normalize(q, system.limits), normalize(q_goal, system.limits), points, d, features,
                       torch.zeros(5, dtype=torch.long), system.bounds, n_e=system.n_e)
    assert torch.allclose(got, denormalize(u, system.limits), atol=1e-5)


def test_near_pairs_feed_the_rigid_and_table_part_to_the_network(run_dir):
    """robot_sdf_pairs=near: a rollout step is the network fed by the robot SDF without the pairs two or more
    joints apart, the same values as the `needed` mask path asking for no point (an upper bound of the
    distances over every pair with the same tables); bad settings are refused."""
    policy = load_policy(run_dir, robot_sdf_pairs="near")
    system = policy.system
    scene, _ = _problem(policy)
    env = policy._environment(scene)
    policy.reset(env)
    lo, hi = system.robot.joint_limits.float().T
    q, q_goal = (lo + (hi - lo) * torch.rand(2, 5, 7, generator=torch.Generator().manual_seed(1))).unbind(0)
    scenes = torch.zeros(5, dtype=torch.long)
    got = policy.step(q, q_goal, EnvBatch(env.grids, env.bounds, scenes))
    with torch.no_grad():
        points = system.robot.transform_points(q)
        near = system.robot_sdf.at_robot_points(q, tables=system.robot_sdf_tables,
                                                needed=torch.zeros(5, len(system.robot.points), dtype=torch.bool))
        every = system.robot_sdf.at_robot_points(q, tables=system.robot_sdf_tables)  # the same tables, every pair
        u = system.net(normalize(q, system.limits), normalize(q_goal, system.limits), points, near,
                       system.net.encode_scenes(env.grids), scenes, system.bounds, n_e=system.n_e)
    assert torch.allclose(got, denormalize(u, system.limits), atol=1e-5)
    assert (near >= every).all() and (near > every + 1e-3).any()  # the skipped pairs mattered here
    assert torch.equal(system.robot_features(q)[1], every) and torch.equal(system.robot_features(q, near=True)[1], near)
    with pytest.raises(ValueError, match="robot_sdf_tables >= 2"):
        load_policy(run_dir, robot_sdf_tables=0, robot_sdf_pairs="near")
    with pytest.raises(ValueError, match="robot_sdf_pairs must be one of"):
        load_policy(run_dir, robot_sdf_pairs="far")


def test_training_feeds_the_network_the_robot_sdf_input_of_its_rollouts(tiny_datamodule, robots, small_robot_sdf):
    """The losses' prediction at q_t reads the robot SDF with the system's robot_sdf_pairs, as a rollout step
    does: the network's robot SDF input in `_losses` is `robot_features(q_t, near)` for near and for all pairs
    (the query itself is the oracle), on a batch whose noisy q_t reach the pairs that near skips."""
    from samp.names import BATCH_Q

    dm = tiny_datamodule(8)
    payload = small_robot_sdf(robots["panda"], spread=True)
    batch = next(iter(dm.train_dataloader()))
    lo, hi = torch.tensor([-2.8, -1.7, -2.8, -3.0, -2.8, 0.0, -2.8]), torch.tensor([2.8, 1.7, 2.8, -0.1, 2.8, 3.7, 2.8])
    batch[BATCH_Q] = lo + (hi - lo) * torch.rand(batch[BATCH_Q].shape, generator=torch.Generator().manual_seed(2))
    inputs = {}
    for pairs in ("near", "all"):
        system = PolicySystem(robot="panda", robot_sdf_payload=payload, model=SMALL_NET, robot_sdf_pairs=pairs)
        system.bind(dm.binding)
        seen = []
        hook = system.net.register_forward_pre_hook(lambda module, args: seen.append(args[3]))
        system._losses(batch)
        hook.remove()
        inputs[pairs] = seen[0]
        assert torch.equal(seen[0], system.robot_features(batch[BATCH_Q], near=pairs == "near")[1])
    assert (inputs["near"] >= inputs["all"]).all() and (inputs["near"] > inputs["all"] + 1e-3).any()


def test_bench_rollout_step_script_times_the_policys_own_step(run_dir):
    """tools/bench_suites/rollout_step.py (what `bench.py policy --baseline-src` runs per checkout): its
    reported first prediction is this policy's step on the same inputs, computed here in-process."""
    import json

    from samp.scene import generate_scene

    env_vars = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    out = subprocess.run([sys.executable, str(REPO / "tools" / "bench_suites" / "rollout_step.py"), "--src", str(REPO),
                          "--run", str(run_dir), "--blocks", "2"], capture_output=True, text=True, timeout=300,
                         env=env_vars, cwd=REPO)
    assert out.returncode == 0, out.stderr[-3000:]
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert 0 < report["step_ms"] <= report["step_ms_median"] and report["batch_ms"] > 0
    policy = load_policy(run_dir)
    env = policy._environment(generate_scene("shelf", seed=7, bounds=policy.system.bounds))
    policy.reset(env)
    lo, hi = policy.robot.joint_limits.to(policy.robot.dtype).T
    qs = lo + (hi - lo) * torch.rand(2, 7, generator=torch.Generator().manual_seed(0), dtype=policy.robot.dtype)
    expected = policy.step(qs[:1], qs[1:2], env)[0]
    assert torch.allclose(torch.tensor(report["q_next"], dtype=expected.dtype), expected, atol=1e-6)


def test_plan_replays_step_by_step_and_judges_the_goal_like_the_evaluation(run_dir):
    policy = load_policy(run_dir)
    scene, problem = _problem(policy)
    result = policy.plan(scene, problem.q_start, problem.q_goal, max_steps=12)
    traj = result.trajectory
    assert traj.shape == (result.steps + 1, 7) and np.allclose(traj[0], problem.q_start)
    assert result.termination in ("reached", "stalled", "max_steps") and len(result.step_times) == result.steps
    env = policy._environment(scene)
    policy.reset(env)
    goal = torch.as_tensor(problem.q_goal[None], dtype=torch.float32)
    for t in range(result.steps):  # every waypoint is the policy's step from the one before
        q_next = policy.step(torch.as_tensor(traj[t][None], dtype=torch.float32), goal, env)
        assert np.allclose(q_next[0].double().numpy(), traj[t + 1], atol=1e-5)
    exact = exact_robot(policy.robot)
    pos, rot = goal_errors(ee_poses(exact, traj[-1:]), ee_poses(exact, problem.q_goal[None]))
    assert result.position_error == pytest.approx(pos[0], abs=1e-4)
    assert result.reached == (pos[0] < 0.02 and rot[0] < 15.0)
    assert result.solution_time == pytest.approx(result.setup_time + sum(result.step_times))
    # a goal the start already meets: reached at once, no step taken
    at_goal = policy.plan(scene, problem.q_goal, problem.q_goal)
    assert at_goal.reached and at_goal.steps == 0


def test_plan_takes_a_grid_and_refuses_what_the_policy_cannot_read(run_dir):
    from samp.scene import generate_scene

    policy = load_policy(run_dir)
    scene, problem = _problem(policy)
    from_grid = policy.plan(scene.anchor_grid(policy.n_e), problem.q_start, problem.q_goal, max_steps=5)
    from_scene = policy.plan(scene, problem.q_start, problem.q_goal, max_steps=5)
    assert np.allclose(from_grid.trajectory, from_scene.trajectory)
    with pytest.raises(ValueError, match=r"\(16, 16, 16\) anchor grids"):
        policy.plan(torch.zeros(20, 20, 20), problem.q_start, problem.q_goal)
    lo, hi = np.asarray(policy.system.bounds)
    other = generate_scene("tabletop", seed=11, bounds=[list(lo), list(hi + 0.1)])
    with pytest.raises(ValueError, match="bounds"):
        policy.plan(other, problem.q_start, problem.q_goal)
    with pytest.raises(ValueError, match="q_goal must be 7 finite joint angles"):
        policy.plan(scene, problem.q_start, problem.q_goal[:6])
    with pytest.raises(ValueError, match="q_start must be 7 finite"):
        policy.plan(scene, np.full(7, np.nan), problem.q_goal)


def test_step_refuses_grids_the_policy_was_not_trained_on(run_dir):
    from samp.policy import SAMPStepPolicy, load_system

    system = load_system(run_dir)
    policy = SAMPStepPolicy(system)
    bounds = torch.tensor([system.bounds], dtype=torch.float32)
    with pytest.raises(ValueError, match="n_e = 16"):
        policy.reset(EnvBatch(torch.zeros(1, 20, 20, 20), bounds, torch.zeros(1, dtype=torch.long)))
    with pytest.raises(ValueError, match="workspace bounds"):
        policy.reset(EnvBatch(torch.zeros(1, 16, 16, 16), bounds + 0.5, torch.zeros(1, dtype=torch.long)))
    system.binding = None
    with pytest.raises(ValueError, match="never fitted"):
        SAMPStepPolicy(system)


def test_example_plan_script_runs(run_dir):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, str(REPO / "examples" / "plan.py"), str(run_dir), "3"], capture_output=True,
                         text=True, timeout=300, env=env, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert "steps: (" in out.stdout and "goal error" in out.stdout
    assert len((REPO / "examples" / "plan.py").read_text().splitlines()) <= 20


def test_device_option(run_dir):
    from samp.device import resolve_device

    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(ValueError, match="auto, cpu or cuda"):
        resolve_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="sees no CUDA device"):
            load_policy(run_dir, device="cuda")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_step_and_rollout_match_the_cpu(run_dir):
    cpu, gpu = load_policy(run_dir, device="cpu"), load_policy(run_dir, device="cuda")
    assert gpu.robot.device.type == "cuda"
    scene, problem = _problem(cpu)
    a = cpu.plan(scene, problem.q_start, problem.q_goal, max_steps=10)
    b = gpu.plan(scene, problem.q_start, problem.q_goal, max_steps=10)
    assert b.steps == a.steps and np.allclose(a.trajectory, b.trajectory, atol=1e-3)


def test_checked_planner_with_one_candidate_is_the_plain_plan(run_dir):
    """samp+check with one candidate steps the same policy from the same start: its trajectory is `plan`'s."""
    from samp.eval import Problem

    plain, checked = load_policy(run_dir), load_policy(run_dir, check={"candidates": 1, "finish": 0.0})
    scene, problem = _problem(plain)
    want = plain.plan(scene, problem.q_start, problem.q_goal, max_steps=40)
    checked.cfg.max_steps = 40
    got = checked.plan(Problem(scene, problem.q_start, problem.q_goal, name="p"))
    np.testing.assert_allclose(got.trajectory, want.trajectory, atol=1e-6)
    assert (got.reason == "") == want.reached


def test_checked_planner_clearance_matches_an_independent_trilinear_oracle(run_dir):
    """The check's clearance of a segment is the smallest anchor-grid SDF at the robot points over its
    sub-steps, recomputed here with scipy's trilinear interpolation of the grid (not samp's grid_sample), a
    point outside the bounds read at the nearest point inside less its distance to it; a sub-step left out
    or a swapped grid axis would change it; with the self-collision check, -inf where the arm touches itself.
    Candidates are deterministic per problem name, and the first heads straight for the goal."""
    from scipy.interpolate import RegularGridInterpolator

    checked = load_policy(run_dir, check={"candidates": 6, "substeps": 3, "self_collision": False})
    scene, _ = _problem(checked.policy)
    grid = scene.anchor_grid(checked.n_e)
    bounds = checked.policy.system.bounds
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    interp = RegularGridInterpolator([np.linspace(lo[a], hi[a], grid.shape[a]) for a in range(3)],
                                     grid.double().numpy())
    limits = checked.robot.joint_limits.double()
    g = torch.Generator().manual_seed(5)
    q0, q1 = (limits[:, 0] + (limits[:, 1] - limits[:, 0]) * torch.rand(2, 5, 7, generator=g, dtype=torch.float64))
    got = checked._clearance(grid.to(checked.robot.dtype), bounds, q0.to(checked.robot.dtype),
                             q1.to(checked.robot.dtype)).double().numpy()
    t = np.arange(1, 4)[None, :, None] / 3
    qs = (q0.numpy()[:, None] + t * (q1 - q0).numpy()[:, None]).reshape(-1, 7)
    pts = checked.robot.transform_points(torch.as_tensor(qs, dtype=checked.robot.dtype)).double().numpy()
    pts = pts.reshape(-1, 3)
    inside = np.clip(pts, lo, hi)
    assert (pts != inside).any(), "no robot point left the bounds: the reading beyond them went untested"
    want = (interp(inside) - np.linalg.norm(pts - inside, axis=1)).reshape(5, -1).min(axis=1)
    np.testing.assert_allclose(got, want, atol=1e-4)
    # with the self-collision check (the default), a segment on which the arm touches itself reads -inf: the
    # evaluation's own self-collision check of the same sub-steps says where
    from samp.eval.checks import TrajectoryChecker

    oracle = TrajectoryChecker(checked.robot)
    folded = oracle._free_world().in_collision(qs, self_collision=True, joint_limits=False).reshape(5, -1).any(axis=1)
    oracle.close()
    assert folded.any() and not folded.all(), "the random segments must include some that fold and some that do not"
    checked.cfg.self_collision = True
    got = checked._clearance(grid.to(checked.robot.dtype), bounds, q0.to(checked.robot.dtype),
                             q1.to(checked.robot.dtype)).double().numpy()
    np.testing.assert_allclose(got, np.where(folded, -np.inf, want), atol=1e-4)
    start, goal = torch.zeros(7, dtype=torch.float64), torch.full((7,), 0.3, dtype=torch.float64)
    vias = checked._vias(start, goal, "x")
    assert torch.equal(vias, checked._vias(start, goal, "x")) and not torch.equal(vias, checked._vias(start, goal, "y"))
    assert torch.equal(vias[0], goal) and (vias[1:] - vias[0]).abs().max() > 0.1


def test_checked_planner_finishes_a_stall_only_on_a_clear_short_segment(run_dir):
    """The straight finish after a stall: taken within `finish` radians when the grid along the segment reads
    above what a segment near the goal must keep (`near`); refused beyond that distance, through an obstacle,
    below `near`, or after a candidate was already unclear (its slack at most 0)."""
    checked = load_policy(run_dir, check={"finish": 0.5, "margin": 0.01})
    bounds, n = checked.policy.system.bounds, checked.n_e
    free, solid, thin = (torch.full((n, n, n), v) for v in (0.5, -0.5, 0.005))
    goal = checked.robot.home.to(checked.robot.dtype)
    close, far = goal + 0.1, goal + 0.4  # joint-space distances 0.26 and 1.06 rad
    assert checked._finishes(free.to(goal.dtype), bounds, close, goal, slack=0.2, near=0.01)
    assert not checked._finishes(free.to(goal.dtype), bounds, far, goal, slack=0.2, near=0.01)
    assert not checked._finishes(solid.to(goal.dtype), bounds, close, goal, slack=0.2, near=0.01)
    assert not checked._finishes(free.to(goal.dtype), bounds, close, goal, slack=-0.005, near=0.01)
    assert not checked._finishes(thin.to(goal.dtype), bounds, close, goal, slack=0.2, near=0.01)
    assert checked._finishes(thin.to(goal.dtype), bounds, close, goal, slack=0.2, near=0.0)


def test_checked_planner_refuses_bad_settings(run_dir):
    with pytest.raises(ValueError, match="check.candidates"):
        load_policy(run_dir, check=0)
    with pytest.raises(ValueError, match="check.spread"):
        load_policy(run_dir, check={"spread": -1.0})


def test_a_checkpoint_from_before_registration_and_norm_loads_with_its_own_conventions(run_dir, caplog):
    """A checkpoint written before `model.registration` and `model.norm` existed (its record's net and its
    hyperparameters without them) loads with the conventions it was trained with, bounds and BatchNorm, and
    says so; today's checkpoint keeps its own."""
    import logging

    from samp.integrity import load_torch_file
    from samp.names import CHECKPOINT_RECORD
    from samp.policy import load_system

    ckpt = load_torch_file(run_dir / "checkpoints" / "last.ckpt", "policy checkpoint", trust=True)
    assert load_system(ckpt).net_cfg.registration == "centres"
    for key in ("registration", "norm"):
        ckpt[CHECKPOINT_RECORD]["net"].pop(key)
        ckpt["hyper_parameters"]["model"].pop(key, None)
    # the old convention had BatchNorm's buffers: rebuild them as such from the GroupNorm-trained weights
    state = ckpt["state_dict"]
    for name in ("running_mean", "running_var", "num_batches_tracked"):
        state[f"net.env.net.1.{name}"] = torch.zeros(2) if name != "num_batches_tracked" else torch.tensor(0)
    with caplog.at_level(logging.INFO, logger="samp.policy.system"):
        old = load_system(ckpt)
    assert (old.net_cfg.registration, old.net_cfg.norm) == ("bounds", "batch")
    assert isinstance(old.net.env.net[1], torch.nn.BatchNorm3d)
    assert "model.registration=bounds" in caplog.text
