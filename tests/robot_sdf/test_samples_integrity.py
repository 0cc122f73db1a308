"""A robot SDF sample set is verified when loaded (issue 21): a flipped byte in one of its files is an
error naming the file, expected and actual sha256."""

from __future__ import annotations

import hashlib
import shutil

import pytest

from samp.data import DatasetError
from samp.robot_sdf.samples import load_samples


def test_a_flipped_byte_in_a_sample_file_is_refused(panda_samples, tmp_path):
    folder = shutil.copytree(panda_samples[0], tmp_path / "samples" / panda_samples[0].name)
    target = sorted((folder / "links").glob("*.npz"))[0]
    before = hashlib.sha256(target.read_bytes()).hexdigest()
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0x01
    target.write_bytes(bytes(data))
    after = hashlib.sha256(target.read_bytes()).hexdigest()
    with pytest.raises(DatasetError, match=rf"links/{target.name}: sha256 expected {before}, actual {after}"):
        load_samples(folder)
