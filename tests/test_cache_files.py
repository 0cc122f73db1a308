"""Cache entries written by several processes at once (generation workers each build the robot's points)."""

from __future__ import annotations

import numpy as np
import pytest

from samp.paths import write_cache_file


def test_an_entry_another_writer_finishes_meanwhile_still_lands(tmp_path):
    """A second writer of the same entry finishes while the first is still writing: both succeed, the entry
    holds the data, and no temporary is left. With one temporary name shared by the writers, the second's
    rename takes the first's file away and the first fails (what broke `samp.data generate workers=2`)."""
    path = tmp_path / "panda-points.npz"

    def other_worker(f):
        np.savez(f, points=np.arange(6.0))

    def first_worker(f):
        write_cache_file(path, other_worker)
        np.savez(f, points=np.arange(6.0))

    write_cache_file(path, first_worker)
    with np.load(path) as z:
        assert z["points"].tolist() == list(range(6))
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_a_writer_that_fails_leaves_the_old_entry_and_no_temporary(tmp_path):
    path = tmp_path / "grid.npy"
    write_cache_file(path, lambda f: np.save(f, np.ones(3)))

    def broken(f):
        f.write(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space"):
        write_cache_file(path, broken)
    assert np.load(path).tolist() == [1.0, 1.0, 1.0]
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
