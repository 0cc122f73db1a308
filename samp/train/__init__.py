"""The top layer: training recipes. `python -m samp.train` (recipe.py) composes a config, fits one system
and records the run; `sweep.py` runs it once per sweep member; `prerequisites.py` builds a missing
robot SDF before a policy needs it; `after_fit.py` evaluates the model just trained, in memory;
`robot_sdf_compare.py` trains and compares the robot SDF methods (Table III).
Nothing below this package imports it (ARCHITECTURE.md)."""

from samp.train.recipe import compose_train_config, main, train

__all__ = ["compose_train_config", "main", "train"]
