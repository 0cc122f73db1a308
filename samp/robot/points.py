"""Robot points P: samples on shells around the moving links (docs/design.md section 4).

For each shell offset d, surface points are drawn area-proportionally, pushed out along the face
normal by d and jittered tangentially by up to `jitter * d` (as the paper's released code does). Each
candidate is then projected onto the exact d-level set of its link (a few closest-point steps), so a
point's distance to its own link equals d up to `tolerance * d`; candidates that miss it, and
candidates inside any collision link at the home configuration, are dropped and redrawn.
"""

from __future__ import annotations

import numpy as np
import trimesh

from samp.robot.config import PointsConfig
from samp.robot.geometry import LinkGeometry

__all__ = ["sample_shell_points", "split_counts"]

_PROJECTION_STEPS = 3
_MAX_ROUNDS = 30


def split_counts(total: int, weights) -> np.ndarray:
    """Integer counts proportional to `weights` that sum to `total` (largest remainder)."""
    w = np.asarray(weights, dtype=np.float64)
    exact = total * w / w.sum()
    counts = np.floor(exact).astype(int)
    counts[np.argsort(-(exact - counts), kind="stable")[: total - counts.sum()]] += 1
    return counts


def _transform(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    return x @ T[:3, :3].T + T[:3, 3]


def _candidates(geom: LinkGeometry, d: float, k: int, jitter: float, rng: np.random.Generator) -> np.ndarray:
    surface, face = trimesh.sample.sample_surface(geom.mesh, k, seed=rng)
    normal = geom.mesh.face_normals[face]
    tangent = rng.normal(size=(k, 3))
    tangent -= (tangent * normal).sum(1, keepdims=True) * normal
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12
    p = surface + d * normal + rng.uniform(0.0, jitter * d, size=(k, 1)) * tangent
    for _ in range(_PROJECTION_STEPS):
        closest, dist, _ = trimesh.proximity.closest_point(geom.mesh, p)
        outside = geom.inside_depth(p) > 0
        scale = np.where(outside, d / np.maximum(dist, 1e-12), -d / np.maximum(dist, 1e-12))
        p = closest + (p - closest) * scale[:, None]
    return p


def sample_shell_points(
    geometry: dict[str, LinkGeometry],
    point_links: list[str],
    home_poses: dict[str, np.ndarray],
    cfg: PointsConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample `cfg.count` points around `point_links`.

    Args:
        geometry: collision geometry of every collision link, in link frames.
        point_links: the links that carry points.
        home_poses: link name -> (4, 4) world pose at the home configuration, for every collision link.
    Returns:
        points (M, 3) in link frames, link index (M,) into `point_links`, shell index (M,) into
        `cfg.offsets`; grouped by link, then shell.
    """
    rng = np.random.default_rng(cfg.seed)
    shell_counts = split_counts(cfg.count, np.ones(len(cfg.offsets)))
    areas = [geometry[name].area for name in point_links]
    chunks: dict[tuple[int, int], np.ndarray] = {}
    for s, (d, n_shell) in enumerate(zip(cfg.offsets, shell_counts)):
        for li, n in enumerate(split_counts(n_shell, areas)):
            chunks[li, s] = _sample_link_shell(geometry, point_links[li], home_poses, d, n, cfg, rng)
    order = sorted(chunks)
    points = np.concatenate([chunks[k] for k in order]).astype(np.float64)
    links = np.concatenate([np.full(len(chunks[k]), k[0]) for k in order])
    shells = np.concatenate([np.full(len(chunks[k]), k[1]) for k in order])
    return points, links, shells


def _sample_link_shell(geometry, link, home_poses, d, n, cfg, rng) -> np.ndarray:
    geom, kept = geometry[link], []
    for _ in range(_MAX_ROUNDS):
        need = n - sum(len(k) for k in kept)
        if need <= 0:
            break
        p = _candidates(geom, d, 2 * need + 16, cfg.jitter, rng)
        ok = np.abs(geom.distance(p) - d) <= cfg.tolerance * d
        ok &= geom.inside_depth(p) > 0
        world = _transform(home_poses[link], p)
        for other, g in geometry.items():
            ok &= g.inside_depth(_transform(np.linalg.inv(home_poses[other]), world)) > 0
        kept.append(p[ok][:need])
    points = np.concatenate(kept) if kept else np.zeros((0, 3))
    if len(points) < n:
        raise RuntimeError(f"could only place {len(points)} of {n} points at {d} m around {link}: the shell is "
                           "mostly inside other links at the home configuration; change `home` or the offsets")
    return points
