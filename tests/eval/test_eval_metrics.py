"""Checks and metrics on synthetic trajectories with known answers (docs/design.md section 4)."""

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


# ---------------------------------------------------------------- the metric registry pins today's output
def _problem(reached: tuple[bool, bool], length, time, steps: list[float], termination: str = "reached",
             collision: float | None = None, self_collision: bool = False, limits: bool = False,
             batch: tuple[int, float] = (0, 1.0), alone: tuple[float, list[float]] | None = None) -> dict:
    """A hand-made record: `reached` at (2cm, 1cm), `collision` the penetration depth when it collided,
    `batch` (index, seconds) of its rollout batch, `alone` its (solution time, step times) at B = 1."""
    return {"reached": {"2cm": reached[0], "1cm": reached[1]}, "collision": collision is not None,
            "self_collision": self_collision, "joint_limit_violation": limits, "path_length": length,
            "solution_time": time, "step_times": steps, "steps": len(steps),
            "collision_depth": 0.0 if collision is None else collision, "termination": termination,
            "batch": batch[0], "batch_time": batch[1], "solution_time_b1": None if alone is None else alone[0],
            "step_times_b1": [] if alone is None else alone[1]}


# Six problems in two batches (0.6 s and 0.8 s), two of them also timed alone; the expected metrics are
# worked out by hand below.
PINNED = [
    _problem((True, True), 1.0, 0.2, [0.01, 0.03], batch=(0, 0.6), alone=(0.1, [0.005, 0.015])),  # success 2, 1 cm
    _problem((True, False), 2.0, 0.4, [0.02], batch=(0, 0.6), alone=(0.3, [0.01])),  # success at 2 cm only
    _problem((True, True), 4.0, 0.6, [0.04], collision=0.05, batch=(0, 0.6)),        # reached, collided
    _problem((False, False), None, None, [0.02, 0.02, 0.02], "stalled", self_collision=True, batch=(1, 0.8)),
    _problem((True, False), 3.0, 0.8, [0.02, 0.02], collision=0.03, limits=True, batch=(1, 0.8)),
    _problem((False, False), 5.0, None, [0.06], "max_steps", batch=(1, 0.8)),
]


def _wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """An independent oracle for the Wilson interval: the two p with (k/n - p)^2 = z^2 p (1 - p) / n."""
    ph = k / n
    roots = np.sort(np.roots([1 + z * z / n, -(2 * ph + z * z / n), ph * ph]).real)
    return float(roots[0]), float(roots[1])


def _with_intervals(rates: dict[str, tuple[int, int]]) -> dict:
    """{key: (k, n)} -> {key: k/n, key_ci_low: .., key_ci_high: ..} (the "@tol" suffix stays last)."""
    out = {}
    for key, (k, n) in rates.items():
        name, at, tol = key.partition("@")
        low, high = _wilson(k, n)
        out.update({key: k / n, f"{name}_ci_low{at}{tol}": low, f"{name}_ci_high{at}{tol}": high})
    return out


def test_wilson_interval_against_the_quadratic_and_published_values():
    from samp.eval.metrics import wilson_interval

    for k, n in [(0, 10), (1, 6), (2, 6), (5, 10), (10, 10), (95, 100), (380, 400)]:
        assert wilson_interval(k, n) == pytest.approx(_wilson(k, n), abs=1e-12), (k, n)
    assert wilson_interval(2, 6) == pytest.approx((0.0968, 0.7000), abs=1e-4)  # Wilson (1927), tabulated
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert wilson_interval(0, 0) == (None, None)
    # the width the benchmark is sized for: n = 384 keeps a 95 % interval within +-5 points at any rate
    assert max(np.subtract(*wilson_interval(k, 384)[::-1]) / 2 for k in range(385)) < 0.05


def test_summarize_keeps_its_keys_order_and_values():
    """Every key metrics.json has had, in its order, with values worked out by hand (population std)."""
    m = summarize(PINNED, RolloutConfig())
    # violations: problems 2 (collision), 3 (self-collision), 4 (collision and limits)
    # successes: problems 0 and 1 at 2 cm, problem 0 at 1 cm; reached: 0, 1, 2, 4 at 2 cm, 0 and 2 at 1 cm
    # path length over the successes {1, 2}: 1.5 ± 0.5; over every known length {1, 2, 4, 3, 5}: 3 ± sqrt(2)
    # solution time over {0.2, 0.4, 0.6, 0.8}: 0.5 ± sqrt(0.05)
    # step times {0.01, 0.03, 0.02, 0.04, 0.02 x5, 0.06}: mean 0.26 / 10, squared deviations sum to 0.00184
    # every rate comes with its Wilson 95 % interval (keys `<name>_ci_low`, `<name>_ci_high`)
    expected = {
        "problems": 6,
        **_with_intervals({"success_rate@2cm": (2, 6), "reach_rate@2cm": (4, 6), "success_rate@1cm": (1, 6),
                           "reach_rate@1cm": (2, 6), "success_rate": (2, 6), "reach_rate": (4, 6),
                           "collision_rate": (2, 6), "self_collision_rate": (1, 6), "joint_limit_rate": (1, 6),
                           "violation_rate": (3, 6)}),
        "path_length_mean": 1.5, "path_length_std": 0.5,
        "path_length_all_mean": 3.0, "path_length_all_std": np.sqrt(2.0),
        "solution_time_mean": 0.5, "solution_time_std": np.sqrt(0.05),
        "inference_time_mean": 0.026, "inference_time_std": np.sqrt(0.00184 / 10),
        # B = 1: solution times {0.1, 0.3}; step times {0.005, 0.015, 0.01}; 6 problems in 0.6 + 0.8 s batched
        "solution_time_b1_mean": 0.2, "solution_time_b1_std": 0.1,
        "step_time_b1_mean": 0.01, "step_time_b1_std": np.sqrt(0.00005 / 3),
        "timed_problems": 2, "throughput": 6 / 1.4,
        "steps_mean": 10 / 6,
        "collision_depth_mean": 0.04, "collision_depth_max": 0.05,
        "terminations": {"reached": 4, "stalled": 1, "max_steps": 1},
    }
    assert list(m) == list(expected), f"keys: expected {list(expected)}, got {list(m)}"
    for key, want in expected.items():
        assert m[key] == pytest.approx(want, rel=1e-9), f"{key}: expected {want}, got {m[key]}"
    assert list(m["terminations"]) == ["reached", "stalled", "max_steps"], "in order of first appearance"
    assert type(m["problems"]) is int and all(type(m[k]) is float for k in expected if k.endswith(("rate", "_mean")))


def test_summarize_without_successes_collisions_or_problems():
    nothing = [_problem((False, False), 2.0, 0.5, [0.01], "max_steps")]
    m = summarize(nothing, RolloutConfig(report_tolerances=[]))
    assert [k for k in m if "@" in k] == ["success_rate@2cm", "success_rate_ci_low@2cm", "success_rate_ci_high@2cm",
                                          "reach_rate@2cm", "reach_rate_ci_low@2cm", "reach_rate_ci_high@2cm"], \
        "one tolerance: one rate and its interval each"
    assert m["success_rate_ci_low"] == 0.0 and m["success_rate_ci_high"] == pytest.approx(_wilson(0, 1)[1])
    assert m["success_rate"] == 0.0 and m["path_length_mean"] is None and m["path_length_std"] is None
    assert m["path_length_all_mean"] == 2.0 and m["path_length_all_std"] == 0.0
    assert m["collision_depth_mean"] is None and m["collision_depth_max"] is None
    assert summarize([], RolloutConfig()) == {"problems": 0}


def test_markdown_table_keeps_its_header_cells_and_note():
    from samp.eval.metrics import TABLE_COLUMNS, markdown_table

    cfg = RolloutConfig()
    table = markdown_table([("samp", "heldout", summarize(PINNED, cfg)), ("expert", "train", {})], cfg)
    # soln. time 0.5 ± sqrt(0.05) = 0.2236; path length 1.5 ± 0.5; rates in percent to one decimal;
    # step time at B = 1: 10 ± 1e3 * sqrt(0.00005 / 3) = 4.08 ms; soln. time at B = 1: 0.2 ± 0.1 s; batched:
    # 6 / 1.4 s = 4.3 problems/s; rates with their Wilson intervals (2/6: [9.7, 70.0], 1/6: [3.0, 56.4],
    # 4/6: [30.0, 90.3])
    expected = (
        "| planner | group | problems | soln. time B=1 [s] | path length [m] | success@2cm [%] | success@1cm [%] "
        "| reach@2cm [%] | reach@1cm [%] | collision [%] | self-coll. [%] | joint limits [%] | step B=1 [ms] "
        "| batched [problems/s] |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
        "| samp | heldout | 6 | 0.200 ± 0.100 | 1.50 ± 0.50 | 33.3 [9.7, 70.0] | 16.7 [3.0, 56.4] | 66.7 [30.0, 90.3] "
        "| 33.3 [9.7, 70.0] | 33.3 [9.7, 70.0] | 16.7 [3.0, 56.4] | 16.7 [3.0, 56.4] | 10.00 ± 4.08 | 4.3 |\n"
        "| expert | train | 0 | - | - | - | - | - | - | - | - | - | - | - |\n"
        "\n"
        "Reached: end-effector within 2cm and 15 deg at the end of the rollout (which stops at 2cm); success: "
        "reached with no collision, self-collision or joint-limit violation. Rates: percent [Wilson 95 % interval]. "
        "Path length: mean ± std over successful problems. Solution and step time: one problem at a time (B = 1), "
        "over the problems timed so; batched: problems per second in the batched rollouts the outcomes come from.\n")
    assert table == expected, f"expected\n{expected}\ngot\n{table}"
    assert TABLE_COLUMNS == ["planner", "group", "problems", "soln. time B=1 [s]", "path length [m]", "success [%]",
                             "reach [%]", "collision [%]", "self-coll. [%]", "joint limits [%]", "step B=1 [ms]",
                             "batched [problems/s]"]


def test_the_registry_names_what_each_consumer_used_to_list():
    """The registry's sets are the tuples the consumers spelled out before it existed."""
    from samp.eval.callback import LOGGED_METRICS, MONITOR
    from samp.eval.metrics import flat_metrics, logged_metrics, metric_keys, table_metrics

    assert logged_metrics() == LOGGED_METRICS == (
        "success_rate", "reach_rate", "collision_rate", "self_collision_rate", "joint_limit_rate", "path_length_mean",
        "solution_time_mean", "inference_time_mean", "steps_mean")
    assert MONITOR == "success_rate"
    # run.json: the rates, the path length, and the times as the paper's tables give them (B = 1), throughput
    assert flat_metrics() == ("success_rate", "reach_rate", "collision_rate", "path_length_mean",
                              "solution_time_b1_mean", "step_time_b1_mean", "throughput")
    assert metric_keys(flat=True, rate=True) == ("success_rate", "reach_rate", "collision_rate")
    assert metric_keys(curve=True) == ("success_rate", "reach_rate")
    assert [m.name for m in table_metrics()] == ["solution_time_b1", "path_length", "success_rate", "reach_rate",
                                                 "collision_rate", "self_collision_rate", "joint_limit_rate",
                                                 "step_time_b1", "throughput"]


def test_the_registry_refuses_unknown_names_and_bad_definitions():
    from samp.eval.metrics import Column, Metric, metric, recorded

    assert metric("path_length").key == "path_length_mean" and metric("collision_rate").key == "collision_rate"
    with pytest.raises(ValueError, match="no metric 'sucess_rate'; registered: success_rate, reach_rate"):
        metric("sucess_rate")
    with pytest.raises(ValueError, match="stats must be one of"):
        Metric("odd", recorded("steps"), "median")
    with pytest.raises(ValueError, match="a table column shows a rate, a mean_std or a throughput"):
        Metric("odd", recorded("termination"), "counts", column=Column("odd", "%", digits=1, rank=99))
    with pytest.raises(ValueError, match="logged=True"):
        Metric("odd", recorded("collision"), "rate", curve=True)


def test_a_metric_added_to_the_registry_reaches_summarize_and_the_table(monkeypatch):
    """Adding a metric is one entry in METRICS: here a stall rate, as a column after the step time."""
    from samp.eval import metrics
    from samp.eval.metrics import METRICS, Column, Metric, markdown_table

    stall = Metric("stall_rate", lambda r, tol: r["termination"] == "stalled", "rate",
                   column=Column("stalled", "%", digits=1, rank=95), logged=True)
    monkeypatch.setattr(metrics, "METRICS", (*METRICS, stall))
    m = summarize(PINNED, RolloutConfig())
    assert list(m)[-4:] == ["terminations", "stall_rate", "stall_rate_ci_low", "stall_rate_ci_high"]
    assert m["stall_rate"] == pytest.approx(1 / 6) and m["stall_rate_ci_low"] == pytest.approx(_wilson(1, 6)[0])
    assert metrics.logged_metrics()[-1] == "stall_rate"
    lines = markdown_table([("samp", "heldout", m)], RolloutConfig()).splitlines()
    assert lines[0].endswith("| step B=1 [ms] | batched [problems/s] | stalled [%] |") and lines[2].endswith("| 10.00 ± 4.08 | 4.3 | 16.7 [3.0, 56.4] |"), lines


def test_the_metrics_module_stays_below_samp_runs():
    """samp.runs reads samp.eval.metrics, never the other way round."""
    import subprocess
    import sys

    code = "import sys, samp.eval.metrics; print(sorted(m for m in sys.modules if m.startswith('samp.runs')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]", f"expected no samp.runs module imported by samp.eval.metrics, got {out}"
