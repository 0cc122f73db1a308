"""Reconstruct an anchor grid from a point cloud file and compare it with the exact one.

    python examples/cloud_to_grid.py --cloud my_cloud.pcd --origin 1.9 0 1.3 --n-e 40
    python examples/cloud_to_grid.py --n-e 24 --out /tmp/cloud      # no cloud given: a simulated camera's

Without --cloud, a depth camera (conf/camera/single.yaml) looks at a generated scene and its cloud is
written as PCD and read back, as a cloud from a real sensor would be; the reconstruction is then compared
with the scene's exact grid. Clouds are in the robot base frame, metres (.ply, .pcd or .npy).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cloud", type=Path, help="a .ply, .pcd or .npy cloud (default: simulate one)")
    parser.add_argument("--origin", type=float, nargs=3, help="the sensor position (m), to carve free space")
    parser.add_argument("--n-e", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0, help="the generated scene (without --cloud)")
    parser.add_argument("--out", type=Path, default=Path("cloud_out"))
    args = parser.parse_args(argv)

    from samp.perception import reconstruct_grid, reconstruction_error, save_point_cloud, scan_from_file
    from samp.scene import generate_scene

    scene, origin = None, args.origin
    args.out.mkdir(parents=True, exist_ok=True)
    if args.cloud is None:
        from samp.robot import load_robot
        from samp.sim import World
        from samp.sim.camera import load_camera_set

        scene = generate_scene("tabletop", seed=args.seed)
        with World(load_robot("panda"), scene) as world:
            (scan,) = world.capture(load_camera_set("single"))
        args.cloud = save_point_cloud(args.out / "cloud.pcd", scan.hits)
        origin = scan.origin
        print(f"simulated a depth camera at {np.round(origin, 2).tolist()}: {len(scan.hits)} points -> {args.cloud}")
    bounds = scene.bounds if scene is not None else ((-1.0, -1.0, 0.05), (1.0, 1.0, 1.25))
    result = reconstruct_grid([scan_from_file(args.cloud, origin=origin)], args.n_e, bounds)
    grid = result.grid.numpy()
    np.save(args.out / "grid.npy", grid)
    print(f"reconstructed grid n_e={args.n_e} -> {args.out / 'grid.npy'} ({(grid < 0).mean():.1%} of anchors occupied)")
    if scene is not None:
        err = reconstruction_error(grid, scene.anchor_grid(args.n_e).numpy())
        print(f"against the exact grid: MAE near obstacles {err['mae_near_mm']:.1f} mm, over all anchors "
              f"{err['mae_all_mm']:.1f} mm, wrong sign near obstacles {err['sign_error_near']:.1%}")


if __name__ == "__main__":
    main()
