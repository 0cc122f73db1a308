"""The robot SDF's one-joint tables (`SelfDistances` with K angles) in the fast tier, on a small untrained
hash grid: at the tabulated angles the tabled query equals the full network query (the oracle, every pair
evaluated), and between them each table is read by linear interpolation of its two neighbouring angles
(checked against numpy on the stored values)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

K = 9


@pytest.fixture(scope="module")
def sdf(robots, small_robot_sdf):
    from samp.robot_sdf.artifact import build_net
    from samp.robot_sdf.whole_robot import RobotSDF

    robot = robots["panda"]
    payload = small_robot_sdf(robot, spread=True)  # values far from zero: many pairs count
    info = payload["info"]
    net = build_net(info["net"])
    net.load_state_dict(payload["state_dict"])
    return RobotSDF(robot, net, torch.tensor(info["centres"]), torch.tensor(info["scales"]), "test", {}).eval()


def _at(robot, fraction: float) -> torch.Tensor:
    """(1, n): every joint at the same fraction of its range (the tables' k-th angle is fraction k / (K - 1))."""
    lo, hi = robot.joint_limits.to(robot.dtype).T
    return (lo + (hi - lo) * fraction)[None]


def test_at_tabulated_angles_the_tables_equal_the_network(sdf):
    robot = sdf.robot
    tables = sdf.self_distances(K)
    assert tables.table is not None and len(tables.table_point) > 0, "the construction must tabulate some pairs"
    for k in (0, 3, 6, K - 1):
        q = _at(robot, k / (K - 1))
        with torch.no_grad():
            truth = sdf.query(robot.transform_points(q), q, cull=False)
            got = sdf.at_robot_points(q, tables=K)
        assert torch.allclose(got, truth, atol=1e-6), f"angle {k}: max difference {float((got - truth).abs().max())}"


@pytest.mark.parametrize("k, f", [(2, 0.25), (5, 0.5), (7, 0.9)])
def test_between_angles_the_tables_interpolate_linearly(sdf, k, f):
    robot = sdf.robot
    tables = sdf.self_distances(K)
    q = _at(robot, (k + f) / (K - 1))
    with torch.no_grad():
        got = sdf.at_robot_points(q, tables=K, needed=False)[0].double().numpy()  # rigid and table part only
    values = tables.table.double().numpy()  # (P, K): each tabulated pair at the K angles
    want = tables.base.double().numpy().copy()
    lerp = values[:, k] * (1 - f) + values[:, k + 1] * f
    np.minimum.at(want, tables.table_point.numpy(), lerp)
    assert np.allclose(got, want, atol=1e-6), f"max difference {np.abs(got - want).max()}"
