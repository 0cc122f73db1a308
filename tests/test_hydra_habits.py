"""What a Hydra user types first, answered by samp's command lines (issue 53).

samp composes configs with Hydra's API and makes its own run folders, so Hydra's application flags and
`hydra.run.dir` mean nothing to it. Each is answered: `--hydra-help` and `--info` with samp's own help and
config folders, `--package` and `hydra.run.dir` refused with what to use instead, and an override Hydra
cannot parse named on one line (exit code 2). Run in process through each command's `main(argv)`, with
`--cfg job` where a run would otherwise start: nothing is trained.
"""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _outputs(tmp_path, monkeypatch):
    monkeypatch.setenv("SAMP_RUNS_DIR", str(tmp_path / "runs"))
    monkeypatch.setenv("SAMP_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("SAMP_CONFIG_PATH", raising=False)


def _train(argv):
    from samp.train.cli import main

    return main(argv)


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-3000:]
    return lines[0]


def test_hydra_run_dir_is_refused_with_run_dir(tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere"
    assert _train(["experiment=quickstart", f"hydra.run.dir={elsewhere}", "--cfg", "job"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"'hydra.run.dir={elsewhere}' has no effect" in line and "run_dir=DIR" in line, line
    assert not elsewhere.exists() and not (tmp_path / "runs").exists()


def test_hydra_run_dir_in_a_sweep_is_refused_too(tmp_path, capsys):
    assert _train(["-m", "experiment=quickstart", "seed=0,1", f"hydra.run.dir={tmp_path / 'x'}", "--cfg", "job"]) == 2
    assert "run_dir=DIR" in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "runs").exists()


def test_hydra_help_prints_samps_help(capsys):
    assert _train(["experiment=quickstart", "--hydra-help"]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("usage: python -m samp.train") and "experiments (experiment=NAME" in out and not err, err


def test_info_names_the_config_folders_and_what_shadows(tmp_path, monkeypatch, capsys):
    from samp import paths

    mine = tmp_path / "mine"
    (mine / "dataset").mkdir(parents=True)
    (mine / "dataset" / "smoke.yaml").write_text((REPO / "conf" / "dataset" / "smoke.yaml").read_text())
    monkeypatch.setenv("SAMP_CONFIG_PATH", str(mine))
    paths._said.clear()
    assert _train(["--info"]) == 0
    out = capsys.readouterr().out
    assert f"  {mine}   (SAMP_CONFIG_PATH)" in out and f"  {REPO / 'conf'}   (samp's own)" in out, out
    assert out.index(str(mine)) < out.index(str(REPO / "conf")), "the user's folder is looked in first"
    assert f"dataset/smoke.yaml of {mine} is used in place of the one in {REPO / 'conf'}" in out, out


@pytest.mark.parametrize("module", ["samp.data", "samp.robot", "samp.scene", "samp.eval"])
def test_every_entry_point_answers_info_and_hydra_help(module, capsys):
    import importlib

    main = importlib.import_module(f"{module}.__main__").main
    assert main(["--info"]) == 0
    assert "config folders, in the order a file is looked for" in capsys.readouterr().out
    assert main(["--hydra-help"]) == 0
    assert capsys.readouterr().out.startswith(f"usage: python -m {module}")


@pytest.mark.parametrize("flag, says", [(["--package", "robot"], "print it whole with --cfg job"),
                                        (["--config-dir", "/tmp"], "SAMP_CONFIG_PATH"),
                                        (["--frobnicate"], "is not an option")])
def test_hydra_application_flags_are_refused_with_what_samp_offers(flag, says, capsys):
    assert _train(["experiment=quickstart", *flag, "--cfg", "job"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"error: {flag[0]} ") and says in line and "key=value" in line, line


@pytest.mark.parametrize("argv", [["experiment=quickstart", "trainer.max_epochs=[1", "--cfg", "job"],
                                  ["-m", "experiment=quickstart", "seed=[0,1"],
                                  ["experiment=quickstart", "seed=1=2"]])
def test_an_override_hydra_cannot_parse_is_named_on_one_line(argv, tmp_path, capsys):
    bad = next(a for a in argv if "[" in a or a.count("=") > 1)
    assert _train(argv) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"override {bad!r} is not valid" in line and "LexerNoViableAlt" not in line, line
    assert not (tmp_path / "runs").exists()


def test_a_bad_override_of_samp_data_is_named_on_one_line(tmp_path, capsys):
    from samp.data.__main__ import main

    assert main(["generate", "dataset=smoke", "workers=[1"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "override 'workers=[1' is not valid" in line, line
