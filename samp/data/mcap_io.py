"""One MCAP file per scene: its geometry, anchor grids, demonstrations, evaluation problems and records.

Topics (log times are deterministic, so equal content gives equal bytes and an equal dataset id):
    /scene             foxglove.SceneUpdate   primitives for viewers (Foxglove, Rerun converters)
    /scene/spec        JSON (jsonschema)      the exact scene (`Scene.to_dict`), scene index and split
    /sdf/n<N>          foxglove.VoxelGrid     the anchor grid at n_e = N, float32 "distance", z-y-x order
    /trajectory        foxglove.JointStates   demonstrations: one message per waypoint (sequence = step),
                                              timed as a robot would move (samp.data.foxglove)
    /episode           JSON (jsonschema)      one record per demonstration problem: start, goal, success,
                                              reason, planner statistics ("purpose": "demonstration")
    /eval/trajectory   foxglove.JointStates   the expert's solutions of the evaluation problems, played
                                              after the demonstrations
    /eval/episode      JSON (jsonschema)      one record per evaluation problem, the same schema
                                              ("purpose": "evaluation")
    /tf, /robot, /ee_path                     for viewers: link poses per waypoint, the robot's link
                                              meshes, the end-effector path (samp.data.foxglove)
and a `samp.dataset` metadata record. Chunks are zstd-compressed. Files of format 1 (`format_version` in
the metadata record) have waypoint t of episode e at e * 1e6 + t ns, no /tf, /robot or /ee_path, mesh
obstacles as file URLs, and a voxel grid placed half a cell off; they are read the same way and a
rewrite keeps their layout, so their ids do not change. Evaluation problems live on their own
topics so that nothing reading /episode and /trajectory (the DataModule's training data) can see them;
in Foxglove they play after the demonstrations on one timeline.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from foxglove_schemas_protobuf.JointState_pb2 import JointState
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.VoxelGrid_pb2 import VoxelGrid
from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema

from samp.data import foxglove as fox
from samp.names import SPLIT_ALIASES, SPLITS
from samp.scene.model import Box, Cylinder, Scene, Sphere

__all__ = ["DETOUR_FORMAT", "EPISODE_SCHEMA", "TIMED_FORMAT", "SceneRecord", "link_poses", "read_scene_file", "stacked",
           "write_scene_file"]

FRAME = "base"
STEP_NS = 1_000_000  # format 1: log_time of waypoint t of episode e is e * STEP_NS + t
TIMED_FORMAT = 2  # from this scene-file format on: realistic timing, /tf, /robot, /ee_path, embedded meshes
DETOUR_FORMAT = 3  # from this format on, every episode record says whether its straight start-goal line is blocked
PATH_COLORS = {"/trajectory": (0.2, 0.5, 0.95, 1.0), "/eval/trajectory": (0.95, 0.6, 0.1, 1.0)}
EPISODE_SCHEMA = {
    "type": "object", "title": "samp.Episode",
    "required": ["episode", "success", "reason", "start", "goal", "stats"],
    "properties": {"episode": {"type": "integer"}, "success": {"type": "boolean"}, "reason": {"type": "string"},
                   "kind": {"enum": ["target", "workspace"]},
                   "purpose": {"enum": ["demonstration", "evaluation"]},
                   "start": {"type": "array", "items": {"type": "number"}},
                   "goal": {"type": ["array", "null"], "items": {"type": "number"}},
                   "goal_pose": {"type": ["array", "null"], "items": {"type": "array"}},
                   "detour": {"type": ["boolean", "null"]},  # format 3: the straight start-goal line is blocked
                   "stats": {"type": "object"}},
}
FILE_SPLITS = (*SPLITS, *SPLIT_ALIASES)  # "heldout": older files with two splits (and their rewrites)
SCENE_SPEC_SCHEMA = {"type": "object", "title": "samp.SceneSpec", "required": ["scene_index", "split", "scene"],
                     "properties": {"scene_index": {"type": "integer"}, "split": {"enum": list(FILE_SPLITS)},
                                    "scene": {"type": "object"}}}
# (episode records, waypoints) of the demonstrations and of the evaluation problems
DEMO_TOPICS, EVAL_TOPICS = ("/episode", "/trajectory"), ("/eval/episode", "/eval/trajectory")


@dataclass
class SceneRecord:
    """What one scene file holds, decoded."""

    scene: Scene
    scene_index: int
    split: str
    joint_names: list[str]
    metadata: dict[str, str] = field(default_factory=dict)  # the file's samp.dataset metadata record
    resolutions: list[int] = field(default_factory=list)  # n_e of every grid in the file
    grids: dict[int, torch.Tensor] = field(default_factory=dict)  # n_e -> (n_e, n_e, n_e), indexed (x, y, z)
    trajectories: np.ndarray | None = None  # (E_ok, T, n) radians, successful episodes in episode order
    episodes: list[dict] = field(default_factory=list)  # every demonstration episode, failures included
    eval_trajectories: np.ndarray | None = None  # (K_ok, T, n) the expert's solutions of the solved eval problems
    eval_episodes: list[dict] = field(default_factory=list)  # every evaluation problem, failures included
    has_eval_topics: bool = True  # False for files written before evaluation problems were stored
    # For viewers (format 2 on; not read back): link poses from joint angles, the end-effector link, link meshes
    poses: fox.Poses | None = None  # (T, n) -> link name -> (T, 4, 4) in the base frame
    ee_link: str | None = None
    link_meshes: dict | None = None  # link name -> trimesh.Trimesh in the link frame

    @property
    def format_version(self) -> int:
        return int(self.metadata.get("format_version", 1))


def _pose(msg_pose, pose) -> None:
    msg_pose.position.x, msg_pose.position.y, msg_pose.position.z = pose.position
    q = msg_pose.orientation
    q.x, q.y, q.z, q.w = pose.quaternion


def _scene_update(scene: Scene, embed: bool) -> SceneUpdate:
    update = SceneUpdate()
    for o in scene.all_obstacles:
        entity = update.entities.add(frame_id=FRAME, id=o.name)
        if isinstance(o, Box):
            prim = entity.cubes.add()
            prim.size.x, prim.size.y, prim.size.z = o.size
        elif isinstance(o, Cylinder):
            prim = entity.cylinders.add(bottom_scale=1.0, top_scale=1.0)
            prim.size.x = prim.size.y = 2 * o.radius
            prim.size.z = o.height
        elif isinstance(o, Sphere):
            prim = entity.spheres.add()
            prim.size.x = prim.size.y = prim.size.z = 2 * o.radius
        elif embed:  # the mesh itself: a viewer cannot resolve samp's pybullet_data:// paths
            from samp.scene.sdf import obstacle_mesh

            prim = entity.models.add()
            fox.embed_mesh(prim, obstacle_mesh(o))
        else:
            prim = entity.models.add(url=str(o.path))
            prim.scale.x = prim.scale.y = prim.scale.z = o.scale
        _pose(prim.pose, o.pose)
        prim.color.r, prim.color.g, prim.color.b, prim.color.a = (0.2, 0.8, 0.3, 1.0) if o is scene.target else (0.7, 0.7, 0.7, 1.0)
    return update


def _voxel_grid(grid: torch.Tensor, bounds, centred: bool) -> VoxelGrid:
    """(n, n, n) grid indexed (x, y, z) -> foxglove.VoxelGrid (data z-major: slice z, row y, column x).

    A VoxelGrid's pose is the corner of its first cell, so cell i spans pose + [i, i + 1] * cell_size. The
    values are samples at the anchors lo + i * cell_size; with `centred`, the grid starts half a cell
    before `lo` so that every cell is centred on its anchor (format 1 put the corner at `lo`)."""
    n = grid.shape[0]
    lo, hi = np.asarray(bounds[0]), np.asarray(bounds[1])
    msg = VoxelGrid(frame_id=FRAME, row_count=n, column_count=n, cell_stride=4, row_stride=4 * n, slice_stride=4 * n * n,
                    data=np.ascontiguousarray(grid.numpy().astype("<f4").transpose(2, 1, 0)).tobytes())
    cell = (hi - lo) / (n - 1)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = lo - cell / 2 if centred else lo
    msg.pose.orientation.w = 1.0
    msg.cell_size.x, msg.cell_size.y, msg.cell_size.z = cell
    msg.fields.add(name="distance", offset=0, type=PackedElementField.FLOAT32)
    return msg


def _check_pairs(episodes: list[dict], trajectories, what: str) -> None:
    solved = sum(e["success"] for e in episodes)
    if solved != len(trajectories):
        raise ValueError(f"{len(trajectories)} {what} trajectories for {solved} successful {what} episodes")


def write_scene_file(path: Path, record: SceneRecord) -> None:
    """Write one scene's file to `path` (atomically: a temporary file renamed on success).

    `record.episodes[i]` and `record.eval_episodes[i]` have keys of EPISODE_SCHEMA; the successful ones,
    in order, pair with `record.trajectories` and `record.eval_trajectories` ((T, n) each).
    """
    if record.split not in FILE_SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {record.split!r}")
    trajectories = [] if record.trajectories is None else list(record.trajectories)
    eval_trajectories = [] if record.eval_trajectories is None else list(record.eval_trajectories)
    _check_pairs(record.episodes, trajectories, "demonstration")
    _check_pairs(record.eval_episodes, eval_trajectories, "evaluation")
    if record.eval_episodes and not record.has_eval_topics:
        raise ValueError(f"{len(record.eval_episodes)} evaluation problems for a scene file without evaluation topics "
                         "(has_eval_topics False, the layout of older datasets with two splits)")
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="samp")
        w.add_metadata("samp.dataset", {k: str(v) for k, v in record.metadata.items()})
        joint_states, episode = register_schema(w, JointStates), _json_schema(w, EPISODE_SCHEMA)
        ch = {"/scene": w.register_channel("/scene", "protobuf", register_schema(w, SceneUpdate)),
              "/scene/spec": w.register_channel("/scene/spec", "json", _json_schema(w, SCENE_SPEC_SCHEMA))}
        # Both kinds of episode share the two schemas; a legacy scene rewritten keeps its lack of eval topics.
        for records, waypoints in (DEMO_TOPICS, EVAL_TOPICS) if record.has_eval_topics else (DEMO_TOPICS,):
            ch[records] = w.register_channel(records, "json", episode)
            ch[waypoints] = w.register_channel(waypoints, "protobuf", joint_states)
        timed = record.format_version >= TIMED_FORMAT
        w.add_message(ch["/scene"], 0, _scene_update(record.scene, embed=timed).SerializeToString(), 0)
        spec = {"scene_index": record.scene_index, "split": record.split, "scene": record.scene.to_dict(),
                "joint_names": record.joint_names}
        w.add_message(ch["/scene/spec"], 0, json.dumps(spec, sort_keys=True).encode(), 0)
        for n_e, grid in sorted(record.grids.items()):
            cid = w.register_channel(f"/sdf/n{n_e}", "protobuf", register_schema(w, VoxelGrid))
            w.add_message(cid, 0, _voxel_grid(grid, record.scene.bounds, centred=timed).SerializeToString(), 0)
        if timed:
            viewer = _viewer_channels(w, record)
            start = 0
            for topics, episodes, trajs in ((DEMO_TOPICS, record.episodes, trajectories),
                                            (EVAL_TOPICS, record.eval_episodes, eval_trajectories)):
                if topics == DEMO_TOPICS or record.has_eval_topics:
                    start = _write_timed(w, [ch[t] for t in topics], episodes, trajs, record, viewer, start,
                                         PATH_COLORS[topics[1]])
        else:
            _write_episodes(w, [ch[t] for t in DEMO_TOPICS], record.episodes, trajectories, record.joint_names, 0)
            if record.has_eval_topics:
                _write_episodes(w, [ch[t] for t in EVAL_TOPICS], record.eval_episodes, eval_trajectories,
                                record.joint_names, len(record.episodes))
        w.finish()
    tmp.replace(path)


def _viewer_channels(w: Writer, record: SceneRecord) -> dict[str, int]:
    """/tf, /robot (the link meshes, once at time 0) and /ee_path, as far as the record allows."""
    channels = {}
    if record.poses is not None:
        channels["/tf"] = w.register_channel("/tf", "protobuf", register_schema(w, fox.FrameTransforms))
        if record.ee_link is not None:
            channels["/ee_path"] = w.register_channel("/ee_path", "protobuf", register_schema(w, SceneUpdate))
    if record.link_meshes:
        cid = w.register_channel("/robot", "protobuf", register_schema(w, SceneUpdate))
        w.add_message(cid, 0, fox.robot_update(record.link_meshes).SerializeToString(), 0)
    return channels


def _joint_states(joint_names: list[str], q, stamp_ns: int) -> bytes:
    msg = JointStates(joints=[JointState(name=name, position=float(v)) for name, v in zip(joint_names, q)])
    msg.timestamp.FromNanoseconds(int(stamp_ns))
    return msg.SerializeToString()


def _write_timed(w: Writer, channels: list[int], episodes: list[dict], trajectories: list[np.ndarray],
                 record: SceneRecord, viewer: dict[str, int], start: int, color) -> int:
    """Episodes one after another from `start` (ns), waypoints timed by `fox.waypoint_times`, with their
    link poses on /tf and the end-effector path on /ee_path; returns where the next episode may start."""
    records, waypoints = channels
    ok = iter(trajectories)
    for e, episode in enumerate(episodes):
        w.add_message(records, start, json.dumps({**episode, "episode": e}, sort_keys=True).encode(), start)
        if not episode["success"]:
            start += int(fox.GAP * fox.NS)
            continue
        traj = np.asarray(next(ok), dtype=np.float64)  # (T, n)
        times = fox.waypoint_times(traj, start)
        poses = record.poses(traj) if record.poses is not None else None
        quats = fox.quaternions(poses) if poses is not None else None
        if "/ee_path" in viewer:
            path = fox.path_update(poses[record.ee_link][:, :3, 3], start, FRAME, color)
            w.add_message(viewer["/ee_path"], start, path.SerializeToString(), start)
        for t, (q, stamp) in enumerate(zip(traj, times)):
            stamp = int(stamp)
            w.add_message(waypoints, stamp, _joint_states(record.joint_names, q, stamp), stamp, sequence=t)
            if poses is not None:
                w.add_message(viewer["/tf"], stamp, fox.frame_transforms(poses, t, stamp, FRAME, quats).SerializeToString(),
                              stamp, sequence=t)
        start = fox.next_start(times)
    return start


def _json_schema(w: Writer, schema: dict) -> int:
    return w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())


def _write_episodes(w: Writer, channels: list[int], episodes: list[dict], trajectories: list[np.ndarray],
                    joint_names: list[str], first: int) -> None:
    """Format 1: episode records and the waypoints of the successful ones; episode e at log time
    (first + e) * STEP_NS."""
    records, waypoints = channels
    ok = iter(trajectories)
    for e, episode in enumerate(episodes):
        t0 = (first + e) * STEP_NS
        w.add_message(records, t0, json.dumps({**episode, "episode": e}, sort_keys=True).encode(), t0)
        if episode["success"]:
            for t, q in enumerate(next(ok)):
                msg = JointStates(joints=[JointState(name=name, position=float(v)) for name, v in zip(joint_names, q)])
                msg.timestamp.FromNanoseconds(t0 + t)
                w.add_message(waypoints, t0 + t, msg.SerializeToString(), t0 + t, sequence=t)


def _grid_from_voxels(msg) -> torch.Tensor:
    n = msg.column_count
    data = np.frombuffer(msg.data, dtype="<f4").reshape(n, n, n)  # (z, y, x)
    return torch.from_numpy(np.ascontiguousarray(data.transpose(2, 1, 0)))


def read_scene_file(path: Path, resolutions: list[int] | None = None) -> SceneRecord:
    """Decode one scene file; `resolutions` limits which grids are decoded (None: all, []: none; chunks
    holding only other grids are not even decompressed)."""
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, validate_crcs=True)  # a flipped byte in a chunk is an error, not data
            summary = reader.get_summary()
            if summary is None:
                raise EOFError("the file has no summary section")
            topics = {c.topic for c in summary.channels.values()}
            grid_topics = {t: int(t[len("/sdf/n"):]) for t in topics if t.startswith("/sdf/n")}
            wanted = [t for t, n in grid_topics.items() if resolutions is None or n in resolutions]
            metadata = {}
            for m in reader.iter_metadata():
                if m.name == "samp.dataset":
                    metadata = dict(m.metadata)
            record, grids = None, {}
            episodes = {t: [] for t in (DEMO_TOPICS[0], EVAL_TOPICS[0])}  # topic -> records
            waypoints = {t: [] for t in (DEMO_TOPICS[1], EVAL_TOPICS[1])}  # topic -> one list of rows per trajectory
            for _, channel, message in reader.iter_messages(topics=["/scene/spec", *episodes, *waypoints, *wanted],
                                                           log_time_order=False):  # file order: written in order
                topic = channel.topic
                if topic == "/scene/spec":
                    spec = json.loads(message.data)
                    record = SceneRecord(Scene.from_dict(spec["scene"]), spec["scene_index"], spec["split"], spec["joint_names"])
                elif topic in grid_topics:
                    grids[grid_topics[topic]] = _grid_from_voxels(VoxelGrid.FromString(message.data))
                elif topic in episodes:
                    episodes[topic].append(json.loads(message.data))
                else:
                    joints = JointStates.FromString(message.data).joints
                    if message.sequence == 0 or not waypoints[topic]:  # every format numbers a trajectory's waypoints from 0
                        waypoints[topic].append([])
                    waypoints[topic][-1].append([j.position for j in joints])
    except (McapError, EOFError, ValueError, KeyError, struct.error, DecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{path} is not a readable samp scene file ({type(err).__name__}: {err}); it may be "
                         "truncated or changed: run `python -m samp.data verify` on its dataset, and restore or generate the "
                         "dataset again") from None
    if record is None:
        raise ValueError(f"{path} has no /scene/spec record; it is not a samp scene file")
    record.metadata, record.resolutions, record.grids = metadata, sorted(grid_topics.values()), grids
    n = len(record.joint_names)
    record.episodes, record.trajectories = _decoded(episodes[DEMO_TOPICS[0]], waypoints[DEMO_TOPICS[1]], n)
    record.eval_episodes, record.eval_trajectories = _decoded(episodes[EVAL_TOPICS[0]], waypoints[EVAL_TOPICS[1]], n)
    record.has_eval_topics = EVAL_TOPICS[0] in topics
    return record


def _decoded(episodes: list[dict], waypoints: list[list], n: int) -> tuple[list[dict], np.ndarray]:
    """Records in episode order, and (E_ok, T, n) the waypoints of the successful ones in the same order
    (written in that order)."""
    trajs = [np.asarray(rows) for rows in waypoints]
    return sorted(episodes, key=lambda e: e["episode"]), stacked(trajs, n)


def link_poses(robot, q: np.ndarray) -> dict[str, np.ndarray]:
    """q (T, n) radians -> link name -> (T, 4, 4) poses in the base frame (float64 forward kinematics)."""
    import torch

    with torch.no_grad():
        fk = robot.fk(torch.as_tensor(np.asarray(q), dtype=robot.dtype))
    names = [*robot.link_meshes, *([] if robot.ee_link in robot.link_meshes else [robot.ee_link])]
    return {name: fk[name].double().cpu().numpy() for name in names}


def stacked(trajectories: list[np.ndarray], n: int) -> np.ndarray:
    """K (T, n) trajectories -> (K, T, n); (0, 0, n) for none."""
    return np.stack(trajectories) if trajectories else np.zeros((0, 0, n))
