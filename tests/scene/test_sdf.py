"""The analytic scene SDF against trimesh's signed distance on meshes of the same shapes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from samp.scene import Box, Cylinder, MeshObstacle, Pose, Scene, Sphere
from samp.scene.sdf import mesh_signed_distance

N_POINTS = 10_000


def _random_pose(rng) -> Pose:
    return Pose(tuple(rng.uniform(-0.3, 0.3, 3)), tuple(Rotation.random(random_state=rng).as_quat()))


def _mesh_of(obstacle) -> tuple[trimesh.Trimesh, float]:
    """A trimesh of the primitive in the base frame and the largest gap between mesh and true surface."""
    if isinstance(obstacle, Box):
        mesh, sag = trimesh.creation.box(extents=obstacle.size), 0.0
    elif isinstance(obstacle, Cylinder):
        n = 512
        mesh = trimesh.creation.cylinder(radius=obstacle.radius, height=obstacle.height, sections=n)
        sag = obstacle.radius * (1 - np.cos(np.pi / n))
    else:
        mesh = trimesh.creation.icosphere(subdivisions=4, radius=obstacle.radius)
        sag = obstacle.radius - np.linalg.norm(mesh.triangles_center, axis=1).min()
    mesh.apply_transform(obstacle.pose.matrix())
    return mesh, float(sag)


def _make(kind, rng):
    pose = _random_pose(rng)
    if kind == "box":
        return Box("o", tuple(rng.uniform(0.05, 0.4, 3)), pose)
    if kind == "cylinder":
        return Cylinder("o", rng.uniform(0.03, 0.15), rng.uniform(0.05, 0.4), pose)
    return Sphere("o", rng.uniform(0.03, 0.08), pose)  # small enough for a 5120-face mesh to be within 1e-4


def _edge_distance(obstacle, points: np.ndarray) -> np.ndarray:
    """Distance from points to the primitive's sharp edges (inf for a sphere)."""
    T = obstacle.pose.matrix()
    local = (points - T[:3, 3]) @ T[:3, :3]
    if isinstance(obstacle, Sphere):
        return np.full(len(points), np.inf)
    if isinstance(obstacle, Cylinder):  # the two rim circles
        rho, z = np.hypot(local[:, 0], local[:, 1]), np.abs(local[:, 2])
        return np.hypot(rho - obstacle.radius, z - obstacle.height / 2)
    h = np.asarray(obstacle.size) / 2  # the 12 box edges: closest point on each
    d = np.full(len(points), np.inf)
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for sa in (-1, 1):
            for sb in (-1, 1):
                corner = np.zeros(3)
                corner[others[0]], corner[others[1]] = sa * h[others[0]], sb * h[others[1]]
                q = local - corner
                q[:, axis] = np.maximum(np.abs(local[:, axis]) - h[axis], 0)
                d = np.minimum(d, np.linalg.norm(q, axis=1))
    return d


@pytest.mark.parametrize("kind", ["box", "cylinder", "sphere"])
def test_primitive_sdf_matches_trimesh(kind):
    rng = np.random.default_rng({"box": 0, "cylinder": 1, "sphere": 2}[kind])
    obstacle = _make(kind, rng)
    scene = Scene("s", obstacles=(obstacle,))
    mesh, sag = _mesh_of(obstacle)
    assert sag < 1e-4, f"test mesh too coarse: sag {sag:.1e}"
    center, reach = np.asarray(obstacle.pose.position), 1.5 * mesh.extents.max()
    points = center + rng.uniform(-reach, reach, size=(N_POINTS, 3))
    points[: N_POINTS // 4] = center + rng.uniform(-0.25, 0.25, size=(N_POINTS // 4, 1)) * (mesh.extents / 2)
    ours = scene.sdf(points)
    theirs = -mesh_signed_distance(mesh, points, chunk=500)  # trimesh: positive inside
    away = _edge_distance(obstacle, points) > 1e-3
    err = np.abs(ours - theirs)[away]
    assert err.max() <= 1e-4, f"{kind}: max error {err.max():.2e} m away from edges, expected <= 1e-4"
    decided = np.abs(ours) > sag + 1e-9
    assert np.array_equal(np.sign(ours[decided]), np.sign(theirs[decided])), f"{kind}: sign differs"
    assert (ours < 0).sum() > N_POINTS // 5, "the test must probe inside too"


def test_union_is_min_and_any_batch_shape_works():
    rng = np.random.default_rng(3)
    a, b = _make("box", rng), Sphere("b", 0.1, _random_pose(rng))
    scene = Scene("s", obstacles=(a, b))
    pts = torch.as_tensor(rng.uniform(-0.6, 0.6, (4, 5, 3)))
    got = scene.sdf(pts)
    assert got.shape == (4, 5)
    want = torch.minimum(Scene("a", obstacles=(a,)).sdf(pts), Scene("b", obstacles=(b,)).sdf(pts))
    assert torch.equal(got, want)
    assert isinstance(scene.sdf(pts.numpy()), np.ndarray)


def test_sdf_gradient_is_the_unit_normal_outside():
    scene = Scene("s", obstacles=(Box("b", (0.2, 0.2, 0.2), Pose((0.5, 0.0, 0.3))),))
    p = torch.tensor([[0.8, 0.0, 0.3]], dtype=torch.float64, requires_grad=True)
    scene.sdf(p).sum().backward()
    assert torch.allclose(p.grad, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64))


def test_mesh_obstacle_matches_the_same_box():
    """pybullet_data's cube.obj (a unit cube) scaled to 0.2 m has the analytic box's distances."""
    pose = Pose((0.4, -0.1, 0.3), tuple(Rotation.from_euler("xyz", [0.3, -0.2, 0.9]).as_quat()))
    mesh_scene = Scene("m", obstacles=(MeshObstacle("cube", "pybullet_data://cube.obj", 0.2, pose),))
    box_scene = Scene("b", obstacles=(Box("cube", (0.2, 0.2, 0.2), pose),))
    pts = np.asarray(pose.position) + np.random.default_rng(4).uniform(-0.3, 0.3, (2000, 3))
    assert np.abs(mesh_scene.sdf(pts) - box_scene.sdf(pts)).max() < 1e-9


def test_open_mesh_is_refused_unless_convex_hull(tmp_path):
    from samp.scene.sdf import obstacle_parts

    open_mesh = trimesh.creation.box(extents=(1, 1, 1))
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) > 1)  # drop one side
    path = tmp_path / "open.obj"
    open_mesh.export(path)
    with pytest.raises(ValueError, match=r"is not closed.*set convex_hull=True"):
        Scene("s", obstacles=(MeshObstacle("m", str(path)),)).sdf(np.zeros((1, 3)))
    assert obstacle_parts(MeshObstacle("m", str(path), convex_hull=True))[0].is_watertight


def test_empty_scene_has_no_sdf():
    with pytest.raises(ValueError, match="has no obstacles"):
        Scene("empty").sdf(np.zeros((2, 3)))
