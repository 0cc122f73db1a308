"""Seeded scene generators for cells unlike the original four: obstacles all around and above the base
(`around`), floating clutter (`clutter`), thin walls and narrow passages (`walls`), cubbies and cages
(`cubbies`). Same contract as `samp.scene.generators`: `(rng, **params) -> (obstacles, target)`, configured
by `conf/scene/NAME.yaml`, table top at z = 0, the base axis kept clear, the target on a surface within
reach with a free pre-grasp point (`samp.scene.registry` redraws a seed whose draw misses either check).

Every generator keeps its obstacles inside the default workspace bounds (x, y in [-1, 1], z up to 1.25 m),
which already reach past the arm's reach all around the base: a policy is bound to one set of bounds
(`samp.policy.base`), so scenes mixed in one dataset must share them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from samp.scene.generators import _check_ranges, _panels, _place, _polar, table
from samp.scene.model import Box, Cylinder, Pose, Sphere

__all__ = ["around", "clutter", "cubbies", "walls"]


def _random_quaternion(rng) -> tuple[float, ...]:
    """A rotation uniform over SO(3), as (x, y, z, w): a normalised 4-d Gaussian draw."""
    q = rng.normal(size=4)
    return tuple(q / np.linalg.norm(q))


def _count(rng, bounds) -> int:
    return int(rng.integers(bounds[0], bounds[1] + 1))


def _target_on(x, y, z, size, yaw=0.0) -> Box:
    """The target box standing on a surface at height z."""
    return Box("target", tuple(size), Pose.from_xyz_yaw(x, y, z + size[2] / 2, yaw))


def _overhead(rng, name, height, side, beam_length, beam_width, offset, thickness) -> Box:
    """A plate (square-ish, `side`) or a beam (long and narrow) above the base at a random height."""
    z = rng.uniform(*height)
    x, y, yaw = _polar(rng, offset, (-np.pi, np.pi))
    size = (rng.uniform(*side), rng.uniform(*side)) if rng.random() < 0.5 else \
        (rng.uniform(*beam_length), rng.uniform(*beam_width))
    return Box(name, (size[0], size[1], thickness), Pose.from_xyz_yaw(x, y, z, rng.uniform(-np.pi, np.pi)))


def around(rng, *, num_obstacles=(3, 16), box=(0.05, 0.3), pillar_radius=(0.02, 0.08), height=(0.1, 1.1),
           radius=(0.35, 0.9), base_clearance=0.25, gap=0.03, overhead_share=0.75, overhead_height=(0.85, 1.15),
           overhead_side=(0.3, 0.8), beam_length=(0.8, 1.6), beam_width=(0.06, 0.15), overhead_offset=(0.0, 0.4),
           overhead_thickness=0.03, target_size=(0.05, 0.05, 0.08), target_radius=(0.4, 0.7),
           target_angle=(-2.6, 2.6), table_size=(2.0, 2.0), max_tries=2000):
    """Boxes and pillars standing all around the base (every bearing, behind and beside it too) on a table
    that reaches behind the robot, and in `overhead_share` of the scenes a plate or a beam above the base."""
    _check_ranges(num_obstacles=num_obstacles, box=box, pillar_radius=pillar_radius, height=height, radius=radius,
                  overhead_height=overhead_height, overhead_side=overhead_side, beam_length=beam_length,
                  beam_width=beam_width, overhead_offset=overhead_offset, target_radius=target_radius)
    tx, ty, ta = _polar(rng, target_radius, target_angle)
    target = _target_on(tx, ty, 0.0, target_size, ta)
    placed = [(tx, ty, float(np.hypot(*target_size[:2])) / 2 + 0.1)]  # an approach ring around the target
    obstacles = [table(table_size, center=(0.0, 0.0))]
    count = _count(rng, num_obstacles)
    for _ in range(max_tries):
        if len(obstacles) - 1 >= count:
            break
        x, y, yaw = _polar(rng, radius, (-np.pi, np.pi))
        h, name = rng.uniform(*height), f"around_{len(obstacles) - 1}"
        if rng.random() < 0.5:
            size = (*rng.uniform(*box, size=2), h)
            item, r = Box(name, size, Pose.from_xyz_yaw(x, y, h / 2, yaw)), float(np.hypot(*size[:2]) / 2)
        else:
            r = float(rng.uniform(*pillar_radius))
            item = Cylinder(name, r, h, Pose((x, y, h / 2)))
        if np.hypot(x, y) - r < base_clearance or any(np.hypot(x - px, y - py) < r + pr + gap for px, py, pr in placed):
            continue
        placed.append((x, y, r))
        obstacles.append(item)
    if rng.random() < overhead_share:
        obstacles.append(_overhead(rng, "overhead", overhead_height, overhead_side, beam_length, beam_width,
                                   overhead_offset, overhead_thickness))
    return obstacles, target


def _floating_item(rng, name, kind, box, cylinder_radius, cylinder_length, sphere_radius):
    """A primitive at the origin with a random orientation, and the radius of a sphere that holds it."""
    if kind == "box":
        size = rng.uniform(*box, size=3)
        return Box(name, tuple(size), Pose(quaternion=_random_quaternion(rng))), float(np.linalg.norm(size) / 2)
    if kind == "cylinder":
        r, length = rng.uniform(*cylinder_radius), rng.uniform(*cylinder_length)
        return Cylinder(name, r, length, Pose(quaternion=_random_quaternion(rng))), float(np.hypot(r, length / 2))
    r = float(rng.uniform(*sphere_radius))
    return Sphere(name, r), r


def clutter(rng, *, num_obstacles=(5, 40), kinds=("box", "cylinder", "sphere"), box=(0.05, 0.2),
            cylinder_radius=(0.02, 0.08), cylinder_length=(0.08, 0.35), sphere_radius=(0.03, 0.1),
            radius=(0.3, 0.9), angle=(-np.pi, np.pi), height=(0.03, 1.15), base_clearance=0.25,
            target_keepout=0.12, target_size=(0.05, 0.05, 0.08), target_radius=(0.4, 0.7),
            target_angle=(-2.6, 2.6), table_size=(2.0, 2.0), max_tries=5000):
    """Boxes, cylinders and spheres of random sizes and orientations floating above the table (none touches
    it), anywhere around the base; they may overlap one another. Items keep `target_keepout` clear of the
    target and of the column above it, so the target (on the table) keeps a way in from above."""
    _check_ranges(num_obstacles=num_obstacles, box=box, cylinder_radius=cylinder_radius,
                  cylinder_length=cylinder_length, sphere_radius=sphere_radius, radius=radius, height=height,
                  target_radius=target_radius)
    tx, ty, ta = _polar(rng, target_radius, target_angle)
    target = _target_on(tx, ty, 0.0, target_size, ta)
    obstacles = [table(table_size, center=(0.0, 0.0))]
    count = _count(rng, num_obstacles)
    for _ in range(max_tries):
        if len(obstacles) - 1 >= count:
            break
        kind = kinds[rng.integers(len(kinds))]
        item, r = _floating_item(rng, f"clutter_{len(obstacles) - 1}", kind, box, cylinder_radius, cylinder_length,
                                 sphere_radius)
        x, y, _ = _polar(rng, radius, angle)
        if height[0] + r > height[1] - r:  # too large to float within the height range
            continue
        z = rng.uniform(height[0] + r, height[1] - r)  # the bounding sphere lies within `height`: it floats
        # Distance to the target's column (from its centre upward), in the horizontal plane above its top.
        to_column = np.hypot(x - tx, y - ty) if z > target.pose.position[2] else np.linalg.norm(
            [x - tx, y - ty, z - target.pose.position[2]])
        if np.hypot(x, y) - r < base_clearance or to_column < r + target_keepout:
            continue
        obstacles.append(replace(item, pose=Pose((x, y, z), item.pose.quaternion)))
    return obstacles, target


def _wall_with_window(prefix, width, height, thickness, window_width, window_height, window_y, window_z):
    """A wall in the plane x = 0 of its own frame (floor at z = 0) with a rectangular window, as four boards
    around the opening: left, right, below and above it."""
    y0, y1 = window_y - window_width / 2, window_y + window_width / 2
    z0, z1 = window_z, window_z + window_height
    boards = [(f"{prefix}_left", (-width / 2, y0), (0.0, height)),
              (f"{prefix}_right", (y1, width / 2), (0.0, height)),
              (f"{prefix}_below", (y0, y1), (0.0, z0)),
              (f"{prefix}_above", (y0, y1), (z1, height))]
    return [Box(name, (thickness, b - a, top - bottom), Pose((0.0, (a + b) / 2, (bottom + top) / 2)))
            for name, (a, b), (bottom, top) in boards if b - a > 1e-3 and top - bottom > 1e-3]


def walls(rng, *, mode="random", distance=(0.3, 0.45), angle=(-2.2, 2.2), wall_width=(0.8, 1.4),
          wall_height=(0.6, 1.1), thickness=(0.01, 0.04), window_width=(0.3, 0.45), window_height=(0.28, 0.4),
          window_z=(0.1, 0.45), behind=(0.08, 0.14), corridor_width=(0.28, 0.45), corridor_start=(0.3, 0.4),
          window_offset=0.25, corridor_length=(0.45, 0.7), corridor_height=(0.3, 0.9),
          target_size=(0.05, 0.05, 0.08), table_size=(2.0, 2.0)):
    """Thin walls: a wall across the robot's way with a window it must reach into to a target on a post just
    behind it (`mode: window`), two parallel walls forming a corridor with the target inside
    (`mode: corridor`), or either at random (`random`)."""
    if mode not in ("window", "corridor", "random"):
        raise ValueError(f"walls mode must be 'window', 'corridor' or 'random', got {mode!r}")
    _check_ranges(distance=distance, wall_width=wall_width, wall_height=wall_height, thickness=thickness,
                  window_width=window_width, window_height=window_height, window_z=window_z, behind=behind,
                  corridor_width=corridor_width, corridor_start=corridor_start, corridor_length=corridor_length,
                  corridor_height=corridor_height)
    mode = ("window", "corridor")[rng.integers(2)] if mode == "random" else mode
    yaw, t = rng.uniform(*angle), rng.uniform(*thickness)
    if mode == "window":
        W, H, d = rng.uniform(*wall_width), rng.uniform(*wall_height), rng.uniform(*distance)
        ww, wh = rng.uniform(*window_width), rng.uniform(*window_height)
        wz = min(rng.uniform(*window_z), H - wh - 0.05)
        side = max(0.0, min((W - ww) / 2 - 0.05, window_offset))  # the window's centre stays this near the bearing
        wy = rng.uniform(-side, side)
        boards = _wall_with_window("wall", W, H, t, ww, wh, wy, wz)
        # The target stands on a post just behind the window, centred in its height, so its pre-grasp point in
        # front of it (toward the base) lies in the opening: a hand reaches it through the window.
        back, top = rng.uniform(*behind), wz + (wh - target_size[2]) / 2
        stand = Box("stand", (0.1, 0.1, top), Pose((back, wy, top / 2)))
        local = [*boards, stand, Box("target", tuple(target_size), Pose((back, wy, top + target_size[2] / 2)))]
    else:
        w, start = rng.uniform(*corridor_width), rng.uniform(*corridor_start)
        length, H = rng.uniform(*corridor_length), rng.uniform(*corridor_height)
        d = start + length / 2
        local = [Box(f"corridor_{side}", (length, t, H), Pose((0.0, s * (w + t) / 2, H / 2)))
                 for side, s in (("left", 1), ("right", -1))]
        tx = rng.uniform(-length / 2 + 0.1, min(length / 2 - 0.05, 0.85 - d))
        local.append(Box("target", tuple(target_size), Pose((tx, rng.uniform(-w / 4, w / 4), target_size[2] / 2))))
    # Local +x points away from the base along the bearing `yaw`.
    placed = _place(local, d * np.cos(yaw), d * np.sin(yaw), yaw)
    return [table(table_size, center=(0.0, 0.0)), *placed[:-1]], placed[-1]


def _bars(prefix, start, end, height, bar, spacing, skip=None):
    """Vertical square bars from `start` to `end` (x, y) standing at z in `height` (bottom, top); bars whose
    lateral coordinate falls in `skip` (lo, hi) along the row are left out (an opening)."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    n = max(2, int(np.linalg.norm(end - start) / spacing) + 1)
    out = []
    for k, s in enumerate(np.linspace(0.0, 1.0, n)):
        x, y = start + s * (end - start)
        if skip is not None and skip[0] < y < skip[1]:
            continue
        out.append(Box(f"{prefix}{k}", (bar, bar, height[1] - height[0]), Pose((x, y, sum(height) / 2))))
    return out


def _cage(rng, size, bar, spacing, opening, roof, plinth, thickness, target_size):
    """A cage of `size` (W, D, H) in its own frame (front face at x = -D/2, floor at z = 0): bars or plates on
    the back and sides, bars with an opening in front, a roof plate if `roof`; the target inside on a plinth
    `plinth` high, so that a hand reaching in level through the opening clears the table."""
    W, D, H = size
    op = min(rng.uniform(*opening), W - 0.1)
    side = max(0.0, (W - op) / 2 - 0.05)  # clamped: W - op may fall short of 0.1 by a rounding
    oy = rng.uniform(-side, side)
    parts = _bars("cage_front", (-D / 2, -W / 2), (-D / 2, W / 2), (0.0, H), bar, spacing, (oy - op / 2, oy + op / 2))
    sides = {"back": ((D / 2, -W / 2), (D / 2, W / 2)), "left": ((-D / 2, W / 2), (D / 2, W / 2)),
             "right": ((-D / 2, -W / 2), (D / 2, -W / 2))}
    for name, (a, b) in sides.items():
        if rng.random() < 0.5:
            parts += _bars(f"cage_{name}", a, b, (0.0, H), bar, spacing)
        else:
            (xa, ya), (xb, yb) = a, b
            plate = (thickness, W, H) if name == "back" else (D, thickness, H)
            parts.append(Box(f"cage_{name}_plate", plate, Pose(((xa + xb) / 2, (ya + yb) / 2, H / 2))))
    if roof:
        parts.append(Box("cage_roof", (D + bar, W + bar, thickness), Pose((0.0, 0.0, H + thickness / 2))))
    tx = rng.uniform(-D / 2 + 0.14, max(-D / 2 + 0.15, D / 2 - 0.08))
    parts.append(Box("cage_plinth", (0.08, 0.08, plinth), Pose((tx, oy, plinth / 2))))
    return parts, Box("target", tuple(target_size), Pose((tx, oy, plinth + target_size[2] / 2)))


def _grid(rng, cell, depth, rows, cols, elevation, max_height, target_floor, thickness, target_size):
    """A grid of open boxes (cells of `cell` (width, height), `depth` deep) in its own frame (front face at
    x = -depth/2), its bottom `elevation` above the table; the target in the front half of one cell whose
    floor lies within `target_floor`."""
    (cw, ch), D = cell, depth
    R = max(1, min(_count(rng, rows), int((max_height - elevation) / ch)))
    C = _count(rng, cols)
    boards = [Box(b.name, b.size, Pose((b.pose.position[0], b.pose.position[1], b.pose.position[2] + elevation)))
              for b in _panels("cubby", C * cw, D, R * ch, thickness, R, C)]
    floor_z = elevation + thickness + np.arange(R) * (R * ch - thickness) / R  # (R,) tops of the cell floors
    floors = np.flatnonzero((floor_z >= target_floor[0]) & (floor_z <= target_floor[1]))
    if len(floors) == 0:  # no floor in range: the registry redraws a target it cannot approach or reach
        floors = np.array([R - 1])
    i, j = int(floors[rng.integers(len(floors))]), int(rng.integers(C))
    y = -C * cw / 2 + (j + 0.5) * cw
    return boards, Box("target", tuple(target_size), Pose((-D / 4, y, floor_z[i] + target_size[2] / 2)))


def cubbies(rng, *, mode="random", distance=(0.35, 0.5), angle=(-2.4, 2.4), cell_width=(0.2, 0.3),
            cell_height=(0.18, 0.3), depth=(0.22, 0.35), rows=(2, 4), cols=(2, 4), elevation=(0.0, 0.35),
            max_height=1.15, target_floor=(0.1, 0.85), cage_width=(0.4, 0.6), cage_depth=(0.3, 0.45),
            cage_height=(0.35, 0.7), bar=(0.01, 0.025), bar_spacing=(0.07, 0.15), opening=(0.22, 0.35),
            roof_share=0.5, plinth=(0.1, 0.2), thickness=0.02, target_size=(0.04, 0.04, 0.06),
            table_size=(2.0, 2.0)):
    """A grid of open boxes facing the robot, possibly raised off the table (mounted), with the target in one
    of them (`mode: grid`), a cage of thin bars and plates with an opening in front and the target inside
    (`mode: cage`), or either at random (`random`). Either may stand at any bearing, beside or behind the base."""
    if mode not in ("grid", "cage", "random"):
        raise ValueError(f"cubbies mode must be 'grid', 'cage' or 'random', got {mode!r}")
    _check_ranges(distance=distance, cell_width=cell_width, cell_height=cell_height, depth=depth, rows=rows,
                  cols=cols, elevation=elevation, target_floor=target_floor, cage_width=cage_width,
                  cage_depth=cage_depth, cage_height=cage_height, bar=bar, bar_spacing=bar_spacing, opening=opening,
                  plinth=plinth)
    mode = ("grid", "cage")[rng.integers(2)] if mode == "random" else mode
    yaw = rng.uniform(*angle)
    if mode == "grid":
        D = rng.uniform(*depth)
        cell = (rng.uniform(*cell_width), rng.uniform(*cell_height))
        parts, target = _grid(rng, cell, D, rows, cols, rng.uniform(*elevation), max_height, target_floor,
                              thickness, target_size)
    else:
        W, D, H = rng.uniform(*cage_width), rng.uniform(*cage_depth), rng.uniform(*cage_height)
        parts, target = _cage(rng, (W, D, H), rng.uniform(*bar), rng.uniform(*bar_spacing), opening,
                              rng.random() < roof_share, rng.uniform(*plinth), thickness, target_size)
    dist = rng.uniform(*distance) + D / 2  # `distance` is to the front face
    placed = _place([*parts, target], dist * np.cos(yaw), dist * np.sin(yaw), yaw)
    return [table(table_size, center=(0.0, 0.0)), *placed[:-1]], placed[-1]
