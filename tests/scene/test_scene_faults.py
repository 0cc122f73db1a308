"""Scene faults: a NaN or infinite number in a scene description is refused where the scene is made (the
fault: accepted, and the whole anchor grid and `sdf()` were NaN), and an anchor grid too large to allocate
is refused naming n_e before anything is allocated (the fault: `samp.scene show n_e=100000` asked for
petabytes)."""

from __future__ import annotations

import math

import pytest

from samp.names import N_E_MAX
from samp.scene import Scene, anchor_points

BOX = {"kind": "box", "name": "b", "size": [0.1, 0.1, 0.1],
       "pose": {"position": [0.5, 0.0, 0.3], "quaternion": [0, 0, 0, 1]}}


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_scene_from_dict_refuses_a_non_finite_position(bad):
    box = {**BOX, "pose": {"position": [0.5, bad, 0.3], "quaternion": [0, 0, 0, 1]}}
    with pytest.raises(ValueError, match=r"a pose needs finite values, got position \[0.5, -?(nan|inf), 0.3\]"):
        Scene.from_dict({"name": "s", "obstacles": [box]})
    with pytest.raises(ValueError, match="a pose needs finite values"):
        Scene.from_dict({"name": "s", "obstacles": [], "target": box})
    with pytest.raises(ValueError, match="size must be positive"):
        Scene.from_dict({"name": "s", "obstacles": [{**BOX, "size": [0.1, bad, 0.1]}]})
    with pytest.raises(ValueError, match="bounds must be"):
        Scene.from_dict({"name": "s", "obstacles": [BOX], "bounds": [[-1, -1, 0], [1, 1, bad]]})


def test_a_finite_scene_still_loads():
    scene = Scene.from_dict({"name": "s", "obstacles": [BOX]})
    assert scene.obstacles[0].pose.position == (0.5, 0.0, 0.3)


def test_n_e_above_the_limit_is_refused_before_allocating():
    with pytest.raises(ValueError, match=rf"n_e \(anchors per axis\) must be an integer in \[2, {N_E_MAX}\], got "
                                         r"100000 \(a grid of 100000\^3 anchors would need 4e\+06 GB\)"):
        anchor_points(100000, ((-1, -1, 0), (1, 1, 1)))


def test_scene_show_refuses_a_huge_n_e_in_one_line(capsys):
    from samp.scene.__main__ import main

    assert main(["show", "scene=tabletop", "n_e=100000"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: n_e (anchors per axis) must be an integer in [2, 256]"), err
