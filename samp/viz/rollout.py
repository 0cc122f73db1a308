"""Drawing rollouts into a Rerun recording: a scene that changes over time, an SDF plane, the robot's
pose and its points coloured by collision risk, end-effector paths, markers, and a blueprint.

One recording holds many rollouts one after another on the `frame` timeline (each also carries its
`rollout` index and `step`), so everything here is logged as temporal data at the caller's time (the
scene helpers in `samp.scene.viz` log static data, which cannot change between rollouts). Robot link
meshes are static (`samp.robot.viz.log_robot_meshes`); only their transforms are logged per step.
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from samp.scene.viz import (OBSTACLE_COLORS, QUAD_TRIANGLES, TABLE_COLOR, TABLE_NAME, TARGET_COLOR, obstacle_trimesh,
                            sdf_colors, slice_quad, zero_contour)

__all__ = ["RISK_COLORMAP", "PATH_COLORS", "log_markers", "log_path", "log_robot_state", "log_scene_frame",
           "log_sdf_plane", "risk_colors", "rollout_blueprint"]

RISK_COLORMAP = "RdYlGn"  # red: touching or inside an obstacle, yellow: close, green: clear
PATH_COLORS = {"success": (40, 190, 80), "failure": (220, 60, 50), "expert": (60, 120, 230), "goal": (250, 200, 30),
               "start": (150, 150, 150), "collision": (255, 0, 200)}


def risk_colors(distances, clear: float = 0.1) -> np.ndarray:
    """(...) environment distances (m) -> (..., 3) uint8: red at or below 0, green from `clear` on."""
    if not (np.isfinite(clear) and clear > 0):
        raise ValueError(f"clear must be a positive distance in metres, got {clear!r}")
    from matplotlib import colormaps

    t = np.clip(np.asarray(distances, dtype=np.float64) / clear, 0.0, 1.0)
    return (colormaps[RISK_COLORMAP](t)[..., :3] * 255).round().astype(np.uint8)


def _mesh(mesh, color) -> rr.Mesh3D:
    return rr.Mesh3D(vertex_positions=mesh.vertices.astype(np.float32), triangle_indices=mesh.faces.astype(np.uint32),
                     vertex_normals=mesh.vertex_normals.astype(np.float32), albedo_factor=color)


def log_scene_frame(rec: rr.RecordingStream, scene, entity: str = "world/scene") -> None:
    """Replace whatever scene was under `entity` by `scene`'s obstacles and target, from the current time on."""
    rec.log(entity, rr.Clear(recursive=True))
    for o in scene.obstacles:
        rec.log(f"{entity}/obstacles/{o.name}", _mesh(obstacle_trimesh(o), TABLE_COLOR if o.name == TABLE_NAME
                                                      else OBSTACLE_COLORS[o.kind]))
    if scene.target is not None:
        rec.log(f"{entity}/target/{scene.target.name}", _mesh(obstacle_trimesh(scene.target), TARGET_COLOR))


def log_sdf_plane(rec: rr.RecordingStream, plane, axis: int, index: int, bounds, vmax: float,
                  entity: str = "world/sdf") -> None:
    """A colour-mapped SDF slice and its zero level set, from the current time on (the temporal twin of
    `samp.scene.viz.log_sdf_slice`, with the same geometry and colours).

    `plane` (n_e, n_e) is the slice `np.take(grid, index, axis)` of an (x, y, z)-indexed grid (n_e,)^3 over
    `bounds`; only the plane is needed, so a caller may compute it alone."""
    plane = np.asarray(plane)
    n_e = plane.shape[0]
    if plane.shape != (n_e, n_e):
        raise ValueError(f"plane must be a square (n_e, n_e) slice of a grid, got shape {plane.shape}")
    image = plane.T  # (v, u), as samp.scene.viz.slice_values orders it
    corners, texcoords = slice_quad(axis, index, n_e, bounds)
    rec.log(f"{entity}/image", rr.Mesh3D(vertex_positions=corners.astype(np.float32), triangle_indices=QUAD_TRIANGLES,
                                         vertex_texcoords=texcoords.astype(np.float32),
                                         albedo_texture=sdf_colors(image, vmax)))
    strips = zero_contour(image, axis, index, n_e, bounds)
    rec.log(f"{entity}/zero_level", rr.LineStrips3D([s.astype(np.float32) for s in strips], colors=(0, 0, 0),
                                                    radii=0.003))


def log_robot_state(rec: rr.RecordingStream, link_poses: dict[str, np.ndarray], points: np.ndarray,
                    distances: np.ndarray, entity: str = "world/robot", clear: float = 0.1) -> None:
    """Link transforms (link name -> (4, 4)) for meshes logged by `log_robot_meshes(rec, robot, entity)`,
    and robot points (m, 3) coloured by their environment distance (m,) (`risk_colors`)."""
    for name, T in link_poses.items():
        rec.log(f"{entity}/links/{name}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
    rec.log(f"{entity}/points", rr.Points3D(np.asarray(points, dtype=np.float32), colors=risk_colors(distances, clear),
                                            radii=0.005))


def log_path(rec: rr.RecordingStream, entity: str, points: np.ndarray | None, color, radius: float = 0.004) -> None:
    """A polyline (W, 3), or clear `entity` when points is None."""
    if points is None or len(points) == 0:
        rec.log(entity, rr.Clear(recursive=False))
        return
    rec.log(entity, rr.LineStrips3D([np.asarray(points, dtype=np.float32)], colors=color, radii=radius))


def log_markers(rec: rr.RecordingStream, entity: str, positions: np.ndarray | None, color, radius: float = 0.02,
                labels: list[str] | None = None) -> None:
    """Marker spheres at positions (k, 3), or clear `entity` when there are none."""
    if positions is None or len(positions) == 0:
        rec.log(entity, rr.Clear(recursive=False))
        return
    rec.log(entity, rr.Points3D(np.asarray(positions, dtype=np.float32).reshape(-1, 3), colors=color, radii=radius,
                                labels=labels))


def rollout_blueprint() -> rrb.Blueprint:
    """The layout a recording opens with: the 3D world large on the left; on the right the current
    rollout's summary, the clearance and goal-error plots, and the evaluation's metrics table."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="rollout"),
            rrb.Vertical(
                rrb.TextDocumentView(origin="summary/rollout", name="this rollout"),
                rrb.TimeSeriesView(origin="plots", name="closest robot point to an obstacle / goal error [m]"),
                rrb.TextDocumentView(origin="summary/metrics", name="metrics"),
                row_shares=[2, 3, 3]),
            column_shares=[3, 2]),
        rrb.TimePanel(timeline="frame", expanded=True),
        rrb.SelectionPanel(expanded=False),
    )
