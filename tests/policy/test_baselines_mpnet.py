"""MPNet-style planner: network shapes and dropout, the loss on hand-computed values, the backward-step
augmentation, path densification and contraction, and planning on a tiny problem whose straight motion is
blocked: a path that an independent World check finds collision-free, or a failure with its reason."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.policy.baselines.mpnet import MPNetConfig, MPNetNet, set_dropout
from samp.policy.baselines.mpnet_planner import MPNetPlanConfig, densify
from samp.policy.baselines.mpnet_system import MPNetSystem, next_config_loss

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

SMALL = {"channels": [4, 8], "code": 16, "hidden": [64, 32], "dropout": 0.2}


@pytest.fixture(scope="module")
def dm(tiny_datamodule):
    return tiny_datamodule(32)


def _system(dm, **kw) -> MPNetSystem:
    system = MPNetSystem(robot="panda", model=SMALL, **kw)
    system.bind(dm.binding)
    return system


@pytest.fixture(scope="module")
def trained(dm):
    """An MPNetSystem fitted for 150 steps on the tiny set (enough to step along its demonstrations)."""
    torch.manual_seed(0)
    system = _system(dm).train()
    opt = torch.optim.Adam(system.net.parameters(), lr=3e-3)
    for i in range(150):
        loss = system._losses(dm.train_samples[torch.arange(i * 32, i * 32 + 32) % len(dm.train_samples)])["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    return system.eval()


@pytest.mark.parametrize("batch", [1, 5])
def test_network_shapes_and_dropout_at_planning_time(batch):
    torch.manual_seed(0)
    net = MPNetNet(MPNetConfig(**SMALL)).eval()
    code = net.encode(torch.rand(2, 16, 16, 16))
    assert code.shape == (2, 16)
    u_t, u_g = torch.rand(batch, 7) * 2 - 1, torch.rand(batch, 7) * 2 - 1
    out = net(code[torch.zeros(batch, dtype=torch.long)], u_t, u_g)
    assert out.shape == (batch, 7) and (out.abs() <= 1).all()
    c = code[:1].expand(batch, -1)
    assert torch.equal(net(c, u_t, u_g), net(c, u_t, u_g)), "without dropout the step is deterministic"
    set_dropout(net, True)
    assert not torch.equal(net(c, u_t, u_g), net(c, u_t, u_g)), "with dropout active, repeated steps differ"
    assert not net.encoder.training, "set_dropout touches only the dropout layers"


def test_next_config_loss_matches_hand_computed_value():
    pred, true = torch.tensor([[0.0, 0.0], [1.0, 1.0]]), torch.tensor([[1.0, 0.0], [1.0, 3.0]])
    assert float(next_config_loss(pred, true)) == pytest.approx((1.0 + 4.0) / 2)


def test_backward_steps_read_the_trajectory_in_reverse(dm):
    batch = dm.train_samples[torch.arange(10)]
    traj, k, t = dm.trajectories, batch["traj"], batch["step"]
    q, q_next, goal = _system(dm, reverse_fraction=1.0).train()._reverse(batch)
    torch.testing.assert_close(q, traj[k, t + 1])
    torch.testing.assert_close(q_next, traj[k, t])
    torch.testing.assert_close(goal, traj[k, 0])
    same = _system(dm, reverse_fraction=0.0).train()._reverse(batch)
    assert all(torch.equal(a, batch[key]) for a, key in zip(same, ("q", "q_next", "q_goal")))
    with pytest.raises(ValueError, match="reverse_fraction"):
        MPNetSystem(robot="panda", reverse_fraction=1.5)


def test_densify_never_falls_short_of_the_waypoint_count():
    """Rounding each segment's share on its own can lose a waypoint (three equal segments of 49 pieces
    round to 16 + 16 + 16 = 48); the largest-remainder split gives at least count - 1 pieces."""
    path = np.array([[0.0], [1.0], [2.0], [3.0]])
    assert len(densify(path, 50)) == 50
    rng = np.random.default_rng(0)
    for _ in range(200):
        path = np.cumsum(rng.normal(size=(int(rng.integers(2, 12)), 3)), axis=0)
        count = int(rng.integers(2, 80))
        got = len(densify(path, count))  # one more per segment at most, where a short one still gets its piece
        assert max(count, len(path)) <= got <= max(count, len(path)) + len(path), (len(path), count, got)


def test_densify_keeps_every_state_and_the_polyline():
    path = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]])
    out = densify(path, 9)
    assert len(out) == 9 and all(any(np.allclose(p, o) for o in out) for p in path)
    assert np.allclose(out[0], path[0]) and np.allclose(out[-1], path[-1])
    on_first = (out[:, 1] == 0) & (out[:, 0] <= 1)
    on_second = (out[:, 0] == 1) & (out[:, 1] >= 0) & (out[:, 1] <= 3)
    assert np.all(on_first | on_second), f"points off the polyline: {out}"
    seg = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert seg.sum() == pytest.approx(4.0)


def test_bad_planning_settings_are_refused():
    with pytest.raises(ValueError, match="fallback must be 'none' or 'ompl'"):
        MPNetPlanConfig(fallback="rrt")
    with pytest.raises(ValueError, match="replan_rounds >= 0"):
        MPNetPlanConfig(replan_rounds=-1)


def _independently_free(robot, scene, traj: np.ndarray) -> bool:
    """A fresh World checks every segment of traj at 0.005 rad (four times the planner's density)."""
    from samp.expert.trajectory import segment_states
    from samp.sim import World

    with World(robot, scene) as world:
        return not world.in_collision(segment_states(traj, 0.005)[0]).any()


def test_contraction_shortens_a_demonstration_and_keeps_it_free(trained, tiny, robots):
    from samp.data import open_dataset

    ds = open_dataset(tiny[0])
    planner = trained.planner()
    scene, traj = ds.scenes[int(ds.traj_scene[0])], ds.trajectories[0].numpy()
    world = planner._world(scene)
    out = planner._contract(list(traj), world)
    assert 2 <= len(out) < len(traj)
    assert np.array_equal(out[0], traj[0]) and np.array_equal(out[-1], traj[-1])
    # checked by a fresh World at four times the planner's density, not by the planner's own `_free`
    assert _independently_free(robots["panda"], scene, np.asarray(out)), "the contracted path collides"
    planner.close()


def _pair(trained, tiny, robots, blocked: bool):
    """A training-scene problem whose straight joint-space motion collides (`blocked`) or is free."""
    from samp.data import open_dataset
    from samp.eval import Problem
    from samp.expert.problems import random_free_configs

    ds = open_dataset(tiny[0])
    scene = ds.scenes[ds.scene_indices("train")[0]]
    planner = trained.planner()
    world = planner._world(scene)
    q = random_free_configs(robots["panda"], world, 40, np.random.default_rng(0), 0.015)
    try:
        for a, b in zip(q[0::2], q[1::2]):
            if planner._free(a, b, world) != blocked:
                return Problem(scene, a, b, split="train", name="blocked" if blocked else "open", robot="panda")
    finally:
        planner.close()
    pytest.fail(f"no start/goal pair with a {'blocked' if blocked else 'free'} straight motion among 20 random pairs")


@pytest.fixture(scope="module")
def blocked(trained, tiny, robots):
    return _pair(trained, tiny, robots, blocked=True)


def test_an_open_problem_is_solved_with_a_free_path(trained, tiny, robots):
    """A problem whose straight motion is free must be solved (a planner that always fails passes the test
    below, which accepts a reasoned failure on a hard problem)."""
    problem = _pair(trained, tiny, robots, blocked=False)
    planner = trained.planner(time_limit=8.0, replan_rounds=4)
    answer = planner.plan(problem)
    assert answer.trajectory is not None, answer.reason
    traj = answer.trajectory
    assert np.array_equal(traj[0], problem.q_start) and np.array_equal(traj[-1], problem.q_goal)
    assert _independently_free(robots["panda"], problem.scene, traj) and planner.outcomes == {"neural": 1}
    planner.close()


def test_planning_gives_a_free_path_or_a_reason(trained, blocked, robots):
    planner = trained.planner(time_limit=8.0, replan_rounds=4)
    answer = planner.plan(blocked)
    assert answer.solution_time > 0
    if answer.trajectory is None:
        assert answer.reason.startswith("neural planner:"), answer.reason
        assert planner.outcomes == {"failed": 1}
    else:
        traj = answer.trajectory
        assert np.array_equal(traj[0], blocked.q_start) and np.array_equal(traj[-1], blocked.q_goal)
        assert len(traj) >= 50 and _independently_free(robots["panda"], blocked.scene, traj)
        assert planner.outcomes == {"neural": 1}
    planner.close()


def test_ompl_fallback_answers_what_the_network_cannot(trained, blocked, robots):
    planner = trained.planner(time_limit=1e-9, fallback="ompl")  # no time at all for the network
    answer = planner.plan(blocked)
    assert answer.trajectory is not None, answer.reason
    assert _independently_free(robots["panda"], blocked.scene, answer.trajectory)
    assert planner.outcomes == {"fallback": 1}
    planner.close()
