"""What a new user sees in the first hour (issue 53): no traceback after a run, no notice they cannot act on,
a results table that fits a terminal, `show` and the help texts in the terms of their install, counts in
good English, and `make install` taking torch through pip as it is configured. Real subprocesses, real
Lightning, the real console commands and `make`; pip alone is stood in for, by a script that records how it
was called (installing torch is not a test's to do)."""

from __future__ import annotations

import json
import os
import re
import shutil
import stat
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent  # the console commands of this install (samp-data, ...) lie beside Python


def _run(cmd: list[str], env: dict | None = None, cwd: Path | None = None, timeout: int = 120):
    """`cmd` with this tree's samp first on the path (a console command imports the installed one otherwise)."""
    path = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    env = {**os.environ, "OMP_NUM_THREADS": "1", "RERUN_ANALYTICS": "0", "PYTHONPATH": path, **(env or {})}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=cwd)


# ----------------------------------------------------------------- 1. the console tee after the run
LATE_WRITES = """
import atexit, logging, sys
from pathlib import Path
from samp.runs.console import RunLog

with RunLog() as log:
    log.attach(Path(sys.argv[1]))
    print("during the run")
    kept_out, kept_err = sys.stdout, sys.stderr  # as another package's handler or hook keeps them
    logging.getLogger("elsewhere").addHandler(logging.StreamHandler(kept_err))
print("restored", sys.stdout is sys.__stdout__, sys.stderr is sys.__stderr__)
atexit.register(lambda: logging.getLogger("elsewhere").warning("late log record"))
atexit.register(lambda: print("late print", file=kept_out, flush=True))
"""


def test_a_stream_kept_past_the_run_writes_to_the_console_only(tmp_path):
    """An atexit hook that writes through the tee after train.log is closed: no 'Exception ignored ...
    I/O operation on closed file'; the text reaches the console and the finished log takes none of it."""
    proc = _run([sys.executable, "-c", LATE_WRITES, str(tmp_path)])
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr, proc.stderr
    assert "restored True True" in proc.stdout, "sys.stdout and sys.stderr are the console's again after the run"
    assert "late print" in proc.stdout and "late log record" in proc.stderr, (proc.stdout, proc.stderr)
    assert (tmp_path / "train.log").read_text().splitlines() == ["during the run"]


# ----------------------------------------------------------------- 2. Lightning's noise
def _fit_with_a_frozen_part(root: Path) -> list[str]:
    """The warnings of one training step of a module whose part is frozen in eval mode, as samp's systems
    freeze their robot SDF."""
    import pytorch_lightning as pl
    import torch

    class Frozen(pl.LightningModule):
        def __init__(self):
            super().__init__()
            self.net = torch.nn.Linear(2, 1)
            self.fixed = torch.nn.Linear(2, 2).requires_grad_(False).eval()

        def training_step(self, batch, _):
            return self.net(self.fixed(batch[0])).pow(2).mean()

        def train(self, mode: bool = True):
            super().train(mode)
            self.fixed.eval()
            return self

        def configure_optimizers(self):
            return torch.optim.SGD(self.net.parameters(), lr=0.1)

    data = torch.utils.data.DataLoader(torch.utils.data.TensorDataset(torch.ones(4, 2)), batch_size=2)
    trainer = pl.Trainer(max_steps=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, default_root_dir=root, accelerator="cpu")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        from samp.runs.console import quiet_lightning

        if root.name == "quiet":
            quiet_lightning()
        trainer.fit(Frozen(), data)
    return [str(w.message) for w in seen]


def test_lightning_s_notice_of_frozen_modules_is_left_out(tmp_path):
    notice = "module(s) in eval mode at the start of training"
    assert any(notice in m for m in _fit_with_a_frozen_part(tmp_path / "plain")), "the oracle: Lightning says it"
    assert not any(notice in m for m in _fit_with_a_frozen_part(tmp_path / "quiet"))


TINY_SWEEP = ["experiment=robot_sdf_panda", "robot_sdf_samples=tiny", "robot_sdf_eval=tiny",
              "datamodule.steps_per_epoch=10", "datamodule.near_per_step=128", "datamodule.uniform_per_step=64",
              "trainer.enable_progress_bar=false", "robot_sdf_eval.timing_batches=[1]", "model.encoding.levels=4",
              "model.encoding.log2_table_size=12", "model.encoding.finest=64", "trainer.max_steps=5"]


@pytest.mark.slow  # a (tiny) training run
def test_a_sweep_member_prints_as_a_single_run_does(tmp_path):
    """`-m`: Lightning's lines plain, without Hydra's format or Lightning's tip, each once in train.log."""
    env = {"SAMP_RUNS_DIR": str(tmp_path / "runs"), "SAMP_DATASETS_DIR": str(tmp_path / "datasets"),
           "SAMP_TRACKING_URI": "off"}
    proc = _run([sys.executable, "-m", "samp.train", "-m", *TINY_SWEEP, "seed=0",
                 f"hydra.sweep.dir={tmp_path / 'sweep'}"], env=env, timeout=600)
    printed = proc.stdout + proc.stderr
    assert proc.returncode == 0, printed[-3000:]
    assert "GPU available: False, used: False" in proc.stderr.splitlines(), printed[-3000:]
    assert "Tip:" not in printed and "[HYDRA]" not in printed, printed[-3000:]
    assert not re.search(r"\]\[(INFO|WARNING)\] - ", printed), "Hydra's log format: " + printed[-3000:]
    log = (tmp_path / "sweep" / "experiment=robot_sdf_panda" / "train.log").read_text()
    assert log.count("GPU available") == 1, log


# ----------------------------------------------------------------- 3. the printed results table
def _records(n: int, successes: int, collisions: int) -> list[dict]:
    return [{"reached": {"2cm": i < successes + collisions, "1cm": i < successes}, "collision": successes <= i < successes + collisions,
             "self_collision": False, "joint_limit_violation": False, "path_length": 1.0 + i / n,
             "solution_time": 0.01, "step_times": [0.001], "solution_time_b1": 0.05 + 0.01 * i,
             "step_times_b1": [0.002], "batch": 0, "batch_time": 0.1, "steps": 40, "collision_depth": 0.0,
             "termination": "reached"} for i in range(n)]


def test_the_printed_table_fits_a_terminal_and_points_at_metrics_md(tmp_path):
    from samp.eval.config import RolloutConfig
    from samp.eval.metrics import markdown_table, summarize
    from samp.eval.report import CONSOLE_WIDTH, console_table

    cfg = RolloutConfig()
    rows = [(planner, group, summarize(_records(n, s, c), cfg))
            for group, n in (("benchmark_tabletop", 108), ("val_hard", 3))
            for planner, s, c in (("samp+check", 2 * n // 3, n // 6), ("expert", n, 0), ("straight", n // 3, n - n // 3))]
    full = markdown_table(rows, cfg)
    assert max(map(len, full.splitlines())) > 200, "the oracle: metrics.md's table is a wide one"
    printed = console_table(rows, cfg, tmp_path / "eval" / "metrics.md")
    lines = printed.splitlines()
    assert max(map(len, lines)) <= CONSOLE_WIDTH, "\n".join(line for line in lines if len(line) > CONSOLE_WIDTH)
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == ["planner", "group", "problems", "success %", "collision %", "reach %", "time B=1 [s]"], header
    cells = {tuple(c.strip() for c in line.strip("|").split("|"))[:2]: [c.strip() for c in line.strip("|").split("|")]
             for line in lines[2:] if line.startswith("| ")}
    samp = cells[("samp+check", "benchmark_tabletop")]  # 72 of 108 succeeded, 18 collided, 90 reached
    assert samp[2:6] == ["108", "66.7", "16.7", "83.3"], samp
    assert re.fullmatch(r"\d\.\d{3} ± \d\.\d{3}", samp[6]), samp
    assert "The full table" in printed and str(tmp_path / "eval" / "metrics.md") in printed


# ----------------------------------------------------------------- 4. show, help texts, plurals
def _show(tmp_path: Path, code: dict) -> str:
    run = tmp_path / "run"
    run.mkdir(exist_ok=True)
    (run / "run.json").write_text(json.dumps({"status": "completed", "code_version": code}))
    proc = _run([sys.executable, "-m", "samp.runs", "show", str(run)])
    assert proc.returncode == 0, proc.stderr
    return next(line for line in proc.stdout.splitlines() if line.startswith("code "))


def test_show_names_the_version_and_a_commit_only_where_one_is_known(tmp_path):
    wheel = {"package": "0.1.0", "git_commit": None, "git_dirty": None}  # as a wheel install records it
    assert _show(tmp_path, wheel) == "code       samp 0.1.0"
    clone = {"package": "0.1.0", "git_commit": "fe3d9f5", "git_dirty": True}
    assert _show(tmp_path, clone) == "code       samp 0.1.0 at fe3d9f5 (dirty)"


def test_help_names_the_console_command_that_was_run():
    installed = _run([sys.executable, str(BIN / "samp-data"), "--help"])
    assert installed.returncode == 0, installed.stderr
    assert installed.stdout.startswith("usage: samp-data COMMAND") and "python -m samp" not in installed.stdout
    assert "`samp-train experiment=NAME --lock`" in installed.stdout, "other commands by their console names too"
    module = _run([sys.executable, "-m", "samp.data", "--help"])
    assert module.stdout.startswith("usage: python -m samp.data COMMAND"), "what the user typed"


def test_help_of_an_install_from_shipped_configs_names_no_conf_folder(tmp_path):
    """Configs other than a clone's conf/ (a wheel's samp/_conf, SAMP_CONF_DIR): no `conf/...` that is not
    there; the folder they are in is named."""
    shipped = tmp_path / "site-packages" / "samp" / "_conf"
    shutil.copytree(REPO / "conf", shipped)
    for command in ("samp-train", "samp-eval", "samp-robot"):
        proc = _run([sys.executable, str(BIN / command), "--help"], env={"SAMP_CONF_DIR": str(shipped)}, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert not re.search(r"(?<![\w./-])conf/", proc.stdout), f"{command}: " + proc.stdout
        assert "in the shipped configs" in proc.stdout and f"the shipped configs: {shipped}" in proc.stdout
    clone = _run([sys.executable, str(BIN / "samp-robot"), "--help"])
    assert "(key=default; conf/robot_show.yaml)" in clone.stdout, "a clone's conf/ is named as it is"


def test_counts_of_one_are_singular(tmp_path, capsys):
    from samp.console import plural
    from samp.data.__main__ import _print_summary

    assert (plural(1, "problem"), plural(0, "problem"), plural(2, "entry", "entries")) == \
        ("1 problem", "0 problems", "2 entries")
    folder = tmp_path / "one" / "abc"
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text(json.dumps({
        "format_version": 1, "name": "one", "id": "abc", "files": {},
        "counts": {"scenes": 1, "train_scenes": 1, "val_scenes": 0, "test_scenes": 0, "trajectories": 1,
                   "failures": 1, "eval_problems": 1, "eval_failures": 0},
        "planning_time": {"total_s": 1.0}, "eval_planning_time": {"total_s": 0.5}}))
    _print_summary(folder)
    out = capsys.readouterr().out
    assert "  1 scene (1 train, 0 val, 0 test), 1 demonstration (1 problem failed), 1 evaluation problem (" in out, out


def test_the_model_card_of_a_one_step_run_counts_in_the_singular(tmp_path):
    from samp.runs.cards import model_card

    folder = tmp_path / "tiny" / "2026-01-01_00-00-00"
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"experiment": "tiny", "seed": 0, "steps": 1, "epochs": 1,
                                                 "status": "completed"}))
    card = model_card(folder)
    assert "- seed 0, 1 step, 1 epoch" in card, [line for line in card.splitlines() if "seed" in line]


# ----------------------------------------------------------------- 5. make install behind a mirror
FAKE_PIP = """#!/bin/sh
# A venv's python for `make install`: records each pip call; torch is missing; a pip install of torch
# succeeds only where this scenario has it (LOCAL: the find-links wheel, INDEX: pip's own indexes, EXTRA:
# the extra CPU index).
echo "$*" >> "$CALLS"
case "$*" in
  "-c import torch") exit 1 ;;
  *"--no-index"*torch*) [ -n "$LOCAL" ] ;;
  *"--extra-index-url"*torch*) [ -n "$EXTRA" ] ;;
  *" torch"*) [ -n "$INDEX" ] ;;
  *) exit 0 ;;
esac
"""


def _make_install(tmp_path: Path, name: str, gpu: bool = False, **scenario) -> tuple[subprocess.CompletedProcess, list[str]]:
    work = tmp_path / name
    (work / "venv" / "bin").mkdir(parents=True)
    for f in ("Makefile", "pyproject.toml", "constraints.txt"):
        shutil.copy(REPO / f, work / f)
    python = work / "venv" / "bin" / "python"
    python.write_text(FAKE_PIP)
    python.chmod(python.stat().st_mode | stat.S_IEXEC)
    path = work / "path"
    path.mkdir()
    if gpu:
        (path / "nvidia-smi").write_text("#!/bin/sh\necho 'GPU 0: H100'\n")
        (path / "nvidia-smi").chmod(0o755)
    calls = work / "calls"
    extra = scenario.pop("TORCH_CPU_INDEX", None)
    env = {"PATH": f"{path}:/usr/bin:/bin", "CALLS": str(calls), **{k: "1" for k, v in scenario.items() if v}}
    args = ["make", "-s", "install", f"VENV={work / 'venv'}"] + ([f"TORCH_CPU_INDEX={extra}"] if extra is not None else [])
    proc = _run(args, env=env, cwd=work)
    return proc, [c for c in calls.read_text().splitlines() if "torch" in c and "import" not in c]


@pytest.mark.skipif(shutil.which("make") is None or sys.platform != "linux", reason="make on Linux (+cpu builds)")
def test_make_install_takes_torch_through_pip_s_own_configuration(tmp_path):
    proc, torch = _make_install(tmp_path, "local", LOCAL=True)
    assert proc.returncode == 0 and torch == ["-m pip install -q --no-index --no-deps torch==2.13.0+cpu"], torch
    proc, torch = _make_install(tmp_path, "mirror", INDEX=True)  # pip's index-url / extra-index-url: a mirror
    assert proc.returncode == 0 and torch[-1] == "-m pip install -q torch==2.13.0+cpu", torch
    proc, torch = _make_install(tmp_path, "pypi", EXTRA=True)
    assert proc.returncode == 0 and "--extra-index-url https://download.pytorch.org/whl/cpu" in torch[-1], torch
    proc, torch = _make_install(tmp_path, "nothing", TORCH_CPU_INDEX="")
    assert proc.returncode != 0 and "no CPU build of torch (torch==2.13.0+cpu)" in proc.stderr, proc.stderr
    every = [c for name in ("local", "mirror", "pypi", "nothing") for c in (tmp_path / name / "calls").read_text().splitlines()]
    assert not any("--index-url" in c.replace("--extra-index-url", "") for c in every), "pip's own index is kept"
    assert all("torch==2.13.0+cpu" in c for c in every if "torch==" in c), "never a CUDA build without a GPU"
    proc, torch = _make_install(tmp_path, "gpu", gpu=True, INDEX=True)
    assert proc.returncode == 0 and torch == ["-m pip install torch==2.13.0"], torch
