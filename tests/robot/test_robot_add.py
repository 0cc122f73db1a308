"""`python -m samp.robot add`: a robot we do not ship, from its URDF, checked against pybullet as an
independent oracle (its own URDF loader, forward kinematics and collision shapes): a 6-joint arm of boxes
and cylinders with continuous and revolute joints written here (six, because the expert's goals are full
end-effector poses), and pybullet_data's xArm 6 with its gripper (we ship the xArm 6 without one).
Then, end to end (slow): its robot SDF trained and its accuracy printed, a smoke dataset of it generated, a
policy trained and evaluated on it, by the commands `add` prints."""

from __future__ import annotations

import io
import json
import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from contextlib import redirect_stdout
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from samp.console import import_pybullet

pb = import_pybullet()

TOY_URDF = """<?xml version="1.0"?>
<robot name="toyarm">
  <link name="world"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/></joint>
  <link name="base">
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry></collision>
  </link>
  <joint name="turn" type="continuous">
    <parent link="base"/><child link="column"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
  </joint>
  <link name="column">
    <collision><origin xyz="0 0 0.1"/><geometry><cylinder radius="0.06" length="0.2"/></geometry></collision>
  </link>
  <joint name="shoulder" type="revolute">
    <parent link="column"/><child link="upper"/><origin xyz="0 0 0.25" rpy="0 0.05 0"/><axis xyz="0 1 0"/>
    <limit lower="-1.6" upper="1.6" effort="10" velocity="1"/>
  </joint>
  <link name="upper">
    <collision><origin xyz="0 0 0.2"/><geometry><box size="0.08 0.08 0.32"/></geometry></collision>
  </link>
  <joint name="elbow" type="revolute">
    <parent link="upper"/><child link="fore"/><origin xyz="0 0 0.4"/><axis xyz="0 1 0"/>
    <limit lower="ELBOW_LOWER" upper="ELBOW_UPPER" effort="10" velocity="1"/>
  </joint>
  <link name="fore">
    <collision><origin xyz="0 0 0.14"/><geometry><cylinder radius="0.035" length="0.2"/></geometry></collision>
  </link>
  <joint name="roll" type="continuous">
    <parent link="fore"/><child link="wrist"/><origin xyz="0.01 0 0.27" rpy="0.1 0 0.2"/><axis xyz="0 0 1"/>
  </joint>
  <link name="wrist">
    <collision><origin xyz="0 0 0.03"/><geometry><cylinder radius="0.03" length="0.05"/></geometry></collision>
  </link>
  <joint name="pitch" type="revolute">
    <parent link="wrist"/><child link="palm"/><origin xyz="0 0 0.09"/><axis xyz="0 1 0"/>
    <limit lower="-2.0" upper="2.0" effort="10" velocity="1"/>
  </joint>
  <link name="palm">
    <collision><origin xyz="0 0 0.04"/><geometry><box size="0.05 0.05 0.05"/></geometry></collision>
  </link>
  <joint name="flange" type="continuous">
    <parent link="palm"/><child link="hand"/><origin xyz="0 0 0.08"/><axis xyz="0 0 1"/>
  </joint>
  <link name="hand">
    <collision><origin xyz="0 0 0.02"/><geometry><box size="0.1 0.04 0.04"/></geometry></collision>
  </link>
  <joint name="tool" type="fixed"><parent link="hand"/><child link="tcp"/><origin xyz="0 0 0.08"/></joint>
  <link name="tcp"/>
</robot>
"""

# What the end-to-end test runs, shrunk from the commands `add` prints (docs/robots-and-scenes.md runs them
# at full size): the robot SDF with tiny samples and steps, the smoke dataset, a few policy steps.
SDF_TINY = "robot_sdf_samples=tiny trainer.max_steps=60 datamodule.steps_per_epoch=20 trainer.enable_progress_bar=false"
POLICY_TINY = ("datamodule.n_e=16 datamodule.val_samples=50 trainer.max_epochs=1 +trainer.limit_train_batches=4 "
               "evaluation.problems=2 trainer.enable_progress_bar=false")


def toy_urdf(folder: Path, elbow=(-2.9, 2.9)) -> Path:
    path = folder / "toyarm.urdf"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(TOY_URDF.replace("ELBOW_LOWER", str(elbow[0])).replace("ELBOW_UPPER", str(elbow[1])))
    return path


def run_add(*args: str) -> tuple[int, str, str]:
    """`python -m samp.robot add ARGS` in this process: (exit status, stdout, stderr)."""
    from contextlib import redirect_stderr

    from samp.robot.__main__ import main

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main(["add", *args])
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def toy(tmp_path_factory, _isolated_cache):
    """The toy arm added from a user's config folder that holds its URDF (so the YAML names it relatively)."""
    out = tmp_path_factory.mktemp("robot_add") / "myconf"
    urdf = toy_urdf(out / "urdf")
    rc, stdout, stderr = run_add(f"urdf={urdf}", "name=toyarm", f"out={out}", "samples=100")
    assert rc == 0, stderr
    return SimpleNamespace(urdf=urdf, out=out, path=out / "robot" / "toyarm.yaml", stdout=stdout)


class Oracle:
    """pybullet's own model of a URDF (fixed base): joint positions in, link frames and contacts out."""

    def __init__(self, urdf: Path):
        self.client = pb.connect(pb.DIRECT)
        self.body = pb.loadURDF(str(urdf), useFixedBase=True, physicsClientId=self.client)
        infos = [pb.getJointInfo(self.body, i, physicsClientId=self.client) for i in range(self.num)]
        self.joint = {info[1].decode(): i for i, info in enumerate(infos)}
        self.link = {info[12].decode(): i for i, info in enumerate(infos)}
        self.link[pb.getBodyInfo(self.body, physicsClientId=self.client)[0].decode()] = -1

    @property
    def num(self) -> int:
        return pb.getNumJoints(self.body, physicsClientId=self.client)

    def set(self, names, q) -> None:
        for name, value in zip(names, q):
            pb.resetJointState(self.body, self.joint[name], float(value), physicsClientId=self.client)

    def frame(self, link: str) -> np.ndarray:
        """(4, 4) the URDF frame of `link` in the world (for the base: from its inertial frame)."""
        i = self.link[link]
        if i == -1:
            pos, orn = pb.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
            local = pb.getDynamicsInfo(self.body, -1, physicsClientId=self.client)[3:5]
            pos, orn = pb.multiplyTransforms(pos, orn, *pb.invertTransform(*local))
        else:
            state = pb.getLinkState(self.body, i, computeForwardKinematics=True, physicsClientId=self.client)
            pos, orn = state[4], state[5]
        T = np.eye(4)
        T[:3, :3] = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
        T[:3, 3] = pos
        return T

    def contacts(self, links, exclude) -> list[tuple[str, str, float]]:
        """Pairs of `links` that penetrate, except `exclude`, with pybullet's own collision shapes."""
        skip = {frozenset(p) for p in exclude}
        hits = []
        for a_i, a in enumerate(links):
            for b in links[a_i + 1:]:
                if frozenset((a, b)) in skip:
                    continue
                # a positive query distance: with 0, pybullet missed a penetration of 11 mm (box against box)
                points = pb.getClosestPoints(self.body, self.body, 0.05, self.link[a], self.link[b],
                                             physicsClientId=self.client)
                depth = min((p[8] for p in points), default=math.inf)
                if depth < 0:
                    hits.append((a, b, depth))
        return hits

    def close(self) -> None:
        pb.disconnect(self.client)


def urdf_limits(urdf: Path, joints: list[str]) -> list[tuple[float, float]]:
    """Each joint's limits read straight from the XML (continuous: the documented one turn)."""
    root = ET.parse(urdf).getroot()
    out = []
    for name in joints:
        j = next(e for e in root.findall("joint") if e.get("name") == name)
        limit = j.find("limit")
        out.append((-math.pi, math.pi) if j.get("type") == "continuous"
                   else (float(limit.get("lower")), float(limit.get("upper"))))
    return out


def check_fk(robot, urdf: Path, count: int = 40) -> float:
    """Largest difference between samp's FK of the end effector and pybullet's, over random
    configurations within the limits (position in metres, rotation matrix entries)."""
    oracle = Oracle(urdf)
    try:
        rng = np.random.default_rng(7)
        lo, hi = robot.joint_limits.numpy().T
        worst = 0.0
        for q in rng.uniform(lo, hi, size=(count, robot.dof)):
            oracle.set(robot.joint_names, q)
            want = np.linalg.inv(oracle.frame(robot.base_link)) @ oracle.frame(robot.ee_link)
            got = robot.fk(torch.tensor(q)[None])[robot.ee_link][0].numpy()
            worst = max(worst, float(np.abs(got - want).max()))
        return worst
    finally:
        oracle.close()


def rigid_pairs(robot) -> list[tuple[str, str]]:
    """Collision links with no arm joint between them: the arm cannot change whether they touch, so only
    the geometry decides (pybullet makes one convex hull of a mesh file where samp keeps its convex parts)."""
    def arm_joints_above(link):
        out = set()
        while (joint := robot.urdf.parent_joint(link)) is not None:
            out |= {joint.name} & set(robot.joint_names)
            link = joint.parent
        return out

    links = robot.link_names
    return [(a, b) for i, a in enumerate(links) for b in links[i + 1:] if arm_joints_above(a) == arm_joints_above(b)]


def check_home_free(robot, urdf: Path) -> list:
    """The pairs that pybullet finds penetrating at the robot's home, except the excluded and rigid ones."""
    oracle = Oracle(urdf)
    try:
        oracle.set(robot.joint_names, robot.home.numpy())
        return oracle.contacts(robot.link_names, [*robot.self_collision_exclude, *rigid_pairs(robot)])
    finally:
        oracle.close()


def test_the_yaml_is_written_and_loads(toy):
    from samp.robot import load_robot

    robot = load_robot(toy.path, dtype=torch.float64)
    assert robot.name == "toyarm" and robot.cfg.urdf == "../urdf/toyarm.urdf"  # inside the config folder: relative
    assert robot.joint_names == ["turn", "shoulder", "elbow", "roll", "pitch", "flange"]
    assert (robot.base_link, robot.ee_link) == ("base", "hand")  # below the bare root; the movable chain's tip
    assert robot.link_names == ["base", "column", "upper", "fore", "wrist", "palm", "hand"]
    assert robot.point_link_names == robot.link_names[1:]  # the base does not move
    assert robot.cfg.gripper.joints == [] and len(robot.points) == robot.cfg.points.count
    assert {frozenset(p) for p in robot.self_collision_exclude} >= {frozenset(("upper", "fore")), frozenset(("base", "column"))}
    assert "robot toyarm: 6 joints, 7 collision links" in toy.stdout and f"wrote {toy.path}" in toy.stdout
    assert "python -m samp.train experiment=robot_sdf_quick robot=toyarm" in toy.stdout
    assert f"SAMP_CONFIG_PATH={toy.out}" in toy.stdout  # the folder is not on the config path yet
    assert "continuous joints turn, roll, flange" in toy.path.read_text().lower()  # the range they were given is said
    assert not list(toy.path.parent.glob(".*")), "the draft was left behind"


def test_limits_are_the_urdfs(toy):
    from samp.robot import load_robot_config

    cfg = load_robot_config(toy.path)
    assert list(zip(cfg.lower, cfg.upper)) == urdf_limits(toy.urdf, cfg.joints)


def test_fk_agrees_with_pybullet(toy):
    from samp.robot import load_robot

    worst = check_fk(load_robot(toy.path, dtype=torch.float64), toy.urdf)
    assert worst < 1e-5, f"samp's FK of the end effector differs from pybullet's by {worst}"


def test_home_is_free_of_self_collision_per_pybullet(toy):
    from samp.robot import load_robot

    robot = load_robot(toy.path, dtype=torch.float64)
    assert check_home_free(robot, toy.urdf) == []
    oracle = Oracle(toy.urdf)  # the oracle is not blind: folded onto itself, the arm touches itself
    try:
        oracle.set(robot.joint_names, [0.0, 1.2, 2.9, 0.0, 0.0, 0.0])
        assert oracle.contacts(robot.link_names, robot.self_collision_exclude)
    finally:
        oracle.close()


def test_a_colliding_middle_of_the_limits_gives_the_nearest_free_home(tmp_path):
    """With the elbow folded back over its whole range, the middle of the limits is in collision: the home is
    then a free sampled configuration, and pybullet agrees it is free."""
    from samp.robot import load_robot

    urdf = toy_urdf(tmp_path / "urdf", elbow=(2.75, 3.05))
    rc, stdout, stderr = run_add(f"urdf={urdf}", "name=folded", f"out={tmp_path}", "samples=60")
    assert rc == 0, stderr
    robot = load_robot(tmp_path / "robot" / "folded.yaml", dtype=torch.float64)
    oracle = Oracle(urdf)
    try:
        oracle.set(robot.joint_names, [0.0, 0.0, 2.9, 0.0, 0.0, 0.0])
        assert oracle.contacts(robot.link_names, robot.self_collision_exclude), "the middle should collide"
    finally:
        oracle.close()
    assert "the sampled configuration free of self-collision nearest" in (tmp_path / "robot" / "folded.yaml").read_text()
    assert check_home_free(robot, urdf) == []


@pytest.mark.parametrize("args, message", [
    (["urdf={tmp}/nope.urdf", "name=x"], "does not exist"),
    (["urdf={tmp}/robot/taken.yaml", "name=x"], "is not a readable URDF"),
    (["urdf={urdf}", "name=x", "ee=claw"], "end-effector link 'claw' is not a link of"),
    (["urdf={urdf}", "name=x", "base=upper"], "base link 'upper' moves with joint 'shoulder'"),
    (["urdf={urdf}", "name=x", "ee=base"], "no movable joint between base 'base' and end effector 'base'"),
    (["urdf={urdf}", "name=panda"], "'panda' is one of samp's own robots"),
    (["urdf={urdf}", "name=taken"], "already exists; pass force=true"),
    (["urdf={urdf}", "name=../up"], "not a plain folder name"),
    (["urdf={urdf}"], "add needs name=..."),
    (["urdf={urdf}", "name=x", "samples=0"], "samples=0 must be at least 1"),
    (["urdf={urdf}", "name=x", "colour=red"], "unknown option 'colour' for add"),
])
def test_bad_inputs_exit_2_with_one_line(tmp_path, args, message):
    urdf = toy_urdf(tmp_path / "urdf")
    (tmp_path / "robot").mkdir()
    (tmp_path / "robot" / "taken.yaml").write_text("kept: true\n")
    args = [a.format(tmp=tmp_path, urdf=urdf) for a in args]
    rc, stdout, stderr = run_add(*args, f"out={tmp_path}")
    assert rc == 2 and message in stderr, stderr
    assert stderr.count("\n") == 1 and "Traceback" not in stderr
    assert (tmp_path / "robot" / "taken.yaml").read_text() == "kept: true\n"  # nothing overwritten
    assert sorted(p.name for p in (tmp_path / "robot").iterdir()) == ["taken.yaml"]


def test_unknown_link_lists_the_links(tmp_path):
    rc, _, stderr = run_add(f"urdf={toy_urdf(tmp_path)}", "name=x", "ee=claw", f"out={tmp_path}")
    assert rc == 2 and "its links are: world, base, column, upper, fore, wrist, palm, hand, tcp" in stderr


def test_the_exclusion_tool_prints_the_same_rule(robots):
    """tools/self_collision_pairs.py and `add` share samp.robot.self_collision: the Panda's configured
    exclusions are what the rule proposes (adjacent links), and the home is free with them."""
    from samp.robot.self_collision import propose_exclusions

    panda = robots["panda"]
    report = propose_exclusions(panda, samples=20, home=panda.home.numpy())
    assert {frozenset(p) for p in report.rows} == {frozenset(p) for p in panda.self_collision_exclude}
    assert all("adjacent" in why for why in report.reasons.values())
    assert report.samples.shape == (20, 7) and report.free.shape == (20,)


@pytest.mark.slow
def test_an_arm_from_pybullet_data_with_a_gripper(tmp_path, _isolated_cache):
    """pybullet_data's xArm 6 with its gripper: the gripper's joints (revolute knuckles, not a parallel
    prismatic gripper) are held, its links carry points, FK and home agree with pybullet."""
    import pybullet_data

    from samp.robot import load_robot

    urdf = Path(pybullet_data.getDataPath()) / "xarm" / "xarm6_with_gripper.urdf"
    rc, stdout, stderr = run_add(f"urdf={urdf}", "name=xarm6_gripper", f"out={tmp_path}", "samples=60")
    assert rc == 0, stderr
    robot = load_robot(tmp_path / "robot" / "xarm6_gripper.yaml", dtype=torch.float64)
    assert robot.cfg.urdf == "pybullet_data://xarm/xarm6_with_gripper.urdf"
    assert robot.joint_names == [f"joint{i}" for i in range(1, 7)] and robot.ee_link == "xarm_gripper_base_link"
    assert robot.base_link == "link_base"  # as in conf/robot/xarm6.yaml: the first link below the bare root
    assert {"left_finger", "right_finger"} <= set(robot.point_link_names)
    assert list(zip(robot.cfg.lower, robot.cfg.upper)) == urdf_limits(urdf, robot.joint_names)
    worst = check_fk(robot, urdf)
    assert worst < 1e-5, f"samp's FK of the end effector differs from pybullet's by {worst}"
    assert check_home_free(robot, urdf) == []
    print(f"\nxarm6_gripper: FK of {robot.ee_link} within {worst:.1e} of pybullet's over 40 configurations")


def _cli(env: dict, *args: str) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=900, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


@pytest.mark.slow
def test_end_to_end_robot_sdf_and_a_smoke_policy(tmp_path, _isolated_cache):
    """The commands `add` prints, shrunk, run as a user would: the config folder on SAMP_CONFIG_PATH."""
    out = tmp_path / "myconf"
    urdf = toy_urdf(out / "urdf")
    env = {**os.environ, "SAMP_RUNS_DIR": str(tmp_path / "runs"), "SAMP_DATASETS_DIR": str(tmp_path / "datasets"),
           "SAMP_CONFIG_PATH": str(out), "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1"}
    env.pop("SAMP_CONF_DIR", None)
    added = _cli(env, "samp.robot", "add", f"urdf={urdf}", "name=toyarm", "samples=100")
    assert "SAMP_CONFIG_PATH=" not in added.stdout  # the folder is already on the path: plain commands
    assert "python -m samp.train experiment=robot_sdf_quick robot=toyarm" in added.stdout
    _cli(env, "samp.robot", "show", "robot=toyarm", "configs=1")
    assert (tmp_path / "runs" / "robot" / "toyarm" / "robot.rrd").is_file()
    _cli(env, "samp.train", "experiment=robot_sdf_quick", "robot=toyarm", *SDF_TINY.split())
    (sdf_run,) = (tmp_path / "runs" / "robot_sdf_toyarm_quick").iterdir()
    record = json.loads((sdf_run / "run.json").read_text())
    mae = record["metrics"]["eval/whole_robot/mae_all_mm"]
    assert record["status"] == "completed" and 0 < mae < 100, mae
    print(f"\ntoyarm robot SDF (tiny): whole-robot MAE {mae:.2f} mm")
    _cli(env, "samp.data", "generate", "dataset=smoke", "dataset.robot=toyarm", "dataset.name=toyarm_smoke")
    _cli(env, "samp.train", "experiment=quickstart", "robot=toyarm", "datamodule.dataset=toyarm_smoke",
         "evaluation.benchmark=null", *POLICY_TINY.split())
    (run,) = (tmp_path / "runs" / "quickstart").iterdir()
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "completed" and record["dataset_id"].startswith("toyarm_smoke@")
    assert record["config"]["robot"]["name"] == "toyarm"
    assert (run / "plots" / "summary.png").is_file()  # drawn with the run's robot (it once took the Panda)
    report = json.loads((run / "eval" / "metrics.json").read_text())
    samp_val = report["metrics"]["val"]
    assert samp_val["problems"] == 2 and 0 <= samp_val["success_rate"] <= 1
    assert report["expert"]["train"]["success_rate"] == 1.0  # the expert's own stored solutions, on the new arm
    print(f"toyarm smoke policy (4 batches): val success {samp_val['success_rate']:.2f} over {samp_val['problems']} "
          f"problems, reach {samp_val['reach_rate']:.2f}; the expert {report['expert']['val']['success_rate']:.2f}")


def test_a_robot_without_its_own_robot_sdf_experiment_gets_the_generic_one():
    """`build_missing.robot_sdf` of the quickstart policy (system.robot_sdf: robot_sdf_<robot>_quick) trains
    a new robot's SDF with experiment=robot_sdf_quick robot=NAME; the Panda keeps its own experiment."""
    from samp.train.prerequisites import build_overrides

    assert build_overrides("robot_sdf_toyarm_quick", "toyarm") == ["experiment=robot_sdf_quick", "robot=toyarm"]
    assert build_overrides("robot_sdf_panda_quick", "panda") == ["experiment=robot_sdf_panda_quick"]
    assert build_overrides("robot_sdf_toyarm_nope", "toyarm") is None
    assert build_overrides("robot_sdf_panda_quick", "toyarm") is None  # another robot's SDF is never built for it


def test_out_defaults_to_the_first_config_folder_and_the_robot_is_found_by_name(tmp_path, monkeypatch):
    """With SAMP_CONFIG_PATH set, `add` writes into its first folder, the robot loads by name like a packaged
    one, and the commands it prints need no prefix."""
    from samp.robot import available_robots, load_robot

    mine, other = tmp_path / "mine", tmp_path / "other"
    mine.mkdir(), other.mkdir()
    monkeypatch.setenv("SAMP_CONFIG_PATH", f"{mine}{os.pathsep}{other}")
    rc, stdout, stderr = run_add(f"urdf={toy_urdf(tmp_path / 'urdf')}", "name=myarm", "samples=20")
    assert rc == 0, stderr
    assert (mine / "robot" / "myarm.yaml").is_file() and not (other / "robot").exists()
    assert "myarm" in available_robots() and load_robot("myarm").cfg.source_dir == str(mine / "robot")
    assert "\n  python -m samp.train experiment=robot_sdf_quick robot=myarm\n" in stdout


@pytest.mark.slow
def test_the_pandas_urdf_gives_back_the_hand_written_panda(tmp_path, robots):
    """Against a hand-written ground truth: from pybullet_data's Panda URDF, `add` finds conf/robot/panda.yaml's
    base, arm joints, gripper (prismatic fingers held open at 4 cm), collision and point links and exclusions.
    (The end effector differs by a fixed joint: the hand, where panda.yaml names its grasp frame; the limits
    are the URDF's, where panda.yaml takes the real arm's soft limits.)"""
    import pybullet_data

    from samp.robot import load_robot_config

    urdf = Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf"
    rc, _, stderr = run_add(f"urdf={urdf}", "name=panda_again", f"out={tmp_path}", "samples=50")
    assert rc == 0, stderr
    got, want = load_robot_config(tmp_path / "robot" / "panda_again.yaml"), robots["panda"].cfg
    for key in ("urdf", "base_link", "joints", "gripper", "collision_links", "point_links"):
        assert getattr(got, key) == getattr(want, key), key
    assert {frozenset(p) for p in got.self_collision_exclude} == {frozenset(p) for p in want.self_collision_exclude}
    assert robots["panda"].urdf.parent_joint(want.ee_link).parent == got.ee_link == "panda_hand"
