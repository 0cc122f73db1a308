"""One MCAP file per scene: its geometry, anchor grids, trajectories and per-episode records.

Topics (log times are deterministic, so equal content gives equal bytes and an equal dataset id):
    /scene             foxglove.SceneUpdate   primitives for viewers (Foxglove, Rerun converters)
    /scene/spec        JSON (jsonschema)      the exact scene (`Scene.to_dict`), scene index and split
    /sdf/n<N>          foxglove.VoxelGrid     the anchor grid at n_e = N, float32 "distance", z-y-x order
    /trajectory        foxglove.JointStates   one message per waypoint, log_time = episode * 1e6 + step
    /episode           JSON (jsonschema)      one record per planning problem: start, goal, success,
                                              reason, planner statistics
and a `samp.dataset` metadata record. Chunks are zstd-compressed.
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

from samp.scene.model import Box, Cylinder, Scene, Sphere

__all__ = ["EPISODE_SCHEMA", "SceneRecord", "read_scene_file", "write_scene_file"]

FRAME = "base"
STEP_NS = 1_000_000  # log_time of waypoint t of episode e: e * STEP_NS + t
EPISODE_SCHEMA = {
    "type": "object", "title": "samp.Episode",
    "required": ["episode", "success", "reason", "start", "goal", "stats"],
    "properties": {"episode": {"type": "integer"}, "success": {"type": "boolean"}, "reason": {"type": "string"},
                   "kind": {"enum": ["target", "workspace"]},
                   "start": {"type": "array", "items": {"type": "number"}},
                   "goal": {"type": ["array", "null"], "items": {"type": "number"}},
                   "goal_pose": {"type": ["array", "null"], "items": {"type": "array"}},
                   "stats": {"type": "object"}},
}
SCENE_SPEC_SCHEMA = {"type": "object", "title": "samp.SceneSpec", "required": ["scene_index", "split", "scene"],
                     "properties": {"scene_index": {"type": "integer"}, "split": {"enum": ["train", "heldout"]},
                                    "scene": {"type": "object"}}}


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
    episodes: list[dict] = field(default_factory=list)  # every episode, failures included


def _pose(msg_pose, pose) -> None:
    msg_pose.position.x, msg_pose.position.y, msg_pose.position.z = pose.position
    q = msg_pose.orientation
    q.x, q.y, q.z, q.w = pose.quaternion


def _scene_update(scene: Scene) -> SceneUpdate:
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
        else:
            prim = entity.models.add(url=str(o.path))
            prim.scale.x = prim.scale.y = prim.scale.z = o.scale
        _pose(prim.pose, o.pose)
        prim.color.r, prim.color.g, prim.color.b, prim.color.a = (0.2, 0.8, 0.3, 1.0) if o is scene.target else (0.7, 0.7, 0.7, 1.0)
    return update


def _voxel_grid(grid: torch.Tensor, bounds) -> VoxelGrid:
    """(n, n, n) grid indexed (x, y, z) -> foxglove.VoxelGrid (data z-major: slice z, row y, column x)."""
    n = grid.shape[0]
    lo, hi = np.asarray(bounds[0]), np.asarray(bounds[1])
    msg = VoxelGrid(frame_id=FRAME, row_count=n, column_count=n, cell_stride=4, row_stride=4 * n, slice_stride=4 * n * n,
                    data=np.ascontiguousarray(grid.numpy().astype("<f4").transpose(2, 1, 0)).tobytes())
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = lo
    msg.pose.orientation.w = 1.0
    msg.cell_size.x, msg.cell_size.y, msg.cell_size.z = (hi - lo) / (n - 1)
    msg.fields.add(name="distance", offset=0, type=PackedElementField.FLOAT32)
    return msg


def write_scene_file(path: Path, scene: Scene, scene_index: int, split: str, joint_names: list[str],
                     grids: dict[int, torch.Tensor], episodes: list[dict], trajectories: list[np.ndarray],
                     metadata: dict[str, str]) -> None:
    """Write one scene's file to `path` (atomically: a temporary file renamed on success).

    `episodes[i]` has keys of EPISODE_SCHEMA; successful ones, in order, pair with `trajectories` (T, n).
    """
    if split not in ("train", "heldout"):
        raise ValueError(f"split must be 'train' or 'heldout', got {split!r}")
    if sum(e["success"] for e in episodes) != len(trajectories):
        raise ValueError(f"{len(trajectories)} trajectories for {sum(e['success'] for e in episodes)} successful episodes")
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="samp")
        w.add_metadata("samp.dataset", {k: str(v) for k, v in metadata.items()})
        ch = {}
        for topic, msg_type in (("/scene", SceneUpdate), ("/trajectory", JointStates)):
            ch[topic] = w.register_channel(topic, "protobuf", register_schema(w, msg_type))
        for topic, schema in (("/scene/spec", SCENE_SPEC_SCHEMA), ("/episode", EPISODE_SCHEMA)):
            sid = w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            ch[topic] = w.register_channel(topic, "json", sid)
        w.add_message(ch["/scene"], 0, _scene_update(scene).SerializeToString(), 0)
        spec = {"scene_index": scene_index, "split": split, "scene": scene.to_dict(), "joint_names": joint_names}
        w.add_message(ch["/scene/spec"], 0, json.dumps(spec, sort_keys=True).encode(), 0)
        for n_e, grid in sorted(grids.items()):
            cid = w.register_channel(f"/sdf/n{n_e}", "protobuf", register_schema(w, VoxelGrid))
            w.add_message(cid, 0, _voxel_grid(grid, scene.bounds).SerializeToString(), 0)
        ok = iter(trajectories)
        for e, episode in enumerate(episodes):
            w.add_message(ch["/episode"], e * STEP_NS, json.dumps({**episode, "episode": e}, sort_keys=True).encode(), e * STEP_NS)
            if episode["success"]:
                for t, q in enumerate(next(ok)):
                    msg = JointStates(joints=[JointState(name=name, position=float(v)) for name, v in zip(joint_names, q)])
                    msg.timestamp.FromNanoseconds(e * STEP_NS + t)
                    w.add_message(ch["/trajectory"], e * STEP_NS + t, msg.SerializeToString(), e * STEP_NS + t, sequence=t)
        w.finish()
    tmp.replace(path)


def _grid_from_voxels(msg) -> torch.Tensor:
    n = msg.column_count
    data = np.frombuffer(msg.data, dtype="<f4").reshape(n, n, n)  # (z, y, x)
    return torch.from_numpy(np.ascontiguousarray(data.transpose(2, 1, 0)))


def read_scene_file(path: Path, resolutions: list[int] | None = None) -> SceneRecord:
    """Decode one scene file; `resolutions` limits which grids are decoded (None: all, []: none; chunks
    holding only other grids are not even decompressed)."""
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise EOFError("the file has no summary section")
            grid_topics = {c.topic: int(c.topic[len("/sdf/n"):]) for c in summary.channels.values()
                           if c.topic.startswith("/sdf/n")}
            wanted = [t for t, n in grid_topics.items() if resolutions is None or n in resolutions]
            metadata = {}
            for m in reader.iter_metadata():
                if m.name == "samp.dataset":
                    metadata = dict(m.metadata)
            record, waypoints, episodes, grids = None, {}, [], {}
            for _, channel, message in reader.iter_messages(topics=["/scene/spec", "/episode", "/trajectory", *wanted],
                                                           log_time_order=False):  # file order: written in order
                topic = channel.topic
                if topic == "/scene/spec":
                    spec = json.loads(message.data)
                    record = SceneRecord(Scene.from_dict(spec["scene"]), spec["scene_index"], spec["split"], spec["joint_names"])
                elif topic in grid_topics:
                    grids[grid_topics[topic]] = _grid_from_voxels(VoxelGrid.FromString(message.data))
                elif topic == "/episode":
                    episodes.append(json.loads(message.data))
                else:
                    joints = JointStates.FromString(message.data).joints
                    waypoints.setdefault(message.log_time // STEP_NS, []).append([j.position for j in joints])
    except (McapError, EOFError, ValueError, KeyError, struct.error, DecodeError) as err:
        raise ValueError(f"{path} is not a readable samp scene file ({type(err).__name__}: {err}); it may be "
                         "truncated: run `python -m samp.data verify` on its dataset") from None
    if record is None:
        raise ValueError(f"{path} has no /scene/spec record; it is not a samp scene file")
    record.metadata, record.resolutions, record.grids = metadata, sorted(grid_topics.values()), grids
    record.episodes = sorted(episodes, key=lambda e: e["episode"])
    trajs = [np.asarray(waypoints[e]) for e in sorted(waypoints)]
    n = len(record.joint_names)
    record.trajectories = np.stack(trajs) if trajs else np.zeros((0, 0, n))
    return record
