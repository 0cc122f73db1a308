"""Drawing a `Scene` and its anchor grid into a Rerun recording: obstacle meshes, SDF slices, anchors.

Grids are (n_e, n_e, n_e) signed distances indexed (x, y, z) over inclusive linspaces of the bounds
(docs/design.md section 4, `samp.scene.grid`). Distances are coloured with one diverging colormap, symmetric
about 0: red inside obstacles, white on their surfaces, blue outside.
"""

from __future__ import annotations

import numpy as np
import rerun as rr
import trimesh

from samp.scene.grid import anchor_points
from samp.scene.model import Box, Cylinder, MeshObstacle, Scene, Sphere, check_bounds

__all__ = ["SDF_COLORMAP", "anchor_stride", "log_anchor_points", "log_scene_obstacles", "log_sdf_slice",
           "nearest_anchor_index", "obstacle_trimesh", "sdf_colors", "slice_quad", "slice_values", "zero_contour"]

SDF_COLORMAP = "RdBu"  # matplotlib's diverging map: low (inside) red, 0 white, high (outside) blue
AXES = "xyz"
QUAD_TRIANGLES = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint32)
OBSTACLE_COLORS = {"box": (205, 180, 140), "cylinder": (185, 165, 205), "sphere": (225, 205, 120),
                   "mesh": (170, 200, 170)}
TABLE_NAME, TABLE_COLOR = "table", (150, 150, 150)  # the generators' table (samp.scene.generators.table)
TARGET_COLOR = (40, 200, 90)  # green: apart from the colormap's reds and blues
BOUNDS_COLOR = (120, 120, 120)


def obstacle_trimesh(obstacle) -> trimesh.Trimesh:
    """The obstacle's surface in the base frame (boxes with one normal per face, for flat shading)."""
    if isinstance(obstacle, Box):
        mesh = trimesh.creation.box(extents=obstacle.size)
        mesh.unmerge_vertices()
    elif isinstance(obstacle, Cylinder):
        mesh = trimesh.creation.cylinder(radius=obstacle.radius, height=obstacle.height, sections=48)  # axis z, centred
    elif isinstance(obstacle, Sphere):
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=obstacle.radius)
    elif isinstance(obstacle, MeshObstacle):
        from samp.scene.sdf import obstacle_mesh

        mesh = obstacle_mesh(obstacle).copy()
    else:
        raise TypeError(f"expected a Box, Cylinder, Sphere or MeshObstacle, got {type(obstacle).__name__}")
    return mesh.apply_transform(obstacle.pose.matrix())


def _log_mesh(rec: rr.RecordingStream, path: str, mesh: trimesh.Trimesh, color) -> None:
    rec.log(path, rr.Mesh3D(vertex_positions=mesh.vertices.astype(np.float32),
                            triangle_indices=mesh.faces.astype(np.uint32),
                            vertex_normals=mesh.vertex_normals.astype(np.float32), albedo_factor=color), static=True)


def log_scene_obstacles(rec: rr.RecordingStream, scene: Scene, entity: str = "scene") -> None:
    """Static meshes under `{entity}/obstacles/{name}` and `{entity}/target/{name}`, and the workspace
    bounds as a box at `{entity}/bounds`."""
    for o in scene.obstacles:
        color = TABLE_COLOR if o.name == TABLE_NAME else OBSTACLE_COLORS[o.kind]
        _log_mesh(rec, f"{entity}/obstacles/{o.name}", obstacle_trimesh(o), color)
    if scene.target is not None:
        _log_mesh(rec, f"{entity}/target/{scene.target.name}", obstacle_trimesh(scene.target), TARGET_COLOR)
    lo, hi = np.asarray(scene.bounds)
    rec.log(f"{entity}/bounds", rr.Boxes3D(mins=[lo], sizes=[hi - lo], colors=BOUNDS_COLOR), static=True)


def sdf_colors(values, vmax: float) -> np.ndarray:
    """(...) signed distances -> (..., 3) uint8 RGB from SDF_COLORMAP over [-vmax, vmax] (clipped)."""
    if not np.isfinite(vmax) or vmax <= 0:
        raise ValueError(f"the colour range must be a positive number of metres, got {vmax!r}")
    from matplotlib import colormaps

    t = (np.clip(np.asarray(values, dtype=np.float64), -vmax, vmax) + vmax) / (2 * vmax)
    return (colormaps[SDF_COLORMAP](t)[..., :3] * 255).round().astype(np.uint8)


def _plane_axes(axis: int) -> tuple[int, int]:
    """The in-plane axes (u, v) of a slice normal to `axis`, in increasing order."""
    if axis not in (0, 1, 2):
        raise ValueError(f"slice axis must be 0 (x), 1 (y) or 2 (z), got {axis!r}")
    u, v = (a for a in range(3) if a != axis)
    return u, v


def _axis_coords(n_e: int, bounds) -> list[np.ndarray]:
    """The anchors' x, y and z coordinates, (n_e,) each, taken from `anchor_points` itself."""
    points = anchor_points(n_e, bounds).numpy()  # (n, n, n, 3); n_e and bounds are checked there
    return [points[:, 0, 0, 0], points[0, :, 0, 1], points[0, 0, :, 2]]


def _min_spacing(n_e: int, bounds) -> float:
    """The smallest anchor spacing over the three axes, metres (sizes points and lines)."""
    lo, hi = np.asarray(check_bounds(bounds))
    return float(((hi - lo) / (n_e - 1)).min())


def slice_values(grid, axis: int, index: int) -> np.ndarray:
    """(n_e, n_e, n_e) grid indexed (x, y, z) -> (n_e, n_e) image of the plane `axis` = anchor `index`.

    Pixel [r, c] is the anchor with index c along the slice's u axis and r along its v axis
    (`_plane_axes`: x = const gives (u, v) = (y, z), y = const (x, z), z = const (x, y)).
    """
    grid = np.asarray(grid)
    _plane_axes(axis)
    if grid.ndim != 3 or not 0 <= index < grid.shape[axis]:
        raise ValueError(f"expected a 3D grid and an index within it, got shape {grid.shape} and index {index}")
    return np.take(grid, index, axis=axis).T  # (n_u, n_v) -> (n_v, n_u)


def slice_quad(axis: int, index: int, n_e: int, bounds) -> tuple[np.ndarray, np.ndarray]:
    """World corners (4, 3) and texture coordinates (4, 2) of the quad showing `slice_values(...)`.

    Each pixel covers one anchor's cell (half a spacing either side), so pixel [r, c], whose centre
    has texcoord ((c + 0.5) / n_e, (r + 0.5) / n_e) (Rerun: origin top-left, u along columns), lands
    on its anchor. The quad reaches half a spacing past the bounds. Triangles: QUAD_TRIANGLES.
    """
    u, v = _plane_axes(axis)
    coords = _axis_coords(n_e, bounds)
    if not 0 <= index < n_e:
        raise ValueError(f"slice index must be in [0, {n_e - 1}], got {index}")
    half = [(c[-1] - c[0]) / (n_e - 1) / 2 for c in coords]  # half a spacing per axis
    texcoords = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)  # (4, 2) as (u, v)
    corners = np.empty((4, 3))
    corners[:, axis] = coords[axis][index]
    for a, t in ((u, texcoords[:, 0]), (v, texcoords[:, 1])):
        corners[:, a] = np.where(t == 0, coords[a][0] - half[a], coords[a][-1] + half[a])
    return corners, texcoords


def zero_contour(image: np.ndarray, axis: int, index: int, n_e: int, bounds) -> list[np.ndarray]:
    """Zero level lines of a `slice_values` image (n_e, n_e) as world polylines, each (k, 3); linear
    interpolation between anchors (contourpy, matplotlib's contouring engine)."""
    import contourpy

    u, v = _plane_axes(axis)
    coords = _axis_coords(n_e, bounds)
    lines = contourpy.contour_generator(x=coords[u], y=coords[v], z=np.asarray(image, dtype=np.float64)).lines(0.0)
    strips = []
    for line in lines:  # (k, 2) in (u, v)
        xyz = np.empty((len(line), 3))
        xyz[:, axis], xyz[:, u], xyz[:, v] = coords[axis][index], line[:, 0], line[:, 1]
        strips.append(xyz)
    return strips


def log_sdf_slice(rec: rr.RecordingStream, grid, axis: int, index: int, bounds, vmax: float,
                  entity: str = "sdf") -> None:
    """A colour-mapped slice as a textured quad at `{entity}/slice_{x|y|z}/image` and its zero level
    set as black lines at `{entity}/slice_{x|y|z}/zero_level`."""
    n_e = np.asarray(grid).shape[0]
    image = slice_values(grid, axis, index)  # (n_v, n_u)
    corners, texcoords = slice_quad(axis, index, n_e, bounds)
    path = f"{entity}/slice_{AXES[axis]}"
    rec.log(f"{path}/image", rr.Mesh3D(vertex_positions=corners.astype(np.float32), triangle_indices=QUAD_TRIANGLES,
                                        vertex_texcoords=texcoords.astype(np.float32),
                                        albedo_texture=sdf_colors(image, vmax)), static=True)
    strips = zero_contour(image, axis, index, n_e, bounds)
    spacing = _min_spacing(n_e, bounds)
    rec.log(f"{path}/zero_level", rr.LineStrips3D([s.astype(np.float32) for s in strips], colors=(0, 0, 0),
                                                  radii=0.08 * spacing), static=True)


def nearest_anchor_index(point, n_e: int, bounds) -> np.ndarray:
    """(3,) base-frame point -> (3,) int index of the nearest anchor (clipped into the grid)."""
    lo, hi = np.asarray(check_bounds(bounds))
    k = np.rint((np.asarray(point, dtype=np.float64) - lo) / (hi - lo) * (n_e - 1))
    return np.clip(k, 0, n_e - 1).astype(int)


def anchor_stride(n_e: int, max_points: int) -> int:
    """The smallest per-axis stride s with ceil(n_e / s)^3 <= max_points."""
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    s = 1
    while -(-n_e // s) ** 3 > max_points:
        s += 1
    return s


def log_anchor_points(rec: rr.RecordingStream, grid, bounds, vmax: float, stride: int = 1,
                      entity: str = "sdf/anchors") -> int:
    """Every `stride`-th anchor per axis as points coloured by signed distance; returns how many."""
    grid = np.asarray(grid)
    n_e = grid.shape[0]
    points = anchor_points(n_e, bounds).numpy()[::stride, ::stride, ::stride].reshape(-1, 3)  # (N, 3)
    values = grid[::stride, ::stride, ::stride].reshape(-1)  # (N,)
    spacing = _min_spacing(n_e, bounds)
    rec.log(entity, rr.Points3D(points.astype(np.float32), colors=sdf_colors(values, vmax),
                                radii=0.12 * spacing * stride), static=True)
    return len(points)
