"""`generate_scene(name, seed, **overrides)`: run a generator configured in `conf/scene/NAME.yaml`."""

from __future__ import annotations

import inspect

import numpy as np
from hydra.utils import get_method
from omegaconf import OmegaConf

from samp.paths import conf_dir
from samp.scene.model import DEFAULT_BOUNDS, Scene

__all__ = ["available_generators", "generate_scene", "scene_from_config", "base_is_clear", "target_is_approachable"]

MAX_ATTEMPTS = 50
APPROACH_OFFSET = 0.10  # pre-grasp distance from the target's centre ...
APPROACH_CLEARANCE = 0.04  # ... where the nearest obstacle must be at least this far
REACH = (0.25, 0.85)  # target distance from the base axis, metres (within a 7-dof arm's reach)
BASE_CLEARANCE = 0.2  # no obstacle but the table within this distance of the base axis ...
BASE_HEIGHT = 0.6  # ... from the table top up to this height


def available_generators() -> list[str]:
    return sorted(p.stem for p in (conf_dir() / "scene").glob("*.yaml"))


def _load_config(name: str) -> dict:
    path = conf_dir() / "scene" / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"unknown scene generator {name!r}; available: {', '.join(available_generators())}")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=True)


def scene_from_config(cfg: dict, seed: int) -> Scene:
    """A scene from a generator config node (`_target_`, `name`, `bounds`, generator parameters)."""
    cfg = dict(cfg)
    target, name = cfg.pop("_target_"), cfg.pop("name")
    bounds = cfg.pop("bounds", None) or DEFAULT_BOUNDS
    fn = get_method(target)
    valid = [p for p in inspect.signature(fn).parameters if p != "rng"]
    unknown = sorted(set(cfg) - set(valid))
    if unknown:
        raise ValueError(f"scene generator {name!r} has no parameters {unknown}; valid: {valid}")
    params = {k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}
    meta = {"generator": name, "seed": int(seed), "params": {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()}}
    for attempt in range(MAX_ATTEMPTS):
        # Attempt 0 draws from the seed itself; redraws are still determined by the seed.
        rng = np.random.default_rng(seed if attempt == 0 else [seed, attempt])
        obstacles, target_obj = fn(rng, **params)
        scene = Scene(name=f"{name}_{seed}", obstacles=tuple(obstacles), target=target_obj, bounds=bounds,
                      meta={**meta, "attempt": attempt})
        if base_is_clear(scene) and target_is_approachable(scene):
            return scene
    raise ValueError(f"scene generator {name!r} with seed {seed} gave no scene with a reachable, approachable "
                     f"target in {MAX_ATTEMPTS} attempts; loosen its parameters (fewer or smaller obstacles)")


def base_is_clear(scene: Scene) -> bool:
    """Every point of the base axis from z = 0 to BASE_HEIGHT is at least BASE_CLEARANCE from every
    obstacle but the table (which the robot stands on)."""
    others = [o for o in scene.all_obstacles if o.name != "table"]
    if not others:
        return True
    axis = np.stack([np.zeros(61), np.zeros(61), np.linspace(0.0, BASE_HEIGHT, 61)], axis=1)
    return bool((Scene(name="others", obstacles=tuple(others), bounds=scene.bounds).sdf(axis) >= BASE_CLEARANCE).all())


def target_is_approachable(scene: Scene) -> bool:
    """The target lies within reach of the base and has a free pre-grasp point above it or in front of
    it (toward the base): no obstacle but the target within APPROACH_CLEARANCE of that point."""
    if scene.target is None:
        return True
    x, y, z = scene.target.pose.position
    r = float(np.hypot(x, y))
    if not REACH[0] <= r <= REACH[1]:
        return False
    others = Scene(name="others", obstacles=scene.obstacles, bounds=scene.bounds)
    toward_base = -np.array([x, y, 0.0]) / max(r, 1e-9)
    candidates = np.array([[x, y, z + APPROACH_OFFSET], np.array([x, y, z]) + APPROACH_OFFSET * toward_base])
    return bool((others.sdf(candidates) >= APPROACH_CLEARANCE).any())


def generate_scene(name: str, seed: int = 0, **overrides) -> Scene:
    """Generate scene `name` (a file in conf/scene/) with `seed`; keyword arguments override parameters."""
    cfg = _load_config(name)
    cfg.update(overrides)
    return scene_from_config(cfg, seed)
