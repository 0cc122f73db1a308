"""`ReconstructedGrids`: a grid source for `samp.eval.evaluate` whose grids come from simulated cameras.

Each distinct scene is rendered once by a camera set with the robot at its home configuration (or at
the first problem's start), the clouds are reconstructed into the anchor grid the policy asked for,
and the grid is compared with the exact one. Collision checks are unaffected: `evaluate` always checks
against the true scene geometry; only what the policy sees changes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from samp.perception.reconstruct import NEAR, Reconstruction, reconstruct_grid, reconstruction_error
from samp.sim.scan import Scan

__all__ = ["CAPTURE_POSES", "ReconstructedGrids", "SceneReconstruction"]

CAPTURE_POSES = ("home", "start")


@dataclass
class SceneReconstruction:
    """One scene's reconstruction: where it came from, the clouds, both grids and the errors."""

    scene: object
    label: str  # scene name and dataset index, for reports
    split: str
    n_e: int
    scans: list[Scan] = field(repr=False)
    reconstruction: Reconstruction = field(repr=False)
    exact: torch.Tensor = field(repr=False)
    error: dict
    capture_s: float
    reconstruct_s: float

    def record(self) -> dict:
        """A JSON-able summary."""
        return {"scene": self.label, "split": self.split, "n_e": self.n_e, "points": self.reconstruction.points,
                "unknown_fraction": self.reconstruction.unknown_fraction, "capture_s": self.capture_s,
                "reconstruct_s": self.reconstruct_s, **self.error}


class ReconstructedGrids:
    """(problem, n_e) -> (n_e, n_e, n_e) reconstructed anchor grid, one reconstruction per scene and n_e.

    Args:
        cameras: a `CameraSet`, a conf/camera name or a YAML path.
        robot: the robot rendered and filtered out (float64 on the CPU is best).
        exact: the exact grid source, for the error (default: each scene's `anchor_grid`).
        unknown: "free" | "occupied", what unobserved space becomes.
        padding: metres of volume beyond the bounds.
        capture: "home" (robot.home) or "start" (the first problem's q_start of each scene).
    """

    def __init__(self, cameras, robot, exact=None, unknown: str = "free", padding: float = 0.1,
                 capture: str = "home", near: float = NEAR):
        from samp.sim.camera import load_camera_set

        if capture not in CAPTURE_POSES:
            raise ValueError(f"capture must be one of {CAPTURE_POSES} (the robot's pose while the cameras look), "
                             f"got {capture!r}")
        self.cameras, self.robot, self.exact = load_camera_set(cameras), robot, exact
        self.unknown, self.padding, self.capture, self.near = unknown, padding, capture, near
        self.scenes: list[SceneReconstruction] = []
        self._grids: dict[tuple[str, int], torch.Tensor] = {}

    def __call__(self, problem, n_e: int) -> torch.Tensor:
        key = (problem.scene.content_hash(), int(n_e))
        if key not in self._grids:
            self._grids[key] = self._reconstruct(problem, int(n_e))
        return self._grids[key]

    def _reconstruct(self, problem, n_e: int) -> torch.Tensor:
        from samp.sim import World
        from samp.sim.camera import robot_volume

        scene = problem.scene
        q = self.robot.home.cpu().numpy() if self.capture == "home" else np.asarray(problem.q_start)
        t0 = time.perf_counter()
        with World(self.robot, scene) as world:
            scans = world.capture(self.cameras, q)
        t1 = time.perf_counter()
        lo, hi = np.asarray(scene.bounds)
        margin = 0.5 * float(np.linalg.norm((hi - lo) / (n_e - 1)))  # half a voxel diagonal: the robot's surface voxels
        rec = reconstruct_grid(scans, n_e, scene.bounds, self.unknown, self.padding, robot_volume(self.robot, q, margin))
        t2 = time.perf_counter()
        exact = self.exact(problem, n_e) if self.exact is not None else scene.anchor_grid(n_e)
        label = scene.name if problem.scene_index is None else f"{scene.name} (scene {problem.scene_index})"
        self.scenes.append(SceneReconstruction(scene, label, problem.split, n_e, scans, rec, exact,
                                               reconstruction_error(rec.grid, exact, self.near), t1 - t0, t2 - t1))
        return rec.grid

    def report(self) -> dict:
        """Settings, per-scene records and the mean errors (mm), for metrics.json."""
        rows = [s.record() for s in self.scenes]
        mean = {k: float(np.nanmean([r[k] for r in rows])) if rows else None
                for k in ("mae_near_mm", "max_near_mm", "mae_all_mm", "sign_error_near", "unknown_fraction",
                          "capture_s", "reconstruct_s")}
        return {"grid_source": "reconstructed", "camera": self.cameras.name, "cameras": len(self.cameras.cameras),
                "unknown": self.unknown, "padding": self.padding, "capture": self.capture, "near": self.near,
                "mean": mean, "scenes": rows}

    def summary(self) -> str:
        """One line for the console."""
        m = self.report()["mean"]
        if not self.scenes:
            return "reconstruction: no grids were needed (the planner takes no anchor grid)"
        return (f"reconstruction ({self.cameras.name}, {len(self.cameras.cameras)} cameras, unknown={self.unknown}), "
                f"{len(self.scenes)} scenes: MAE near obstacles {m['mae_near_mm']:.1f} mm (|d| < {self.near} m), "
                f"all {m['mae_all_mm']:.1f} mm, unknown {100 * m['unknown_fraction']:.0f}% of anchors, "
                f"{m['capture_s'] + m['reconstruct_s']:.2f} s per scene")
