"""The suites of `tools/bench.py`, one module each, and `common` for what they share.

Every suite module has `add_arguments(parser)`, which adds the options it owns, and `run(args) -> (metrics,
table)`: a flat dict for the JSON report and the rows of the printed table, header first. All suites' options go
on one flat parser (the command line predates this split: `bench.py SUITE --anchors ...` takes any option for any
suite), so a suite may read an option that another one adds; each module's docstring says which.

Suite modules import samp inside their functions, so that `bench.py --help` stays fast and a suite's
dependencies (pybullet, OMPL, Lightning) load only when it runs.
"""

from __future__ import annotations

import importlib

# The order the suites were defined in when bench.py was one file; their options appear in --help in this order.
NAMES = ("robot", "scene", "data", "eval", "policy", "robot_sdf", "perception", "baselines", "paper")

# name -> module (imported by name: the `eval` suite's module would shadow the builtin as a plain import).
SUITES = {name: importlib.import_module(f"{__name__}.{name}") for name in NAMES}
