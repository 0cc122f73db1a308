"""`python tools/bench.py --help` and `SUITE --help`: the dispatcher and every suite module load, the suites are
listed, and each suite's options reach the one flat parser. No benchmark runs (about 1.5 s per call: torch)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

REPO = Path(__file__).resolve().parents[2]
BENCH = REPO / "tools" / "bench.py"

# suite -> an option it reads, added by its module (policy adds none: --anchors is the scene suite's). The command
# line takes every suite's options whichever suite runs, so each --help must list them all.
SUITES = {"robot": "--batch", "scene": "--configs", "data": "--workers", "eval": "--expert-problems",
          "policy": "--anchors", "robot_sdf": "--override", "perception": "--camera",
          "baselines": "--baseline-problems", "paper": "--steps"}


def _help(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
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


# Every suite run end to end on tiny settings (seconds to a minute each), so that none rots between the runs
# that produce the README's tables: each must finish, write its JSON report and report finite, positive times.
TINY_RUNS = {
    "robot": ["--batch", "1", "4"],
    "scene": ["--anchors", "8", "--configs", "20"],
    "data": ["--workers", "1", "--scenes", "2", "--trajectories", "1"],
    "eval": ["--problems", "2", "--n-e", "8", "--expert-problems", "1"],
    "policy": ["--anchors", "8"],
    "robot_sdf": ["--override", "robot_sdf_samples=tiny", "trainer.max_steps=20", "--sdf-eval", "tiny"],
    "perception": ["--anchors", "8"],
    "baselines": ["--baseline-problems", "1"],
    "paper": ["--steps", "1", "--train-n-e", "8", "--disk-max-n-e", "16"],
}


def _numbers(tree) -> list[float]:
    if isinstance(tree, dict):
        return [x for v in tree.values() for x in _numbers(v)]
    if isinstance(tree, (list, tuple)):
        return [x for v in tree for x in _numbers(v)]
    return [float(tree)] if isinstance(tree, (int, float)) and not isinstance(tree, bool) else []


@pytest.mark.parametrize("suite", sorted(TINY_RUNS))
def test_each_suite_runs_on_tiny_settings(suite, tmp_path):
    import json

    out = tmp_path / f"{suite}.json"
    # PYTHONPATH: a script's sys.path starts at tools/, so without it `import samp` would find whichever
    # checkout the environment's editable install points at, not this one
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO), "SAMP_RUNS_DIR": str(tmp_path / "runs"),
           "SAMP_DATASETS_DIR": str(tmp_path / "datasets"), "RERUN_ANALYTICS": "0"}
    run = subprocess.run([sys.executable, str(BENCH), suite, *TINY_RUNS[suite], "--out", str(out)],
                         capture_output=True, text=True, timeout=600, env=env, cwd=REPO)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["suite"] == suite and report["metrics"], report
    numbers = _numbers(report["metrics"])
    assert numbers and all(x == x for x in numbers), f"NaN in the {suite} report: {report['metrics']}"
    times = {k: v for k, v in report["metrics"].items() if isinstance(v, (int, float)) and k.endswith(("_s", "_ms"))}
    assert all(v > 0 for v in times.values()), f"non-positive times: {times}"
