"""Robot points on shells: distances, placement, counts, caching and `transform_points`."""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from samp.robot.points import split_counts


def _world(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    return x @ T[:3, :3].T + T[:3, 3]


def test_points_lie_on_their_shells(robot):
    """Each point's exact distance to its own link (trimesh signed distance to every convex part,
    union by max) equals its shell offset within the tolerance."""
    cfg = robot.cfg.points
    pts, links, shells = robot.points.numpy(), robot.point_links.numpy(), robot.point_shells.numpy()
    for li, name in enumerate(robot.point_link_names):
        sel = links == li
        signed = np.max([trimesh.proximity.signed_distance(p, pts[sel]) for p in robot.geometry[name].parts], axis=0)
        want = np.asarray(cfg.offsets)[shells[sel]]
        err = np.abs(-signed - want)  # trimesh: positive inside
        bound = cfg.tolerance * want
        worst = np.argmax(err - bound)
        assert np.all(err <= bound), (f"{robot.name}/{name}: a point is {-signed[worst]:.5f} m from its link, "
                                      f"expected {want[worst]} +- {bound[worst]:.5f}")


def test_no_point_inside_the_robot_at_home(robot):
    fk = robot.fk(robot.home[None])
    world = robot.transform_points(robot.home[None])[0].numpy()
    for name in robot.link_names:
        T = fk[name][0].numpy()
        local = _world(np.linalg.inv(T), world)
        for part in robot.geometry[name].parts:
            inside = part.contains(local)
            assert not inside.any(), f"{robot.name}: {inside.sum()} robot points inside {name} at the home configuration"


def test_counts_split_by_shell_and_area(robot):
    cfg = robot.cfg.points
    assert robot.points.shape == (cfg.count, 3) and robot.point_links.shape == (cfg.count,)
    shell_counts = np.bincount(robot.point_shells.numpy(), minlength=len(cfg.offsets))
    assert shell_counts.max() - shell_counts.min() <= 1, f"points per shell {shell_counts}, expected an even split"
    areas = np.array([robot.geometry[n].area for n in robot.point_link_names])
    for s, n_shell in enumerate(shell_counts):
        got = np.bincount(robot.point_links.numpy()[robot.point_shells.numpy() == s], minlength=len(areas))
        want = n_shell * areas / areas.sum()
        assert np.all(np.abs(got - want) < 1.0), f"{robot.name} shell {s}: {got} points per link, expected ~{want.round(1)}"


def test_split_counts_is_exact_and_proportional():
    counts = split_counts(10, [1.0, 1.0, 1.0])
    assert counts.sum() == 10 and sorted(counts.tolist()) == [3, 3, 4]
    assert split_counts(7, [3.0, 0.0, 4.0]).tolist() == [3, 0, 4]


def test_points_are_cached_and_deterministic(robots, tmp_path, monkeypatch):
    from samp.robot import load_robot

    monkeypatch.setenv("SAMP_CACHE_DIR", str(tmp_path))
    fresh = load_robot("xarm6", dtype=torch.float64)  # sampled anew in an empty cache
    files = list((tmp_path / "robot_points").glob("xarm6-*.npz"))
    assert len(files) == 1, f"expected one cache file, found {files}"
    assert torch.equal(fresh.points, robots["xarm6"].points), "same seed and asset must give the same points"
    stamp = files[0].stat().st_mtime_ns
    again = load_robot("xarm6", dtype=torch.float64)
    assert files[0].stat().st_mtime_ns == stamp and torch.equal(again.points, fresh.points)


def test_transform_points_matches_fk_by_hand(robot):
    g = torch.Generator().manual_seed(4)
    lo, hi = robot.joint_limits.T
    q = lo + (hi - lo) * torch.rand(3, robot.dof, generator=g, dtype=robot.dtype)
    got = robot.transform_points(q)
    fk = robot.fk(q)
    for m in range(0, len(robot.points), 37):
        T = fk[robot.point_link_names[int(robot.point_links[m])]]  # (B, 4, 4)
        want = (T @ torch.cat([robot.points[m], torch.ones(1, dtype=robot.dtype)]))[:, :3]
        assert torch.allclose(got[:, m], want, atol=1e-12), f"point {m}: got {got[:, m]}, expected {want}"


def test_transform_points_gradient_matches_finite_differences(robots):
    robot = robots["panda"]
    q = (robot.home + 0.1 * torch.arange(robot.dof, dtype=robot.dtype))[None].repeat(2, 1)
    q[1] += 0.2
    q.requires_grad_(True)
    subset = torch.arange(0, len(robot.points), 16)
    assert torch.autograd.gradcheck(lambda x: robot.transform_points(x)[:, subset], (q,), eps=1e-6, atol=1e-6)
