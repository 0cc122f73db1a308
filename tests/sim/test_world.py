"""`World` collision and distance queries against an independent oracle: the exact scene SDF at dense
points on the robot's link surfaces, posed by samp's FK."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as pb
import pytest
import torch
from scipy.spatial.transform import Rotation

from samp.scene import Box, Cylinder, MeshObstacle, Pose, Scene, Sphere
from samp.scene.sdf import obstacle_parts
from samp.sim import World

N_CONFIGS = 500
SPACING = 0.005  # m, longest edge of the lattice triangles on the link surfaces
CLUSTER = 0.03  # m, voxel size grouping lattice points for the oracle's culling
NUMERIC = 1e-4  # m, pybullet's GJK and the probes' residual error (about 1e-5) with room to spare


def _pose(xyz, euler=(0.0, 0.0, 0.0)) -> Pose:
    return Pose(tuple(xyz), tuple(Rotation.from_euler("xyz", euler).as_quat()))


def _primitives_scene() -> Scene:
    return Scene("primitives", obstacles=(
        Box("crate", (0.3, 0.2, 0.4), _pose((0.5, 0.2, 0.3), (0.0, 0.0, 0.4))),
        Cylinder("post", 0.06, 0.5, _pose((0.1, -0.5, 0.35), (0.4, 0.0, 0.0))),
        Sphere("ball", 0.12, _pose((-0.4, 0.3, 0.5)))),
        target=MeshObstacle("cube", "pybullet_data://cube.obj", scale=0.15, pose=_pose((0.3, -0.2, 0.7), (0.3, 0.5, 0.2))))


def _table_scene() -> Scene:
    return Scene("table", obstacles=(
        Box("table", (1.2, 1.6, 0.05), _pose((0.5, 0.0, -0.03))),
        Box("wall", (0.05, 1.0, 0.8), _pose((0.75, 0.0, 0.4), (0.1, -0.2, 0.3))),
        Cylinder("rail", 0.05, 0.8, _pose((0.4, 0.0, 0.9), (math.pi / 2, 0.0, 0.0))),
        MeshObstacle("stone", "pybullet_data://stone.obj", scale=0.6, pose=_pose((-0.3, -0.4, 0.3), (0.5, 0.0, 1.0)))),
        target=Sphere("goal", 0.04, _pose((0.5, -0.3, 0.25))))


def _bunny_scene(scale=0.35, xyz=(0.45, 0.0, 0.35)) -> Scene:
    return Scene("bunny", obstacles=(MeshObstacle("bunny", "pybullet_data://bunny.obj", scale=scale, pose=_pose(xyz)),))


# ----------------------------------------------------------------------------------------- the oracle
@dataclass
class LinkSamples:
    """Lattice points on one link's surface (link frame), grouped into clusters for culling."""

    points: np.ndarray  # (S, 3)
    cluster: np.ndarray  # (S,) cluster index
    centres: np.ndarray  # (C, 3)
    radii: np.ndarray  # (C,) largest distance from a centre to its points
    cover: float  # every surface point lies within this distance of a lattice point


def surface_lattice(triangles: np.ndarray, spacing: float) -> tuple[np.ndarray, float]:
    """(F, 3, 3) triangles -> (S, 3) points of a barycentric lattice on each, and its covering radius.

    A triangle with longest edge e is cut into n^2 similar triangles (edges e / n <= spacing); every point
    of a triangle lies within e / n / sqrt(3) of one of its corners (circumradius bound for acute
    triangles, half the longest edge for the others), so that is a sound covering radius.
    """
    points, cover = [], 0.0
    for tri in triangles:
        e = max(np.linalg.norm(tri[i] - tri[(i + 1) % 3]) for i in range(3))
        n = max(1, math.ceil(e / spacing))
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        bary = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n  # (k, 3)
        points.append(bary @ tri)
        cover = max(cover, e / n / math.sqrt(3))
    return np.concatenate(points), cover


def link_samples(robot, name: str) -> LinkSamples:
    triangles = np.concatenate([part.triangles for part in robot.geometry[name].parts])
    points, cover = surface_lattice(triangles, SPACING)
    _, cluster = np.unique(np.floor(points / CLUSTER), axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    centres = np.stack([points[cluster == c].mean(axis=0) for c in range(cluster.max() + 1)])
    radii = np.array([np.linalg.norm(points[cluster == c] - centres[c], axis=1).max() for c in range(len(centres))])
    return LinkSamples(points, cluster, centres, radii, cover)


def oracle_min_sdf(robot, scene: Scene, q: np.ndarray, samples: dict[str, LinkSamples]) -> np.ndarray:
    """q (B, n) -> (B,) min of the exact scene SDF over the lattice points of every sampled link.

    The SDF is 1-Lipschitz, so a cluster with centre sdf s and radius r holds values in [s - r, s + r]:
    only clusters whose lower end is below the best upper end are evaluated, which gives the same minimum.
    """
    fk = robot.fk(torch.as_tensor(q))
    poses = {name: fk[name].numpy() for name in samples}  # (B, 4, 4) each
    centres = np.concatenate([_apply(poses[n], s.centres) for n, s in samples.items()], axis=1)  # (B, C, 3)
    radii = np.concatenate([s.radii for s in samples.values()])
    at_centres = scene.sdf(centres)  # (B, C)
    upper = (at_centres + radii).min(axis=1)
    todo = at_centres - radii <= upper[:, None]  # (B, C)
    best = np.full(len(q), np.inf)
    offset = 0
    for name, s in samples.items():
        for c in range(len(s.centres)):
            configs = np.flatnonzero(todo[:, offset + c])
            if len(configs):
                values = scene.sdf(_apply(poses[name][configs], s.points[s.cluster == c]))  # (b, k)
                best[configs] = np.minimum(best[configs], values.min(axis=1))
        offset += len(s.centres)
    return best


def _apply(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(B, 4, 4) poses, (N, 3) points -> (B, N, 3)."""
    return np.einsum("bij,nj->bni", T[:, :3, :3], points) + T[:, None, :3, 3]


@pytest.fixture(scope="module")
def panda(robots):
    return robots["panda"]


@pytest.fixture(scope="module")
def samples(panda) -> dict[str, LinkSamples]:
    """Lattice samples of every Panda link but the fixed base."""
    return {name: link_samples(panda, name) for name in panda.link_names if name != panda.base_link}


def _random_q(robot, count: int, seed: int) -> np.ndarray:
    lo, hi = robot.joint_limits.numpy().T
    return np.random.default_rng(seed).uniform(lo, hi, size=(count, robot.dof))


# ----------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("make_scene, seed", [(_primitives_scene, 0), (_table_scene, 1)])
def test_collisions_and_distances_match_the_sdf_oracle(panda, samples, make_scene, seed):
    scene = make_scene()
    q = _random_q(panda, N_CONFIGS, seed)
    with World(panda, scene) as world:
        hit = world.in_collision(q, self_collision=False)
        dist = world.min_distance(q)
    oracle = oracle_min_sdf(panda, scene, q, samples)
    cover = max(s.cover for s in samples.values())
    assert 0.1 < hit.mean() < 0.9, f"{scene.name}: expected a mix of free and colliding configurations, got {hit.mean():.0%} colliding"
    assert np.array_equal(hit, dist < 0), "in_collision and min_distance < 0 disagree"

    # A lattice point inside an obstacle is a collision; a shallow one (< cover) may fall between points.
    wrong = (hit != (oracle < 0)) & (np.abs(dist) >= max(0.002, cover))
    assert not wrong.any(), (f"{scene.name}: {wrong.sum()} configurations disagree with the oracle, e.g. q={q[wrong][0].tolist()}: "
                             f"expected collision={oracle[wrong][0] < 0} (oracle {oracle[wrong][0]:.5f} m), got min_distance {dist[wrong][0]:.5f}")

    # Where the oracle is positive it bounds the true distance D: D <= oracle <= D + cover.
    free = oracle > 0
    low, high = oracle[free] - cover - NUMERIC, oracle[free] + NUMERIC
    bad = (dist[free] < low) | (dist[free] > high)
    assert not bad.any(), (f"{scene.name}: min_distance {dist[free][bad][:5]} outside [oracle - {cover * 1000:.2f} mm, oracle] "
                           f"for oracle {oracle[free][bad][:5]}")
