"""The robot SDF's one-joint tables (`SelfDistances` with K angles) in the fast tier, on a small untrained
hash grid: at the tabulated angles the tabled query equals the full network query (the oracle, every pair
evaluated), and between them each table is read by linear interpolation of its two neighbouring angles
(checked against numpy on the stored values). And its values are metres: far from the robot, a metre
further along a ray is a metre more."""

from __future__ import annotations

import numpy as np
import pytest
import torch

K = 9


@pytest.fixture(scope="module")
def sdf(untrained_sdf):
    return untrained_sdf


def test_far_from_the_robot_the_distance_grows_a_metre_per_metre(sdf):
    """Far outside every link's box, the robot SDF is the metric distance to the nearest box plus a constant
    (the network's value at the box corner): one metre further along a ray adds one metre. Values left in
    the links' normalised units would add 1 / scale instead."""
    robot = sdf.robot
    q = robot.home.to(robot.dtype)[None]
    ray = torch.tensor([0.6, -0.48, 0.64], dtype=robot.dtype)  # a unit vector
    points = torch.stack([ray * 60.0, ray * 61.0])[None]  # (1, 2, 3) metres from the base
    with torch.no_grad():
        near, far = sdf.query(points, q, cull=False)[0].tolist()
    assert far - near == pytest.approx(1.0, abs=1e-3), f"one metre further changed the distance by {far - near}"


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
