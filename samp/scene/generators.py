"""Seeded scene generators. Each is a function `(rng, **params) -> (obstacles, target)`, wrapped by
`generate_scene`, and configured by a YAML file in `conf/scene/` that lists its parameters.

Every scene stands on a table whose top is the plane z = 0 of the robot base frame. Generators keep a
cylinder of radius `base_clearance` around the base axis free, and leave the target with a free
approach from above or from the front (checked with the exact SDF).
"""

from __future__ import annotations

import numpy as np

from samp.scene.model import Box, Cylinder, Pose, Sphere

__all__ = ["blocks", "cabinet", "shelf", "tabletop", "table"]


def table(size=(1.6, 1.6), thickness=0.04, center=(0.3, 0.0)) -> Box:
    """The table under the robot, top surface at z = 0."""
    return Box("table", (size[0], size[1], thickness), Pose((center[0], center[1], -thickness / 2)))


def _polar(rng, r_range, angle_range):
    r, a = rng.uniform(*r_range), rng.uniform(*angle_range)
    return r * np.cos(a), r * np.sin(a), a


def _check_ranges(**ranges) -> None:
    for key, (lo, hi) in ranges.items():
        if not (0 <= lo <= hi):
            raise ValueError(f"{key} must be a range [min, max] with 0 <= min <= max, got {[lo, hi]}")


def _clutter_item(rng, name, kind, sizes, x, y, yaw):
    """One obstacle standing on the table at (x, y) and its footprint radius."""
    if kind == "box":
        size = rng.uniform(*sizes["box"], size=3)
        return Box(name, tuple(size), Pose.from_xyz_yaw(x, y, size[2] / 2, yaw)), float(np.hypot(size[0], size[1]) / 2)
    if kind == "cylinder":
        radius, height = rng.uniform(*sizes["cylinder_radius"]), rng.uniform(*sizes["cylinder_height"])
        return Cylinder(name, radius, height, Pose.from_xyz_yaw(x, y, height / 2, yaw)), float(radius)
    radius = rng.uniform(*sizes["sphere_radius"])
    z = radius + rng.uniform(0.0, sizes["sphere_lift"])  # spheres may float, as obstacles in the paper's scenes
    return Sphere(name, radius, Pose((x, y, z))), float(radius)


def tabletop(rng, *, num_obstacles=(6, 12), kinds=("box", "cylinder", "sphere"), box=(0.04, 0.25),
             cylinder_radius=(0.02, 0.08), cylinder_height=(0.08, 0.35), sphere_radius=(0.03, 0.1),
             sphere_lift=0.4, radius=(0.3, 0.85), angle=(-2.6, 2.6), base_clearance=0.25, gap=0.02,
             target_size=(0.05, 0.05, 0.08), target_radius=(0.4, 0.7), table_size=(1.6, 1.6), max_tries=2000):
    """A table with a random clutter of boxes, cylinders and spheres, and a small target box on it."""
    _check_ranges(num_obstacles=num_obstacles, box=box, cylinder_radius=cylinder_radius,
                  cylinder_height=cylinder_height, sphere_radius=sphere_radius, radius=radius, target_radius=target_radius)
    sizes = dict(box=box, cylinder_radius=cylinder_radius, cylinder_height=cylinder_height,
                 sphere_radius=sphere_radius, sphere_lift=sphere_lift)
    tx, ty, ta = _polar(rng, target_radius, angle)
    target = Box("target", tuple(target_size), Pose.from_xyz_yaw(tx, ty, target_size[2] / 2, ta))
    placed = [(tx, ty, float(np.hypot(*target_size[:2])) / 2 + 0.1)]  # keep an approach ring around the target
    obstacles = [table(table_size)]
    count = int(rng.integers(num_obstacles[0], num_obstacles[1] + 1))
    for _ in range(max_tries):
        if len(obstacles) - 1 >= count:
            break
        x, y, yaw = _polar(rng, radius, angle)
        item, r = _clutter_item(rng, f"clutter_{len(obstacles) - 1}", kinds[rng.integers(len(kinds))], sizes, x, y, yaw)
        if np.hypot(x, y) - r < base_clearance or any(np.hypot(x - px, y - py) < r + pr + gap for px, py, pr in placed):
            continue
        placed.append((x, y, r))
        obstacles.append(item)
    return obstacles, target


def _panels(prefix, width, depth, height, thickness, rows, cols, open_front=True):
    """Boards of a shelf carcass in its own frame (front face at x = -depth/2, floor at z = 0)."""
    t, boards = thickness, []
    boards.append(Box(f"{prefix}_back", (t, width, height), Pose((depth / 2 - t / 2, 0.0, height / 2))))
    for side, y in (("left", width / 2 - t / 2), ("right", -width / 2 + t / 2)):
        boards.append(Box(f"{prefix}_{side}", (depth, t, height), Pose((0.0, y, height / 2))))
    for i in range(rows + 1):
        z = t / 2 + i * (height - t) / rows
        boards.append(Box(f"{prefix}_board{i}", (depth, width, t), Pose((0.0, 0.0, z))))
    for j in range(1, cols):
        y = -width / 2 + j * width / cols
        boards.append(Box(f"{prefix}_divider{j}", (depth, t, height), Pose((0.0, y, height / 2))))
    return boards


def _place(boxes, x, y, yaw):
    """Move boxes given in a local frame to a base-frame pose (x, y, yaw) on the table."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = []
    for b in boxes:
        px, py, pz = b.pose.position
        out.append(Box(b.name, b.size, Pose.from_xyz_yaw(x + c * px - s * py, y + s * px + c * py, pz, yaw)))
    return out


def shelf(rng, *, distance=(0.4, 0.55), angle=(-0.6, 0.6), width=(0.7, 1.0), depth=(0.3, 0.4),
          height=(0.9, 1.15), rows=(3, 4), cols=(2, 3), thickness=0.02, target_size=(0.04, 0.04, 0.08)):
    """A bookshelf of cubbies facing the robot, a target in one cubby."""
    _check_ranges(distance=distance, width=width, depth=depth, height=height, rows=rows, cols=cols)
    W, D, H = rng.uniform(*width), rng.uniform(*depth), rng.uniform(*height)
    R, C = int(rng.integers(rows[0], rows[1] + 1)), int(rng.integers(cols[0], cols[1] + 1))
    dist, yaw = rng.uniform(*distance) + D / 2, rng.uniform(*angle)  # `distance` is to the front face
    boards = _panels("shelf", W, D, H, thickness, R, C)
    # Target in a random cubby, in its front half so a hand can reach it.
    i, j = int(rng.integers(1, R)), int(rng.integers(C))  # row 0 (floor level) is skipped: too low to reach
    cz = thickness + i * (H - thickness) / R
    cy = -W / 2 + (j + 0.5) * W / C
    local_target = Box("target", tuple(target_size), Pose((-D / 4, cy, cz + target_size[2] / 2)))
    # The shelf faces the robot (its local -x axis points at the base), `yaw` around the base.
    placed = _place([*boards, local_target], dist * np.cos(yaw), dist * np.sin(yaw), yaw)
    return [table(), *placed[:-1]], placed[-1]


def cabinet(rng, *, distance=(0.4, 0.5), angle=(-0.5, 0.5), width=(0.5, 0.7), depth=(0.4, 0.5),
            height=(0.5, 0.75), drawer_height=(0.12, 0.18), opening=(0.15, 0.3), thickness=0.02,
            target_size=(0.04, 0.04, 0.06)):
    """A cabinet with a partly open top drawer (as in the paper's real-world test), a target in the drawer."""
    _check_ranges(distance=distance, width=width, depth=depth, height=height, drawer_height=drawer_height, opening=opening)
    W, D, H = rng.uniform(*width), rng.uniform(*depth), rng.uniform(*height)
    dh, op = rng.uniform(*drawer_height), rng.uniform(*opening)
    dist, yaw = rng.uniform(*distance) + op + D / 2, rng.uniform(*angle)  # `distance` is to the open drawer
    t = thickness
    body = _panels("cabinet", W, D, H, t, rows=1, cols=1)  # back, sides, bottom and top boards
    # Drawer: a tray below the top board, slid out by `op` toward the robot (-x).
    dz = H - t - dh / 2 - 0.005
    dw, dd = W - 2 * t - 0.01, D - t - 0.01
    cx = -op + (-D / 2 + dd / 2)
    drawer = [Box("drawer_bottom", (dd, dw, t), Pose((cx, 0.0, dz - dh / 2 + t / 2))),
              Box("drawer_front", (t, dw + 0.02, dh + 0.02), Pose((cx - dd / 2 - t / 2, 0.0, dz))),
              Box("drawer_back", (t, dw, dh), Pose((cx + dd / 2 - t / 2, 0.0, dz))),
              Box("drawer_left", (dd, t, dh), Pose((cx, dw / 2 - t / 2, dz))),
              Box("drawer_right", (dd, t, dh), Pose((cx, -dw / 2 + t / 2, dz)))]
    # Target in the open part of the drawer, reachable from above.
    tx = cx - dd / 2 + rng.uniform(0.05, max(0.06, op - 0.03))
    ty = rng.uniform(-dw / 2 + 0.06, dw / 2 - 0.06)
    local_target = Box("target", tuple(target_size), Pose((tx, ty, dz - dh / 2 + t + target_size[2] / 2)))
    placed = _place([*body, *drawer, local_target], dist * np.cos(yaw), dist * np.sin(yaw), yaw)
    return [table(), *placed[:-1]], placed[-1]


def blocks(rng, *, mode="random", num_blocks=(3, 6), block=(0.06, 0.3), radius=(0.35, 0.8), angle=(-2.4, 2.4),
           t_size=(0.5, 0.12, 0.35), base_clearance=0.3, gap=0.05, target_size=(0.05, 0.05, 0.05), max_tries=2000):
    """A large T block (`mode: t`), several blocks (`mode: several`), or either at random (`random`)."""
    if mode not in ("t", "several", "random"):
        raise ValueError(f"blocks mode must be 't', 'several' or 'random', got {mode!r}")
    _check_ranges(num_blocks=num_blocks, block=block, radius=radius)
    mode = ("t", "several")[rng.integers(2)] if mode == "random" else mode
    tx, ty, ta = _polar(rng, (0.4, 0.65), angle)
    target = Box("target", tuple(target_size), Pose.from_xyz_yaw(tx, ty, target_size[2] / 2, ta))
    obstacles = [table()]
    if mode == "t":
        L, T, Ht = t_size
        x, y, a = _polar(rng, (max(radius[0], base_clearance + L / 2), radius[1]), angle)
        while np.hypot(x - tx, y - ty) < L / 2 + 0.15:  # keep the target clear of the T
            x, y, a = _polar(rng, (max(radius[0], base_clearance + L / 2), radius[1]), angle)
        bar = Box("t_bar", (L, T, Ht), Pose((0.0, 0.0, Ht / 2)))
        stem = Box("t_stem", (T, L * 0.8, Ht), Pose((0.0, -T / 2 - L * 0.4, Ht / 2)))
        obstacles += _place([bar, stem], x, y, a + np.pi / 2)
        return obstacles, target
    placed = [(tx, ty, 0.12)]
    count = int(rng.integers(num_blocks[0], num_blocks[1] + 1))
    for _ in range(max_tries):
        if len(obstacles) - 1 >= count:
            break
        x, y, yaw = _polar(rng, radius, angle)
        size = rng.uniform(*block, size=3)
        r = float(np.hypot(size[0], size[1]) / 2)
        if np.hypot(x, y) - r < base_clearance or any(np.hypot(x - px, y - py) < r + pr + gap for px, py, pr in placed):
            continue
        placed.append((x, y, r))
        obstacles.append(Box(f"block_{len(obstacles) - 1}", tuple(size), Pose.from_xyz_yaw(x, y, size[2] / 2, yaw)))
    return obstacles, target
