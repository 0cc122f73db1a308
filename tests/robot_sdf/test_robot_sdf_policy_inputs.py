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
