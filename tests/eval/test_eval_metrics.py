"""Checks and metrics on synthetic trajectories with known answers (DESIGN section 4)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from samp.eval import PlannedTrajectory, Problem, evaluate, polyline_length, summarize
from samp.eval.checks import goal_errors
from samp.eval.config import RolloutConfig, rollout_config
from samp.scene import Box, Pose, Scene
from samp.sim import LinkBodies

EMPTY = Scene(name="empty")
# A vertical plate in the x-z plane at y = 0, in front of the base: the arm at home lies in that plane.
PLATE = Scene(name="plate", obstacles=(Box("plate", (0.3, 0.02, 0.4), Pose((0.31, 0.0, 0.55))),))


class Replay:
    """A trajectory planner that answers every problem with one given trajectory."""

    name = "replay"

    def __init__(self, trajectory: np.ndarray, solution_time: float = 0.25):
        self.trajectory, self.time = np.asarray(trajectory, dtype=np.float64), solution_time

    def plan(self, problem) -> PlannedTrajectory:
        return PlannedTrajectory(self.trajectory, self.time)


def _one(robot, scene, traj, goal=None, **cfg) -> dict:
    traj = np.asarray(traj, dtype=np.float64)
    problem = Problem(scene, traj[0], traj[-1] if goal is None else goal)
    result = evaluate(Replay(traj), [problem], cfg or None, robot=robot)
    return result["records"][0]


def _sweep(robot, lo: float, hi: float, count: int) -> np.ndarray:
    """(count, n) home with joint 1 (the base yaw) going from lo to hi."""
    traj = np.tile(robot.home.numpy(), (count, 1))
    traj[:, 0] = np.linspace(lo, hi, count)
    return traj


def _oracle_min_sdf(robot, scene, traj: np.ndarray, step: float = 0.005) -> np.ndarray:
    """Per segment end (waypoint 1..W-1): the smallest scene SDF of points on the exact link surfaces over
    states every `step` rad along the segment. Independent of pybullet (trimesh samples, analytic SDF)."""
    surface = {name: torch.as_tensor(trimesh.sample.sample_surface(mesh, 400, seed=0)[0], dtype=torch.float64)
               for name, mesh in robot.link_meshes.items() if name != robot.base_link}
    out = []
    for a, b in zip(traj[:-1], traj[1:]):
        k = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        states = torch.as_tensor(a + np.linspace(0, 1, k + 1)[1:, None] * (b - a))
        fk = robot.fk(states)
        d = min(float(scene.sdf(pts @ fk[n][:, :3, :3].transpose(1, 2) + fk[n][:, None, :3, 3]).min())
                for n, pts in surface.items())
        out.append(d)
    return np.array(out)


def test_polyline_length_of_a_known_polyline():
    points = np.array([[0, 0, 0], [3, 4, 0], [3, 4, 12], [3, 4, 12]], dtype=float)
    assert polyline_length(points) == pytest.approx(5 + 12, abs=1e-12)
    assert polyline_length(points[:1]) == 0.0


def test_path_length_of_a_base_rotation_is_the_sum_of_chords(panda):
    """Turning only the base joint moves the end effector on a circle of radius r about the base axis:
    each waypoint step of dtheta adds a chord 2 r sin(dtheta / 2)."""
    traj = _sweep(panda, -0.6, 0.9, 16)
    ee = panda.fk(torch.as_tensor(traj[:1]))[panda.ee_link][0, :3, 3].numpy()
    r = np.hypot(ee[0], ee[1])
    expected = 15 * 2 * r * np.sin(0.1 / 2)
    rec = _one(panda, EMPTY, traj)
    assert rec["path_length"] == pytest.approx(expected, rel=1e-9), f"expected {expected}, got {rec['path_length']}"
    assert rec["joint_path_length"] == pytest.approx(1.5, rel=1e-12)
    assert not rec["collision"] and rec["reached"]["2cm"] and rec["success"]["2cm"]


def test_a_path_through_a_box_collides_where_the_oracle_says(panda):
    traj = _sweep(panda, -1.2, 1.2, 25)  # 0.1 rad per waypoint, through the plate at 0
    oracle = _oracle_min_sdf(panda, PLATE, traj)
    assert oracle.min() < -0.005, "the test scene should put the plate (2 cm thick) through the arm"
    expected_step = int(np.flatnonzero(oracle < 0)[0]) + 1
    rec = _one(panda, PLATE, traj)
    assert rec["collision"], "a sweep through the plate must collide"
    assert abs(rec["first_collision_step"] - expected_step) <= 1, \
        f"first collision: oracle step {expected_step}, got {rec['first_collision_step']}"
    assert rec["collision_depth"] > 0.005, f"expected a deep penetration, got {rec['collision_depth']}"
    assert rec["reached"]["2cm"] and not rec["success"]["2cm"], "reached but collided: no success"
    assert not rec["self_collision"] and not rec["joint_limit_violation"]

    clear = _sweep(panda, -1.2, -0.9, 4)  # stops short of the plate
    assert _oracle_min_sdf(panda, PLATE, clear).min() > 0.0
    rec = _one(panda, PLATE, clear)
    assert not rec["collision"] and rec["first_collision_step"] is None and rec["collision_depth"] == 0.0


def test_a_path_ending_inside_the_tolerance_is_reached(panda):
    """A base rotation of delta moves the end effector by the chord 2 r sin(delta / 2) and turns it by delta."""
    home = panda.home.numpy()
    ee = panda.fk(torch.as_tensor(home[None]))[panda.ee_link][0, :3, 3].numpy()
    r = np.hypot(ee[0], ee[1])
    delta = 2 * np.arcsin(0.015 / (2 * r))  # a 15 mm miss
    end = home.copy()
    end[0] += delta
    rec = _one(panda, EMPTY, [home - [0.3, 0, 0, 0, 0, 0, 0], end], goal=home)
    assert rec["position_error"] == pytest.approx(0.015, abs=1e-9)
    assert rec["orientation_error"] == pytest.approx(np.degrees(delta), abs=1e-6)
    assert rec["reached"] == {"2cm": True, "1cm": False}, rec["reached"]
    assert rec["success"] == {"2cm": True, "1cm": False}

    turned = home.copy()
    turned[6] += np.radians(20)  # the flange turns about an axis through the end effector: no position error
    rec = _one(panda, EMPTY, [home, turned], goal=home)
    assert rec["position_error"] < 1e-9 and rec["orientation_error"] == pytest.approx(20, abs=1e-6)
    assert rec["reached"] == {"2cm": False, "1cm": False}, "20 degrees off is beyond the 15 degree tolerance"


def test_goal_errors_of_a_known_rotation_and_offset():
    goal = np.eye(4)[None]
    pose = np.eye(4)[None].copy()
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    pose[0, :3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    pose[0, :3, 3] = [0.003, 0.004, 0.0]
    pos, rot = goal_errors(pose, goal)
    assert pos[0] == pytest.approx(0.005) and rot[0] == pytest.approx(30.0)


def test_a_path_outside_the_limits_is_a_violation(panda):
    home = panda.home.numpy()
    beyond = home.copy()
    beyond[3] = panda.joint_limits[3, 1].item() + 0.05  # elbow past its upper limit
    rec = _one(panda, EMPTY, [home, beyond, home])
    assert rec["joint_limit_violation"] and rec["first_limit_step"] == 1
    assert rec["reached"]["2cm"] and not rec["success"]["2cm"]
    assert not rec["collision"]


def test_a_folded_arm_is_a_self_collision(panda):
    folded = np.array([0.0, 1.76, 0.0, -3.07, 0.0, 0.2, 0.0])
    with LinkBodies(panda) as bodies:  # the oracle: pairwise link contacts, not World
        bodies.set_q(folded)
        assert bodies.colliding_pairs(exclude=panda.self_collision_exclude)
    rec = _one(panda, EMPTY, [panda.home.numpy(), folded])
    assert rec["self_collision"] and rec["first_self_collision_step"] == 1
    assert not rec["collision"] and not rec["success"]["2cm"]


def _record(reached: bool, collision=False, self_collision=False, limits=False, length=1.0, time=0.5, steps=(0.01,)):
    return {"reached": {"2cm": reached, "1cm": False}, "collision": collision, "self_collision": self_collision,
            "joint_limit_violation": limits, "path_length": length, "solution_time": time, "step_times": list(steps),
            "steps": len(steps), "collision_depth": 0.01 if collision else 0.0, "termination": "reached"}


def test_summarize_rates_means_and_stds():
    records = [_record(True, length=1.0), _record(True, length=3.0), _record(True, collision=True, length=10.0),
               _record(False, self_collision=True), _record(True, limits=True), _record(False, time=1.5)]
    m = summarize(records, RolloutConfig())
    assert m["problems"] == 6
    assert m["success_rate"] == pytest.approx(2 / 6) and m["reach_rate"] == pytest.approx(4 / 6)
    assert m["success_rate@1cm"] == 0.0
    assert m["collision_rate"] == pytest.approx(1 / 6) and m["self_collision_rate"] == pytest.approx(1 / 6)
    assert m["joint_limit_rate"] == pytest.approx(1 / 6) and m["violation_rate"] == pytest.approx(3 / 6)
    assert m["path_length_mean"] == pytest.approx(2.0) and m["path_length_std"] == pytest.approx(1.0)
    assert m["solution_time_mean"] == pytest.approx((5 * 0.5 + 1.5) / 6)
    assert m["collision_depth_mean"] == pytest.approx(0.01)


def test_rollout_config_refuses_unknown_keys_and_bad_values():
    with pytest.raises(ValueError, match="max_step.*Valid keys: max_steps"):
        rollout_config({"max_step": 10})
    with pytest.raises(ValueError, match="stall_steps"):
        rollout_config({"stall_steps": 0})


def test_the_float64_copy_of_a_float32_robot_keeps_its_exact_limits(panda):
    """Checks run on a float64 copy of the policy's robot; its limits must be the config's, not float32's."""
    from samp.eval.checks import exact_robot
    from samp.robot import load_robot

    copy = exact_robot(load_robot("panda", dtype=torch.float32))
    assert copy.dtype == torch.float64
    torch.testing.assert_close(copy.joint_limits, panda.joint_limits, rtol=0, atol=0)
    torch.testing.assert_close(copy.home, panda.home, rtol=0, atol=0)
