"""Exact signed distance of a scene: analytic for primitives (vectorised torch), trimesh for meshes.

The union of obstacles is the minimum over obstacles. All distances are in metres, negative inside.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch
import trimesh

from samp.meshes import load_mesh
from samp.scene.model import Box, Cylinder, MeshObstacle, Scene, Sphere

__all__ = ["box_sdf", "cylinder_sdf", "sphere_sdf", "scene_sdf", "mesh_signed_distance", "obstacle_mesh", "obstacle_parts"]

CHUNK = 1 << 18  # points per chunk: bounds peak memory at (CHUNK, obstacles, 3)


def box_sdf(local: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """(..., K, 3) points in box frames, (K, 3) half extents -> (..., K)."""
    q = local.abs() - half
    outside = q.clamp(min=0).norm(dim=-1)
    inside = q.max(dim=-1).values.clamp(max=0)
    return outside + inside


def cylinder_sdf(local: torch.Tensor, radius: torch.Tensor, half_height: torch.Tensor) -> torch.Tensor:
    """(..., K, 3) points in cylinder frames (axis z), (K,) radius and half height -> (..., K)."""
    d = torch.stack([local[..., :2].norm(dim=-1) - radius, local[..., 2].abs() - half_height], dim=-1)
    return d.max(dim=-1).values.clamp(max=0) + d.clamp(min=0).norm(dim=-1)


def sphere_sdf(local: torch.Tensor, radius: torch.Tensor) -> torch.Tensor:
    """(..., K, 3) points relative to sphere centres, (K,) radius -> (..., K)."""
    return local.norm(dim=-1) - radius


def _frames(obstacles, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotations (K, 3, 3) and translations (K, 3) of the obstacles' poses."""
    T = np.stack([o.pose.matrix() for o in obstacles])
    return (torch.as_tensor(T[:, :3, :3], dtype=dtype, device=device),
            torch.as_tensor(T[:, :3, 3], dtype=dtype, device=device))


def _to_local(points: torch.Tensor, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """(N, 3) base-frame points -> (N, K, 3) in each obstacle's frame: R^T (p - t)."""
    return torch.einsum("nkj,kji->nki", points[:, None, :] - t, R)


def _primitive_sdf(scene: Scene, points: torch.Tensor) -> torch.Tensor:
    """(N, 3) -> (N,) min over the scene's primitives (+inf when it has none)."""
    best = torch.full(points.shape[:1], float("inf"), dtype=points.dtype, device=points.device)
    groups = {cls: [o for o in scene.all_obstacles if isinstance(o, cls)] for cls in (Box, Cylinder, Sphere)}
    kw = dict(dtype=points.dtype, device=points.device)
    for cls, obs in groups.items():
        if not obs:
            continue
        R, t = _frames(obs, **kw)
        local = _to_local(points, R, t)
        if cls is Box:
            d = box_sdf(local, torch.tensor([o.size for o in obs], **kw) / 2)
        elif cls is Cylinder:
            d = cylinder_sdf(local, torch.tensor([o.radius for o in obs], **kw),
                             torch.tensor([o.height for o in obs], **kw) / 2)
        else:
            d = sphere_sdf(local, torch.tensor([o.radius for o in obs], **kw))
        best = torch.minimum(best, d.min(dim=-1).values)
    return best


@lru_cache(maxsize=64)
def obstacle_parts(obstacle: MeshObstacle) -> tuple[trimesh.Trimesh, ...]:
    """The obstacle's closed bodies in its own frame (scaled, welded by position); its convex hull when
    asked for. A file of several bodies (a V-HACD decomposition) is their union."""
    mesh = load_mesh(obstacle.resolved_path(), solid=True)  # checked: bounded, not empty, not flat
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.apply_scale(obstacle.scale)
    if obstacle.convex_hull:
        return (mesh.convex_hull,)
    if not mesh.is_watertight:  # every edge shared by two faces; a union of closed bodies passes too
        raise ValueError(f"mesh obstacle {obstacle.name!r} ({obstacle.path}) is not closed, so its inside is "
                         "undefined; set convex_hull=True to use its convex hull")
    return tuple(mesh.split(only_watertight=False))


def obstacle_mesh(obstacle: MeshObstacle) -> trimesh.Trimesh:
    """All bodies of the obstacle as one mesh (for drawing and for the simulator)."""
    return trimesh.util.concatenate(list(obstacle_parts(obstacle)))


def _mesh_sdf(obstacle: MeshObstacle, points: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Signed distance to one mesh obstacle for (N, 3) points, computed exactly only where it can beat
    `upper` (the distance to a body's bounding box is a lower bound; elsewhere the result is `upper`)."""
    T = obstacle.pose.matrix()
    local = (points - T[:3, 3]) @ T[:3, :3]
    out = upper.copy()
    for body in obstacle_parts(obstacle):
        lo, hi = body.bounds
        box_dist = np.linalg.norm(np.maximum(np.maximum(lo - local, local - hi), 0.0), axis=1)
        need = box_dist < out
        if need.any():
            out[need] = np.minimum(out[need], -mesh_signed_distance(body, local[need]))
    return out


def mesh_signed_distance(mesh: trimesh.Trimesh, points: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """trimesh's signed distance (positive inside) in chunks: its closest-point query holds a candidate
    list per point and runs out of memory on large point sets far from a fine mesh."""
    return np.concatenate([trimesh.proximity.signed_distance(mesh, points[i:i + chunk])
                           for i in range(0, len(points), chunk)]) if len(points) else np.zeros(0)


def scene_sdf(scene: Scene, points):
    """(..., 3) points, torch or numpy -> (...) signed distance of the same kind. Differentiable in the
    points for primitives (torch input); mesh distances come from trimesh and carry no gradient."""
    is_numpy = not isinstance(points, torch.Tensor)
    pts = torch.as_tensor(np.asarray(points, dtype=np.float64)) if is_numpy else points
    if pts.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {tuple(pts.shape)}")
    flat = pts.reshape(-1, 3)
    out = torch.cat([_primitive_sdf(scene, chunk) for chunk in flat.split(CHUNK)]) if len(flat) else flat[:, 0]
    meshes = [o for o in scene.all_obstacles if isinstance(o, MeshObstacle)]
    if meshes:
        upper = out.detach().double().cpu().numpy()
        np_pts = flat.detach().double().cpu().numpy()
        for m in meshes:
            upper = _mesh_sdf(m, np_pts, upper)
        exact = torch.as_tensor(upper, dtype=out.dtype, device=out.device)
        out = torch.where(exact < out, exact, out)
    if torch.isinf(out).any():
        raise ValueError(f"scene {scene.name!r} has no obstacles; its signed distance is undefined")
    out = out.reshape(pts.shape[:-1])
    return out.numpy() if is_numpy else out
