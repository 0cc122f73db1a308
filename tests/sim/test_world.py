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

from samp.robot.bodies import MESH_MARGIN
from samp.scene import Box, Cylinder, MeshObstacle, Pose, Scene, Sphere
from samp.scene.sdf import obstacle_parts
from samp.sim import World
from samp.sim.world import SELF_SLACK

N_CONFIGS = 500
COVER = 0.003  # m, every point of a link surface lies this close to an oracle sample
CLUSTER = 0.03  # m, voxel size grouping the samples for the oracle's culling
NUMERIC = 1e-4  # m, pybullet's GJK and the probes' residual error (about 1e-5) with room to spare


def _pose(xyz, euler=(0.0, 0.0, 0.0)) -> Pose:
    return Pose(tuple(xyz), tuple(Rotation.from_euler("xyz", euler).as_quat()))


def _primitives_scene() -> Scene:
    return Scene("primitives", obstacles=(
        Box("crate", (0.3, 0.2, 0.4), _pose((0.5, 0.2, 0.3), (0.0, 0.0, 0.4))),
        Cylinder("post", 0.06, 0.5, _pose((0.1, -0.5, 0.35), (0.4, 0.0, 0.0))),
        Sphere("ball", 0.12, _pose((-0.4, 0.3, 0.5)))),
        target=MeshObstacle("cube", "pybullet_data://cube.obj", scale=0.15,
                            pose=_pose((0.3, -0.2, 0.7), (0.3, 0.5, 0.2))))


def _table_scene() -> Scene:
    return Scene("table", obstacles=(
        Box("table", (1.2, 1.6, 0.05), _pose((0.5, 0.0, -0.03))),
        Box("wall", (0.05, 1.0, 0.8), _pose((0.75, 0.0, 0.4), (0.1, -0.2, 0.3))),
        Cylinder("rail", 0.05, 0.8, _pose((0.4, 0.0, 0.9), (math.pi / 2, 0.0, 0.0))),
        MeshObstacle("stone", "pybullet_data://stone.obj", scale=0.6,  # closed and convex: no convex_hull flag
                     pose=_pose((-0.3, -0.4, 0.3), (0.5, 0.0, 1.0)))),
        target=Sphere("goal", 0.04, _pose((0.5, -0.3, 0.25))))


def _bunny_scene(scale=0.35, xyz=(0.45, 0.0, 0.35)) -> Scene:
    return Scene("bunny", obstacles=(MeshObstacle("bunny", "pybullet_data://bunny.obj", scale=scale, pose=_pose(xyz)),))


# ----------------------------------------------------------------------------------------- the oracle
@dataclass
class LinkSamples:
    """Lattice points on one link's surface (link frame), in clusters for culling."""

    clusters: list[np.ndarray]  # (k, 3) points each
    centres: np.ndarray  # (C, 3) the point of each cluster nearest its mean
    radii: np.ndarray  # (C,) largest distance from a centre to the other points of its cluster


def triangle_lattice(tri: np.ndarray, cover: float) -> np.ndarray:
    """(3, 3) triangle -> (k, 3) points such that every point of the triangle is within `cover` of one.

    Layers parallel to the longest edge BC run from the opposite corner A, at most cover / sqrt(2) apart,
    each with points at most sqrt(2) cover apart, ends included. A point between two layers has its foot
    on the longer one within that gap (the angles at B and C are acute, BC being the longest edge), and
    the foot is within half the spacing of a layer point: sqrt(cover^2 / 2 + cover^2 / 2) = cover.
    """
    k = int(np.argmax([np.linalg.norm(tri[(i + 1) % 3] - tri[(i + 2) % 3]) for i in range(3)]))
    A, B, C = tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]
    base = np.linalg.norm(C - B)
    height = np.linalg.norm(np.cross(B - A, C - A)) / base
    layers = max(1, math.ceil(height / (cover / math.sqrt(2))))
    points = [A[None]]
    for t in np.arange(1, layers + 1) / layers:
        count = math.ceil(t * base / (cover * math.sqrt(2))) + 1
        u = np.linspace(0.0, 1.0, count)[:, None]
        points.append(A + t * ((1 - u) * (B - A) + u * (C - A)))
    return np.concatenate(points)


def link_samples(robot, name: str) -> LinkSamples:
    triangles = np.concatenate([part.triangles for part in robot.geometry[name].parts])
    points = np.concatenate([triangle_lattice(tri, COVER) for tri in triangles])
    _, cluster = np.unique(np.floor(points / CLUSTER), axis=0, return_inverse=True)
    clusters = [points[cluster.reshape(-1) == c] for c in range(cluster.max() + 1)]
    centres = np.stack([c[np.argmin(np.linalg.norm(c - c.mean(axis=0), axis=1))] for c in clusters])
    radii = np.array([np.linalg.norm(c - m, axis=1).max() for c, m in zip(clusters, centres)])
    return LinkSamples(clusters, centres, radii)


def oracle_min_sdf(robot, scene: Scene, q: np.ndarray, samples: dict[str, LinkSamples]) -> np.ndarray:
    """q (B, n) -> (B,) min of the exact scene SDF over the lattice points of every sampled link.

    The SDF is 1-Lipschitz, so a cluster whose centre (one of its points) has value s and whose radius is r
    holds values in [s - r, s]: only clusters with s - r below the smallest centre value are evaluated,
    which gives the same minimum.
    """
    fk = robot.fk(torch.as_tensor(q))
    poses = {name: fk[name].numpy() for name in samples}  # (B, 4, 4) each
    centres = np.concatenate([_apply(poses[n], s.centres) for n, s in samples.items()], axis=1)  # (B, C, 3)
    radii = np.concatenate([s.radii for s in samples.values()])
    at_centres = scene.sdf(centres)  # (B, C)
    todo = at_centres - radii <= at_centres.min(axis=1, keepdims=True)  # (B, C)
    points, owners = [], []
    clusters = [(name, cluster) for name, s in samples.items() for cluster in s.clusters]
    for c in np.flatnonzero(todo.any(axis=0)):
        name, cluster = clusters[c]
        configs = np.flatnonzero(todo[:, c])
        points.append(_apply(poses[name][configs], cluster).reshape(-1, 3))
        owners.append(np.repeat(configs, len(cluster)))
    best = np.full(len(q), np.inf)
    np.minimum.at(best, np.concatenate(owners), scene.sdf(np.concatenate(points)))
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
def _generated(name: str):
    from samp.scene import generate_scene

    return lambda: generate_scene(name, seed=4)


@pytest.mark.parametrize("make_scene, seed", [(_primitives_scene, 0), (_table_scene, 1)] +
                         [(_generated(g), 2 + i) for i, g in enumerate(["tabletop", "shelf", "cabinet", "blocks"])])
def test_collisions_and_distances_match_the_sdf_oracle(panda, samples, make_scene, seed):
    scene = make_scene()
    q = _random_q(panda, N_CONFIGS, seed)
    with World(panda, scene) as world:
        hit = world.in_collision(q, self_collision=False)
        dist = world.min_distance(q)
    oracle = oracle_min_sdf(panda, scene, q, samples)
    assert 0.1 < hit.mean() < 0.9, f"{scene.name}: expected free and colliding configurations, got {hit.mean():.0%}"
    assert np.array_equal(hit, dist < 0), "in_collision and min_distance < 0 disagree"

    # A lattice point inside an obstacle is a collision, always.
    missed = (oracle < -NUMERIC) & ~hit
    assert not missed.any(), (f"{scene.name}: {missed.sum()} configurations free but a surface point is "
                              f"{-oracle[missed][0]:.5f} m deep, e.g. q={q[missed][0].tolist()}")
    # A shallow penetration (an obstacle corner into a link face) can fall between lattice points.
    extra = hit & (oracle >= 0) & (np.abs(dist) >= max(0.002, COVER))
    assert not extra.any(), (f"{scene.name}: {extra.sum()} configurations in collision ({dist[extra][0]:.5f} m) "
                             f"with no lattice point inside, e.g. q={q[extra][0].tolist()}")

    # Where the oracle is positive it bounds the true distance D: D <= oracle <= D + COVER.
    free = oracle > 0
    bad = (dist[free] < oracle[free] - COVER - NUMERIC) | (dist[free] > oracle[free] + NUMERIC)
    assert not bad.any(), (f"{scene.name}: min_distance {dist[free][bad][:5]} outside "
                           f"[oracle - {COVER * 1000:g} mm, oracle] for oracle {oracle[free][bad][:5]}")
    # That bound cannot see pybullet's 1 mm margins left in, but the typical gap can: the closest point is
    # mostly a hull vertex, itself a lattice point, so the oracle is usually exact (gaps measured < 0.1 mm).
    typical = np.median(oracle[free] - dist[free])
    assert abs(typical) < 2e-4, f"{scene.name}: median oracle - min_distance is {typical * 1000:.3f} mm, expected ~0"


def test_a_closed_concave_mesh_matches_an_inside_oracle(panda, samples):
    """A non-convex closed mesh is a triangle soup to pybullet; lattice points inside it (trimesh's ray
    test) must agree with in_collision, and min_distance with the scene SDF on configurations near it."""
    scene = _bunny_scene()
    q = _random_q(panda, N_CONFIGS, seed=2)
    with World(panda, scene) as world:
        hit = world.in_collision(q, self_collision=False)
        dist = world.min_distance(q)
    assert np.array_equal(hit, dist < 0), "in_collision and min_distance < 0 disagree"
    inside = inside_oracle(panda, scene.obstacles[0], q, samples)
    assert 0.1 < inside.mean() < 0.9, f"expected a mix of free and colliding configurations, got {inside.mean():.0%}"
    missed = inside & ~hit & (dist >= NUMERIC)
    assert not missed.any(), (f"{missed.sum()} configurations free ({dist[missed][0]:.5f} m) with a lattice point "
                              f"inside the mesh, e.g. q={q[missed][0].tolist()}")
    extra = hit & ~inside & (np.abs(dist) >= max(0.002, COVER))  # shallow ones can fall between lattice points
    assert not extra.any(), (f"{extra.sum()} configurations in collision ({dist[extra][0]:.5f} m) with no lattice "
                             f"point inside the mesh, e.g. q={q[extra][0].tolist()}")
    near = np.flatnonzero((dist > 0) & (dist < 0.1))[:10]  # trimesh's distance is slow: a few configurations
    oracle = oracle_min_sdf(panda, scene, q[near], samples)
    assert np.all((dist[near] >= oracle - COVER - NUMERIC) & (dist[near] <= oracle + NUMERIC)), (
        f"min_distance {dist[near]} outside [oracle - {COVER * 1000:g} mm, oracle] for oracle {oracle}")


def inside_oracle(robot, obstacle: MeshObstacle, q: np.ndarray, samples: dict[str, LinkSamples]) -> np.ndarray:
    """q (B, n) -> (B,) bool: some lattice point of a sampled link is inside the closed mesh obstacle.
    Only clusters whose centre is within their radius of the mesh's bounding box are tested."""
    (mesh,) = obstacle_parts(obstacle)
    lo, hi = mesh.bounds
    T_inv = np.linalg.inv(obstacle.pose.matrix())
    fk = robot.fk(torch.as_tensor(q))
    out = np.zeros(len(q), dtype=bool)
    for name, s in samples.items():
        T = T_inv @ fk[name].numpy()  # (B, 4, 4) link -> obstacle frame
        centres = _apply(T, s.centres)  # (B, C, 3)
        gap = np.linalg.norm(np.maximum(np.maximum(lo - centres, centres - hi), 0.0), axis=-1)
        for c in np.flatnonzero((gap <= s.radii).any(axis=0)):
            configs = np.flatnonzero((gap[:, c] <= s.radii[c]) & ~out)
            if len(configs):
                points = _apply(T[configs], s.clusters[c])  # (b, k, 3)
                out[configs] |= mesh.contains(points.reshape(-1, 3)).reshape(len(configs), -1).any(axis=1)
    return out


def test_a_link_inside_a_closed_concave_mesh_is_in_collision(panda, samples):
    """The whole arm inside a large bunny crosses no triangle, yet collides; its distance is minus the
    depth of its deepest vertex, as the scene SDF measures it."""
    scene = _bunny_scene(scale=2.0, xyz=(0.2, 0.1, 0.5))
    q = panda.home[None].numpy()
    fk = panda.fk(panda.home[None])
    moving = [name for name in panda.link_names if name != panda.base_link]
    vertices = np.concatenate([_apply(fk[n].numpy(), panda.geometry[n].mesh.vertices)[0] for n in moving])
    at_vertices = scene.sdf(vertices)
    assert at_vertices.max() < -0.1, "the arm should lie well inside the mesh, clear of its surface"
    with World(panda, scene) as world:
        assert world.in_collision(q, self_collision=False)[0], "an arm inside a closed mesh must be in collision"
        dist = world.min_distance(q)[0]
    assert dist == pytest.approx(at_vertices.min(), abs=NUMERIC), f"expected {at_vertices.min():.5f}, got {dist:.5f}"
    oracle = oracle_min_sdf(panda, scene, q, samples)[0]
    assert oracle <= dist + NUMERIC, (f"the deepest vertex ({dist:.5f}) cannot lie deeper than the deepest "
                                      f"lattice point ({oracle:.5f})")


@pytest.mark.parametrize("name", ["panda", "iiwa", "xarm6"])
def test_broadphase_loses_nothing(robots, name):
    """in_collision and min_distance equal an exhaustive check of every part against every obstacle
    (the xArm's links have several convex parts each)."""
    robot = robots[name]
    q = _random_q(robot, 100, seed=3)
    with World(robot, _primitives_scene()) as world:
        hit, dist = world.in_collision(q, self_collision=False), world.min_distance(q)
        brute = np.array([_exhaustive_distance(world, qi) for qi in q])
    assert 0.05 < hit.mean() < 0.95, f"{name}: expected free and colliding configurations, got {hit.mean():.0%}"
    assert np.array_equal(hit, brute < 0), f"{name}: in_collision {hit.astype(int)} vs {(brute < 0).astype(int)}"
    np.testing.assert_allclose(dist, brute, atol=1e-9, err_msg=f"{name}: min_distance vs exhaustive")


def _exhaustive_distance(world: World, q: np.ndarray) -> float:
    """Every non-base part against every obstacle body, with pybullet's margins added back."""
    robot, bodies = world.robot, world.links.bodies
    world.links.set_q(q)
    best = world.max_distance
    for link in (n for n in robot.link_names if n != robot.base_link):
        for body in bodies[link]:
            for o in world.obstacles:
                points = pb.getClosestPoints(body, o.body, world.max_distance, physicsClientId=world.client)
                best = min([best] + [p[8] + MESH_MARGIN + o.inflation for p in points])
    return best


def test_self_collision_and_joint_limits(robots):
    """A folded arm touches itself and home does not; beyond a limit is a violation; the flags switch each off."""
    panda = robots["panda"]
    folded = [0.0, 1.76, 0.0, -3.07, 0.0, 0.2, 0.0]  # shoulder down, elbow fully bent: the hand meets the base
    home = panda.home.tolist()
    beyond = [3.0, *home[1:]]  # joint 1 past its 2.8973 rad limit
    q = torch.tensor([folded, home, beyond], dtype=torch.float64)
    with World(panda, Scene("empty")) as world:
        np.testing.assert_array_equal(world.in_collision(q), [True, False, True])
        np.testing.assert_array_equal(world.in_collision(q, self_collision=False), [False, False, True])
        np.testing.assert_array_equal(world.in_collision(q, joint_limits=False), [True, False, False])
        np.testing.assert_array_equal(world.min_distance(q), [world.max_distance] * 3)


@pytest.mark.parametrize("name", ["panda", "iiwa", "xarm6"])
def test_self_collision_matches_link_bodies(robots, name):
    """The broadphase keeps every pair that LinkBodies finds in contact, checking all link pairs."""
    robot = robots[name]
    q = _random_q(robot, 100, seed=4)
    with World(robot, Scene("empty")) as world:
        hit = world.in_collision(q)
        expected = []
        for qi in q:
            world.links.set_q(qi)
            expected.append(bool(world.links.colliding_pairs(exclude=robot.self_collision_exclude)))
    assert 0.05 < np.mean(expected) < 0.95, f"{name}: expected some self-collisions, got {np.mean(expected):.0%}"
    np.testing.assert_array_equal(hit, expected, err_msg=f"{name}: World vs LinkBodies.colliding_pairs")


@pytest.mark.parametrize("name", ["panda", "iiwa", "xarm6"])
def test_link_frame_boxes_drop_only_pairs_pybullet_finds_apart(robots, name):
    """A self pair whose world boxes overlap but whose boxes in one part's link frame are SELF_SLACK apart is
    not asked of pybullet: every such pair is apart by pybullet too (so no collision outcome changes), and
    the filter removes a good share of the candidates (it is what keeps most free configurations out of
    the narrowphase)."""
    robot = robots[name]
    q = _random_q(robot, 300, seed=6)
    with World(robot, Scene("empty")) as world:
        T = world.links.link_poses(q)
        lo, hi = world._part_boxes(T)
        touch = world._self_gaps(lo, hi) <= 0.0
        dropped = np.argwhere(touch & ~world._apart_in_link_frames(T, touch))
        assert len(dropped) > 0.2 * touch.sum(), f"{name}: dropped {len(dropped)} of {touch.sum()} candidates"
        bodies = world.links.part_bodies
        for j, s in dropped:
            world.links.set_q(q[j])
            a, b = world._self_pairs[s]
            points = pb.getClosestPoints(bodies[a], bodies[b], 1.0, physicsClientId=world.client)
            d = min(p[8] for p in points) + 2 * MESH_MARGIN
            assert d > SELF_SLACK / 2, f"{name}: dropped pair {a}-{b} at configuration {j} is {d:.5f} m apart"


@pytest.mark.parametrize("name", ["panda", "xarm6"])
def test_part_boxes_of_a_big_batch_equal_those_of_one_configuration_at_a_time(robots, name):
    """Big batches take the parts in groups of equal vertex count, small ones one padded product: the
    boxes are the same floats either way, so no collision outcome depends on how queries are batched."""
    robot = robots[name]
    q = _random_q(robot, 40, seed=7)
    with World(robot, Scene("empty")) as world:
        T = world.links.link_poses(q)
        lo, hi = world._part_boxes(T)
        one = [world._part_boxes(T[i:i + 1]) for i in range(len(q))]
    assert np.array_equal(lo, np.concatenate([a for a, _ in one]))
    assert np.array_equal(hi, np.concatenate([b for _, b in one]))


@pytest.mark.parametrize("name", ["panda", "iiwa", "xarm6"])
def test_compiled_broadphase_equals_the_numpy_one(robots, name):
    """The compiled broadphase (`samp.sim.broadphase`) gives the numpy reference's link poses and box gaps to
    rounding and the same candidate self pairs, so collision queries answer the same either way."""
    robot = robots[name]
    q = _random_q(robot, 300, seed=8)
    with World(robot, _primitives_scene()) as world:
        assert world.compiled, f"{name} is a serial arm: its queries take the compiled broadphase"
        T, gaps, touch = world._broadphase(q, True, compiled=True)
        T_np, gaps_np, touch_np = world._broadphase(q, True, compiled=False)
        np.testing.assert_allclose(T, T_np, rtol=0, atol=1e-12)
        np.testing.assert_allclose(gaps, gaps_np, rtol=0, atol=1e-12)
        assert 0.0 < (gaps == 0.0).mean() < 0.5, "some part boxes overlap an obstacle's, most do not"
        assert touch.any() and np.array_equal(touch, touch_np)
        assert not world._broadphase(q, False, compiled=True)[2].any()  # no self pairs unless asked
        hit, distance = world.in_collision(q, margin=0.02), world.min_distance(q)
        world.compiled = False
        np.testing.assert_array_equal(world.in_collision(q, margin=0.02), hit)
        # poses a rounding error apart: pybullet's GJK answers to its own accuracy (~1e-5 m, NUMERIC)
        np.testing.assert_allclose(world.min_distance(q), distance, rtol=0, atol=NUMERIC)


def test_margin(panda):
    """A configuration d metres away is free at margins below d and in collision above it."""
    q = _random_q(panda, 200, seed=5)
    with World(panda, _primitives_scene()) as world:
        dist = world.min_distance(q)
        chosen = np.flatnonzero((dist > 0.01) & (dist < 0.05))[:5]
        assert len(chosen), "expected configurations 1 to 5 cm from the obstacles"
        for i in chosen:
            qi, d = q[i:i + 1], dist[i]
            assert not world.in_collision(qi, self_collision=False)[0], f"{d:.4f} m away is free at margin 0"
            below, above = d - 0.005, d + 0.005
            assert not world.in_collision(qi, margin=below, self_collision=False)[0], f"{d:.4f} m, margin {below:.4f}"
            assert world.in_collision(qi, margin=above, self_collision=False)[0], f"{d:.4f} m, margin {above:.4f}"


def test_bad_input_is_refused_with_what_was_expected(panda):
    with World(panda, _primitives_scene()) as world:
        with pytest.raises(ValueError, match=r"shape \(B, 7\).*got \(7,\); use q\[None\]"):
            world.in_collision(panda.home)
        with pytest.raises(ValueError, match=r"shape \(B, 7\).*got \(2, 6\)"):
            world.min_distance(np.zeros((2, 6)))
        with pytest.raises(ValueError, match="finite"):
            world.in_collision(np.full((1, 7), np.nan))
        with pytest.raises(ValueError, match="margin must be a non-negative"):
            world.in_collision(panda.home[None], margin=-0.01)
    with pytest.raises(RuntimeError, match="closed"):
        world.min_distance(panda.home[None])


def test_the_client_is_closed_on_exit_and_on_error(panda):
    """`with World(...)` disconnects its pybullet client however the block ends; close() is idempotent."""
    with World(panda, _primitives_scene()) as world:
        client = world.client
        assert pb.isConnected(client)
    assert not pb.isConnected(client) and world.closed
    world.close()  # idempotent

    with pytest.raises(KeyError):
        with World(panda, _primitives_scene()) as world:
            client = world.client
            raise KeyError("boom")
    assert not pb.isConnected(client)
