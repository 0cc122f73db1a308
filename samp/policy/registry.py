"""Which system a policy checkpoint holds, in one place.

Every policy checkpoint carries `checkpoint["samp"]["kind"]` (written by `PolicySystemBase`); the kind
names the system class that rebuilds it, registered when the class is defined
(`class MPiNetSystem(PolicySystemBase, kind="mpinet")`). `load_policy(checkpoint)` reads the kind and
returns that system's planner. Checkpoints written before the record existed (a `policy` or a `baseline`
entry, n_e and bounds among the hyperparameters) are translated once, in `_legacy_record`.
"""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path

import torch

from samp.device import resolve_device
from samp.names import CHECKPOINT_RECORD
from samp.paths import find_checkpoint

__all__ = ["load_policy", "load_system", "policy_kinds", "read_checkpoint", "register_policy"]

_SYSTEMS: dict[str, type] = {}


def register_policy(kind: str, cls: type) -> None:
    """Make `cls` the system that rebuilds checkpoints of `kind` (called by `PolicySystemBase.__init_subclass__`)."""
    known = _SYSTEMS.get(kind)
    if known is not None and known.__qualname__ != cls.__qualname__:
        raise ValueError(f"policy kind {kind!r} is taken by {known.__module__}.{known.__qualname__}")
    _SYSTEMS[kind] = cls


def _discover() -> None:
    """Import the SAMP system and every module of `samp.policy.baselines`, so that their kinds register:
    a new baseline is found without being listed anywhere."""
    import samp.policy.baselines as baselines

    importlib.import_module("samp.policy.system")
    for module in pkgutil.iter_modules(baselines.__path__):
        if module.name.endswith("_system"):
            importlib.import_module(f"{baselines.__name__}.{module.name}")


def policy_kinds() -> list[str]:
    _discover()
    return sorted(_SYSTEMS)


def _legacy_record(ckpt: dict) -> dict:
    """The record of a checkpoint saved before `checkpoint["samp"]` existed, and its hyperparameters
    rewritten to today's arguments (n_e, bounds and dataset id became the binding; lr, weight decay and
    restarts became the optimizer and scheduler nodes; evaluation and build settings moved to the recipe)."""
    hp = dict(ckpt.get("hyper_parameters") or {})
    old = ckpt.get("baseline") or ckpt.get("policy")
    if old is None:
        raise ValueError("the checkpoint holds no policy record (no 'samp', 'policy' or 'baseline' entry): it was not "
                         "written by a samp policy system")
    kind = ckpt["baseline"]["kind"] if "baseline" in ckpt else "samp"
    binding = None
    if hp.get("n_e") is not None:
        binding = {"robot": old["robot"], "robot_asset_hash": old["robot_asset_hash"], "n_e": hp["n_e"],
                   "bounds": hp["bounds"], "dataset_id": hp.get("dataset_id")}
    for key in ("n_e", "bounds", "dataset_id", "eval_problems", "runs_dir", "build_robot_sdf", "build_overrides"):
        hp.pop(key, None)
    if "lr" in hp:
        hp["optimizer"] = {"_target_": "torch.optim.AdamW", "_partial_": True, "lr": hp.pop("lr"),
                           "weight_decay": hp.pop("weight_decay", 1e-2)}
        hp["scheduler"] = {"_target_": "torch.optim.lr_scheduler.CosineAnnealingWarmRestarts", "_partial_": True,
                           "T_0": hp.pop("restart_epochs", 10), "T_mult": hp.pop("restart_mult", 2)}
    if kind == "samp" and "goal_features" not in old.get("net", {"goal_features": True}):
        hp["model"] = {**(hp.get("model") or {}), "goal_features": False}  # saved before goal features: the paper's MLP_I
    ckpt["hyper_parameters"] = hp
    record = {"kind": kind, "robot": old["robot"], "robot_asset_hash": old["robot_asset_hash"], "binding": binding}
    if kind == "samp":
        record["robot_sdf"] = ckpt.get("robot_sdf_payload")
    return record


def read_checkpoint(checkpoint: str | Path | dict, map_location="cpu", trust_checkpoint: bool | None = None) -> dict:
    """A policy checkpoint (a file, a run folder or the loaded dict) as a dict with its `samp` record (older
    formats translated).

    A file is first compared with the sha256 its run recorded, then loaded without running code from it
    (`samp.integrity.load_torch_file`); `trust_checkpoint=True` (or SAMP_TRUST_CHECKPOINTS=1) unpickles it
    fully, for a file from someone you trust that needs more than tensors and plain values."""
    from samp.integrity import check_recorded_hash, load_torch_file

    if isinstance(checkpoint, dict):
        ckpt = checkpoint
    else:
        path = Path(checkpoint)
        if path.is_dir():
            path = find_checkpoint(path)
        if not path.is_file():
            raise FileNotFoundError(f"no checkpoint at {path}")
        check_recorded_hash(path)
        ckpt = load_torch_file(path, "policy checkpoint", trust=trust_checkpoint, map_location=map_location)
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        raise ValueError(f"{checkpoint if not isinstance(checkpoint, dict) else 'the object'} is not a Lightning "
                         "checkpoint (no state_dict)")
    if CHECKPOINT_RECORD not in ckpt:
        ckpt[CHECKPOINT_RECORD] = _legacy_record(ckpt)
    return ckpt


def load_system(checkpoint: str | Path | dict, map_location="cpu", trust_checkpoint: bool | None = None):
    """The trained system a policy checkpoint (or a run folder's) holds, whatever its kind, in eval mode."""
    ckpt = read_checkpoint(checkpoint, map_location, trust_checkpoint)
    kind = ckpt[CHECKPOINT_RECORD].get("kind")
    _discover()
    if kind not in _SYSTEMS:
        raise ValueError(f"the checkpoint holds a policy of kind {kind!r}; this samp knows {sorted(_SYSTEMS)}")
    return _SYSTEMS[kind].from_checkpoint(ckpt, map_location)


def load_policy(checkpoint: str | Path | dict, run_dir: str | Path | None = None, *,
                device: str | torch.device | None = "cpu", trust_checkpoint: bool | None = None, **options):
    """The planner of a policy checkpoint or run folder (a `StepPolicy` with `plan`, or a `TrajectoryPlanner`
    for MPNet), on `device` (auto | cpu | cuda[:N]), with `options` for its `planner(...)`. The run folder
    is not needed besides a checkpoint file: a checkpoint is whole. `trust_checkpoint`: see `read_checkpoint`."""
    device = resolve_device(device)
    return load_system(checkpoint, trust_checkpoint=trust_checkpoint).to(device).planner(**options)
