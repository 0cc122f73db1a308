"""The training config: compose conf/train.yaml with overrides and check it strictly (unknown top-level
keys and unknown `_target_` arguments are errors that name the valid keys, docs/design.md section 7)."""

from __future__ import annotations

import inspect
import re
from dataclasses import dataclass, fields
from typing import Any

from samp.names import N_E_MAX

__all__ = ["MAX_BATCH", "TrainSchema", "compose_train_config"]

PICK_EXPERIMENT = "pick an experiment with experiment=NAME (`python -m samp.train --help` lists them)"
HYDRA_KEYS = {"_target_", "_partial_", "_convert_", "_recursive_", "_args_"}
# Ranges of arguments by name, for every `_target_` that takes them: checked with the types when the config
# is composed, before any run folder or prerequisite. (low, high), inclusive; None: unbounded.
# Keys that size memory have upper limits: n_e that of the anchor grids (`samp.names.N_E_MAX`).
MAX_BATCH = 65536  # batch_size, scenes_per_batch, val_samples: far above any run here, far below an allocation error
RANGES = {"n_e": (2, N_E_MAX), "batch_size": (1, MAX_BATCH), "num_workers": (0, 256), "max_steps": (-1, None),
          "max_epochs": (-1, None), "steps_per_epoch": (1, None), "val_samples": (0, MAX_BATCH * 16),
          "noise": (0, None), "scenes_per_batch": (0, MAX_BATCH), "lr": (0, None), "weight_decay": (0, None)}
_SCALARS = {"int": int, "float": float, "bool": bool, "str": str, "None": type(None)}


@dataclass
class TrainSchema:
    """The top-level keys of conf/train.yaml; config groups (conf/<group>/) may add their own node."""

    name: str = "???"
    seed: int = 0
    system: Any = None
    datamodule: Any = None
    trainer: Any = None
    callbacks: Any = None
    logger: Any = None
    model: Any = None
    paths: Any = None
    robot: Any = None
    build_missing: Any = None
    dagger: Any = None
    evaluation: Any = None
    tracking: Any = None
    run_dir: Any = None
    resume: Any = None
    init_from: Any = None
    trust_checkpoint: bool = False


def _groups() -> set[str]:
    from samp.paths import conf_dir

    return {p.name for p in conf_dir().iterdir() if p.is_dir()}


def _compose(overrides: list[str]):
    from hydra.errors import ConfigCompositionException

    from samp.cli import compose

    try:
        return compose("train", overrides)
    except ConfigCompositionException as err:
        match = re.search(r"Could not override '([^']+)'", str(err))
        if not match:
            raise
        key = match.group(1)
        parent, _, leaf = key.rpartition(".")
        rest = [o for o in overrides if not o.lstrip("+~").startswith(f"{key}=")]
        try:
            from omegaconf import OmegaConf

            node = compose("train", rest)
            node = OmegaConf.select(node, parent) if parent else node
            valid = ", ".join(sorted(node.keys())) if hasattr(node, "keys") else "none (not a mapping)"
        except Exception:  # noqa: BLE001 - the hint is best effort; the original error stands
            raise err from None
        raise ValueError(f"unknown config key {key!r} ({leaf!r} is not under {parent or 'the top level'}); "
                         f"valid keys there: {valid}. Use +{key}=... only to add a key on purpose") from None


def _check_targets(node, path: str = "") -> None:
    """Every `_target_` node's keys must be parameters of its target (unless it takes **kwargs).
    `node` is the config as plain containers, interpolations unresolved."""
    from hydra.utils import get_object

    if isinstance(node, dict):
        target = node.get("_target_")
        if target is not None:
            try:
                params = inspect.signature(get_object(target)).parameters
            except (ImportError, AttributeError, ValueError, TypeError) as err:
                raise ValueError(f"config node {path or '<root>'!r}: cannot import _target_ {target!r} ({err})") from None
            if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
                unknown = sorted(set(node) - HYDRA_KEYS - set(params))
                if unknown:
                    valid = ", ".join(p for p in params if p != "self")
                    raise ValueError(f"config node {path or '<root>'!r}: unknown key(s) {unknown} for {target}; "
                                     f"valid keys: {valid}")
        for key, value in node.items():
            _check_targets(value, f"{path}.{key}" if path else str(key))
    elif isinstance(node, list):
        for i, item in enumerate(node):
            _check_targets(item, f"{path}[{i}]")


def _allowed(annotation) -> tuple[type, ...] | None:
    """The scalar types an annotation admits (`int`, `float | None`, `Optional[int]`, ...); None when it
    admits anything else too (then nothing is checked)."""
    import typing

    if isinstance(annotation, str):
        parts = [p.strip() for p in annotation.replace("Optional[", "None | ").rstrip("]").split("|")]
        return tuple(_SCALARS[p] for p in parts) if parts and all(p in _SCALARS for p in parts) else None
    if annotation in _SCALARS.values():
        return (annotation,)
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, getattr(__import__("types"), "UnionType", None)) and args:
        return tuple(args) if all(a in _SCALARS.values() for a in args) else None
    return None


def _fits(value, types: tuple[type, ...]) -> bool:
    if isinstance(value, bool):
        return bool in types
    if isinstance(value, int):
        return int in types or float in types
    return any(isinstance(value, t) for t in types if t is not bool)


def _check_values(node, resolved, path: str = "") -> None:
    """Every `_target_` argument given a scalar must have a type its annotation admits and lie in RANGES:
    a ValueError names the key, the value and what is allowed. `node` is unresolved (interpolations are
    checked by their resolved value, `resolved`)."""
    from hydra.utils import get_object

    if isinstance(node, dict):
        target = node.get("_target_")
        params = {}
        if target is not None:
            try:
                params = inspect.signature(get_object(target)).parameters
            except (ImportError, AttributeError, ValueError, TypeError):
                params = {}
        for key, value in node.items():
            where = f"{path}.{key}" if path else str(key)
            got = resolved.get(key) if isinstance(resolved, dict) else None
            later = isinstance(value, str) and "${" in value and got is None  # set by the recipe (run_dir, ...)
            if key in params and not isinstance(got, (dict, list)) and key not in HYDRA_KEYS and not later:
                types = _allowed(params[key].annotation)
                if types is not None and not _fits(got, types):
                    names = " or ".join("null" if t is type(None) else t.__name__ for t in types)
                    raise ValueError(f"config key {where}={got!r}: {target} takes {names} for {key!r}, got a "
                                     f"{type(got).__name__}; give e.g. {where}={_example(types)}")
                low, high = RANGES.get(key, (None, None))
                if isinstance(got, (int, float)) and not isinstance(got, bool) and (
                        (low is not None and got < low) or (high is not None and got > high)):
                    allowed = f">= {low}" if high is None else f"in [{low}, {high}]"
                    raise ValueError(f"config key {where}={got!r} is out of range: {key} must be {allowed}")
            _check_values(value, got, where)
    elif isinstance(node, list):
        for i, item in enumerate(node):
            _check_values(item, resolved[i] if isinstance(resolved, list) and i < len(resolved) else None,
                          f"{path}[{i}]")


def _example(types: tuple[type, ...]) -> str:
    return {int: "50", float: "0.5", bool: "true", str: "NAME"}.get(next(t for t in types if t is not type(None)), "null")


def compose_train_config(overrides: list[str]):
    """The composed config, checked strictly: unknown top-level keys and unknown `_target_` arguments
    are errors that name the valid keys (docs/design.md section 7)."""
    from omegaconf import OmegaConf
    from omegaconf.errors import ConfigKeyError, ValidationError

    cfg = _compose(overrides)
    schema_keys = {f.name for f in fields(TrainSchema)}
    allowed = schema_keys | (set(cfg.keys()) & _groups())  # a selected group (robot_sdf_eval: ...) adds its node
    unknown = sorted(set(cfg.keys()) - allowed)
    if unknown:
        raise ValueError(f"unknown top-level config key(s) {unknown}; valid keys: {', '.join(sorted(allowed))}")
    for key in ("name", "system", "datamodule"):
        if OmegaConf.is_missing(cfg, key):
            raise ValueError(f"the config sets no `{key}`; {PICK_EXPERIMENT}")
    from samp.paths import check_name

    check_name(cfg.name, "experiment name (name=...), the folder its runs go to,")
    plain = OmegaConf.to_container(cfg, resolve=False)
    try:  # types of the top-level values (seed must be an int, ...)
        OmegaConf.merge(OmegaConf.structured(TrainSchema), {k: v for k, v in plain.items() if k in schema_keys})
    except (ConfigKeyError, ValidationError) as err:
        key = getattr(err, "full_key", None) or "?"
        raise ValueError(f"invalid top-level config value for key {key!r}: {str(err).splitlines()[0]} (see "
                         "conf/train.yaml for what it takes)") from None
    _check_targets(plain)
    resolved = _resolved(cfg)
    _check_values(plain, resolved)
    trainer = resolved.get("trainer") if isinstance(resolved.get("trainer"), dict) else {}
    if trainer.get("max_epochs") == -1 and trainer.get("max_steps", -1) in (-1, None):
        raise ValueError("trainer.max_epochs=-1 with trainer.max_steps=-1 would train forever; give "
                         "trainer.max_epochs=N (epochs) or trainer.max_steps=N (optimizer steps)")
    for key in ("max_steps", "max_epochs"):  # Lightning stops before the first step: a run "completed" untrained
        if trainer.get(key) == 0:
            raise ValueError(f"trainer.{key}=0 trains nothing, and the run would be recorded as completed with an "
                             f"untrained model; give trainer.{key}=N with N >= 1 (to evaluate without training, use "
                             "`python -m samp.eval`)")
    return cfg



def _resolved(cfg) -> dict:
    """The config resolved where it can be (an interpolation that cannot be resolved yet stays as written)."""
    from omegaconf import OmegaConf

    from samp.cli import _resolved as resolve

    return resolve(cfg, OmegaConf.to_container(cfg, resolve=False))
