"""The robot-SDF input of the SAMP policy with a trained robot SDF: at the robot's own points (samples on
shells 1, 30 and 60 mm around the links) the values must sit near the shell offsets and near the exact
(trimesh) distance. The policy tests use an untrained robot SDF, where any value passes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.slow  # trains a hash-grid SDF (shared with test_robot_sdf_model)

SMALL_NET = {"channels": 2, "env_hidden": [32], "point_hidden": [16, 32], "config_hidden": [16], "fusion_hidden": [32]}


@pytest.fixture(scope="module")
def system(panda, trained_sdf):
    """A SAMP `PolicySystem` whose robot SDF is the trained fixture (handed over in the artifact format)."""
    from samp.policy.system import PolicySystem
    from samp.robot_sdf.artifact import describe, net_spec

    net = trained_sdf.net
    info = describe(panda, net_spec(net), "test", trained_sdf.centres, trained_sdf.scales)
    payload = {"info": info, "state_dict": net.state_dict(), "artifact_id": "test"}
    return PolicySystem(robot="panda", robot_sdf_payload=payload, model=SMALL_NET).eval()


def test_the_policy_reads_robot_sdf_values_near_the_shell_offsets(panda, system):
    """At home and at two other configurations, the policy's robot-SDF input at each robot point: near the
    exact distance to the posed robot (trimesh) and, on the median, near the offset of the point's shell.
    Measured with the fixture's few seconds of training: see the messages. Catches a robot SDF evaluated at
    the wrong points or configuration, in link units instead of metres, or without its trained weights."""
    from samp.robot_sdf.evaluate import robot_signed_distance

    offsets = torch.tensor(panda.cfg.points.offsets)[panda.point_shells].numpy()  # (M,) metres
    q = torch.stack([panda.home, panda.home + 0.3, panda.home - 0.2]).float()
    points, values = system.robot_features(q)
    assert values.shape == (3, len(offsets)) and torch.isfinite(values).all()
    poses = panda.link_poses(q)
    for b in range(3):
        got = values[b].numpy()
        exact = robot_signed_distance(panda, points[b].double().numpy(), poses[b].double().numpy())
        err = np.abs(got - exact)
        assert np.median(err) < 0.006 and np.quantile(err, 0.95) < 0.02, \
            f"q {b}: |robot SDF - exact| median {1e3 * np.median(err):.1f} mm, 95 % {1e3 * np.quantile(err, 0.95):.1f} mm"
        for k, d in enumerate(panda.cfg.points.offsets):
            shell = panda.point_shells.numpy() == k
            # another link can be closer than the point's own shell, never farther (exact <= offset)
            assert (exact[shell] <= d + 1e-4).all(), "the exact distance exceeds the shell offset"
            assert abs(np.median(got[shell]) - d) < 0.008, \
                f"q {b}, shell {1e3 * d:.0f} mm: median robot SDF {1e3 * np.median(got[shell]):.1f} mm"


def test_the_collision_loss_weighs_points_by_their_true_robot_distance(panda, system):
    """L_coll of the system's own training step against docs/design.md's formula with exact robot distances
    (trimesh at the predicted posed points) and the grid's trilinear environment SDF: equal within 1 %
    (measured: 4.4215e-4 exact vs 4.4256e-4, 0.09 % apart). Catches weights of the wrong sign or
    temperature (the weights span exp(0.09) = 1.09 over the margin), read at other points, or a robot SDF
    in other units."""
    from samp.data.binding import DatasetBinding
    from samp.robot_sdf.evaluate import robot_signed_distance
    from samp.scene import Box, Pose, Scene, sample_grid

    bounds = ((-0.2, -0.6, 0.0), (0.9, 0.6, 1.0))
    ee = panda.fk(panda.home[None].to(panda.dtype))[panda.ee_link][0, :3, 3].tolist()
    wall = Box("wall", (0.04, 0.4, 0.4), Pose((ee[0] + 0.1, ee[1], ee[2])))  # 8 cm in front of the hand at home
    scene = Scene("near_wall", obstacles=(wall,), bounds=bounds)
    grids = scene.anchor_grid(16, bounds)[None]  # (1, 16, 16, 16)
    system.bind(DatasetBinding("panda", panda.asset_hash, "synthetic@000000000000", 16, bounds, grids))
    g = torch.Generator().manual_seed(0)
    q = (panda.home + 0.2 * torch.randn(6, panda.dof, generator=g, dtype=torch.float64)).float()
    batch = {"q": q, "q_next": q, "q_goal": q, "scene": torch.zeros(6, dtype=torch.long)}
    got = float(system._losses(batch)["coll"])
    with torch.no_grad():
        q_hat = system.predict(q, q, system.encode(grids), batch["scene"], bounds)
        points = panda.transform_points(q_hat)  # (B, M, 3)
        poses = panda.link_poses(q_hat)
        exact = torch.stack([torch.as_tensor(robot_signed_distance(panda, points[b].double().numpy(),
                                                                   poses[b].double().numpy())) for b in range(6)])
        env = torch.stack([sample_grid(grids[0], points[b], bounds) for b in range(6)]).double()  # (B, M)
    cfg = system.loss_cfg
    want = float((torch.exp(-(exact - cfg.d_target) / cfg.tau) * torch.relu(cfg.d_margin - env)).mean())
    assert want > 1e-4, f"the wall must be within d_margin of some robot points (L_coll = {want})"
    assert got == pytest.approx(want, rel=0.01), \
        f"L_coll: docs/design.md formula with exact distances {want:.6f}, got {got:.6f}"
