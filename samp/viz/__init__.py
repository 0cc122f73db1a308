"""Rerun drawing functions. Each takes an explicit `rerun.RecordingStream`; none uses global state."""

from samp.viz.robot import SHELL_COLORS, log_robot_meshes, log_robot_pose

__all__ = ["SHELL_COLORS", "log_robot_meshes", "log_robot_pose"]
