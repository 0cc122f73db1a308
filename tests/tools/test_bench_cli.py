"""`python tools/bench.py --help` and `SUITE --help`: the dispatcher and every suite module load, the suites are
listed, and each suite's options reach the one flat parser. No benchmark runs (about 1.5 s per call: torch)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
BENCH = REPO / "tools" / "bench.py"

# suite -> an option it reads, added by its module (policy adds none: --anchors is the scene suite's). The command
# line takes every suite's options whichever suite runs, so each --help must list them all.
SUITES = {"robot": "--batch", "scene": "--configs", "data": "--workers", "eval": "--expert-problems",
          "policy": "--anchors", "robot_sdf": "--override", "perception": "--camera",
          "baselines": "--baseline-problems"}


def _help(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, str(BENCH), *args, "--help"], capture_output=True, text=True,
                          timeout=120, env=env, cwd=REPO)


def _check(out: subprocess.CompletedProcess) -> None:
    assert out.returncode == 0, out.stderr
    choices = "{" + ",".join(sorted(SUITES)) + "}"  # the suite choices, as argparse's usage line lists them
    assert choices in out.stdout
    for suite, option in SUITES.items():
        assert option in out.stdout, f"{option} ({suite}) missing from --help"


def test_help_lists_every_suite():
    out = _help()
    _check(out)
    for suite in SUITES:  # and the description says what each one measures
        assert f"\n    {suite} " in out.stdout


@pytest.mark.parametrize("suite", sorted(SUITES))
def test_suite_help(suite):
    _check(_help(suite))


def test_modules_under_400_lines():
    """The project's limit, which splitting bench.py into bench_suites/ was for."""
    for path in [BENCH, *sorted((REPO / "tools" / "bench_suites").glob("*.py"))]:
        assert len(path.read_text().splitlines()) <= 400, path
