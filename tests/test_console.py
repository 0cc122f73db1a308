"""samp.console and samp.runs.console: progress that suits a log, pybullet without its banner, the run's
train.log. Real streams, real subprocesses; no timing is asserted (intervals of 0 or of days)."""

from __future__ import annotations

import io
import logging
import subprocess
import sys

from samp.console import Progress
from samp.runs.console import RunLog


def test_progress_in_a_file_writes_plain_lines():
    out = io.StringIO()  # not a terminal
    with Progress(3, "plans", unit="plan", every_s=0.0, stream=out) as bar:
        for _ in range(3):
            bar.update()
    lines = out.getvalue().splitlines()
    assert len(lines) == 4 and lines[0].startswith("plans: 1/3 plan (33 %)"), lines
    assert lines[-1].startswith("plans: 3/3 plan (100 %)") and lines[-1].endswith("(done)"), lines
    assert "\r" not in out.getvalue()


def test_a_short_task_stays_silent_in_a_file():
    out = io.StringIO()
    with Progress(2, "checks", every_s=1e9, stream=out) as bar:
        bar.update(2)
    assert out.getvalue() == ""


def test_disabled_progress_prints_nothing():
    out = io.StringIO()
    with Progress(2, "checks", every_s=0.0, stream=out, enabled=False) as bar:
        bar.update(2)
    assert out.getvalue() == ""


def _stderr_of(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120).stderr


def test_pybullet_is_imported_without_its_banner():
    assert "pybullet build time" in _stderr_of("import pybullet"), "the oracle: plain pybullet prints its banner"
    quiet = _stderr_of("from samp.console import import_pybullet; pb = import_pybullet(); "
                       "import sys; print('after', file=sys.stderr)")
    assert "pybullet build time" not in quiet and "after" in quiet, quiet  # stderr works again afterwards


def test_run_log_keeps_everything_printed_as_a_log_file_should(tmp_path, capsys):
    with RunLog() as log:
        print("before the folder")
        path = log.attach(tmp_path)
        sys.stderr.write("bar 1/3\rbar 2/3\rbar 3/3\n")
        sys.stderr.write("\x1b[Aafter a cursor move\n")
        logging.getLogger("pytorch_lightning").warning("from Lightning's logger")
        logging.getLogger("pytorch_lightning").warning("💡 Tip: an advert")
        print("unfinished line", end="")
    assert path == tmp_path / "train.log"
    assert path.read_text().splitlines() == ["before the folder", "bar 3/3", "after a cursor move",
                                             "from Lightning's logger", "unfinished line"]
    seen = capsys.readouterr()
    assert "before the folder" in seen.out and "bar 1/3" in seen.err  # the console still gets everything
