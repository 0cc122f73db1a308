"""Untrusted robots (issues 52 and 53): a URDF or mesh that is not what it claims is refused by
`samp-robot add` with one line naming the file and the joint or link, exit status 2, and nothing written;
a valid one still loads, however deep its chain; the robot file names its URDF relative to itself, so the
project folder can move."""

from __future__ import annotations

import io
import shutil
import struct
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest

ARM = """<?xml version="1.0"?>
<robot name="arm">
  <link name="world"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/></joint>
  <link name="base">
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry></collision>
  </link>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="upper"/><origin xyz="0 0 0.15" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-1.5" upper="1.5" effort="10" velocity="1"/>
  </joint>
  <link name="upper">
    <collision><origin xyz="0 0 0.15"/><geometry><MESH_OR_BOX/></geometry></collision>
  </link>
  <joint name="elbow" type="revolute">
    <parent link="upper"/><child link="fore"/><origin xyz="0 0 0.35"/><axis xyz="0 1 0"/>
    <limit lower="-2.5" upper="2.5" effort="10" velocity="1"/>
  </joint>
  <link name="fore">
    <collision><origin xyz="0 0 0.12"/><geometry><cylinder radius="0.03" length="0.16"/></geometry></collision>
  </link>
</robot>
"""
BOX = '<box size="0.06 0.06 0.2"/>'


def arm_urdf(folder: Path, text: str = ARM, geometry: str = BOX) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "arm.urdf"
    path.write_text(text.replace("<MESH_OR_BOX/>", geometry))
    return path


def run_add(urdf: Path, out: Path, *extra: str) -> tuple[int, str, str]:
    """`samp-robot add` in this process: (exit status, stdout, stderr)."""
    from samp.robot.__main__ import main

    stdout, stderr = io.StringIO(), io.StringIO()
    with redirect_stdout(stdout), redirect_stderr(stderr):
        rc = main(["add", f"urdf={urdf}", "name=arm", f"out={out}", "samples=20", *extra])
    return rc, stdout.getvalue(), stderr.getvalue()


def assert_refused(tmp_path: Path, urdf: Path, *fragments: str) -> str:
    rc, _, stderr = run_add(urdf, tmp_path / "conf")
    assert rc == 2, f"expected exit status 2, got {rc}: {stderr}"
    assert stderr.count("\n") == 1 and "Traceback" not in stderr, stderr
    for fragment in fragments:
        assert fragment in stderr, f"expected {fragment!r} in: {stderr}"
    assert not (tmp_path / "conf" / "robot").exists() or not list((tmp_path / "conf" / "robot").iterdir())
    return stderr


def replaced(old: str, new: str, text: str = ARM) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


# (id, mutation of ARM, fragments of the one line; the URDF's path is asserted in every case)
GRAPH_FAULTS = [
    ("cycle", replaced("</robot>", '<link name="a"/><link name="b"/>'
                                   '<joint name="ab" type="fixed"><parent link="a"/><child link="b"/></joint>'
                                   '<joint name="ba" type="fixed"><parent link="b"/><child link="a"/></joint></robot>'),
     ["form a cycle", "'ab'", "'ba'"]),
    ("whole_tree_a_cycle", replaced('<joint name="mount" type="fixed"><parent link="world"/><child link="base"/></joint>',
                                    '<joint name="mount" type="fixed"><parent link="fore"/><child link="world"/></joint>'
                                    '<joint name="down" type="fixed"><parent link="world"/><child link="base"/></joint>'),
     ["exactly one root link", "cycle"]),
    ("two_parents", replaced("</robot>", '<joint name="again" type="fixed"><parent link="base"/>'
                                         '<child link="fore"/></joint></robot>'),
     ["link 'fore' is the child of joints 'elbow' and 'again'"]),
    ("two_roots", replaced("</robot>", '<link name="loose"/></robot>'), ["exactly one root link", "'loose'"]),
    ("undefined_link", replaced('<child link="fore"/>', '<child link="ghost"/>'),
     ["joint 'elbow' names child link 'ghost', which is not a <link>"]),
    ("no_parent_element", replaced('<parent link="upper"/>', ""), ["joint 'elbow' has no <parent link=...>"]),
    ("duplicate_joint", replaced('name="elbow"', 'name="shoulder"'), ["two <joint> elements are named 'shoulder'"]),
    ("duplicate_link", replaced('<link name="fore">', '<link name="upper">'), ["two <link> elements are named 'upper'"]),
    ("unknown_joint_type", replaced('name="elbow" type="revolute"', 'name="elbow" type="hinge"'),
     ["joint 'elbow' has type 'hinge'"]),
    ("self_joint", replaced('<child link="fore"/>', '<child link="upper"/>'), ["joint 'elbow' joins link 'upper' to itself"]),
]
NUMBER_FAULTS = [
    ("inf_limit", replaced('upper="2.5"', 'upper="inf"'), ["joint 'elbow' <limit> upper is 'inf'; expected a finite number"]),
    ("nan_limit", replaced('lower="-1.5"', 'lower="nan"'), ["joint 'shoulder' <limit> lower is 'nan'"]),
    ("lower_above_upper", replaced('lower="-2.5" upper="2.5"', 'lower="2.5" upper="-2.5"'),
     ["joint 'elbow' has lower limit 2.5 above its upper limit -2.5"]),
    ("garbage_limit", replaced('upper="1.5"', 'upper="1.5rad"'), ["joint 'shoulder' <limit> upper is '1.5rad'"]),
    ("garbage_effort", replaced('effort="10" velocity="1"/>\n  </joint>\n  <link name="fore">',
                                'effort="ten" velocity="1"/>\n  </joint>\n  <link name="fore">'),
     ["joint 'elbow' <limit> effort is 'ten'"]),
    ("nan_origin", replaced('<origin xyz="0 0 0.35"/>', '<origin xyz="0 nan 0.35"/>'),
     ["joint 'elbow' <origin xyz> is '0 nan 0.35'; expected 3 finite numbers"]),
    ("inf_rpy", replaced('rpy="0 0 0"', 'rpy="0 -inf 0"'), ["joint 'shoulder' <origin rpy> is '0 -inf 0'"]),
    ("short_origin", replaced('<origin xyz="0 0 0.35"/>', '<origin xyz="0 0.35"/>'), ["joint 'elbow' <origin xyz>"]),
    ("link_nan_origin", replaced('<origin xyz="0 0 0.12"/>', '<origin xyz="nan 0 0.12"/>'),
     ["link 'fore' <origin xyz> is 'nan 0 0.12'"]),
    ("zero_axis", replaced('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>'), ["joint 'shoulder' has axis [0.0, 0.0, 0.0]"]),
    ("negative_box", replaced('size="0.2 0.2 0.1"', 'size="0.2 -0.2 0.1"'), ["link 'base' <box>", "positive numbers"]),
    ("missing_radius", replaced('radius="0.03" ', ""), ["link 'fore' <cylinder>", "radius"]),
]


@pytest.mark.parametrize("text, fragments", [c[1:] for c in GRAPH_FAULTS + NUMBER_FAULTS],
                         ids=[c[0] for c in GRAPH_FAULTS + NUMBER_FAULTS])
def test_a_bad_urdf_is_refused_with_one_line(tmp_path, text, fragments):
    urdf = arm_urdf(tmp_path / "robots", text)
    assert_refused(tmp_path, urdf, str(urdf), *fragments)


def test_the_unchanged_arm_is_added(tmp_path):
    """The control: the file the faults above are made from is a valid robot."""
    rc, stdout, stderr = run_add(arm_urdf(tmp_path / "robots"), tmp_path / "conf")
    assert rc == 0, stderr
    assert "robot arm: 2 joints" in stdout


ENTITY_BOMB = """<?xml version="1.0"?>
<!DOCTYPE robot [
  <!ENTITY a "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa">
  <!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">
  <!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">
  <!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">
  <!ENTITY e "&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;">
]>
<robot name="&e;"><link name="base"/></robot>
"""


def test_an_entity_bomb_is_refused_before_it_expands(tmp_path):
    """3 kB that expand to 3 GB (32^4 copies of 100 bytes) in the robot's name: refused unread."""
    urdf = tmp_path / "robots" / "bomb.urdf"
    urdf.parent.mkdir()
    urdf.write_text(ENTITY_BOMB)
    assert_refused(tmp_path, urdf, str(urdf), "declares a DOCTYPE or entities")


def test_an_oversized_urdf_is_refused_unread(tmp_path):
    from samp.robot.urdf import MAX_URDF_BYTES

    urdf = arm_urdf(tmp_path / "robots")
    with open(urdf, "a") as f:
        f.write("<!--" + "x" * MAX_URDF_BYTES + "-->")
    assert_refused(tmp_path, urdf, str(urdf), "over samp's limit for a URDF", "MAX_URDF_BYTES")


def chain_urdf(folder: Path, links: int) -> Path:
    """A serial chain of `links` links, boxes on the first and the last, revolute joints between."""
    parts = ['<robot name="snake">']
    for i in range(links):
        box = '<collision><geometry><box size="0.05 0.05 0.05"/></geometry></collision>' if i in (0, links - 1) else ""
        parts.append(f'<link name="l{i}">{box}</link>')
        if i:
            parts.append(f'<joint name="j{i}" type="revolute"><parent link="l{i - 1}"/><child link="l{i}"/>'
                         '<origin xyz="0 0 0.01"/><axis xyz="0 1 0"/><limit lower="-0.1" upper="0.1"/></joint>')
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "snake.urdf"
    path.write_text("".join(parts) + "</robot>")
    return path


def test_a_deep_chain_loads_without_recursion_error(tmp_path):
    """A 450-link chain (deeper than Python's recursion limit allows a recursive walk here) is added,
    and samp's FK of its tip matches the product of its joint transforms (a straight chain at q = 0)."""
    import torch

    from samp.robot import load_robot

    urdf = chain_urdf(tmp_path / "robots", 450)
    rc, _, stderr = run_add(urdf, tmp_path / "conf", "samples=1")
    assert rc == 0, stderr[-2000:]
    robot = load_robot(tmp_path / "conf" / "robot" / "arm.yaml", dtype=torch.float64)
    assert robot.dof == 449 and robot.ee_link == "l449"
    tip = robot.fk(torch.zeros(1, 449, dtype=torch.float64))["l449"][0].numpy()
    np.testing.assert_allclose(tip[:3, 3], [0, 0, 4.49], atol=1e-9)


def test_too_many_links_are_refused(tmp_path):
    from samp.robot.urdf import MAX_URDF_LINKS

    urdf = chain_urdf(tmp_path / "robots", MAX_URDF_LINKS + 1)
    assert_refused(tmp_path, urdf, str(urdf), f"has {MAX_URDF_LINKS + 1} links", "MAX_URDF_LINKS")


# --- mesh paths and mesh files ----------------------------------------------------------------------------

def binary_stl(path: Path, triangles: np.ndarray, declared: int | None = None) -> Path:
    """(T, 3, 3) triangles as a binary STL; `declared` overrides the triangle count in the header."""
    path.parent.mkdir(parents=True, exist_ok=True)
    body = b"".join(struct.pack("<12fH", 0, 0, 0, *t.ravel(), 0) for t in triangles)
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(triangles) if declared is None else declared) + body)
    return path


def cube_triangles(half: float = 0.03) -> np.ndarray:
    import trimesh

    box = trimesh.creation.box(extents=[2 * half] * 3)
    return box.vertices[box.faces]


def mesh_arm(tmp_path: Path, filename: str) -> Path:
    return arm_urdf(tmp_path / "robots", geometry=f'<mesh filename="{filename}"/>')


def test_a_mesh_inside_the_folder_is_read(tmp_path):
    binary_stl(tmp_path / "robots" / "meshes" / "upper.stl", cube_triangles())
    rc, stdout, stderr = run_add(mesh_arm(tmp_path, "meshes/upper.stl"), tmp_path / "conf")
    assert rc == 0, stderr


@pytest.mark.parametrize("filename", ["../secret.stl", "meshes/../../secret.stl", "{abs}", "file://{abs}",
                                      "package://robots/../../secret.stl"])
def test_a_mesh_path_leaving_the_folder_is_refused(tmp_path, filename):
    secret = binary_stl(tmp_path / "secret.stl", cube_triangles())  # exists: refused for where it is
    urdf = mesh_arm(tmp_path, filename.format(abs=secret))
    assert_refused(tmp_path, urdf, str(urdf), "link 'upper'", "collision mesh")


def test_a_missing_mesh_names_the_link(tmp_path):
    urdf = mesh_arm(tmp_path, "meshes/nope.stl")
    assert_refused(tmp_path, urdf, str(urdf), "link 'upper'", "'meshes/nope.stl' does not exist")


def test_an_stl_declaring_more_triangles_than_it_holds_is_refused(tmp_path):
    """The header claims 4e9 triangles (200 GB) in a 684-byte file: refused for that reason, unread."""
    stl = binary_stl(tmp_path / "robots" / "meshes" / "upper.stl", cube_triangles(), declared=4_000_000_000)
    assert_refused(tmp_path, mesh_arm(tmp_path, "meshes/upper.stl"), str(stl),
                   "declares 4000000000 triangles (200000000084 bytes), but the file has 684 bytes")


@pytest.mark.parametrize("content, fragment", [
    (b"solid empty\nendsolid empty\n", "has no triangles"),
    (b"", "is not an STL"),
    ("flat", "is flat"),
], ids=["ascii_empty", "zero_bytes", "one_triangle"])
def test_an_empty_or_flat_mesh_is_refused_with_its_path(tmp_path, content, fragment):
    stl = tmp_path / "robots" / "meshes" / "upper.stl"
    if content == "flat":
        binary_stl(stl, np.array([[[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]], dtype=float))
    else:
        stl.parent.mkdir(parents=True)
        stl.write_bytes(content)
    assert_refused(tmp_path, mesh_arm(tmp_path, "meshes/upper.stl"), str(stl), fragment)


def test_an_oversized_mesh_is_refused_unread(tmp_path):
    from samp.meshes import MAX_MESH_BYTES

    obj = tmp_path / "robots" / "meshes" / "upper.obj"
    obj.parent.mkdir(parents=True)
    with open(obj, "wb") as f:
        f.truncate(MAX_MESH_BYTES + 1)  # sparse: no disk used
    assert_refused(tmp_path, mesh_arm(tmp_path, "meshes/upper.obj"), str(obj), "over samp's limit", "MAX_MESH_BYTES")


def test_the_real_command_refuses_a_cyclic_urdf(tmp_path):
    """The installed entry point, as a user runs it: one line on stderr, exit status 2."""
    urdf = arm_urdf(tmp_path / "robots", GRAPH_FAULTS[0][1])
    proc = subprocess.run([sys.executable, "-m", "samp.robot", "add", f"urdf={urdf}", "name=arm",
                           f"out={tmp_path / 'conf'}"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert str(urdf) in proc.stderr and "form a cycle" in proc.stderr and "Traceback" not in proc.stderr


# --- issue 53: the robot file names its URDF relative to itself -------------------------------------------

def test_a_urdf_beside_the_config_folder_is_named_relatively_and_the_project_moves(tmp_path):
    """docs/bring-your-own.md's layout (robots/ beside conf/): the YAML says ../../robots/arm/arm.urdf, and
    the robot still loads after the whole project folder is moved (as a clone elsewhere would be)."""
    import yaml

    from samp.robot import load_robot

    project = tmp_path / "myproject"
    urdf = arm_urdf(project / "robots" / "arm")
    rc, _, stderr = run_add(urdf, project / "conf")
    assert rc == 0, stderr
    written = yaml.safe_load((project / "conf" / "robot" / "arm.yaml").read_text())
    assert written["urdf"] == "../../robots/arm/arm.urdf", written["urdf"]
    moved = tmp_path / "elsewhere" / "clone"
    moved.parent.mkdir()
    shutil.move(project, moved)
    robot = load_robot(moved / "conf" / "robot" / "arm.yaml")
    assert robot.urdf.path == (moved / "robots" / "arm" / "arm.urdf").resolve()


def test_a_urdf_outside_the_project_keeps_its_absolute_path(tmp_path):
    urdf = arm_urdf(tmp_path / "elsewhere")
    out = tmp_path / "deep" / "myproject" / "conf"
    rc, _, stderr = run_add(urdf, out)
    assert rc == 0, stderr
    assert f"urdf: {urdf.resolve()}" in (out / "robot" / "arm.yaml").read_text()


# --- issue 53: a problem without a goal says why ----------------------------------------------------------

def test_a_problem_without_a_valid_goal_says_why(robots):
    """Goals 1.2-1.4 m from the Panda's base lie beyond its reach: each problem's reason names that
    first (what `samp.data show` counts by) and then every count, where it used to say only "no valid goal"."""
    from samp.expert import load_expert_config
    from samp.expert.problems import sample_problems
    from samp.scene import generate_scene

    cfg = load_expert_config({"ik": {"seeds": 4, "iterations": 20},
                              "problems": {"target_fraction": 0.0, "radius": [1.2, 1.4], "goal_rounds": 2,
                                           "poses_per_goal": 3, "start": "random"}})
    problems = sample_problems(robots["panda"], generate_scene("tabletop", seed=0, num_obstacles=[3, 3]), 2, seed=0, cfg=cfg)
    for p in problems:
        assert p.q_goal is None and p.reason.split(":")[0] == "no valid goal (IK failed)", p.reason
        assert "of 6 sampled workspace poses, IK failed for 6" in p.reason, p.reason
