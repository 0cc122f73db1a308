"""Robot model: description (YAML + URDF), batched FK, link meshes and robot points."""

from samp.robot.config import RobotConfig, available_robots, load_robot_config
from samp.robot.model import Robot, load_robot

__all__ = ["Robot", "RobotConfig", "available_robots", "load_robot", "load_robot_config"]
