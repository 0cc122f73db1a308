"""`python -m samp.robot show robot=NAME ...` and `python -m samp.robot add urdf=PATH name=NAME ...`

`show` prints a summary of the robot (joints, limits, links, robot points per link and shell) and writes a
Rerun recording with the link meshes at a few configurations and the robot points coloured by shell.
`add` writes a new robot's config from its URDF (samp/robot/add.py), loads it and prints the same summary
and the commands that train its robot SDF and a policy.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from samp.cli import compose, output_path, run_command

USAGE = """usage: python -m samp.robot show robot=NAME [out=FILE.rrd] [configs=N] [seed=S]
       python -m samp.robot add urdf=PATH name=NAME [base=LINK] [ee=LINK] [out=DIR] [samples=N] [seed=S] [force=true]
  show    print a robot's joints, limits, links and robot points; write a Rerun recording of it
  add     write DIR/robot/NAME.yaml from a URDF (joints, limits, collision and point links, self-collision
          exclusions, a collision-free home), load it, and print what to run next"""


def summary(robot) -> str:
    """A plain-text report of joints, limits, links and robot points."""
    lines = [f"robot {robot.name}: {robot.dof} joints, {len(robot.link_names)} collision links, "
             f"{len(robot.points)} robot points", f"  urdf   {robot.urdf.path}",
             f"  base   {robot.base_link}    end effector {robot.ee_link}",
             f"  asset  sha256 {robot.asset_hash[:16]}", "", "  joint                      lower [rad]  upper [rad]"]
    for name, (lo, hi) in zip(robot.joint_names, robot.joint_limits.tolist()):
        lines.append(f"  {name:<26} {lo:>11.4f}  {hi:>11.4f}")
    offsets = robot.cfg.points.offsets
    counts = np.zeros((len(robot.point_link_names), len(offsets)), dtype=int)
    np.add.at(counts, (robot.point_links.cpu().numpy(), robot.point_shells.cpu().numpy()), 1)
    header = "".join(f"{f'{d * 1000:g} mm':>9}" for d in offsets)
    lines += ["", f"  link                  parts  area [m^2]{header}    total"]
    for name in robot.link_names:
        geom = robot.geometry[name]
        row = counts[robot.point_link_names.index(name)] if name in robot.point_link_names else None
        cells = "".join(f"{c:>9}" for c in row) + f"{row.sum():>9}" if row is not None else "   (no points)"
        lines.append(f"  {name:<22}{len(geom.parts):>5}  {geom.area:>10.4f}{cells}")
    lines.append(f"  {'total':<39}" + "".join(f"{c:>9}" for c in counts.sum(0)) + f"{counts.sum():>9}")
    if robot.self_collision_exclude:
        lines += ["", "  self-collision exclusions: " + ", ".join(f"{a}-{b}" for a, b in robot.self_collision_exclude)]
    return "\n".join(lines)


def sample_free_configurations(robot, count: int, seed: int) -> torch.Tensor:
    """(count, n): home, then random configurations within the limits that are free of self-collision."""
    from samp.robot.bodies import LinkBodies

    rng = np.random.default_rng(seed)
    lo, hi = robot.joint_limits.double().cpu().numpy().T
    qs = [robot.home.double().cpu().numpy()]
    with LinkBodies(robot) as bodies:
        for _ in range(1000 * count):
            if len(qs) >= count:
                break
            q = rng.uniform(lo, hi)
            bodies.set_q(q)
            if not bodies.colliding_pairs(exclude=robot.self_collision_exclude):
                qs.append(q)
    return torch.tensor(np.stack(qs[:count]))


def show(overrides: list[str]) -> Path:
    import rerun as rr

    from samp.robot import load_robot
    from samp.robot.viz import log_robot_meshes, log_robot_pose

    cfg = compose("robot_show", overrides)
    robot = load_robot(cfg.robot, dtype=torch.float64)
    print(summary(robot))
    out = output_path(cfg.out)
    rec = rr.RecordingStream("samp_robot", recording_id=f"robot-{robot.name}")
    log_robot_meshes(rec, robot)
    for i, q in enumerate(sample_free_configurations(robot, int(cfg.configs), int(cfg.seed))):
        rec.set_time("configuration", sequence=i)
        log_robot_pose(rec, robot, q)
    rec.save(out)
    print(f"\nwrote {out} ({cfg.configs} configurations); open it with `rerun {out}`")
    return out


def _help() -> str:
    from samp.cli import command_help
    from samp.robot.add import ADD_OPTIONS

    return (f"{USAGE}\n\nshow's options (key=default; conf/robot_show.yaml):\n{command_help('robot_show')}"
            f"\n\nadd's options:\n{ADD_OPTIONS}")


def add(overrides: list[str]) -> Path:
    from samp.robot.add import add_robot

    return add_robot(overrides, summary)


def main(argv: list[str] | None = None) -> int:
    return run_command(argv, _help, {"show": show, "add": add})


if __name__ == "__main__":
    sys.exit(main())
