"""`samp.robot.goal.goal_errors` against poses built here: a rotation by a known angle about any axis reads
as that angle (the angle of the relative rotation, in degrees), a translation as its length, independent of
the goal's own orientation."""

from __future__ import annotations

import numpy as np
import pytest

from samp.robot.goal import goal_errors


def _rotation(axis, angle: float) -> np.ndarray:
    """Rodrigues' formula: (3, 3) rotation by `angle` radians about `axis`."""
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.mark.parametrize("degrees", [0.0, 5.0, 15.0, 90.0, 170.0])
def test_a_known_rotation_and_offset_read_as_themselves(degrees):
    rng = np.random.default_rng(3)
    goal = np.eye(4)
    goal[:3, :3] = _rotation(rng.normal(size=3), 1.1)  # any goal orientation
    goal[:3, 3] = [0.4, -0.2, 0.5]
    pose = goal.copy()
    pose[:3, :3] = goal[:3, :3] @ _rotation(rng.normal(size=3), np.radians(degrees))
    pose[:3, 3] += [0.03, 0.0, -0.04]
    pos, rot = goal_errors(pose[None], goal)
    assert pos[0] == pytest.approx(0.05, abs=1e-12)
    assert rot[0] == pytest.approx(degrees, abs=1e-5), f"expected {degrees} degrees, got {rot[0]}"
