"""Offset layers of robot SDFs in a Rerun recording, as in the paper's robot SDF figure.

For each method, two slices through the robot at its home configuration (the vertical plane through
the base and the end effector, and the horizontal plane through the elbow) are coloured by distance
band, [0, 1) cm, [1, 2) cm, ... up to 6 cm, with the iso-lines at 0.01 ... 0.06 m drawn on top.
The exact distance (trimesh) is drawn the same way under `sdf/ground_truth`, so a method's bands can
be held against it. Entities: `robot/...` (meshes, posed), `sdf/<method>/slice_<k>/{bands,levels/<mm>}`.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

__all__ = ["LEVELS", "log_offset_layers", "slice_planes", "write_offset_recording"]

LEVELS = (0.01, 0.02, 0.03, 0.04, 0.05, 0.06)  # metres
# One colour per band (RGB), inside the robot dark grey, beyond the last level transparent.
BAND_COLORS = np.array([[215, 48, 39], [244, 109, 67], [253, 174, 97], [171, 217, 233], [116, 173, 209],
                        [69, 117, 180]], dtype=np.uint8)
INSIDE_COLOR = (60, 60, 60)


def slice_planes(robot, q: torch.Tensor, spacing: float, margin: float = 0.12) -> list[dict]:
    """Two (H, W) point grids through the posed robot: {"points": (H, W, 3), "corners": (4, 3)}."""
    with torch.no_grad():
        fk = robot.fk(q[None].to(robot.dtype))
        ee = fk[robot.ee_link][0, :3, 3].double().cpu().numpy()
        origins = np.stack([fk[n][0, :3, 3].double().cpu().numpy() for n in robot.link_names])
    lo, hi = origins.min(0) - margin, origins.max(0) + margin
    lo[2] = min(lo[2], 0.0)
    # Vertical plane spanned by z and the horizontal direction towards the end effector.
    u = np.array([ee[0], ee[1], 0.0])
    u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-6 else np.array([1.0, 0.0, 0.0])
    reach = np.linalg.norm(origins[:, :2], axis=1).max() + margin
    vertical = (np.zeros(3), u * 1.0, np.array([0, 0, 1.0]), (-reach, reach), (lo[2], hi[2]))
    elbow_z = float(np.median(origins[:, 2]))
    horizontal = (np.array([0, 0, elbow_z]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), (lo[0], hi[0]), (lo[1], hi[1]))
    planes = []
    for origin, a, b, (a0, a1), (b0, b1) in (vertical, horizontal):
        sa, sb = np.arange(a0, a1, spacing), np.arange(b1, b0, -spacing)  # rows from top to bottom
        grid = origin + sa[None, :, None] * a + sb[:, None, None] * b  # (H, W, 3)
        half = spacing / 2
        corners = np.stack([origin + (sa[0] - half) * a + (sb[0] + half) * b, origin + (sa[-1] + half) * a + (sb[0] + half) * b,
                            origin + (sa[-1] + half) * a + (sb[-1] - half) * b, origin + (sa[0] - half) * a + (sb[-1] - half) * b])
        planes.append({"points": grid, "corners": corners})
    return planes


def _band_image(d: np.ndarray) -> np.ndarray:
    """(H, W) distances -> (H, W, 4) RGBA: band colours, inside grey, beyond the last level clear."""
    img = np.zeros((*d.shape, 4), dtype=np.uint8)
    band = np.floor(d / (LEVELS[1] - LEVELS[0])).astype(int)
    ok = (d >= 0) & (band < len(BAND_COLORS))
    img[ok, :3], img[ok, 3] = BAND_COLORS[band[ok]], 255
    img[d < 0, :3], img[d < 0, 3] = INSIDE_COLOR, 255
    return img


def log_offset_layers(rec, entity: str, distances: np.ndarray, plane: dict, spacing: float) -> None:
    """One slice: the band image as a textured quad and the iso-lines of `LEVELS` as line strips."""
    import contourpy
    import rerun as rr

    from samp.scene.viz import QUAD_TRIANGLES

    texcoords = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float32)
    rec.log(f"{entity}/bands", rr.Mesh3D(vertex_positions=plane["corners"].astype(np.float32),
                                         triangle_indices=QUAD_TRIANGLES, vertex_texcoords=texcoords,
                                         albedo_texture=_band_image(distances)), static=True)
    grid = plane["points"]
    H, W = distances.shape
    gen = contourpy.contour_generator(x=np.arange(W, dtype=np.float64), y=np.arange(H, dtype=np.float64), z=distances)
    for k, level in enumerate(LEVELS):
        strips = []
        for line in gen.lines(level):  # (m, 2) as (column, row) -> bilinear position on the plane
            c, r = line[:, 0], line[:, 1]
            c0, r0 = np.clip(np.floor(c).astype(int), 0, W - 2), np.clip(np.floor(r).astype(int), 0, H - 2)
            fc, fr = (c - c0)[:, None], (r - r0)[:, None]
            p = ((1 - fr) * ((1 - fc) * grid[r0, c0] + fc * grid[r0, c0 + 1])
                 + fr * ((1 - fc) * grid[r0 + 1, c0] + fc * grid[r0 + 1, c0 + 1]))
            strips.append(p.astype(np.float32))
        rec.log(f"{entity}/levels/{level * 1000:g}mm", rr.LineStrips3D(strips, colors=BAND_COLORS[k % len(BAND_COLORS)],
                                                                       radii=spacing * 0.35), static=True)


def _entity_name(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", label).strip("_") or "method"


@torch.no_grad()
def write_offset_recording(path: Path | str, robot, models: dict, q: torch.Tensor | None = None,
                           spacing: float = 0.004) -> Path:
    """Save a recording of the robot and each model's offset layers (plus ground truth) to `path`."""
    import rerun as rr

    from samp.robot_sdf.evaluate import _link_poses, robot_signed_distance
    from samp.viz import log_robot_meshes

    q = (robot.home if q is None else q).to(robot.dtype)
    planes = slice_planes(robot, q, spacing)
    rec = rr.RecordingStream("samp_robot_sdf", recording_id=f"robot-sdf-{robot.name}")
    log_robot_meshes(rec, robot)
    with torch.no_grad():
        fk = robot.fk(q[None])
    for name in robot.link_meshes:
        T = fk[name][0].double().cpu().numpy()
        rec.log(f"robot/links/{name}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
    pose = _link_poses(robot, q[None].double().cpu().numpy())[0]
    for k, plane in enumerate(planes):
        pts = plane["points"].reshape(-1, 3)
        truth = robot_signed_distance(robot, pts, pose).reshape(plane["points"].shape[:2])
        log_offset_layers(rec, f"sdf/ground_truth/slice_{k}", truth, plane, spacing)
        for label, model in models.items():
            model = model.eval()
            t = torch.as_tensor(pts[None], dtype=model.robot.dtype, device=model.robot.device)
            d = model.query(t, q[None].to(device=model.robot.device, dtype=model.robot.dtype)).double().cpu().numpy().reshape(truth.shape)
            log_offset_layers(rec, f"sdf/{_entity_name(label)}/slice_{k}", d, plane, spacing)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec.save(path)
    return path
