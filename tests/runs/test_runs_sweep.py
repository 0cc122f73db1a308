"""A two-member sweep through the real CLI (`python -m samp.train -m ...`), then `python -m samp.runs`
over it: the table's rows against run.json, skipping completed members, plots, and bad input."""

from __future__ import annotations

import json
import os
import shutil

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

# Typed `+experiment=` below, the experiment is named without the `+` (conf/train.yaml's defaults list has it).
MEMBERS = ("experiment=robot_sdf_panda,seed=0", "experiment=robot_sdf_panda,seed=1")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, cli, tiny_sdf):
    """(runs folder, sweep folder, the first run's output) of a tiny sweep over the seed."""
    runs = tmp_path_factory.mktemp("sweep_runs")
    folder = runs / "sweeps" / "seeds"
    proc = cli("samp.train", ["-m", "+experiment=robot_sdf_panda", "seed=0,1", "trainer.max_steps=40", *tiny_sdf,
                              f"hydra.sweep.dir={folder}"], runs)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return runs, folder, proc


def test_members_run_in_folders_named_by_their_override(sweep):
    _, folder, _ = sweep
    assert sorted(p.name for p in folder.iterdir() if p.is_dir()) == sorted(MEMBERS)
    for name, seed in zip(MEMBERS, (0, 1)):
        record = json.loads((folder / name / "run.json").read_text())
        assert record["status"] == "completed" and record["seed"] == seed and record["steps"] == 40, record["status"]
        assert record["sweep"]["member"] == name and record["run_dir"] == str(folder / name)
        assert (folder / name / "checkpoints" / "last.ckpt").is_file() and (folder / name / "metrics.csv").is_file()
        assert "mlflow" not in (record.get("loggers") or {}), "tracked with SAMP_TRACKING_URI=off"


def test_tracking_off_leaves_no_store(sweep):
    """The suite runs with SAMP_TRACKING_URI=off (tests/conftest.py): no store, no sweep run file."""
    runs, folder, _ = sweep
    assert os.environ["SAMP_TRACKING_URI"] == "off"
    assert not list(runs.glob("mlflow*")) and not list(folder.glob(".mlflow-sweep-*")), sorted(runs.iterdir())


def test_table_prints_both_rows_with_their_metrics(sweep, cli):
    runs, folder, _ = sweep
    metrics = ["val/mae_mm", "eval/whole_robot/mae_all_mm"]
    proc = cli("samp.runs", ["table", str(folder), "--by", "seed", "--metrics", *metrics], runs)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stdout.splitlines() if line.startswith("| ")]
    assert lines[0] == "| seed | runs | status | " + " | ".join(metrics) + " |"
    for line, name, seed in zip(lines[1:], MEMBERS, (0, 1)):
        got = json.loads((folder / name / "run.json").read_text())["metrics"]
        want = f"| {seed} | 1 | completed | " + " | ".join(f"{got[m]:.4g}" for m in metrics) + " |"
        assert line == want, f"expected {want!r}, got {line!r}"
    assert (folder / "table_by_seed.md").read_text().count("| completed |") == 2
    assert (folder / "table_by_seed.csv").read_text().splitlines()[0] == "seed,runs,status," + ",".join(metrics)


def test_running_the_sweep_again_skips_completed_members(sweep, cli, tiny_sdf):
    runs, folder, _ = sweep
    before = {m: (folder / m / "run.json").read_text() for m in MEMBERS}
    proc = cli("samp.train", ["-m", "+experiment=robot_sdf_panda", "seed=0,1", "trainer.max_steps=40", *tiny_sdf,
                              f"hydra.sweep.dir={folder}"], runs)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.count("completed earlier, skipped") == 2, proc.stdout[-2000:]
    assert {m: (folder / m / "run.json").read_text() for m in MEMBERS} == before


def test_member_completed_with_other_overrides_is_refused_not_skipped(sweep, tiny_sdf):
    from samp.train.sweep import member_state

    _, folder, _ = sweep
    same = ["+experiment=robot_sdf_panda", "seed=0", "trainer.max_steps=40",
            *[o.replace("=false", "=False") for o in tiny_sdf]]
    assert member_state(folder / MEMBERS[0], same) == "skip"
    with pytest.raises(ValueError, match=r"was completed with overrides \['trainer.max_steps=40'\] where this sweep "
                                         r"has \['trainer.max_steps=80'\]"):
        member_state(folder / MEMBERS[0], [o.replace("max_steps=40", "max_steps=80") for o in same])


def test_plots_are_written_as_png(sweep, cli):
    runs, folder, _ = sweep
    for args, name in ((["--metrics", "train/loss", "--x", "step"], "curves_by_seed.png"),
                       (["--kind", "bars", "--metrics", "val/mae_mm"], "bars_by_seed.png")):
        proc = cli("samp.runs", ["plot", str(folder), "--by", "seed", *args], runs)
        assert proc.returncode == 0, proc.stderr
        assert (folder / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ls_filters_by_any_key_and_show_names_lineage(sweep, cli):
    runs, folder, _ = sweep
    proc = cli("samp.runs", ["ls", "seed=1", "status=completed", "--keys", "datamodule.seed"], runs)
    assert proc.returncode == 0, proc.stderr
    assert MEMBERS[1] in proc.stdout and MEMBERS[0] not in proc.stdout and "1 run(s)" in proc.stdout
    proc = cli("samp.runs", ["show", str(folder / MEMBERS[0])], runs)
    record = json.loads((folder / MEMBERS[0] / "run.json").read_text())
    assert proc.returncode == 0 and record["dataset_id"] in proc.stdout and record["robot_sdf_artifact_id"] in proc.stdout


def test_bad_input_is_named(sweep, cli, tmp_path):
    runs, folder, _ = sweep
    proc = cli("samp.runs", ["table", str(folder), "--by", "n_anchors"], runs)
    assert proc.returncode == 2 and "unknown --by key 'n_anchors'" in proc.stderr, proc.stderr
    assert "Keys that vary between these runs:" in proc.stderr and "seed" in proc.stderr
    assert "datamodule.near_per_step" in proc.stderr  # the keys that exist are listed, not only the varying ones
    proc = cli("samp.runs", ["show", str(tmp_path / "no_such_run")], runs)
    assert proc.returncode == 2 and f"run folder {tmp_path / 'no_such_run'} does not exist" in proc.stderr
    other = tmp_path / "iiwa_run"  # the same run, said to be for another robot
    shutil.copytree(folder / MEMBERS[0], other)
    record = json.loads((other / "run.json").read_text())
    record["config"]["robot"]["name"] = "iiwa"
    (other / "run.json").write_text(json.dumps(record))
    proc = cli("samp.runs", ["compare", str(folder / MEMBERS[0]), str(other)], runs)
    assert proc.returncode == 0 and "warning: these runs are for different robots (iiwa, panda)" in proc.stderr
    assert "| robot.name | panda | iiwa |" in proc.stdout
