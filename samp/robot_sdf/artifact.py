"""Trained robot SDFs on disk, and `load_robot_sdf(REF)`.

An artifact is one `torch.save` file of plain data (loadable with `weights_only=True`): format, robot
name and asset hash, link names, the network's class and keyword arguments, its state dict, the link
boxes (centres, scales), the method label, the samples dataset id and the code version. Training
writes it as `robot_sdf.pt` into the run folder; the run's Lightning checkpoints carry the same
description under the key `robot_sdf` (weights from their `state_dict`, prefix `net.`).

REF may be:
  - a run folder (`runs/robot_sdf_panda/<timestamp>/`): its `robot_sdf.pt`, else `checkpoints/last.ckpt`;
  - an artifact file (`.../robot_sdf.pt`);
  - a Lightning checkpoint of a robot SDF run (`.../checkpoints/last.ckpt`).
"""

from __future__ import annotations

import hashlib
import importlib
from datetime import datetime, timezone
from pathlib import Path

import torch
from torch import nn

from samp.cli import paste
from samp.robot_sdf.whole_robot import RobotSDF

__all__ = ["ARTIFACT_FILE", "ARTIFACT_FORMAT", "CHECKPOINT_KEY", "artifact_id", "build_net", "describe",
           "load_robot_sdf", "net_spec", "save_artifact"]

ARTIFACT_FILE = "robot_sdf.pt"
ARTIFACT_FORMAT = "samp-robot-sdf-v1"
CHECKPOINT_KEY = "robot_sdf"  # the description inside a Lightning checkpoint
STATE_PREFIX = "net."


def net_spec(net: nn.Module, kwargs: dict | None = None) -> dict:
    """{"target": dotted class path, "kwargs": plain keyword arguments} to rebuild `net` (default: the
    `config` the network classes of this package keep of their constructor arguments)."""
    cls = type(net)
    if kwargs is None:
        if not hasattr(net, "config"):
            raise ValueError(f"{cls.__name__} keeps no `config`; pass its constructor arguments as kwargs")
        kwargs = net.config
    return {"target": f"{cls.__module__}.{cls.__qualname__}", "kwargs": _plain(kwargs)}


NET_PACKAGE = "samp.robot_sdf."  # where every robot SDF network class lives


def build_net(spec: dict) -> nn.Module:
    """The network an artifact or checkpoint describes. Its class must be an `nn.Module` of samp's robot SDF
    package: the description comes from a file, and anything else it named would be called when the file
    loads (docs/design.md section 7)."""
    target = spec.get("target") if isinstance(spec, dict) else None
    if not isinstance(target, str) or not target.startswith(NET_PACKAGE):
        raise ValueError(f"robot SDF network {target!r} is not a class of {NET_PACKAGE}*; the artifact names code "
                         "samp does not build networks from (a damaged or crafted file): refused")
    module, _, name = target.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        raise ValueError(f"robot SDF network class {target!r} cannot be imported; the artifact was "
                         "written by another samp version") from None
    if not (isinstance(cls, type) and issubclass(cls, nn.Module)):
        raise ValueError(f"robot SDF network {target!r} is not a network class (an nn.Module): refused")
    kwargs = spec.get("kwargs")
    if not isinstance(kwargs, dict) or _has_target(kwargs):
        raise ValueError(f"robot SDF network {target!r}: its arguments must be plain values, got {kwargs!r}")
    return cls(**kwargs)


def _has_target(value) -> bool:
    if isinstance(value, dict):
        return "_target_" in value or any(_has_target(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return any(_has_target(v) for v in value)
    return False


def _plain(obj):
    """OmegaConf containers and tuples -> plain dicts and lists (for weights_only loading)."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(obj, (DictConfig, ListConfig)):
            return OmegaConf.to_container(obj, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf comes with hydra
        pass
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj


def describe(robot, spec: dict, method: str, centres: torch.Tensor, scales: torch.Tensor,
             dataset_id: str | None = None, extra: dict | None = None) -> dict:
    """The artifact's description without the weights (what a checkpoint stores beside its state dict).
    `robot` needs only `name`, `asset_hash` and `link_names`."""
    from samp.provenance import code_version

    return {"format": ARTIFACT_FORMAT, "robot": robot.name, "robot_asset_hash": robot.asset_hash,
            "link_names": list(robot.link_names), "net": spec, "method": method,
            "centres": centres.detach().double().cpu().tolist(), "scales": scales.detach().double().cpu().tolist(),
            "dataset_id": dataset_id, "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "code_version": code_version(), **(extra or {})}


def save_artifact(path: Path | str, model: RobotSDF, spec: dict, dataset_id: str | None = None,
                  extra: dict | None = None) -> Path:
    """Write `model` (its network, boxes and robot identity) to `path`, atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = describe(model.robot, spec, model.method, model.centres, model.scales, dataset_id, extra)
    payload["state_dict"] = {k: v.detach().cpu() for k, v in model.net.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def artifact_id(path: Path | str) -> str:
    """First 12 hex digits of the artifact file's sha256 (recorded by runs that use it)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:12]


def _read(ref: Path | str) -> tuple[dict, dict, Path]:
    """(description, network state dict, file) for any accepted REF."""
    path = Path(ref)
    if path.is_dir():
        for candidate in (path / ARTIFACT_FILE, path / "checkpoints" / "last.ckpt"):
            if candidate.is_file():
                path = candidate
                break
        else:
            raise FileNotFoundError(f"{ref} holds no {ARTIFACT_FILE} and no checkpoints/last.ckpt; pass the run folder "
                                    "of a finished `python -m samp.train +experiment=robot_sdf_<robot>` run")
    if not path.is_file():
        raise FileNotFoundError(f"robot SDF {ref!r} not found: REF is a run folder, a {ARTIFACT_FILE} file or a "
                                "Lightning checkpoint of a robot SDF run")
    from samp.integrity import check_recorded_hash

    check_recorded_hash(path)  # the sha256 its run recorded, when it is in a run folder
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - torch raises several types for a foreign file
        raise ValueError(f"{path} is not a robot SDF artifact or checkpoint ({type(err).__name__}: {err})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path} is not a robot SDF artifact or checkpoint")
    if CHECKPOINT_KEY in data:  # a Lightning checkpoint
        info = data[CHECKPOINT_KEY]
        state = {k[len(STATE_PREFIX):]: v for k, v in data["state_dict"].items() if k.startswith(STATE_PREFIX)}
    else:
        info, state = data, data.get("state_dict")
    if info.get("format") != ARTIFACT_FORMAT or state is None:
        raise ValueError(f"{path} is not a robot SDF artifact of format {ARTIFACT_FORMAT} "
                         f"(format: {info.get('format')!r})")
    return info, state, path


def load_robot_sdf(ref: Path | str, robot=None, *, dtype: torch.dtype | None = None,
                   device: torch.device | str | None = None) -> RobotSDF:
    """A trained `RobotSDF` from REF (module docstring).

    `robot` (a `Robot` or a robot name) states which robot the caller means; an artifact trained for
    another robot, or for other link meshes (asset hash), is refused. Without it the artifact's own
    robot is loaded and its meshes are checked against the artifact's hash the same way. `dtype`
    defaults to the given robot's dtype, else float32.
    """
    from samp.robot import load_robot

    info, state, path = _read(ref)
    if robot is None or isinstance(robot, str):
        name = robot or info["robot"]
        if name != info["robot"]:
            raise ValueError(f"robot SDF {path} was trained for robot {info['robot']!r}, not {name!r}; train one with "
                             f"`{paste('python -m samp.train', experiment=f'robot_sdf_{name}')}`")
        robot = load_robot(name, dtype=dtype or torch.float32)
    if robot.name != info["robot"] or robot.asset_hash != info["robot_asset_hash"]:
        raise ValueError(f"robot SDF {path} was trained for robot {info['robot']!r} (asset hash "
                         f"{info['robot_asset_hash'][:12]}), but the robot given is {robot.name!r} (asset hash "
                         f"{robot.asset_hash[:12]}); its URDF or meshes differ. Retrain with "
                         f"`{paste('python -m samp.train', experiment=f'robot_sdf_{robot.name}')}`")
    if list(robot.link_names) != list(info["link_names"]):
        raise ValueError(f"robot SDF {path} covers links {info['link_names']}, but {robot.name}'s collision links are "
                         f"{robot.link_names}; retrain it for this robot configuration")
    net = build_net(info["net"])
    net.load_state_dict(state)
    meta = {"path": str(path), "dataset_id": info.get("dataset_id"), "artifact_id": artifact_id(path),
            **{k: info[k] for k in ("train_time_s", "code_version") if k in info}}
    model = RobotSDF(robot, net, torch.tensor(info["centres"]), torch.tensor(info["scales"]), info.get("method", ""), meta)
    dtype = dtype or robot.dtype
    return model.to(device=device, dtype=dtype) if device is not None else model.to(dtype)
