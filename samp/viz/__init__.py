"""Rerun drawing functions. Each takes an explicit `rerun.RecordingStream`; none uses global state."""

from samp.viz.robot import SHELL_COLORS, log_robot_meshes, log_robot_pose
from samp.viz.rollout import (RISK_COLORMAP, log_markers, log_path, log_robot_state, log_scene_frame, log_sdf_plane,
                              risk_colors, rollout_blueprint)
from samp.viz.scene import (SDF_COLORMAP, anchor_stride, log_anchor_points, log_scene_obstacles, log_sdf_slice,
                            nearest_anchor_index, obstacle_trimesh, sdf_colors, slice_quad, slice_values, zero_contour)

__all__ = ["RISK_COLORMAP", "SDF_COLORMAP", "SHELL_COLORS", "anchor_stride", "log_anchor_points", "log_markers",
           "log_path", "log_robot_meshes", "log_robot_pose", "log_robot_state", "log_scene_frame", "log_scene_obstacles",
           "log_sdf_plane", "log_sdf_slice", "nearest_anchor_index", "obstacle_trimesh", "risk_colors",
           "rollout_blueprint", "sdf_colors", "slice_quad", "slice_values", "zero_contour"]
