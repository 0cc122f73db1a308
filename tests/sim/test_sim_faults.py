"""A camera config whose image size would crash the renderer is refused before pybullet sees it (the fault:
a 200000 x 200000 camera ended in a segfault, exit status 139)."""

from __future__ import annotations

import pytest
import yaml

from samp.sim.camera import MAX_SIDE, Camera, load_camera_set


def test_a_huge_camera_from_a_yaml_file_is_refused_before_rendering(tmp_path):
    path = tmp_path / "huge.yaml"
    path.write_text(yaml.safe_dump({
        "_target_": "samp.sim.camera.camera_set", "name": "huge", "seed": 0,
        "cameras": [{"name": "front", "width": 200000, "height": 200000, "fov": 70.0, "eye": [1.9, 0.0, 1.3],
                     "target": [0.3, 0.0, 0.15]}]}))
    with pytest.raises(ValueError, match=rf"camera 'front': 200000 x 200000 pixels is larger than the {MAX_SIDE} "
                                         rf"pixels a side allowed; give width and height <= {MAX_SIDE}"):
        load_camera_set(path)


def test_the_largest_allowed_camera_is_accepted():
    cam = Camera(name="c", width=MAX_SIDE, height=1, fov=60, eye=[1, 0, 1], target=[0, 0, 0])
    assert cam.width == MAX_SIDE
