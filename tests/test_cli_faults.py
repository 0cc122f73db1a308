"""Environment faults as one line: a real ENOSPC (a write to /dev/full, which fails as a full disk does)
inside a write that cleans up after itself names the file being written and what to do, and leaves no
partial file; errors samp raises itself keep their message; a bug keeps its traceback."""

from __future__ import annotations

import errno
import os

import pytest

from samp.cli import user_error


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_a_full_disk_names_the_file_and_leaves_nothing(tmp_path):
    from samp.data.workfolder import removed_on_error

    tmp, sidecar = tmp_path / "scene_0000.mcap.tmp", tmp_path / "scene_0000.mcap.json"
    tmp.write_bytes(b"partial")
    sidecar.write_text("{}")
    with pytest.raises(OSError) as err:
        with removed_on_error(tmp, sidecar), open("/dev/full", "wb", buffering=0) as full:
            full.write(b"x")  # ENOSPC, as a full disk answers a write: the error names no file
    assert err.value.errno == errno.ENOSPC and not tmp.exists() and not sidecar.exists()
    assert user_error(err.value) == (f"no space is left on the disk of {tmp} ({os.strerror(errno.ENOSPC)}); free space "
                                     "there, or point the output elsewhere (root=DIR or SAMP_DATASETS_DIR / "
                                     "SAMP_RUNS_DIR / SAMP_CACHE_DIR) and run again")


def test_errors_of_samp_keep_their_message_and_bugs_their_traceback(tmp_path):
    assert user_error(NotADirectoryError("SAMP_HOME=x is a file, not a folder")) == "SAMP_HOME=x is a file, not a folder"
    assert user_error(ValueError("bad")) == "bad"
    assert user_error(KeyError("k")) is None  # a bug: raised again with its traceback
    assert user_error(OSError(errno.EIO, "Input/output error", "f")) is None  # not an environment fault we can name
    with pytest.raises(OSError) as err:
        (tmp_path / ("n" * 300)).mkdir()
    assert user_error(err.value).startswith(f"a name is too long for the file system in {tmp_path / ('n' * 300)}")
