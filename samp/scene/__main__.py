"""`python -m samp.scene show scene=NAME [seed=S] [n_e=N] [out=FILE.rrd]`, or `show file=PATH` for a scene file

Generates a scene (or reads one from a file, `samp.scene.files`), prints a summary of it and of its anchor
grid (exact signed distances), and writes a Rerun recording with the obstacle meshes, three orthogonal
colour-mapped SDF slices through the target (or the grid centre) with their zero level sets, and the
anchors coloured by signed distance.
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import numpy as np

from samp.cli import compose, output_path, paste, run_command

USAGE = """usage: python -m samp.scene show scene=NAME [seed=S] [n_e=N] [out=FILE.rrd]
       python -m samp.scene show file=PATH [n_e=N] [out=FILE.rrd]
  show    generate a scene (or read a scene file), print it and its anchor grid; write a Rerun recording
          (obstacles, SDF slices, anchors)"""


def slice_indices(scene, n_e: int) -> np.ndarray:
    """(3,) anchor indices of the x, y and z slices: nearest the target, else the grid centre."""
    if scene.target is None:
        return np.full(3, n_e // 2)
    from samp.scene.viz import nearest_anchor_index

    return nearest_anchor_index(scene.target.pose.position, n_e, scene.bounds)


def summary(scene, grid: np.ndarray, slices: np.ndarray) -> str:
    """A plain-text report of the scene and its (n_e, n_e, n_e) anchor grid sliced at `slices` (3,)."""
    n_e = grid.shape[0]
    lo, hi = np.asarray(scene.bounds)
    spacing = (hi - lo) / (n_e - 1)
    kinds = Counter(o.kind for o in scene.obstacles)
    meta = scene.meta
    made = (f"from file {meta['file']} ({meta.get('source', 'scene')})" if "file" in meta else
            f"generator {meta.get('generator', '?')}, seed {meta.get('seed', '?')} "
            f"(attempt {meta.get('attempt', '?')})")
    lines = [f"scene {scene.name}: {made}",
             f"  content hash  {scene.content_hash()[:12]}",
             f"  obstacles     {len(scene.obstacles)}: " + ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))]
    if scene.target is None:
        lines.append("  target        none")
    else:
        x, y, z = scene.target.pose.position
        lines.append(f"  target        {scene.target.kind} {scene.target.name!r} at ({x:.3f}, {y:.3f}, {z:.3f}) m")
    lines += ["  bounds        " + "  ".join(f"{a} [{lo[i]:.3f}, {hi[i]:.3f}]" for i, a in enumerate("xyz")) + " m",
              f"  anchors       n_e {n_e}: {grid.size} anchors, spacing "
              + "  ".join(f"{a} {spacing[i]:.4f}" for i, a in enumerate("xyz")) + " m",
              f"  sdf           min {grid.min():.4f} m, max {grid.max():.4f} m; "
              f"{100 * (grid < 0).mean():.2f}% of anchors inside obstacles (sdf < 0)",
              "  slices        " + ", ".join(f"{a} = {lo[i] + slices[i] * spacing[i]:.3f} m (index {slices[i]})"
                                           for i, a in enumerate("xyz"))
              + (" through the target" if scene.target is not None else " through the grid centre")]
    return "\n".join(lines)


def show(overrides: list[str]) -> Path:
    from omegaconf import OmegaConf


    cfg = compose("scene_show", overrides)
    # Drawing libraries only once the config is known to be good: a typo fails fast.
    import rerun as rr

    from samp.scene.registry import scene_from_config
    from samp.scene.viz import SDF_COLORMAP, anchor_stride, log_anchor_points, log_scene_obstacles, log_sdf_slice

    if cfg.file:
        from samp.scene.files import load_scene_file, resolve_scene_file

        scene = load_scene_file(resolve_scene_file(str(cfg.file)))
    else:
        scene = scene_from_config(OmegaConf.to_container(cfg.scene, resolve=True), int(cfg.seed))
    grid = scene.anchor_grid(cfg.n_e).numpy()  # (n_e, n_e, n_e), indexed (x, y, z); n_e is checked there
    slices = slice_indices(scene, grid.shape[0])
    print(summary(scene, grid, slices))
    vmax = float(np.abs(grid).max()) if cfg.color_range is None else float(cfg.color_range)
    out = output_path(cfg.out if not cfg.file or _given("out", overrides) else _file_out(scene.name))
    rec = rr.RecordingStream("samp_scene", recording_id=f"scene-{scene.name}-{scene.content_hash()[:12]}")
    log_scene_obstacles(rec, scene)
    for axis in range(3):
        log_sdf_slice(rec, grid, axis, int(slices[axis]), scene.bounds, vmax)
    stride = anchor_stride(grid.shape[0], int(cfg.max_points))
    count = log_anchor_points(rec, grid, scene.bounds, vmax, stride)
    rec.save(out)
    print(f"  drawn         {count} of {grid.size} anchors as points (stride {stride}, at most {cfg.max_points}); "
          f"colours {SDF_COLORMAP} over [-{vmax:.3f}, {vmax:.3f}] m: red inside, white on surfaces, blue outside")
    print(f"\nwrote {out}; open it with `{paste('rerun', out)}`")
    return out


def _given(key: str, overrides: list[str]) -> bool:
    return any(o.split("=", 1)[0].lstrip("+") == key for o in overrides)


def _file_out(name: str) -> str:
    """The default recording of a scene file: beside the generated scenes', under the file's scene name."""
    import os

    return str(Path(os.environ.get("SAMP_RUNS_DIR", "runs")) / "scene" / f"file_{name}" / "scene.rrd")


def _help() -> str:
    from samp.cli import command_help

    return f"{USAGE}\n\nshow's options (key=default; conf/scene_show.yaml):\n{command_help('scene_show')}"


def main(argv: list[str] | None = None) -> int:
    return run_command(argv, _help, {"show": show})


if __name__ == "__main__":
    sys.exit(main())
