"""Dataset shards as submitit jobs (`hydra/launcher=shards_submitit_local`: shards_slurm's job semantics, run
by submitit's LOCAL executor): two shards of a spec of its own (the smoke spec, another name and seed), each
a pickled call in a process of its own with submitit's folder and logs under the runs folder, then `python -m
samp.data merge`, give the dataset id that one process generating the whole spec gives, file for file; nothing
is written into the working directory or the repository."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs and dataset generation: deselected by `make test-fast`

REPO = Path(__file__).resolve().parents[2]
SPEC = ["dataset=smoke", "dataset.name=shards", "dataset.seed=5"]  # `+dataset=` for the Hydra app samp.data.shards


def _run(tmp: Path, args: list[str], datasets: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "SAMP_RUNS_DIR": str(tmp / "runs"), "SAMP_DATASETS_DIR": str(datasets),
           "OMP_NUM_THREADS": "1", "RERUN_ANALYTICS": "0"}
    return subprocess.run([sys.executable, "-m", *args], cwd=tmp / "cwd", env=env, capture_output=True, text=True,
                          timeout=600)


def _dataset(stdout: str) -> str:
    found = re.findall(r"^dataset (shards@[0-9a-f]{12}) in ", stdout, re.M)
    assert len(found) == 1, stdout
    return found[0]


def _files(folder: Path) -> dict:
    return {k: v["sha256"] for k, v in json.loads((folder / "manifest.json").read_text())["files"].items()}


@pytest.fixture(scope="module")
def sharded(tmp_path_factory):
    """(tmp folder, the shards' multirun output, the merge's output, the single-process output)."""
    tmp = tmp_path_factory.mktemp("shards_submitit")
    (tmp / "cwd").mkdir()
    shards = _run(tmp, ["samp.data.shards", "-m", f"+{SPEC[0]}", *SPEC[1:], "num_shards=2", "shard=range(0,2)",
                        "progress=false", "hydra/launcher=shards_submitit_local"], tmp / "datasets")
    assert shards.returncode == 0, shards.stdout[-2000:] + shards.stderr[-3000:]
    merged = _run(tmp, ["samp.data", "merge", *SPEC], tmp / "datasets")
    assert merged.returncode == 0, merged.stderr[-3000:]
    whole = _run(tmp, ["samp.data", "generate", *SPEC, "workers=2", "progress=false"], tmp / "whole")
    assert whole.returncode == 0, whole.stderr[-3000:]
    for name in (".submitit", "multirun", "outputs"):  # submitit's and Hydra's default folders
        assert not (REPO / name).exists(), f"{name} written into the repository"
    return tmp, shards, merged, whole


def test_two_submitit_shards_and_a_merge_give_the_single_process_dataset(sharded):
    tmp, _, merged, whole = sharded
    assert "already merged into shards@" in merged.stdout, merged.stdout  # the shard that completed the set merged
    ident, single = _dataset(merged.stdout), _dataset(whole.stdout)
    print(f"dataset ids: 2 shards through submitit local + merge {ident}; one process (workers=2) {single}")
    assert ident == single, f"2 shards through submitit give {ident}, one process {single}"
    name, _, short = ident.partition("@")
    assert _files(tmp / "datasets" / name / short) == _files(tmp / "whole" / name / short)
    assert [p.name for p in (tmp / "datasets" / name).iterdir()] == [short], "work or temporary folders left"


def test_each_shard_ran_as_a_submitit_job_with_its_logs_in_the_runs_folder(sharded):
    tmp, shards, _, _ = sharded
    assert "Submitit 'local' sweep output dir" in shards.stdout + shards.stderr
    (sweep,) = (tmp / "runs" / "data_shards").iterdir()  # conf/data.yaml's hydra.sweep.dir
    jobs = sorted(p for p in (sweep / ".submitit").iterdir() if p.name.isdigit())  # one folder per job id (its pid)
    assert len(jobs) == 2, sorted(p.name for p in (sweep / ".submitit").iterdir())
    shard_lines = []
    for job in jobs:
        for suffix in ("_submitted.pkl", "_0_result.pkl", "_0_log.out", "_0_log.err"):
            assert (job / f"{job.name}{suffix}").is_file(), f"{job.name}{suffix} missing in {job}"
        out = (job / f"{job.name}_0_log.out").read_text()
        assert f"JobEnvironment(job_id={job.name}," in out and "Job completed successfully" in out, out
        shard_lines += re.findall(r"shards shard \d/2: .*", out)
    # a shard that finished before the other says so in its job's log (the other merges, silently)
    assert all(re.search(r"\d+ scenes? of other shards (is|are) not finished yet", line) for line in shard_lines), shard_lines
    assert sorted(p.name for p in sweep.iterdir() if not p.name.startswith(".")) == ["0", "1", "multirun.yaml"]
    assert not any((tmp / "cwd").iterdir()), "something was written into the working directory"
