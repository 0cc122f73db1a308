"""Trajectory post-processing against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from samp.expert.trajectory import joint_path_length, resample, segment_states


def test_resample_is_uniform_in_arc_length_on_the_polyline():
    path = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.0]])  # an L of length 4
    out = resample(path, 5)  # spacing 1
    expected = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [3.0, 1.0]])
    np.testing.assert_allclose(out, expected, atol=1e-12)
    assert np.array_equal(out[0], path[0]) and np.array_equal(out[-1], path[-1])


def test_resample_zero_length_and_bad_input():
    out = resample(np.ones((3, 7)), 50)
    assert out.shape == (50, 7) and np.all(out == 1.0)
    with pytest.raises(ValueError, match="count"):
        resample(np.zeros((2, 3)), 1)
    with pytest.raises(ValueError, match=r"\(W, n\)"):
        resample(np.zeros(3), 5)


def test_segment_states_cover_every_segment_at_the_resolution():
    traj = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.05]])
    states, owner = segment_states(traj, 0.1)
    assert len(states) == 1 + 10 + 1
    assert np.array_equal(states[0], traj[0]) and np.array_equal(states[-1], traj[-1])
    assert np.linalg.norm(np.diff(states, axis=0), axis=1).max() <= 0.1 + 1e-12
    assert owner.tolist() == [0] * 11 + [1]


def test_joint_path_length():
    assert joint_path_length(np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 5.0]])) == pytest.approx(6.0)
