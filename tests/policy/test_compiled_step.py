"""The compiled step inputs (`samp.policy.compiled`) against the torch path they replace on a CPU: each input
the network reads (robot points, robot SDF at the near pairs, scene features, normalised configurations and
goal terms) against torch's own computation of it, the whole step against `compiled=False` for every
architecture switch, the border and NaN cases, and the refusals."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.policy.compiled import StepInputs, _trilinear, compiled_step_available
from samp.policy.interface import EnvBatch
from samp.policy.network import goal_features, normalize, sample_by_scene
from samp.policy.step import SAMPStepPolicy
from samp.policy.system import PolicySystem
from samp.scene import generate_scene

SMALL_NET = {"channels": 3, "env_hidden": [32], "point_hidden": [16, 32], "config_hidden": [16], "fusion_hidden": [32]}


@pytest.fixture(scope="module")
def payload(robots, small_robot_sdf):
    return small_robot_sdf(robots["panda"], spread=True)


@pytest.fixture(scope="module")
def binding(tiny_datamodule):
    return tiny_datamodule(8).binding


def _system(payload, binding, **model) -> PolicySystem:
    torch.manual_seed(0)
    system = PolicySystem(robot="panda", robot_sdf_payload=payload, model={**SMALL_NET, **model})
    system.bind(binding)
    return system.eval()


def _env(system, scenes: int = 2, rows: int = 7) -> EnvBatch:
    grids = torch.stack([generate_scene(kind, seed=3, bounds=system.bounds).anchor_grid(system.n_e)
                         for kind in ["tabletop", "shelf"][:scenes]])
    bounds = torch.tensor([system.bounds] * scenes, dtype=torch.float32)
    return EnvBatch(grids, bounds, torch.arange(rows) % scenes)


def _configurations(system, rows: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    lo, hi = system.robot.joint_limits.float().T
    q, q_goal = (lo + (hi - lo) * torch.rand(2, rows, 7, generator=torch.Generator().manual_seed(seed))).unbind(0)
    q[0], q[1] = lo, hi  # the tables' first and last angles
    q_goal[2] = q[2]  # at the goal: the goal direction's length is clamped
    return q, q_goal


def test_each_input_is_what_the_torch_path_computes(payload, binding):
    system = _system(payload, binding)
    env = _env(system)
    q, q_goal = _configurations(system, 7, seed=0)
    inputs = StepInputs(system)
    with torch.no_grad():
        features = system.encode(env.grids)
        inputs.set_features(features)
        u_t, config_in, env_in, point_in = inputs(q, q_goal, env.scene_index)
        points, d = system.robot_features(q, near=True)  # torch: FK, posed points, robot SDF at the near pairs
        box = system.net.env.feature_bounds(system.bounds, system.n_e, features.shape[-1])
        sampled = sample_by_scene(features, env.scene_index, points, box).transpose(1, 2)  # (B, M, C)
    assert torch.allclose(u_t, normalize(q, system.limits), atol=1e-6)
    assert torch.allclose(config_in, goal_features(normalize(q, system.limits), normalize(q_goal, system.limits), True),
                          atol=1e-5)
    assert torch.allclose(point_in[..., :3], points, atol=2e-6)  # metres
    assert torch.allclose(point_in[..., 3], d, atol=2e-6)
    C = features.shape[1]
    assert torch.allclose(env_in.view(7, -1, C + 1)[..., :C], sampled, atol=2e-5)
    assert torch.equal(env_in.view(7, -1, C + 1)[..., C], point_in[..., 3])
    assert (d < system.robot_sdf.self_distances(system.robot_sdf_tables).base).any()  # the tables lowered some


@pytest.mark.parametrize("model", [{}, {"env_encoder": False}, {"point_encoder": False}, {"goal_features": False}])
def test_the_compiled_step_is_the_torch_step(payload, binding, model):
    system = _system(payload, binding, **model)
    env = _env(system)
    q, q_goal = _configurations(system, 7, seed=1)
    fast, plain = SAMPStepPolicy(system), SAMPStepPolicy(system, compiled=False)
    assert fast.compiled and not plain.compiled
    for policy in (fast, plain):
        policy.reset(env)
    got, want = fast.step(q, q_goal, env), plain.step(q, q_goal, env)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert torch.allclose(got, want, atol=1e-5) and not torch.equal(got, q)
    one = EnvBatch(env.grids, env.bounds, env.scene_index[3:4])
    assert torch.allclose(fast.step(q[3:4], q_goal[3:4], one), want[3:4], atol=1e-5)  # B = 1


def test_without_the_robot_sdf_feature_the_network_reads_zeros(payload, binding):
    torch.manual_seed(0)
    system = PolicySystem(robot="panda", robot_sdf_payload=payload, model=SMALL_NET, robot_sdf_feature=False)
    system.bind(binding)
    env = _env(system.eval())
    q, q_goal = _configurations(system, 7, seed=2)
    fast, plain = SAMPStepPolicy(system), SAMPStepPolicy(system, compiled=False)
    fast.reset(env)
    plain.reset(env)
    assert torch.allclose(fast.step(q, q_goal, env), plain.step(q, q_goal, env), atol=1e-5)
    assert not fast._inputs(q, q_goal, env.scene_index)[3][..., 3].any()


def test_a_configuration_with_nan_gives_nan_and_leaves_the_others(payload, binding):
    system = _system(payload, binding)
    env = _env(system)
    q, q_goal = _configurations(system, 7, seed=3)
    q[4, 2] = float("nan")
    policy = SAMPStepPolicy(system)
    policy.reset(env)
    got = policy.step(q, q_goal, env)
    assert got[4].isnan().all() and got[[0, 1, 2, 3, 5, 6]].isfinite().all()
    keep = torch.tensor([0, 1, 2, 3, 5, 6])
    assert torch.allclose(got[keep], policy.step(q[keep], q_goal[keep], env.subset(keep)), atol=1e-6)


def test_the_interpolation_clamps_to_the_border_as_grid_sample_does():
    """Points inside, on the edge of and outside the feature box, against torch's grid_sample (via
    `sample_by_scene`) on a random volume of another size on each axis' box."""
    g = torch.Generator().manual_seed(4)
    volume = torch.rand(1, 3, 6, 6, 6, generator=g)
    lo, hi = np.array([-0.5, -1.0, 0.0]), np.array([1.0, 1.0, 1.5])
    points = torch.rand(1, 200, 3, generator=g, dtype=torch.float64) * 3 - 1  # about a third outside
    points[0, :3] = torch.from_numpy(np.array([lo, hi, [lo[0], hi[1], 0.7]]))
    want = sample_by_scene(volume, torch.zeros(1, dtype=torch.long), points.float(), (lo.tolist(), hi.tolist()))[0]
    channels_last = np.ascontiguousarray(volume.permute(0, 2, 3, 4, 1).numpy())
    got = np.zeros(3 * 200, np.float32)
    for m, (x, y, z) in enumerate(points[0].numpy()):
        _trilinear(channels_last, 0, x, y, z, lo, hi, got, 3 * m)
    assert np.allclose(got.reshape(200, 3).T, want.numpy(), atol=1e-6)


def test_compiled_is_refused_where_it_does_not_apply(payload, binding):
    system = _system(payload, binding)
    system.planner(robot_sdf_tables=0)  # the exact robot SDF at every pair: the network, not tables
    assert not compiled_step_available(system)
    assert not system.planner().compiled  # the default falls back to the torch path
    with pytest.raises(ValueError, match="robot_sdf_pairs=near"):
        system.planner(compiled=True)
    inputs = _system(payload, binding).planner()._inputs
    with pytest.raises(ValueError, match="shape"):
        inputs(torch.zeros(1, 6), torch.zeros(1, 6), torch.zeros(1, dtype=torch.long))


def test_a_scene_index_outside_the_encoded_scenes_is_refused(payload, binding):
    """The compiled loops do not check bounds themselves: the kernel refuses the index before it reads."""
    system = _system(payload, binding)
    env = _env(system, scenes=2, rows=3)
    policy = SAMPStepPolicy(system)
    q, q_goal = _configurations(system, 3, seed=5)
    with pytest.raises(IndexError, match="outside the encoded scenes"):  # nothing encoded yet
        policy._inputs(q, q_goal, env.scene_index)
    policy.reset(env)
    with pytest.raises(IndexError, match="outside the encoded scenes"):
        policy.step(q, q_goal, EnvBatch(env.grids, env.bounds, torch.tensor([0, 2, 1])))
    assert policy.step(q, q_goal, env).isfinite().all()
