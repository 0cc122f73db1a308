"""The robot SDF at the robot's own points (`RobotSDF.at_robot_points`): equal to the generic query of the
posed points with every pair evaluated (the oracle), exactly without tables and within the interpolation
error with them (shrinking as the tables get finer); NaN configurations stay NaN; cached pieces follow the
weights. And the hash grid's single pass over all levels equals the level-by-level loop."""

from __future__ import annotations

import pytest
import torch


def _configurations(robot, count: int, seed: int) -> torch.Tensor:
    """Uniform over the joint limits: many fold the arm onto itself, so pairs far along the chain count too."""
    lo, hi = robot.joint_limits.to(robot.dtype).T
    return lo + (hi - lo) * torch.rand(count, robot.dof, generator=torch.Generator().manual_seed(seed), dtype=robot.dtype)


def _oracle(sdf, q):
    with torch.no_grad():
        return sdf.query(sdf.robot.transform_points(q), q, cull=False)


@pytest.mark.parametrize("batch", [1, 40])
@pytest.mark.slow  # trains the hash-grid fixture (shared with the slow model tests)
def test_exact_path_equals_every_pair_evaluated(trained_sdf, batch):
    q = _configurations(trained_sdf.robot, batch, seed=batch)
    got = trained_sdf.at_robot_points(q, tables=0)
    assert got.shape == (batch, len(trained_sdf.robot.points))
    assert torch.allclose(got, _oracle(trained_sdf, q), atol=2e-6)  # float32 round-off of the posed points only
    # one at a time (the cached values must not be changed by a query) gives the same numbers
    for b in range(min(batch, 5)):
        assert torch.allclose(trained_sdf.at_robot_points(q[b:b + 1], tables=0), got[b:b + 1], atol=1e-7)


@pytest.mark.slow  # trains the hash-grid fixture (shared with the slow model tests)
@pytest.mark.parametrize("tables", [0, 64])
def test_needed_points_are_exact_and_the_others_upper_bounds(trained_sdf, tables):
    """`needed` restricts the network pairs to some points (the collision loss asks only where its hinge
    acts): those values equal the full query's (up to float rounding), and the others never fall below the true
    distance."""
    q = _configurations(trained_sdf.robot, 12, seed=21)
    full = trained_sdf.at_robot_points(q, tables=tables)
    needed = torch.rand(full.shape, generator=torch.Generator().manual_seed(1)) < 0.2
    got = trained_sdf.at_robot_points(q, tables=tables, needed=needed)
    # the same pairs through the network, batched with other pairs than in the full query: equal up to the
    # product's float32 rounding, which BLAS may order by batch size on some CPUs (1 ulp seen on an AMD EPYC)
    assert torch.allclose(got[needed], full[needed], rtol=1e-6, atol=1e-8)
    assert (got[~needed] >= full[~needed] - 1e-7).all() and (got[~needed] > full[~needed] + 1e-3).any()
    none = trained_sdf.at_robot_points(q, tables=tables, needed=torch.zeros_like(needed))
    assert torch.equal(none[~needed], got[~needed])  # a point's value depends on whether it is needed only


@pytest.mark.slow  # trains the hash-grid fixture (shared with the slow model tests)
def test_tables_approximate_the_network_and_converge(trained_sdf):
    q = _configurations(trained_sdf.robot, 60, seed=3)
    truth = _oracle(trained_sdf, q)
    errors = {K: (trained_sdf.at_robot_points(q, tables=K) - truth).abs() for K in (32, 512)}
    # Linear interpolation over K angles: its error falls roughly as 1/K^2. Measured on this network: max
    # 4.0 mm at K = 32 and 0.03 mm at K = 512; a table indexed one angle off (or a wrong joint) gives cm errors.
    assert errors[512].max() < 1e-3 and errors[512].mean() < 2e-5
    assert errors[512].max() < errors[32].max() / 10


@pytest.mark.slow  # trains the hash-grid fixture (shared with the slow model tests)
def test_nan_configuration_stays_nan(trained_sdf):
    q = trained_sdf.robot.home.to(trained_sdf.robot.dtype).repeat(2, 1)
    q[0, 3] = float("nan")
    for K in (0, 64):
        d = trained_sdf.at_robot_points(q, tables=K)  # with a joint undefined, so is every distance
        assert d[0].isnan().all() and not d[1].isnan().any()


@pytest.mark.slow  # trains the hash-grid fixture (shared with the slow model tests)
def test_cached_pieces_follow_the_weights(trained_sdf):
    import copy

    sdf = copy.deepcopy(trained_sdf)
    q = _configurations(sdf.robot, 4, seed=9)
    before = sdf.at_robot_points(q, tables=0)
    with torch.no_grad():
        sdf.net.decoder[-1].bias += 0.5  # every normalised distance up by 0.5: the values change
    after = sdf.at_robot_points(q, tables=0)
    assert torch.allclose(after, _oracle(sdf, q), atol=2e-6) and not torch.allclose(after, before)


@pytest.mark.parametrize("encoding", [
    {"levels": 8, "features": 2, "log2_table_size": 15, "coarsest": 2, "finest": 256},  # dense and hashed levels
    {"levels": 4, "features": 3, "log2_table_size": 10, "dense": False, "interpolation": "linear"},  # 12-byte rows
])
def test_hash_grid_single_pass_equals_the_level_loop(encoding):
    from samp.robot_sdf.encoding import HashGridEncoding

    enc = HashGridEncoding(**encoding, init_scale=1.0)
    x = torch.rand(5000, 3, generator=torch.Generator().manual_seed(0))
    x[0], x[1] = 0.0, 1.0  # the lower and upper faces
    loop = torch.cat([enc._level(x.T.contiguous(), level) for level in range(enc.levels)], dim=1).detach()
    with torch.no_grad():
        fused = enc(x)  # no autograd: the single pass, in chunks
    assert torch.allclose(fused, loop, atol=1e-6, rtol=0)
    with torch.no_grad():
        enc.tables[0] += 1.0  # a changed table is seen (the packed copy is rebuilt)
        assert torch.allclose(enc(x[:10])[:, :encoding["features"]], loop[:10, :encoding["features"]] + 1.0, atol=1e-5)
