"""Drawing a `Robot` into a Rerun recording: link meshes once, then poses and robot points per time."""

from __future__ import annotations

import numpy as np
import rerun as rr
import torch

__all__ = ["SHELL_COLORS", "log_robot_meshes", "log_robot_pose", "visual_meshes"]

# One colour per shell offset, innermost first (RGB); more shells cycle.
SHELL_COLORS = np.array([[230, 60, 60], [240, 170, 40], [60, 140, 230], [120, 200, 90]], dtype=np.uint8)
LINK_COLOR = (200, 200, 210, 255)


def visual_meshes(robot) -> dict[str, "trimesh.Trimesh"]:
    """link name -> the link's `<visual>` meshes from the URDF, in the link frame (with the colours their
    files carry, as vertex colours), for every link of `robot.link_meshes`. A link whose visuals are not
    meshes, or cannot be read, keeps its collision mesh."""
    import xml.etree.ElementTree as ET

    import trimesh

    from samp.meshes import load_mesh
    from samp.robot.urdf import _floats, origin_matrix, resolve_mesh

    root = ET.parse(robot.urdf.path).getroot()
    out = {}
    for link in root.findall("link"):
        name = link.get("name")
        if name not in robot.link_meshes:
            continue
        parts = []
        for visual in link.findall("visual"):
            shape = visual.find("geometry/mesh")
            if shape is None:
                continue
            try:
                mesh = load_mesh(resolve_mesh(shape.get("filename", ""), robot.urdf.path.parent), process=True)
            except (FileNotFoundError, ValueError):
                continue
            if hasattr(mesh.visual, "to_color"):  # a textured mesh: its colours per vertex
                mesh.visual = mesh.visual.to_color()
            where = f"{robot.urdf.path}: link {name!r} <visual>"  # a bad number is refused with its place
            mesh.apply_scale(_floats(shape.get("scale"), (1.0, 1.0, 1.0), f"{where} <mesh scale>"))
            mesh.apply_transform(origin_matrix(visual, where))
            parts.append(mesh)
        out[name] = trimesh.util.concatenate(parts) if parts else robot.link_meshes[name]
    return out


def log_robot_meshes(rec: rr.RecordingStream, robot, entity: str = "robot", visual: bool = False) -> None:
    """Log every collision link's mesh (link frame) as static data under `{entity}/links/{link}`; with
    `visual`, the URDF's visual meshes in their colours instead (`visual_meshes`)."""
    meshes = visual_meshes(robot) if visual else robot.link_meshes
    for name, mesh in meshes.items():
        colors = None
        if visual and getattr(mesh.visual, "kind", None) == "vertex":
            colors = np.asarray(mesh.visual.vertex_colors)[:, :3]
        rec.log(f"{entity}/links/{name}", rr.Mesh3D(
            vertex_positions=mesh.vertices.astype(np.float32), triangle_indices=mesh.faces.astype(np.uint32),
            vertex_normals=mesh.vertex_normals.astype(np.float32), vertex_colors=colors,
            albedo_factor=None if colors is not None else LINK_COLOR), static=True)


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
