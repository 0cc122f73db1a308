"""`python -m samp.robot show`: the summary and a Rerun recording that the rerun CLI can read."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

RERUN = Path(sys.executable).parent / "rerun"


def _run(*args: str, cwd=None) -> subprocess.CompletedProcess:
    env = {**os.environ, "RERUN_ANALYTICS": "0"}
    return subprocess.run([sys.executable, "-m", "samp.robot", *args], capture_output=True, text=True,
                          timeout=300, env=env, cwd=cwd)


def test_show_prints_summary_and_writes_recording(tmp_path, robots):
    out = tmp_path / "xarm6.rrd"
    proc = _run("show", "robot=xarm6", f"out={out}", "configs=3")
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert "robot xarm6: 6 joints, 7 collision links, 1024 robot points" in text
    for joint in robots["xarm6"].joint_names:
        assert re.search(rf"^\s+{joint}\s+-?\d+\.\d+\s+-?\d+\.\d+$", text, re.M), f"no limits row for {joint}"
    total = re.search(r"^\s+total\s+(\d+)\s+(\d+)\s+(\d+)\s+(\d+)$", text, re.M)
    assert total and int(total.group(4)) == 1024, f"no per-shell totals in:\n{text}"
    assert out.is_file() and out.stat().st_size > 10_000

    verify = subprocess.run([str(RERUN), "rrd", "verify", str(out)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    printed = subprocess.run([str(RERUN), "rrd", "print", str(out)], capture_output=True, text=True, timeout=120).stdout
    for link in robots["xarm6"].link_names:
        assert re.search(rf"/robot/links/{link} - data columns: \[Mesh3D", printed), f"no mesh for {link}"
        # Rerun may split one entity's rows over several chunks: count them all.
        rows = re.findall(rf"with (\d+) rows .* /robot/links/{link} - data columns: \[Transform3D", printed)
        assert sum(map(int, rows)) == 3, f"{link}: {rows} transform rows, expected 3 configurations"
    for shell in ("1mm", "30mm", "60mm"):
        assert f"/robot/points/shell_{shell}" in printed


@pytest.mark.parametrize("args, message", [
    (["show", "robot=ur5"], "Could not find 'robot/ur5'"),
    (["show", "robot=panda", "colour=red"], "Could not override 'colour'"),
    (["draw"], "usage: python -m samp.robot show"),
])
def test_show_rejects_bad_arguments(args, message):
    proc = _run(*args)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
