"""Config folders and YAML files of a user's that would never finish loading, or fail far from the file.

Each test writes its bad folder in `tmp_path` and runs the real command: a YAML alias bomb (as a dataset
spec of `SAMP_CONFIG_PATH`, and as a scene file), symbolic links that loop in a config folder, and a
garbage file that shadows one of samp's. Each must end with exit code 2 and one line naming the user's
own file or link, quickly; the commands that could blow up memory on older code run in a subprocess with a
memory limit.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# "Billion laughs" in 342 bytes: nine levels of nine aliases, 9**9 (387 million) strings once expanded.
BOMB = "".join([f"{chr(97 + i)}: &{chr(97 + i)} [" + ",".join([f"*{chr(96 + i)}"] * 9) + "]\n" if i else
                'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' for i in range(9)])


def _limit_memory():  # older code expands the bomb until memory runs out: stop it at 2 GiB instead
    resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))


def _run(args: list[str], env: dict, timeout: float = 30) -> subprocess.CompletedProcess:
    try:
        return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=timeout,
                              env={**os.environ, "OMP_NUM_THREADS": "1", **env}, cwd=REPO, preexec_fn=_limit_memory)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{' '.join(args)} did not finish within {timeout} s")


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("samp: ")]  # shadowing notes
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err[-3000:]
    return lines[0]


@pytest.fixture
def env(tmp_path) -> dict:
    return {"SAMP_CACHE_DIR": str(tmp_path / "cache"), "SAMP_DATASETS_DIR": str(tmp_path / "datasets"),
            "SAMP_RUNS_DIR": str(tmp_path / "runs")}


def test_an_alias_bomb_as_a_dataset_spec_is_refused_at_once(tmp_path, env):
    spec = tmp_path / "mine" / "dataset" / "bomb.yaml"
    spec.parent.mkdir(parents=True)
    spec.write_text(BOMB)
    proc = _run(["-m", "samp.data", "generate", "dataset=bomb"], {**env, "SAMP_CONFIG_PATH": str(tmp_path / "mine")})
    assert proc.returncode == 2, proc.stderr[-3000:]
    line = _one_line(proc.stderr)
    assert str(spec) in line and "alias" in line and "cache" not in line, line
    assert not (tmp_path / "datasets").exists(), "nothing is written"


def test_the_scan_stops_at_the_first_alias_past_the_bound(tmp_path):
    """The refusal names the alias at which the expanded count first passes the bound, computed here from the
    bomb's shape: level k's list holds 9 aliases of level k-1, so nothing past that line is expanded."""
    from samp.yaml_files import MAX_YAML_ALIAS_NODES, YamlFileError, check_yaml

    (tmp_path / "bomb.yaml").write_text(BOMB)
    nodes, added, line = [10], 0, None  # level a: a list of 9 strings
    for level in range(1, 9):
        for _ in range(9):
            added += nodes[level - 1]
            if added > MAX_YAML_ALIAS_NODES and line is None:
                line = level + 1
        nodes.append(1 + 9 * nodes[level - 1])
    with pytest.raises(YamlFileError) as err:
        check_yaml(tmp_path / "bomb.yaml", "dataset spec")
    assert f"*{chr(96 + line - 1)}, line {line})" in str(err.value), (line, str(err.value))


def test_an_alias_bomb_in_a_scene_file_is_refused(tmp_path, env):
    scene = tmp_path / "cell.yaml"
    scene.write_text("obstacles: []\nmeta:\n" + textwrap.indent(BOMB, "  "))  # the scene's hash expands it
    script = f"from samp.scene.files import load_scene_file\nload_scene_file({str(scene)!r})\n"
    proc = _run(["-c", script], env, timeout=30)
    assert proc.returncode == 1 and "YamlFileError" in proc.stderr, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert f"scene file {scene}: its aliases expand to more than" in last, last


@pytest.mark.parametrize("links", [["again"], ["a", "b"]])
@pytest.mark.timeout(30)
def test_a_symbolic_link_loop_in_a_config_folder_is_refused_with_the_link(tmp_path, env, links, monkeypatch, capsys):
    """Two links to `.` made every config command hang; one made forty nested copies of the folder."""
    from samp import paths
    from samp.train.cli import main

    mine = tmp_path / "mine"
    (mine / "robot").mkdir(parents=True)
    (mine / "robot" / "mypanda.yaml").write_text((REPO / "conf" / "robot" / "panda.yaml").read_text()
                                                 .replace("name: panda", "name: mypanda"))
    for name in links:
        (mine / name).symlink_to(".")
    for key, value in {**env, "SAMP_CONFIG_PATH": str(mine)}.items():
        monkeypatch.setenv(key, value)
    paths._said.clear()
    assert main(["experiment=quickstart", "--cfg", "job"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"symbolic link {mine / links[0]} leads to {mine}" in line and "never end" in line, line
    assert not any((tmp_path / "cache" / "config").iterdir()), "no view (with nested copies) is built"


@pytest.mark.timeout(30)
def test_two_ways_into_one_folder_are_refused(tmp_path, env, monkeypatch, capsys):
    """Links that fork and join again double the walk at each level: refused at the second way in."""
    from samp.data.__main__ import main

    mine = tmp_path / "mine"
    (mine / "x").mkdir(parents=True)
    (mine / "y" / "robot").mkdir(parents=True)
    (mine / "x" / "c").symlink_to(mine / "y")
    for key, value in {**env, "SAMP_CONFIG_PATH": str(mine)}.items():
        monkeypatch.setenv(key, value)
    assert main(["--help"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"symbolic link {mine / 'x' / 'c'} leads to {mine / 'y'}" in line and "already reaches" in line, line


@pytest.mark.parametrize("text, said", [("workers: [\n", "is not valid YAML"),
                                        ("- 1\n- 2\n", "holds a list, not a mapping"),
                                        ("\x80\x81garbage", "is not valid YAML")])
def test_a_garbage_file_shadowing_samps_own_is_named_at_the_users_path(tmp_path, env, monkeypatch, capsys, text, said):
    """A user's `data.yaml` in place of samp's: the error names that file, not its link in samp's cache."""
    from samp import paths
    from samp.data.__main__ import main

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "data.yaml").write_bytes(text.encode("latin-1"))
    for key, value in {**env, "SAMP_CONFIG_PATH": str(mine)}.items():
        monkeypatch.setenv(key, value)
    paths._said.clear()
    assert main(["generate", "dataset=smoke"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"config file {mine / 'data.yaml'} {said}" in line and str(tmp_path / "cache") not in line, line
    assert not (tmp_path / "datasets").exists()


def test_a_good_folder_with_a_linked_group_still_loads(tmp_path, env, monkeypatch):
    """The checks refuse loops and bad files only: a robot folder linked in from elsewhere still counts."""
    from samp import paths
    from samp.robot import available_robots

    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "mypanda.yaml").write_text((REPO / "conf" / "robot" / "panda.yaml").read_text()
                                         .replace("name: panda", "name: mypanda"))
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "robot").symlink_to(shared)
    for key, value in {**env, "SAMP_CONFIG_PATH": str(mine)}.items():
        monkeypatch.setenv(key, value)
    paths._said.clear()
    assert "mypanda" in available_robots() and "panda" in available_robots()
