"""Depth cameras against ground truth: the linearised depth of a known plane, back-projected points on
the obstacles' exact surfaces, the robot's pixels found by the segmentation mask, seeded noise."""

from __future__ import annotations

import numpy as np
import pytest

from samp.scene import Box, Pose, Scene
from samp.sim import World
from samp.sim.camera import Camera, camera_set, linear_depth, load_camera_set


def test_linear_depth_inverts_the_projection_of_the_depth_buffer():
    near, far = 0.1, 5.0
    z = np.array([0.1, 0.5, 1.0, 2.5, 5.0])
    ndc = (far + near) / (far - near) - 2 * far * near / ((far - near) * z)  # OpenGL: z_ndc of a point at depth z
    np.testing.assert_allclose(linear_depth((ndc + 1) / 2, near, far), z, rtol=1e-12)


@pytest.mark.parametrize("height", [0.6, 1.3])
def test_a_plane_at_a_known_distance_reads_that_depth(panda, height):
    """A camera looking straight down at a table top (z = 0) from `height`: every pixel's depth is `height`."""
    from samp.scene.generators import table

    scene = Scene("plane", obstacles=(table(size=(6.0, 6.0)),))
    cam = {"name": "down", "width": 64, "height": 48, "fov": 50.0, "eye": [0.3, 0.0, height],
           "target": [0.3, 0.0, 0.0], "up": [1.0, 0.0, 0.0]}
    with World(panda, scene) as world:
        image = world.depth_images({"name": "one", "cameras": [cam]}, q=panda.home.numpy())[0]
    floor = ~image.robot
    assert floor.mean() > 0.5, "the robot should hide at most part of the table"
    err = np.abs(image.depth[floor] - height)
    assert err.max() < 1e-3, f"depth of the plane: expected {height} m everywhere, got errors up to {err.max():.2e} m"
    points = image.scan().hits
    assert np.abs(points[:, 2]).max() < 1e-3, "back-projected table points must lie on z = 0"


@pytest.mark.parametrize("intrinsics", [{"fov": 55.0}, {"fx": 70.0, "fy": 60.0, "cx": 25.0, "cy": 30.0}])
def test_back_projected_points_lie_on_the_exact_surfaces(panda, box_scene, intrinsics):
    """Oblique views (also with an off-centre principal point): every measured point is on an obstacle."""
    cam = {"name": "oblique", "width": 80, "height": 60, "eye": [1.5, 0.6, 0.9], "target": [0.6, 0.0, 0.1], **intrinsics}
    with World(panda, box_scene) as world:
        scan = world.capture({"name": "one", "cameras": [cam]})[0]
    d = np.abs(box_scene.sdf(scan.hits))
    assert len(scan.hits) > 1000 and d.max() < 2e-3, f"points off the surfaces by up to {1e3 * d.max():.2f} mm"
    assert np.sum(np.abs(scan.hits[:, 2]) > 0.01) > 100, "the box must be in view"


def test_the_robots_own_points_are_removed(panda):
    """A camera aimed at the robot: its pixels are masked (the robot's geometry confirms every one of them),
    and no point left in the cloud is off the obstacles."""
    from samp.scene.generators import table
    from samp.sim.camera import back_project, robot_volume

    scene = Scene("robot_view", obstacles=(table(), Box("box", (0.1, 0.1, 0.1), Pose((0.5, 0.4, 0.05)))))
    cam = {"name": "at_robot", "width": 96, "height": 72, "fov": 60.0, "eye": [1.1, 0.4, 0.8], "target": [0.2, 0.0, 0.4]}
    q = panda.home.numpy()
    with World(panda, scene) as world:
        image = world.depth_images({"name": "one", "cameras": [cam]}, q=q)[0]
        scan = image.scan()
    assert image.robot.sum() > 300, f"the robot should fill part of the image, got {image.robot.sum()} pixels"
    robot_points = back_project(image.depth, image.camera)[image.robot]  # (R, 3)
    on_robot = robot_volume(panda, q, margin=0.003)(robot_points)
    assert on_robot.all(), f"{(~on_robot).sum()} masked pixels are not on the robot's surface"
    off = np.abs(scene.sdf(scan.hits))
    assert off.max() < 2e-3, f"a point {1e3 * off.max():.1f} mm off the obstacles is left in the cloud"
    touching = robot_volume(panda, q, margin=0.003)(scan.hits)
    assert np.abs(scan.hits[touching, 2]).max(initial=0) < 1e-3, "points on the robot left in the cloud (only the " \
        "table where the base stands may touch it)"
    assert len(scan.free_ends) >= image.robot.sum(), "rays to the robot still carve free space"


def test_noise_is_seeded_and_as_configured(panda, box_scene, ring_cameras):
    cams = ring_cameras(count=1, top=False, size=(80, 60), depth_noise=0.01, dropout=0.2)
    clean = ring_cameras(count=1, top=False, size=(80, 60))
    with World(panda, box_scene) as world:
        a, b = (world.depth_images(cams)[0] for _ in range(2))
        c = world.depth_images(cams, seed=1)[0]
        exact = world.depth_images(clean)[0]
    np.testing.assert_array_equal(a.depth, b.depth)  # NaNs compare equal here
    assert not np.array_equal(np.nan_to_num(a.depth), np.nan_to_num(c.depth)), "another seed, other noise"
    dropped = np.isnan(a.depth).mean()
    assert 0.15 < dropped < 0.25, f"dropout 0.2 asked, {dropped:.2f} of pixels dropped"
    hit = ~np.isnan(a.depth) & (exact.depth < 4.9)
    std = np.std(a.depth[hit] - exact.depth[hit])
    assert 0.008 < std < 0.012, f"depth noise 0.01 m asked, got a standard deviation of {std:.4f} m"


def test_every_camera_set_in_conf_instantiates():
    """Each conf/camera option through Hydra's instantiate (its _target_) and through load_camera_set."""
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from samp.paths import conf_dir

    files = sorted((conf_dir() / "camera").glob("*.yaml"))
    assert files, "conf/camera/ has no camera sets"
    for path in files:
        built = instantiate(OmegaConf.load(path), _convert_="all")
        loaded = load_camera_set(path.stem)
        assert built == loaded and loaded.cameras, path
        for cam in loaded.cameras:
            T = cam.pose_matrix()
            np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)


def test_bad_camera_settings_say_what_was_wrong(tmp_path):
    base = {"name": "c", "width": 8, "height": 6, "eye": [1, 0, 1], "target": [0, 0, 0]}
    with pytest.raises(ValueError, match="either fov .* or fx"):
        Camera(**base)
    with pytest.raises(ValueError, match="either fov .* or fx"):
        Camera(**base, fov=60, fx=10)
    with pytest.raises(ValueError, match="up must not be parallel"):
        Camera(**{**base, "eye": [0, 0, 1]}, fov=60)
    with pytest.raises(ValueError, match="unknown keys \\['fovy'\\]; valid: \\['name', 'width'"):
        camera_set("s", [{**base, "fovy": 60}])
    with pytest.raises(ValueError, match="has no cameras"):
        camera_set("s", [])
    with pytest.raises(FileNotFoundError, match="no camera set 'nowhere'.*one of \\[.*'default'"):
        load_camera_set("nowhere")
    with pytest.raises(ValueError, match="pose must be a 4x4 rigid transform"):
        Camera(name="p", width=8, height=6, fov=60, pose=np.eye(4)[:3].tolist())
