"""The top layer: training recipes. `python -m samp.train` (cli.py) runs `recipe.train`, which composes and
checks a config (config.py), builds what is missing (prerequisites.py), fits one system, evaluates it in
memory (after_fit.py) and records the run. `sweep.py` runs the recipe once per sweep member;
`robot_sdf_compare.py` trains and compares the robot SDF methods (Table III). Nothing below this package
imports it (docs/architecture.md)."""

from samp.train.cli import main
from samp.train.config import compose_train_config
from samp.train.recipe import train

__all__ = ["compose_train_config", "main", "train"]
