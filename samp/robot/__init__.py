"""Robot model: description (YAML + URDF), batched FK, link meshes and robot points. Names are imported on
first use: reading a robot's config (`available_robots`, `load_robot_config`) needs no torch."""

from samp import lazy_exports

__getattr__, __all__ = lazy_exports(__name__, {
    "RobotConfig": "samp.robot.config", "available_robots": "samp.robot.config",
    "load_robot_config": "samp.robot.config", "Robot": "samp.robot.model", "load_robot": "samp.robot.model"})
