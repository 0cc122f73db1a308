"""tools/gpu_check.sh without a GPU (fast): it parses, it refuses at once with a clear message and exit status 3
when no GPU is visible (hidden from torch here, whatever the machine has), leaving nothing behind, and what it would
run is consistent: its training overrides compose and its bench options exist. The GPU run itself is by hand."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tools" / "gpu_check.sh"

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")

# The overrides the script passes to `samp.train`, as it spells them (each must appear in the script).
ROBOT_SDF = ["experiment=robot_sdf_panda_paper", "trainer=gpu", "robot_sdf_samples=tiny", "'~robot_sdf_eval'"]
TRAIN = ["experiment=samp_paper", "trainer=gpu", "trainer.max_epochs=100", "+trainer.limit_val_batches=0",
         "callbacks=default", "evaluation.problems=0", "evaluation.benchmark=null"]


def test_the_script_parses():
    out = subprocess.run(["bash", "-n", str(SCRIPT)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_it_refuses_without_a_gpu(tmp_path):
    env = {**os.environ, "CUDA_VISIBLE_DEVICES": "", "PYTHON": sys.executable}
    out = subprocess.run(["bash", str(SCRIPT), str(tmp_path / "out")], capture_output=True, text=True, env=env,
                         timeout=120)
    assert out.returncode == 3, out.stdout + out.stderr
    assert "gpu_check: no GPU here" in out.stderr and "Nothing was run" in out.stderr, out.stderr
    assert not (tmp_path / "out").exists()


def test_what_it_runs_is_consistent():
    from samp.train import compose_train_config

    text = SCRIPT.read_text()
    for override in ROBOT_SDF + TRAIN:
        assert override in text, f"{override} is no longer in the script: update this test"
    compose_train_config([o.strip("'") for o in ROBOT_SDF] + ["trainer.max_steps=300"])
    cfg = compose_train_config(TRAIN + ["datamodule.dataset=gpu_check", "trainer.max_steps=300"])
    assert cfg.system.scheduler.T_0 == 100  # one cosine over the epochs allowed, whatever max_steps stops it at

    sys.path.insert(0, str(REPO / "tools"))
    try:
        from bench import build_parser
    finally:
        sys.path.remove(str(REPO / "tools"))
    known = {o for action in build_parser()._actions for o in action.option_strings}
    lines = [line for line in text.splitlines() if "tools/bench.py" in line]
    used = {o for line in lines for o in re.findall(r"(--[a-z][a-z0-9-]*)", line)}
    assert used and used <= known, f"options the bench does not take: {sorted(used - known)}"
    assert re.search(r"tools/bench\.py policy .*--anchors 40 160", text) and "tools/bench.py paper" in text
