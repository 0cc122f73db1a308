"""The training config: compose conf/train.yaml with overrides and check it strictly (unknown top-level
keys and unknown `_target_` arguments are errors that name the valid keys, DESIGN section 7)."""

from __future__ import annotations

import inspect
import re
from dataclasses import dataclass, fields
from typing import Any

__all__ = ["TrainSchema", "compose_train_config"]

PICK_EXPERIMENT = "pick an experiment with experiment=NAME (`python -m samp.train --help` lists them)"
HYDRA_KEYS = {"_target_", "_partial_", "_convert_", "_recursive_", "_args_"}


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
    evaluation: Any = None
    run_dir: Any = None
    resume: Any = None
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


def compose_train_config(overrides: list[str]):
    """The composed config, checked strictly: unknown top-level keys and unknown `_target_` arguments
    are errors that name the valid keys (DESIGN section 7)."""
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
    plain = OmegaConf.to_container(cfg, resolve=False)
    try:  # types of the top-level values (seed must be an int, ...)
        OmegaConf.merge(OmegaConf.structured(TrainSchema), {k: v for k, v in plain.items() if k in schema_keys})
    except (ConfigKeyError, ValidationError) as err:
        raise ValueError(f"invalid top-level config value: {str(err).splitlines()[0]}") from None
    _check_targets(plain)
    return cfg
