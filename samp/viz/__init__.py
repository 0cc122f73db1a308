"""Rerun drawing functions. Each takes an explicit `rerun.RecordingStream`; none uses global state."""

from samp.viz.robot import SHELL_COLORS, log_robot_meshes, log_robot_pose
from samp.viz.scene import (SDF_COLORMAP, anchor_stride, log_anchor_points, log_scene_obstacles, log_sdf_slice,
                            nearest_anchor_index, obstacle_trimesh, sdf_colors, slice_quad, slice_values, zero_contour)

__all__ = ["SDF_COLORMAP", "SHELL_COLORS", "anchor_stride", "log_anchor_points", "log_robot_meshes", "log_robot_pose",
           "log_scene_obstacles", "log_sdf_slice", "nearest_anchor_index", "obstacle_trimesh", "sdf_colors",
           "slice_quad", "slice_values", "zero_contour"]
