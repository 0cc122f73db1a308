"""Checks of executed trajectories (docs/design.md section 4): goal errors, path lengths and physical violations.

A trajectory (W, n) radians is executed as straight joint-space segments between its waypoints (the
policy's steps, or the expert's waypoints). Violations are checked in pybullet (`samp.sim.World`,
margin 0) at every waypoint and at sub-steps no farther apart than `resolution` radians (joint-space
Euclidean, the expert's own motion-check metric and subdivision, `samp.expert.trajectory.segment_states`):
  * collision: a non-base link penetrates an obstacle (distance < 0); its depth is the deepest
    penetration pybullet reports over the colliding states (`World.min_distance`);
  * self-collision: two non-excluded links touch; checked in a World with no obstacles so that it is
    reported apart from obstacle collisions;
  * joint limits: a state outside the limits (by more than `samp.sim.world.LIMIT_TOLERANCE`).
A violation's step is the index of the waypoint that ends the segment where it first occurs (0: the
start itself), so a policy's first colliding step is the step whose motion collided.
"""

from __future__ import annotations

import numpy as np

from samp.expert.trajectory import segment_states
from samp.robot.goal import ee_poses, goal_errors  # re-exported: the robot layer owns them
from samp.robot.precision import exact_robot  # re-exported: checks run on this float64 copy

__all__ = ["TrajectoryChecker", "ee_poses", "exact_robot", "goal_errors", "polyline_length"]


def polyline_length(points: np.ndarray) -> float:
    """(W, 3) -> sum of segment lengths (docs/design.md: path length = sum ||dp_ee||); 0 for one point."""
    points = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


def _first(hits: np.ndarray, steps: np.ndarray) -> int | None:
    k = np.flatnonzero(hits)
    return None if len(k) == 0 else int(steps[k[0]])


class TrajectoryChecker:
    """pybullet checks of trajectories for one robot. Opens one `World` per scene on first use and one
    obstacle-free World for self-collision; use as a context manager or call `close()`.

    Args:
        robot: the `Robot` (any dtype; a float64 CPU copy is made for the checks if needed).
        resolution: sub-step spacing, joint-space Euclidean radians.
    """

    def __init__(self, robot, resolution: float = 0.02):
        if not (np.isfinite(resolution) and resolution > 0):
            raise ValueError(f"substep_resolution must be positive radians, got {resolution!r}")
        self.robot = exact_robot(robot)
        self.resolution = float(resolution)
        self._worlds: dict[str, object] = {}
        self._free = None

    def __enter__(self) -> "TrajectoryChecker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for world in [*self._worlds.values(), self._free]:
            if world is not None:
                world.close()
        self._worlds.clear()
        self._free = None

    def world(self, scene):
        from samp.sim import World

        key = scene.content_hash()
        if key not in self._worlds:
            self._worlds[key] = World(self.robot, scene)
        return self._worlds[key]

    def _free_world(self):
        from samp.scene import Scene
        from samp.sim import World

        if self._free is None:
            self._free = World(self.robot, Scene(name="no_obstacles"))
        return self._free

    def check(self, scene, trajectories: list[np.ndarray]) -> list[dict]:
        """Check (W_i, n) trajectories in one scene, all sub-states in one batch per query -> one dict each:
        collision, first_collision_step, collision_depth (m, >= 0), first_collision_state (n,) list,
        self_collision, first_self_collision_step, joint_limit_violation, first_limit_step."""
        if not trajectories:
            return []
        states, steps, owner = [], [], []
        for i, traj in enumerate(trajectories):
            s, seg = segment_states(traj, self.resolution)  # (C, n), (C,) segment index
            step = seg + 1
            step[0] = 0  # the start itself
            states.append(s)
            steps.append(step)
            owner.append(np.full(len(s), i))
        states, steps, owner = np.concatenate(states), np.concatenate(steps), np.concatenate(owner)
        world = self.world(scene)
        obstacle = world.in_collision(states, margin=0.0, self_collision=False, joint_limits=False)
        self_hit = self._free_world().in_collision(states, margin=0.0, self_collision=True, joint_limits=False)
        limits = world.outside_limits(states)
        depth = np.zeros(len(states))
        if obstacle.any():
            depth[obstacle] = np.maximum(0.0, -world.min_distance(states[obstacle]))
        out = []
        for i in range(len(trajectories)):
            mine = owner == i
            hits, st = obstacle[mine], steps[mine]
            first = np.flatnonzero(hits)
            out.append({
                "collision": bool(hits.any()),
                "first_collision_step": _first(hits, st),
                "collision_depth": float(depth[mine].max()) if hits.any() else 0.0,
                "first_collision_state": states[mine][first[0]].tolist() if len(first) else None,
                "self_collision": bool(self_hit[mine].any()),
                "first_self_collision_step": _first(self_hit[mine], st),
                "joint_limit_violation": bool(limits[mine].any()),
                "first_limit_step": _first(limits[mine], st),
                "checked_states": int(mine.sum()),
            })
        return out
