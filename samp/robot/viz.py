"""Drawing a `Robot` into a Rerun recording: link meshes once, then poses and robot points per time."""

from __future__ import annotations

import numpy as np
import rerun as rr
import torch

__all__ = ["SHELL_COLORS", "log_robot_meshes", "log_robot_pose"]

# One colour per shell offset, innermost first (RGB); more shells cycle.
SHELL_COLORS = np.array([[230, 60, 60], [240, 170, 40], [60, 140, 230], [120, 200, 90]], dtype=np.uint8)
LINK_COLOR = (200, 200, 210, 255)


def log_robot_meshes(rec: rr.RecordingStream, robot, entity: str = "robot") -> None:
    """Log every collision link's mesh (link frame) as static data under `{entity}/links/{link}`."""
    for name, mesh in robot.link_meshes.items():
        rec.log(f"{entity}/links/{name}", rr.Mesh3D(
            vertex_positions=mesh.vertices.astype(np.float32), triangle_indices=mesh.faces.astype(np.uint32),
            vertex_normals=mesh.vertex_normals.astype(np.float32), albedo_factor=LINK_COLOR), static=True)


def log_robot_pose(rec: rr.RecordingStream, robot, q: torch.Tensor, entity: str = "robot") -> None:
    """Log link transforms and world robot points (coloured by shell) for one configuration q (n,).

    The caller sets the time (`rec.set_time(...)`) before calling.
    """
    with torch.no_grad():
        qb = q.reshape(1, -1).to(robot.dtype)
        fk = robot.fk(qb)
        points = robot.transform_points(qb)[0].double().cpu().numpy()  # (M, 3)
    for name in robot.link_meshes:
        T = fk[name][0].double().cpu().numpy()
        rec.log(f"{entity}/links/{name}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
    shells = robot.point_shells.cpu().numpy()
    offsets = robot.cfg.points.offsets
    for s, d in enumerate(offsets):
        sel = shells == s
        rec.log(f"{entity}/points/shell_{d * 1000:g}mm",
                rr.Points3D(points[sel], colors=SHELL_COLORS[s % len(SHELL_COLORS)], radii=0.004))
