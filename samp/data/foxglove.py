"""What a scene file carries for viewers (Foxglove Studio), beside the data samp reads back.

Scene files of format 2 and later play as motion, not as a burst of messages:

* **Timing.** Each trajectory lasts its joint-space path length at `JOINT_SPEED` (rad/s, the Euclidean norm
  over the joints), at least `MIN_DURATION` s, with its waypoints spaced by the path length between them
  (constant joint speed along the path). Trajectories follow one another with `GAP` s between them.
  Everything is computed from the waypoints alone, so equal data gives equal bytes.
* **/tf** (`foxglove.FrameTransforms`): per waypoint, the pose of every robot link in the `base` frame, from
  forward kinematics, so the links' frames move in a 3D panel.
* **/robot** (`foxglove.SceneUpdate`): one entity per link, drawn in that link's frame from its collision
  mesh (embedded as binary glTF), so the arm moves with /tf.
* **/ee_path** (`foxglove.SceneUpdate`): the end-effector's path of the trajectory that is playing.
* Mesh obstacles on /scene are embedded as binary glTF (`data`), not as a file URL a viewer cannot resolve.

Format 1 files (ids made before) keep their layout: waypoint t of episode e at e * 1e6 + t ns.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

__all__ = ["GAP", "JOINT_SPEED", "MIN_DURATION", "embed_mesh", "frame_transforms", "path_update", "quaternions",
           "robot_update", "waypoint_times"]

JOINT_SPEED = 1.0  # rad/s along the joint-space path: a calm speed for a 7-joint arm (the Panda allows ~2)
MIN_DURATION = 0.5  # s: even a tiny motion plays visibly
GAP = 1.0  # s between one trajectory's end and the next one's start
NS = 1_000_000_000

Poses = Callable[[np.ndarray], dict[str, np.ndarray]]  # (T, n) -> link name -> (T, 4, 4) in the base frame


def waypoint_times(traj: np.ndarray, start_ns: int) -> np.ndarray:
    """(T,) int64 nanoseconds of the waypoints of `traj` (T, n) radians, the first at `start_ns`."""
    steps = np.linalg.norm(np.diff(np.asarray(traj, dtype=np.float64), axis=0), axis=1)  # (T-1,)
    length = float(steps.sum())
    duration = max(length / JOINT_SPEED, MIN_DURATION)
    fraction = np.concatenate([[0.0], np.cumsum(steps)]) / length if length > 0 else np.linspace(0, 1, len(traj))
    return start_ns + np.round(fraction * duration * NS).astype(np.int64)


def next_start(times: np.ndarray) -> int:
    """The start of the trajectory after one whose waypoints are at `times`."""
    return int(times[-1]) + int(GAP * NS)


def quaternions(poses: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """link -> (T, 4, 4) poses -> link -> (T, 4) quaternions x, y, z, w, in one scipy call (per-call cost
    dominates a waypoint's few links; the batched conversion gives the same numbers)."""
    from scipy.spatial.transform import Rotation

    if not poses:
        return {}
    names = list(poses)
    quat = Rotation.from_matrix(np.concatenate([poses[n][:, :3, :3] for n in names])).as_quat()
    return dict(zip(names, np.split(quat, len(names))))


def frame_transforms(poses: dict[str, np.ndarray], j: int, stamp_ns: int, parent: str,
                     quats: dict[str, np.ndarray] | None = None) -> FrameTransforms:
    """Waypoint j's link poses (link -> (T, 4, 4)) as `parent` -> link transforms; `quats`: their
    `quaternions`, when the caller has them for all waypoints."""
    quats = quats if quats is not None else quaternions(poses)
    msg = FrameTransforms()
    for name, T in poses.items():
        tf = msg.transforms.add(parent_frame_id=parent, child_frame_id=name)
        tf.timestamp.FromNanoseconds(int(stamp_ns))
        tf.translation.x, tf.translation.y, tf.translation.z = T[j, :3, 3].tolist()
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = quats[name][j].tolist()
    return msg


def embed_mesh(prim, mesh) -> None:
    """Put `mesh` (trimesh, in the primitive's frame) into a ModelPrimitive as binary glTF."""
    prim.data = mesh.export(file_type="glb")
    prim.media_type = "model/gltf-binary"
    prim.scale.x = prim.scale.y = prim.scale.z = 1.0


def robot_update(link_meshes: dict, color=(0.85, 0.85, 0.9, 1.0)) -> SceneUpdate:
    """One entity per link, in the link's own frame (moved by /tf), with its mesh embedded."""
    update = SceneUpdate()
    for name, mesh in link_meshes.items():
        entity = update.entities.add(frame_id=name, id=f"robot/{name}", frame_locked=True)
        prim = entity.models.add()
        prim.pose.orientation.w = 1.0
        prim.color.r, prim.color.g, prim.color.b, prim.color.a = color
        prim.override_color = True
        embed_mesh(prim, mesh)
    return update


def path_update(points: np.ndarray, stamp_ns: int, frame: str, color) -> SceneUpdate:
    """The end-effector path (T, 3) as a line strip, replacing the previous one."""
    update = SceneUpdate()
    entity = update.entities.add(frame_id=frame, id="ee_path")
    entity.timestamp.FromNanoseconds(int(stamp_ns))
    line = entity.lines.add(type=LinePrimitive.LINE_STRIP, thickness=0.006)
    line.pose.orientation.w = 1.0
    for p in np.asarray(points, dtype=np.float64):
        q = line.points.add()
        q.x, q.y, q.z = (float(v) for v in p)
    line.color.r, line.color.g, line.color.b, line.color.a = color
    return update
