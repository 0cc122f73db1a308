"""`load_planner(source)`: a trained policy from its run folder, the expert, or the straight-line baseline.

A run folder (docs/design.md section 6) is read for what evaluation needs:
  * `run.json`: the dataset the run trained on and its robot. Read tolerantly, since the run registry
    writes it: `dataset` as a reference string (name@id or a folder) or a mapping with `ref`, `path`,
    or `name` and `id` (also a top-level `dataset_id`); `robot` as a name or a mapping with `name` and
    `asset_hash` (also a top-level `robot_asset_hash`).
  * `checkpoints/best.ckpt` (the best rollout success, `EvalCallback`), else `checkpoints/last.ckpt`.
The checkpoint is turned into a `StepPolicy` by `samp.policy.load_policy(checkpoint, run_dir)`, imported
only when a run is loaded, so evaluation works before (and without) the policy package.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from samp.eval.names import CHECKPOINT_DIR, RUN_JSON
from samp.eval.planners import ExpertTrajectoryPlanner, StraightLinePolicy
from samp.paths import find_checkpoint  # re-exported

__all__ = ["RunInfo", "check_policy_robot", "check_robot", "find_checkpoint", "load_planner", "read_run"]

BUILTIN = ("expert", "straight")


@dataclass
class RunInfo:
    """What a run folder says about itself (the parts evaluation uses)."""

    path: Path
    dataset: str | None  # a reference open_dataset understands
    robot: str | None
    robot_asset_hash: str | None
    raw: dict


def read_run(run_dir: str | Path) -> RunInfo:
    """Read `run_dir/run.json`; FileNotFoundError if the folder or the file is missing."""
    path = Path(run_dir).expanduser()
    if not path.is_dir():
        raise FileNotFoundError(f"run folder {path} does not exist; give run=RUNS/EXPERIMENT/TIMESTAMP "
                                "(a folder written by `python -m samp.train`)")
    file = path / RUN_JSON
    if not file.is_file():
        raise FileNotFoundError(f"{path} is not a run folder: it has no {RUN_JSON}. Give the folder that "
                                f"`python -m samp.train` created (it holds {RUN_JSON} and {CHECKPOINT_DIR}/)")
    try:
        raw = json.loads(file.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{file} is not valid JSON ({err}); the run record is damaged") from None
    ds = raw.get("dataset")
    if isinstance(ds, dict):
        ds = ds.get("ref") or ds.get("path") or (f"{ds['name']}@{ds['id']}" if ds.get("name") and ds.get("id") else None)
    ds = ds or raw.get("dataset_id")
    robot = raw.get("robot")
    asset = raw.get("robot_asset_hash")
    if isinstance(robot, dict):
        robot, asset = robot.get("name"), robot.get("asset_hash", asset)
    return RunInfo(path, ds, robot, asset, raw)


def check_robot(run: RunInfo, manifest: dict) -> None:
    """Refuse a run trained for another robot (name or asset hash) than the dataset's."""
    robot = manifest.get("robot", {})
    label = f"dataset {manifest.get('name')}@{manifest.get('id')}"
    if run.robot and robot.get("name") and run.robot != robot["name"]:
        raise ValueError(f"run {run.path} is a policy for robot {run.robot!r}, but {label} is for {robot['name']!r}; "
                         f"evaluate it on a {run.robot} dataset (dataset=REF)")
    if run.robot_asset_hash and robot.get("asset_hash") and run.robot_asset_hash != robot["asset_hash"]:
        raise ValueError(f"run {run.path} was trained on robot assets {run.robot_asset_hash[:12]}, but {label} was made "
                         f"with {robot['asset_hash'][:12]} (same name {robot.get('name')!r}, different URDF or meshes); "
                         "evaluate on a dataset generated with the run's robot files")


def check_policy_robot(policy, manifest: dict) -> None:
    """Refuse a loaded policy whose robot (name or asset hash) is not the dataset's: run.json may not name
    the robot, but the policy's own `robot` always does."""
    want = manifest.get("robot", {})
    robot = policy.robot
    label = f"dataset {manifest.get('name')}@{manifest.get('id')}"
    if want.get("name") and robot.name != want["name"]:
        raise ValueError(f"the policy is for robot {robot.name!r}, but {label} is for {want['name']!r}; evaluate it "
                         f"on a {robot.name} dataset (dataset=REF)")
    if want.get("asset_hash") and getattr(robot, "asset_hash", want["asset_hash"]) != want["asset_hash"]:
        raise ValueError(f"the policy's robot assets {robot.asset_hash[:12]} differ from those {label} was made with "
                         f"({want['asset_hash'][:12]}, same name {robot.name!r}, different URDF or meshes)")


def _robot(robot):
    from samp.robot import load_robot

    if robot is None:
        raise ValueError("this planner needs a robot: load_planner(..., robot='panda' or a Robot)")
    return load_robot(robot) if isinstance(robot, (str, Path)) else robot


def load_planner(source: str | Path, *, robot=None, device: str = "cpu", **options):
    """A planner to `evaluate`.

    Args:
        source: a run folder (its policy checkpoint), "expert" (`ExpertTrajectoryPlanner`: options mode, config,
            seed) or "straight" (`StraightLinePolicy`: options max_step, n_e; needs `robot`).
        robot: a robot name or `Robot`, for "straight" and for the expert in mode "plan".
        device: where a trained policy runs: auto | cpu | cuda[:N] (the expert always plans on the CPU;
            the straight line runs where its `robot` is).
    """
    if str(source) == "expert":
        return ExpertTrajectoryPlanner(robot=None if robot is None else _robot(robot), **options)
    if str(source) == "straight":
        return StraightLinePolicy(_robot(robot), **options)
    run = read_run(source)
    checkpoint = find_checkpoint(run.path)
    try:
        from samp.policy import load_policy
    except ImportError as err:
        if err.name != "samp.policy":
            raise  # a missing dependency inside the policy package: its own message is the useful one
        raise ValueError(f"cannot load {checkpoint}: the policy package (samp.policy with load_policy) is not "
                         "available in this version of samp. Evaluate the built-in planners instead: planner=expert "
                         "or planner=straight") from None
    policy = load_policy(checkpoint, run.path, device=device, **options)
    name = getattr(policy.robot, "name", None)
    if run.robot and name and name != run.robot:
        raise ValueError(f"{checkpoint} holds a policy for robot {name!r} but {run.path / RUN_JSON} says {run.robot!r}")
    if robot is not None and name and name != getattr(robot, "name", robot):
        raise ValueError(f"{checkpoint} is a policy for robot {name!r}, not {getattr(robot, 'name', robot)!r}")
    return policy
