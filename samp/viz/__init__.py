"""Rerun drawing functions. Each takes an explicit `rerun.RecordingStream`; none uses global state.

Robots and scenes are drawn by their own packages (`samp.robot.viz`, `samp.scene.viz`, so that their CLIs
need nothing above them); their functions are re-exported here beside the rollout drawings.
"""

from samp.robot.viz import SHELL_COLORS, log_robot_meshes, log_robot_pose
from samp.scene.viz import (SDF_COLORMAP, anchor_stride, log_anchor_points, log_scene_obstacles, log_sdf_slice,
                            nearest_anchor_index, obstacle_trimesh, sdf_colors, slice_quad, slice_values, zero_contour)
from samp.viz.rollout import (RISK_COLORMAP, log_markers, log_path, log_robot_state, log_scene_frame, log_sdf_plane,
                              risk_colors, rollout_blueprint)

__all__ = ["RISK_COLORMAP", "SDF_COLORMAP", "SHELL_COLORS", "anchor_stride", "log_anchor_points", "log_markers",
           "log_path", "log_robot_meshes", "log_robot_pose", "log_robot_state", "log_scene_frame", "log_scene_obstacles",
           "log_sdf_plane", "log_sdf_slice", "nearest_anchor_index", "obstacle_trimesh", "risk_colors",
           "rollout_blueprint", "sdf_colors", "slice_quad", "slice_values", "zero_contour"]
