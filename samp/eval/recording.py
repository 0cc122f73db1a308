"""One Rerun recording per evaluation (`write_recording`): every rollout on one `frame` timeline, in the
robot's base frame with z up, its recording id derived from where it is written (`recording_id_for`).

Per rollout: the scene (re-drawn when it changes) with a horizontal SDF slice through the goal's
height, the end-effector path of the planner (green: success, red: failure) and of the expert beside it
(blue), start and goal markers, and a collision marker at the robot point deepest in an obstacle at the
first colliding state. The first `record_rollouts` rollouts are animated step by step: the robot's
visual meshes (from its URDF) move along the trajectory, `record_points` robot points are coloured by their exact environment
distance (the collision risk), and the closest point's distance and the goal error are plotted. The
other rollouts get one frame (the robot at its final configuration), which keeps 100 or more rollouts a
file of a few MB.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from samp.console import plural
from samp.eval.checks import exact_robot
from samp.eval.problems import Problem

__all__ = ["APPLICATION_ID", "recording_id_for", "write_recording"]

APPLICATION_ID = "samp_eval"


def recording_id_for(path: str | Path, planner: str) -> str:
    """The recording id of an evaluation written to `path`: a UUID derived from the file's absolute path
    and the planner, so each run's recording is its own when several are opened together
    (`rerun A.rrd B.rrd`), and writing the same run again gives the same id."""
    import uuid

    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"samp-eval:{planner}:{Path(path).resolve()}"))

RISK_CLEAR = 0.1  # metres: points this far from obstacles are drawn fully green
SLICE_N_E = 100  # anchors per axis of the drawn SDF slice (the paper's n_e)


def _ee(robot, traj: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return robot.fk(torch.as_tensor(traj, dtype=robot.dtype))[robot.ee_link][:, :3, 3].numpy()


def _fmt(value, digits: int, unit: str) -> str:
    return "-" if value is None else f"{value:.{digits}f} {unit}"


def _summary(problem: Problem, record: dict, index: int) -> str:
    """Markdown: what happened in one rollout."""
    primary = next(iter(record["success"]))  # the stopping tolerance comes first
    first = record["first_collision_step"]
    collision = "no" if first is None else f"at step {first}, {1000 * record['collision_depth']:.1f} mm deep"
    return "\n".join([
        f"### rollout {index}: {'success' if record['success'][primary] else 'failure'} (within {primary})", "",
        f"- problem: `{problem.name or '-'}` ({problem.split}), scene {problem.scene.name}",
        f"- planner: {record['planner']}, {plural(record['steps'], 'step')}, ended: {record['termination']}",
        f"- final error: {_fmt(record['position_error'], 4, 'm')}, {_fmt(record['orientation_error'], 1, 'deg')}",
        f"- collision: {collision}; self-collision: {record['self_collision']}; "
        f"joint limits: {record['joint_limit_violation']}",
        f"- path length: {_fmt(record['path_length'], 3, 'm')}; solution time: {_fmt(record['solution_time'], 4, 's')}",
    ])


class _Writer:
    def __init__(self, rec, robot, slice_n_e: int, points: int):
        self.rec, self.robot, self.slice_n_e = rec, robot, slice_n_e
        m = len(robot.points)
        self.subset = np.sort(np.random.default_rng(0).choice(m, size=min(points, m), replace=False))
        self.frame, self.scene_key = 0, None

    def time(self, rollout: int, step: int) -> None:
        # Two timelines that never go back: `frame` (each rollout a run of frames after the one before) and
        # `rollout`. The step within a rollout is shown in the plots (`plots/step`), not as a timeline of its
        # own: one that restarted at every rollout would lay all rollouts over each other.
        self.rec.set_time("frame", sequence=self.frame)
        self.rec.set_time("rollout", sequence=rollout)

    def scene(self, problem: Problem, goal_z: float) -> None:
        from samp.scene import anchor_points
        from samp.viz import nearest_anchor_index
        from samp.viz.rollout import log_scene_frame, log_sdf_plane

        key = problem.scene.content_hash()
        if key == self.scene_key:
            return
        self.scene_key = key
        log_scene_frame(self.rec, problem.scene)
        # The z = goal height plane of the anchor grid at slice_n_e, from the exact SDF: the plane alone,
        # not the whole grid (n_e^2 instead of n_e^3 distances).
        bounds, n_e = problem.scene.bounds, self.slice_n_e
        index = int(nearest_anchor_index([0.0, 0.0, goal_z], n_e, bounds)[2])
        plane = problem.scene.sdf(anchor_points(n_e, bounds)[:, :, index])  # (n_e, n_e) indexed (x, y)
        log_sdf_plane(self.rec, np.asarray(plane), 2, index, bounds, vmax=0.3)

    def robot_at(self, problem: Problem, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q (T, n) -> robot points (T, M, 3) and their exact environment distances (T, M)."""
        with torch.no_grad():
            pts = self.robot.transform_points(torch.as_tensor(q, dtype=self.robot.dtype))  # (T, M, 3)
        d = problem.scene.sdf(pts.reshape(-1, 3)).reshape(pts.shape[:2])
        return pts.numpy(), np.asarray(d)

    def rollout(self, k: int, problem: Problem, record: dict, expert: dict | None, animate: bool) -> None:
        import rerun as rr

        from samp.viz.rollout import PATH_COLORS, log_markers, log_path, log_robot_state

        rec, robot = self.rec, self.robot
        traj = np.asarray(record["trajectory"])
        ee = _ee(robot, traj)
        goal = _ee(robot, problem.q_goal[None])[0]
        success = record["success"][next(iter(record["success"]))]
        self.time(k, 0)
        self.scene(problem, goal[2])
        log_path(rec, "world/paths/planner", ee, PATH_COLORS["success" if success else "failure"])
        log_path(rec, "world/paths/expert", None if expert is None else _ee(robot, np.asarray(expert["trajectory"])),
                 PATH_COLORS["expert"])
        log_markers(rec, "world/markers/start", ee[:1], PATH_COLORS["start"], 0.015)
        log_markers(rec, "world/markers/goal", goal[None], PATH_COLORS["success" if success else "goal"], 0.02,
                    labels=["goal: " + ("reached" if record["reached"][next(iter(record["reached"]))] else "missed")])
        hit = None
        if record["first_collision_state"] is not None:
            pts, d = self.robot_at(problem, np.asarray(record["first_collision_state"])[None])
            hit = pts[0, int(np.argmin(d[0]))][None]
        log_markers(rec, "world/markers/collision", hit, PATH_COLORS["collision"], 0.025,
                    labels=None if hit is None else [f"collision at step {record['first_collision_step']}"])
        rec.log("summary/rollout", rr.TextDocument(_summary(problem, record, k), media_type="text/markdown"))
        steps = list(range(len(traj))) if animate else [len(traj) - 1]
        pts, d = self.robot_at(problem, traj[steps])  # (T, M, 3), (T, M)
        closest = d.min(axis=1)  # the collision risk of the whole robot, per step
        pts, d = pts[:, self.subset], d[:, self.subset]  # drawn points
        with torch.no_grad():
            fk = robot.fk(torch.as_tensor(traj[steps], dtype=robot.dtype))
        for j, t in enumerate(steps):
            self.time(k, t)
            poses = {name: fk[name][j].numpy() for name in robot.link_meshes}
            log_robot_state(rec, poses, pts[j], d[j], clear=RISK_CLEAR)
            if animate:
                rec.log("plots/step", rr.Scalars(float(t)))
                rec.log("plots/closest_point_distance", rr.Scalars(float(closest[j])))
                rec.log("plots/goal_position_error", rr.Scalars(float(np.linalg.norm(ee[t] - goal))))
            self.frame += 1
        self.frame += 1  # a gap between rollouts


def write_recording(path: str | Path, problems: list[Problem], result: dict, expert: dict | None = None, *,
                    robot=None, slice_n_e: int = SLICE_N_E,
                    record_rollouts: int = 10, record_points: int = 256, metrics_md: str = "",
                    recording_id: str | None = None) -> Path:
    """Write `result` (from `evaluate`) on `problems` to `path` (.rrd); returns the path.

    Args:
        expert: the expert's `evaluate` result on the same problems, drawn beside (optional).
        robot: the robot (default: the one the problems name).
        slice_n_e: anchors per axis of the drawn SDF slice (the exact SDF on that plane of the grid).
        record_rollouts: rollouts animated step by step (spread over the splits); the rest get one frame.
        record_points: robot points drawn per step.
        metrics_md: the metrics table, shown beside the 3D view.
    """
    import rerun as rr

    from samp.viz import log_robot_meshes
    from samp.viz.rollout import rollout_blueprint

    if len(result["records"]) != len(problems):
        raise ValueError(f"the result has {len(result['records'])} records for {len(problems)} problems")
    if robot is None:
        from samp.robot import load_robot

        names = {p.robot for p in problems if p.robot}
        if len(names) != 1:
            raise ValueError(f"say which robot to draw: write_recording(..., robot=...); the problems name {sorted(names)}")
        robot = load_robot(names.pop())
    robot = exact_robot(robot)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id or recording_id_for(path, result["planner"]))
    rec.save(path, default_blueprint=rollout_blueprint())
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # the robot's base frame: z up
    log_robot_meshes(rec, robot, entity="world/robot", visual=True)
    rec.log("summary/metrics", rr.TextDocument(metrics_md or "(no metrics)", media_type="text/markdown"), static=True)
    by_split: dict[str, list[int]] = {}
    for i, p in enumerate(problems):
        by_split.setdefault(p.split, []).append(i)
    animated = set()
    for round_ in range(max(map(len, by_split.values()))):  # round-robin over the splits
        for rows in by_split.values():
            if round_ < len(rows) and len(animated) < record_rollouts:
                animated.add(rows[round_])
    writer = _Writer(rec, robot, slice_n_e, record_points)
    for k, (problem, record) in enumerate(zip(problems, result["records"])):
        writer.rollout(k, problem, record, None if expert is None else expert["records"][k], k in animated)
    rec.flush()
    rec.disconnect()
    return path
