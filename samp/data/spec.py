"""Dataset specs (`conf/dataset/*.yaml`): what to generate, validated, plus the scene list and its hash.

A spec names a robot, how many training and held-out scenes, which scene generators (mixed round-robin
in the order listed, so every split sees every generator), the trajectories per scene, the anchor-grid
resolutions to store, the expert config and a seed. Everything a dataset contains follows from the
resolved spec: scene i uses generator `generators[i % len(generators)]` and seed `derive_seed(seed, i)`;
the last `heldout_scenes` scenes are held out. `config_hash` is sha256 over the resolved spec, including
the full expert config and each generator's parameters, so a change anywhere gives a different hash.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, ValidationError

from samp.expert.config import ExpertConfig, load_expert_config
from samp.expert.planner import derive_seed
from samp.paths import conf_dir
from samp.scene.registry import _load_config as load_generator_config

__all__ = ["DatasetSpec", "SceneJob", "available_specs", "load_spec"]


@dataclass
class DatasetSpec:
    """A dataset to generate (`conf/dataset/<name>.yaml`)."""

    name: str = "???"
    robot: str = "panda"
    seed: int = 0
    train_scenes: int = 3
    heldout_scenes: int = 1
    trajectories_per_scene: int = 24
    generators: list[str] = field(default_factory=lambda: ["tabletop"])  # mixed round-robin over scenes
    generator_overrides: dict[str, Any] = field(default_factory=dict)  # generator -> {parameter: value}
    resolutions: list[int] = field(default_factory=lambda: [40])  # anchor grids stored per scene (n_e)
    expert: str = "default"  # a name in conf/expert/ or a YAML path
    expert_overrides: dict[str, Any] = field(default_factory=dict)  # nested keys of the expert config

    @property
    def num_scenes(self) -> int:
        return self.train_scenes + self.heldout_scenes

    def expert_config(self) -> ExpertConfig:
        base = OmegaConf.create(asdict(load_expert_config(self.expert)))  # plain: a typo in the overrides
        return load_expert_config(OmegaConf.merge(base, OmegaConf.create(self.expert_overrides)))  # fails here

    def generator_config(self, generator: str) -> dict:
        cfg = load_generator_config(generator)
        cfg.update(self.generator_overrides.get(generator, {}))
        return cfg

    def resolved(self) -> dict:
        """The spec with the expert config and generator parameters spelled out (what the hash covers)."""
        out = asdict(self)
        out["expert_config"] = asdict(self.expert_config())
        out["generator_configs"] = {g: self.generator_config(g) for g in self.generators}
        return out

    def config_hash(self) -> str:
        return hashlib.sha256(json.dumps(self.resolved(), sort_keys=True).encode()).hexdigest()

    def scene_jobs(self) -> list["SceneJob"]:
        jobs = []
        for i in range(self.num_scenes):
            generator = self.generators[i % len(self.generators)]
            split = "train" if i < self.train_scenes else "heldout"
            jobs.append(SceneJob(i, generator, derive_seed(self.seed, i), split))
        return jobs


@dataclass(frozen=True)
class SceneJob:
    """One scene of a spec: the unit of work, of sharding and of resumption."""

    index: int
    generator: str
    seed: int
    split: str

    @property
    def file(self) -> str:
        return f"scene_{self.index:04d}.mcap"


def available_specs() -> list[str]:
    return sorted(p.stem for p in (conf_dir() / "dataset").glob("*.yaml"))


def load_spec(source: str | Path | dict | DictConfig) -> DatasetSpec:
    """A validated spec from a name in `conf/dataset/`, a YAML path or a mapping (a composed Hydra node)."""
    if isinstance(source, (dict, DictConfig)):
        raw = OmegaConf.create(source) if isinstance(source, dict) else source
    else:
        path = Path(str(source))
        if path.suffix not in (".yaml", ".yml"):
            path = conf_dir() / "dataset" / f"{source}.yaml"
            if not path.is_file():
                raise ValueError(f"unknown dataset spec {source!r}; available: {', '.join(available_specs())} "
                                 "(or pass the path of a YAML file)")
        elif not path.is_file():
            raise FileNotFoundError(f"dataset spec {path} does not exist")
        raw = OmegaConf.load(path)
    try:
        merged = OmegaConf.merge(OmegaConf.structured(DatasetSpec), raw)
        spec: DatasetSpec = OmegaConf.to_object(merged)
    except (ConfigKeyError, ValidationError) as err:
        raise ValueError(f"invalid dataset spec: {str(err).splitlines()[0]} (key {err.full_key!r}); valid keys: "
                         f"{', '.join(DatasetSpec.__dataclass_fields__)}; see conf/dataset/quickstart.yaml") from None
    _check(spec)
    return spec


def _check(spec: DatasetSpec) -> None:
    from samp.robot import available_robots
    from samp.scene import available_generators

    def require(ok: bool, what: str) -> None:
        if not ok:
            raise ValueError(f"dataset spec {spec.name!r}: {what}")

    require(spec.name not in ("", "???") and "/" not in spec.name and "@" not in spec.name,
            f"name must be a plain folder name (no '/' or '@'), got {spec.name!r}")
    require(spec.robot in available_robots(), f"unknown robot {spec.robot!r}; available: {available_robots()}")
    require(spec.train_scenes >= 0 and spec.heldout_scenes >= 0 and spec.num_scenes >= 1,
            f"train_scenes and heldout_scenes must be >= 0 with at least one scene, got "
            f"{spec.train_scenes} and {spec.heldout_scenes}")
    require(spec.trajectories_per_scene >= 1, f"trajectories_per_scene must be >= 1, got {spec.trajectories_per_scene}")
    require(len(spec.generators) >= 1, "generators must list at least one scene generator")
    unknown = sorted(set(spec.generators) - set(available_generators()))
    require(not unknown, f"unknown scene generators {unknown}; available: {available_generators()}")
    stray = sorted(set(spec.generator_overrides) - set(spec.generators))
    require(not stray, f"generator_overrides for generators not in `generators`: {stray}")
    require(len(spec.resolutions) >= 1 and all(2 <= n <= 512 for n in spec.resolutions),
            f"resolutions must list anchor counts per axis in [2, 512], got {spec.resolutions}")
    require(len(set(spec.resolutions)) == len(spec.resolutions), f"resolutions has duplicates: {spec.resolutions}")
    spec.expert_config()  # raises with the expert config's own message
