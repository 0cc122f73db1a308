"""One command-line dialect on every entry point (samp/cli.py): `--help` on stdout with exit code 0, the
usage on stderr with 2 for no or an unknown command; `experiment=` and `+experiment=` alike; `--cfg job`;
`key=value` options on samp.runs and samp.data, their older `--flag value` spellings still read."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

ENTRY_POINTS = ["samp.train", "samp.eval", "samp.data", "samp.runs", "samp.robot", "samp.scene"]


def _main(module: str):
    """The `main` of `python -m MODULE`."""
    name = {"samp.train": "samp.train.cli", "samp.eval": "samp.eval.__main__"}.get(module, f"{module}.__main__")
    return importlib.import_module(name).main


def _run(module: str, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RERUN_ANALYTICS": "0", **(env or {})}
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=300, env=env)


@pytest.mark.parametrize("module", ENTRY_POINTS)
def test_help_goes_to_stdout_and_exits_0(module):
    proc = _run(module, "--help")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith(f"usage: python -m {module}"), proc.stdout[:500]
    assert "usage:" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr[-2000:]


@pytest.mark.parametrize("module", ENTRY_POINTS)
def test_h_help_and_bad_commands_in_process(module, capsys):
    main = _main(module)
    assert main(["-h"]) == 0
    out, err = capsys.readouterr()
    assert out.startswith(f"usage: python -m {module}") and not err
    assert main([]) == 2
    out, err = capsys.readouterr()
    assert err.startswith(f"usage: python -m {module}") and not out, "no arguments: the usage on stderr"
    if module not in ("samp.train", "samp.eval"):  # the others take a subcommand first
        assert main(["frobnicate"]) == 2
        out, err = capsys.readouterr()
        assert "unknown command 'frobnicate'" in err and f"usage: python -m {module}" in err and not out


@pytest.mark.parametrize("module, texts", [
    ("samp.data", ["generate dataset=NAME", "inspect dataset=REF", "workers=1", "quickstart"]),
    ("samp.runs", ["table DIR by=KEY", "metrics=M,M", "kind=curves|bars", "paper-tables [root=DIR] [out=DIR]"]),
    ("samp.robot", ["show robot=NAME", "robot=panda", "iiwa", "configs=4"]),
    ("samp.scene", ["show scene=NAME", "scene=tabletop", "shelf", "n_e=64"]),
    ("samp.eval", ["[run=]RUN_DIR", "planner=expert", "splits=", "benchmark=", "problems=100"]),
])
def test_each_help_lists_its_commands_and_options(module, texts, capsys):
    assert _main(module)(["--help"]) == 0
    out = capsys.readouterr().out
    for text in texts:
        assert text in out, f"{text!r} not in the help of {module}:\n{out}"


def test_train_help_lists_experiments_sweeps_and_groups(capsys):
    from samp.cli import config_names

    assert _main("samp.train")(["--help"]) == 0
    out = capsys.readouterr().out
    for name in config_names("experiment") + config_names("sweep"):
        assert f"\n  {name} " in out, f"{name} not listed:\n{out}"
    groups = {line.split()[0]: line.split()[1:] for line in out.split("config groups", 1)[1].splitlines()[1:]
              if line.startswith("  ") and not line.startswith("   ")}
    for group in ("robot", "trainer", "callbacks", "logger", "model"):
        assert group in groups, f"group {group} not listed: {sorted(groups)}"
    assert "panda*" in groups["robot"] and "gpu" in groups["trainer"] and "csv*" in groups["logger"], groups


@pytest.mark.parametrize("experiment, extra", [("quickstart", []), ("robot_sdf_panda", []),
                                               ("robot_sdf_panda", ["model=robot_sdf_nn"]), ("samp_n40", ["sweep=anchor_size"])])
def test_experiment_with_and_without_plus_compose_the_same(experiment, extra):
    from omegaconf import OmegaConf

    from samp.train import compose_train_config

    plain = compose_train_config([f"experiment={experiment}", *extra])
    plus = compose_train_config([f"+experiment={experiment}", *("+" + e if e.startswith("sweep") else e for e in extra)])
    assert OmegaConf.to_yaml(plain) == OmegaConf.to_yaml(plus)
    assert OmegaConf.select(plain, "datamodule._target_"), "the experiment sets the datamodule"
    if extra == ["model=robot_sdf_nn"]:  # the command line beats the experiment's `override /model: robot_sdf_hash`
        assert plain.model._target_.endswith("NNSDF"), plain.model._target_
    elif experiment == "robot_sdf_panda":
        assert plain.model._target_.endswith("UnifiedHashSDF"), plain.model._target_


def test_a_typo_in_the_experiment_lists_the_available_ones():
    from samp.train import compose_train_config

    for spelling in ("experiment", "+experiment"):
        with pytest.raises(Exception, match=r"(?s)Could not find 'experiment/quikstart'.*quickstart"):
            compose_train_config([f"{spelling}=quikstart"])


def test_cfg_job_prints_the_config_and_trains_nothing(tmp_path):
    runs = tmp_path / "runs"
    proc = _run("samp.train", "experiment=quickstart", "trainer.max_epochs=2", "--cfg", "job",
                env={"SAMP_RUNS_DIR": str(runs)})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "\nname: quickstart\n" in proc.stdout and "  max_epochs: 2\n" in proc.stdout, proc.stdout[-2000:]
    assert "robot_sdf: robot_sdf_panda_quick" in proc.stdout, "interpolations are resolved where they can be"
    assert not runs.exists(), "--cfg trains nothing and makes no run folder"


def test_cfg_refuses_what_it_does_not_know(capsys):
    assert _main("samp.train")(["experiment=quickstart", "--cfg", "everything"]) == 2
    assert "--cfg takes job, hydra or all" in capsys.readouterr().err


def _fake_run(folder, seed: int, loss: float):
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"status": "completed", "experiment": "exp", "seed": seed,
                                                 "start": f"2026-01-0{seed + 1}T00:00:00", "metrics": {"val/loss": loss}}))


def test_runs_table_takes_key_value_and_the_older_flags(tmp_path, capsys):
    main = _main("samp.runs")
    for seed, loss in ((0, 0.5), (1, 0.25)):
        _fake_run(tmp_path / "sweep" / f"experiment=exp,seed={seed}", seed, loss)
    assert main(["table", str(tmp_path / "sweep"), "by=seed", "metrics=val/loss", f"out={tmp_path / 'new'}"]) == 0
    new = capsys.readouterr().out
    assert "| seed | runs | status | val/loss |" in new and "| 1 | 1 | completed | 0.25 |" in new, new
    assert main(["table", str(tmp_path / "sweep"), "--by", "seed", "--metrics", "val/loss", "--out",
                 str(tmp_path / "old")]) == 0
    assert capsys.readouterr().out.replace("old", "new") == new
    assert (tmp_path / "new.md").read_text() == (tmp_path / "old.md").read_text()
    member = tmp_path / "sweep" / "experiment=exp,seed=1"  # a run folder holding `=` is a folder, not an option
    assert main(["compare", str(member), str(tmp_path / "sweep" / "experiment=exp,seed=0"), "metrics=val/loss"]) == 0
    assert "| val/loss | 0.25 | 0.5 |" in capsys.readouterr().out
    assert main(["ls", "seed=1", f"root={tmp_path / 'sweep'}"]) == 0
    assert "1 run(s)" in capsys.readouterr().out
    assert main(["table", str(tmp_path / "sweep"), "bye=seed"]) == 2
    assert "unknown option 'bye' for table; options: by=..." in capsys.readouterr().err


def test_data_takes_dataset_key_value(tmp_path, capsys):
    from omegaconf import OmegaConf

    from samp.data import generate
    from samp.data.__main__ import _config

    assert OmegaConf.to_yaml(_config(["dataset=smoke", "workers=2"])) == OmegaConf.to_yaml(
        _config(["+dataset=smoke", "workers=2"]))
    spec = {"name": "cli_tiny", "robot": "panda", "seed": 3, "train_scenes": 1, "val_scenes": 0,
            "trajectories_per_scene": 1, "eval_problems_per_scene": 1, "generators": ["tabletop"], "resolutions": [8]}
    folder = generate(spec, root=tmp_path, progress=False)
    main = _main("samp.data")
    assert main(["verify", "dataset=cli_tiny", f"root={tmp_path}"]) == 0
    assert f"dataset {folder}: every file matches its sha256" in capsys.readouterr().out
    assert main(["show", f"root={tmp_path}", f"dataset=cli_tiny@{folder.name[:6]}"]) == 0
    assert f'"id": "{folder.name}"' in capsys.readouterr().out
    assert main(["show", "cli_tiny", f"root={tmp_path}"]) == 0, "a bare dataset reference still works"
    capsys.readouterr()
    assert main(["verify", "dataset=cli_tiny", "cli_tiny", f"root={tmp_path}"]) == 2
    assert "one dataset at a time" in capsys.readouterr().err


def test_a_sweep_member_folder_named_with_plus_is_found_again(tmp_path):
    from omegaconf import OmegaConf

    from samp.train.sweep import _legacy_folder, member_state

    legacy = tmp_path / "+experiment=exp,seed=0"
    _fake_run(legacy, 0, 0.5)
    record = json.loads((legacy / "run.json").read_text())
    (legacy / "run.json").write_text(json.dumps({**record, "overrides": ["+experiment=exp", "seed=0", "x=1"]}))
    new = tmp_path / "experiment=exp,seed=0"
    new.mkdir()
    (new / "train.log").write_text("")  # what Hydra leaves in a member folder before the member runs
    hc = OmegaConf.create({"overrides": {"task": ["experiment=exp", "seed=0", "x=1"]},
                           "job": {"config": {"override_dirname": {"exclude_keys": ["x"], "item_sep": ",",
                                                                   "kv_sep": "="}}}})
    assert _legacy_folder(new, hc, tidy=True) == legacy
    assert not new.exists(), "the empty folder Hydra made is removed"
    assert member_state(legacy, ["experiment=exp", "seed=0", "x=1"]) == "skip", "+experiment= and experiment= are one"
    with pytest.raises(ValueError, match="was completed with overrides"):
        member_state(legacy, ["experiment=exp", "seed=0", "x=2"])
