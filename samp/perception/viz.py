"""A Rerun recording of reconstructions: per scene, the cameras and their clouds beside the true scene,
and the reconstructed and exact SDF slices side by side, swept upwards through the workspace.

Timeline `frame`: each scene takes `slices` frames, one per z slice (timeline `scene` carries its index).
Entities: `recon/cloud/<camera>` (points coloured per camera), `recon/cameras/<camera>` (pinhole
frusta), `recon/sdf` and `exact/sdf` (3D slices), `exact/scene` (the true obstacles), and 2D images
`slices/reconstructed`, `slices/exact`, `slices/error` (reconstructed minus exact).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["reconstruction_blueprint", "write_reconstruction_recording"]

VMAX = 0.3  # metres: colour range of the SDF slices
ERROR_VMAX = 0.05  # metres: colour range of the error image
MAX_POINTS = 30_000  # cloud points drawn per scene (a seeded subsample)
CAMERA_COLORS = [(230, 100, 40), (40, 150, 230), (120, 200, 60), (200, 60, 200), (230, 200, 40), (60, 200, 200)]


def reconstruction_blueprint():
    """Reconstructed (with the clouds) and exact views side by side, the slice images below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(rrb.Spatial3DView(origin="recon", name="clouds and reconstructed SDF"),
                           rrb.Spatial3DView(origin="exact", name="true scene and exact SDF")),
            rrb.Horizontal(rrb.Spatial2DView(origin="slices/reconstructed", name="reconstructed slice"),
                           rrb.Spatial2DView(origin="slices/exact", name="exact slice"),
                           rrb.Spatial2DView(origin="slices/error", name="error (reconstructed - exact)"),
                           rrb.TextDocumentView(origin="summary", name="errors")),
            row_shares=[3, 2]),
        rrb.TimePanel(timeline="frame", expanded=True),
    )


def _log_clouds(rec, scans, rng) -> None:
    import rerun as rr

    total = sum(len(s.hits) for s in scans)
    keep = min(1.0, MAX_POINTS / max(total, 1))
    rec.log("recon/cloud", rr.Clear(recursive=True))
    for i, s in enumerate(scans):
        pts = s.hits[rng.random(len(s.hits)) < keep]
        rec.log(f"recon/cloud/{s.name}", rr.Points3D(pts.astype(np.float32), colors=CAMERA_COLORS[i % len(CAMERA_COLORS)],
                                                     radii=0.004))


def _log_cameras(rec, cameras) -> None:
    import rerun as rr

    for c in cameras.cameras:
        T = c.pose_matrix()
        fx, fy, cx, cy = c.intrinsics
        rec.log(f"recon/cameras/{c.name}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
        rec.log(f"recon/cameras/{c.name}", rr.Pinhole(focal_length=[fx, fy], principal_point=[cx, cy],
                                                      resolution=[c.width, c.height], camera_xyz=rr.ViewCoordinates.RDF,
                                                      image_plane_distance=0.15), static=True)


def _summary(s) -> str:
    e = s.error
    return "\n".join([f"### {s.label} ({s.split}), n_e = {s.n_e}", "",
                      f"- MAE near obstacles: {e['mae_near_mm']:.1f} mm (max {e['max_near_mm']:.1f} mm)",
                      f"- MAE over all anchors: {e['mae_all_mm']:.1f} mm",
                      f"- wrong sign near obstacles: {100 * e['sign_error_near']:.1f}% of anchors",
                      f"- unknown anchors: {100 * s.reconstruction.unknown_fraction:.0f}% "
                      f"(policy: {s.reconstruction.unknown})",
                      f"- points: {s.reconstruction.points}"])


def write_reconstruction_recording(path: str | Path, scenes, cameras, slices: int = 6,
                                   recording_id: str | None = None) -> Path:
    """Write `scenes` (`SceneReconstruction`s, e.g. `ReconstructedGrids.scenes`) seen by `cameras` to
    `path` (.rrd): `slices` z slices per scene, evenly spaced over the grid."""
    import rerun as rr

    from samp.scene.viz import sdf_colors
    from samp.viz.rollout import log_scene_frame, log_sdf_plane

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("samp_reconstruction", recording_id=recording_id or f"reconstruction-{path.parent.name}")
    rec.save(path, default_blueprint=reconstruction_blueprint())
    _log_cameras(rec, cameras)
    rng, frame = np.random.default_rng(0), 0
    for k, s in enumerate(scenes):
        recon, exact = s.reconstruction.grid.numpy(), np.asarray(s.exact)
        rec.set_time("frame", sequence=frame)
        rec.set_time("scene", sequence=k)
        log_scene_frame(rec, s.scene, entity="exact/scene")
        _log_clouds(rec, s.scans, rng)
        rec.log("summary", rr.TextDocument(_summary(s), media_type="text/markdown"))
        for index in np.unique(np.linspace(0, s.n_e - 1, slices).round().astype(int)):
            rec.set_time("frame", sequence=frame)
            for root, grid in (("recon", recon), ("exact", exact)):
                log_sdf_plane(rec, grid[:, :, index], 2, int(index), s.scene.bounds, VMAX, entity=f"{root}/sdf")
            # Images: rows along y (flipped, so +y is up), columns along x.
            for name, grid, vmax in (("reconstructed", recon, VMAX), ("exact", exact, VMAX),
                                     ("error", recon - exact, ERROR_VMAX)):
                rec.log(f"slices/{name}", rr.Image(sdf_colors(grid[:, :, index].T[::-1], vmax)))
            frame += 1
    rec.flush()
    rec.disconnect()
    return path
