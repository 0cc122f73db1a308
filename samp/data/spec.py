"""Dataset specs (`conf/dataset/*.yaml`): what to generate, validated, plus the scene list and its hash.

A spec names a robot, how many training, validation and test scenes, which scene generators (mixed
round-robin over the scenes in the order listed), the expert demonstrations per
training and validation scene, the evaluation problems per scene, the anchor-grid resolutions to store,
the expert config, the share of problems drawn to need a detour (`detour_share`, see
`samp.expert.problems.sample_problems`) and a seed. Everything a dataset contains follows from the resolved spec: scenes are
ordered train, then val, then test; scene i uses generator `generators[i % len(generators)]` and seed
`derive_seed(seed, namespace_key(scene_namespace), i)`, so two specs share scenes only when they share
seed and namespace (by default the spec's name). Test scenes get no demonstrations: nothing of them can
reach training. `scene_files` adds scenes read from files (samp's scene JSON/YAML, a cell URDF, a cuRobo-style
world or a problem set, `samp.scene.files`) to each split; they come after the generated scenes, in the order
listed. An entry may be a folder or a glob, expanded in sorted order (a problem set expands to one scene per
distinct obstacle set); the resolved spec carries the expansion and each scene's content hash, so adding,
removing or editing a file gives another dataset. With `problems_from_files`, the test split's file scenes
take the problems their files give (a problem set's starts and goals, hashed into the spec too) instead of
drawing `eval_problems_per_scene` from the sampler.
`config_hash` is sha256 over the resolved spec, including the full expert config and each
generator's parameters, so a change anywhere gives a different hash.
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
from samp.expert.seeding import derive_seed
from samp.names import N_E_MAX
from samp.paths import conf_dir, shown_path
from samp.scene.registry import _load_config as load_generator_config
from samp.yaml_files import load_config

__all__ = ["FILE_GENERATOR", "SPLIT_ORDER", "DatasetSpec", "SceneJob", "available_specs", "check_overrides", "load_spec", "namespace_key"]

SPLIT_ORDER = ("train", "val", "test")
FILE_GENERATOR = "file"  # the `generator` of a scene read from a file

# Keys of older specs (two splits, train and heldout), and what replaced them.
RETIRED_KEYS = {"heldout_scenes": "val_scenes and test_scenes (validation scenes drive the validation loss and the "
                                  "choice of checkpoint; test scenes only the final evaluation)"}


def namespace_key(namespace: str) -> int:
    """A scene namespace -> a 64-bit int for `derive_seed` (sha256, stable across processes and machines;
    Python's `hash()` of a string is salted per process)."""
    return int.from_bytes(hashlib.sha256(namespace.encode()).digest()[:8], "big")


@dataclass
class DatasetSpec:
    """A dataset to generate (`conf/dataset/<name>.yaml`)."""

    name: str = "???"
    robot: str = "panda"
    seed: int = 0
    scene_namespace: str | None = None  # scene seeds come from (seed, namespace, index); None: the spec's name
    train_scenes: int = 3  # scenes with demonstrations to train on
    val_scenes: int = 1  # scenes with demonstrations to validate on (loss, evaluation callback, checkpoint)
    test_scenes: int = 0  # scenes with evaluation problems only, for the final evaluation
    trajectories_per_scene: int = 24  # expert demonstrations per train and val scene
    eval_problems_per_scene: int = 8  # evaluation problems per scene (every split), stored apart
    detour_share: float = 0.0  # share of problems (both kinds) drawn so that the straight joint-space line is blocked
    generators: list[str] = field(default_factory=lambda: ["tabletop"])  # mixed round-robin over scenes
    generator_overrides: dict[str, Any] = field(default_factory=dict)  # generator -> {parameter: value}
    resolutions: list[int] = field(default_factory=lambda: [40])  # anchor grids stored per scene (n_e)
    expert: str = "default"  # a name in conf/expert/ or a YAML path
    expert_overrides: dict[str, Any] = field(default_factory=dict)  # nested keys of the expert config
    scene_files: dict[str, list[str]] = field(default_factory=dict)  # split -> scene files, folders or globs
    problems_from_files: bool = False  # test file scenes: the files' own problems, not the sampler's

    @property
    def num_scenes(self) -> int:
        return self.train_scenes + self.val_scenes + self.test_scenes + sum(map(len, self.file_refs().values()))

    @property
    def namespace(self) -> str:
        """The scene namespace in effect: `scene_namespace`, or the spec's name."""
        return self.scene_namespace or self.name

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
        out["scene_namespace"] = self.namespace  # explicit, so leaving it out and naming it hash the same
        out["expert_config"] = asdict(self.expert_config())
        out["generator_configs"] = {g: self.generator_config(g) for g in self.generators}
        if not out["detour_share"]:  # the default: left out, so specs from before the key keep their hash (and
            del out["detour_share"]  # their datasets, e.g. the standing benchmark, are found, not regenerated)
        if not out["problems_from_files"]:  # likewise: the default is left out
            del out["problems_from_files"]
        refs = self.file_refs()
        if any(refs.values()):  # likewise: only specs that name scene files carry the key
            out["scene_file_hashes"] = {ref: self.file_scene(ref).content_hash()
                                        for split in refs for ref in refs[split]}
            if refs != {k: list(v) for k, v in self.scene_files.items()}:  # folders, globs or problem sets expanded
                out["scene_file_expansion"] = refs
            if self.problems_from_files:  # the given starts and goals are part of the benchmark
                out["scene_file_problems"] = {ref: _problems_hash(ref) for ref in refs.get("test", [])}
        else:
            del out["scene_files"]
        return out

    def file_refs(self) -> dict[str, list[str]]:
        """split -> one reference per file scene: `scene_files` with folders, globs and problem sets expanded
        (`samp.scene.files.scene_refs`)."""
        from samp.scene.files import scene_refs

        return {split: [r for ref in refs for r in scene_refs(ref)] for split, refs in self.scene_files.items()}

    def file_scene(self, ref: str):
        """The scene of one expanded `scene_files` reference (samp.scene.files)."""
        from samp.scene.files import load_scene_file, resolve_scene_file

        return load_scene_file(resolve_scene_file(ref))

    def config_hash(self) -> str:
        return hashlib.sha256(json.dumps(self.resolved(), sort_keys=True).encode()).hexdigest()

    def scene_jobs(self) -> list["SceneJob"]:
        """Every scene of the spec, in index order: train scenes, then val, then test."""
        splits = ["train"] * self.train_scenes + ["val"] * self.val_scenes + ["test"] * self.test_scenes
        key = namespace_key(self.namespace)
        jobs = [SceneJob(i, self.generators[i % len(self.generators)], derive_seed(self.seed, key, i), split,
                         0 if split == "test" else self.trajectories_per_scene, self.eval_problems_per_scene)
                for i, split in enumerate(splits)]
        refs = self.file_refs()
        files = [(split, ref) for split in SPLIT_ORDER for ref in refs.get(split, [])]
        for i, (split, ref) in enumerate(files, start=len(jobs)):
            given = self.problems_from_files and split == "test"
            jobs.append(SceneJob(i, FILE_GENERATOR, derive_seed(self.seed, key, i), split,
                                 0 if split == "test" else self.trajectories_per_scene,
                                 _file_problem_count(ref) if given else self.eval_problems_per_scene,
                                 scene_file=ref, file_problems=given))
        return jobs


@dataclass(frozen=True)
class SceneJob:
    """One scene of a spec: the unit of work, of sharding and of resumption."""

    index: int
    generator: str
    seed: int
    split: str  # "train" | "val" | "test"
    trajectories: int  # expert demonstrations to plan (0 in a test scene)
    eval_problems: int  # evaluation problems to plan, stored apart from the demonstrations
    scene_file: str | None = None  # the scene's file (`generator` is then "file"); None: drawn by `generator`
    file_problems: bool = False  # its evaluation problems are those its file gives (`problems_from_files`)

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
        raw = load_config(shown_path(path), "dataset spec")  # aliases and size bounded; the user's own file named
    retired = sorted(set(raw) & set(RETIRED_KEYS)) if isinstance(raw, DictConfig) else []
    if retired:
        raise ValueError(f"dataset spec key {retired[0]!r} is retired: use {RETIRED_KEYS[retired[0]]}; "
                         "see conf/dataset/quickstart.yaml")
    try:
        merged = OmegaConf.merge(OmegaConf.structured(DatasetSpec), raw)
        spec: DatasetSpec = OmegaConf.to_object(merged)
    except (ConfigKeyError, ValidationError) as err:
        raise ValueError(f"invalid dataset spec: {str(err).splitlines()[0]} (key {err.full_key!r}); valid keys: "
                         f"{', '.join(DatasetSpec.__dataclass_fields__)}; see conf/dataset/quickstart.yaml") from None
    _check(spec)
    return spec


def check_overrides(overrides: list[str]) -> None:
    """Refuse a command-line override of a retired spec key (`dataset.heldout_scenes=1`), naming what
    replaced it; Hydra alone would only say the key is not in the config."""
    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~").rsplit(".", 1)[-1]
        if key in RETIRED_KEYS:
            raise ValueError(f"{override!r}: {key!r} is retired; use {RETIRED_KEYS[key]} "
                             "(dataset.val_scenes=N dataset.test_scenes=M)")
        _check_key(override)


def _check_key(override: str) -> None:
    """Refuse a misspelt key (`workrs=2`, `dataset.train_scene=3`) with the valid keys and the closest one;
    Hydra would only suggest appending it with `+`. Hydra's own keys and options are left to Hydra."""
    import difflib

    key, eq, _ = override.partition("=")
    if not eq or key.startswith(("+", "~", "-", "hydra")) or "/" in key or key == "dataset":
        return
    head, _, leaf = key.partition(".")
    if head == "dataset":
        valid, name, shown = sorted(DatasetSpec.__dataclass_fields__), leaf.split(".")[0], "spec keys (dataset.KEY)"
    else:
        valid = [k for k in load_config(shown_path(conf_dir() / "data.yaml")) if k not in ("defaults", "hydra")]
        name, shown = key, "settings"
    if "." in key and head != "dataset" or name not in valid:
        close = [f"dataset.{c}" if head == "dataset" else c for c in difflib.get_close_matches(name, valid, n=1)]
        raise ValueError(f"unknown key {key!r}{f' (did you mean {close[0]!r}?)' if close else ''}; {shown}: "
                         f"{', '.join(valid)}{'' if head == 'dataset' else ', dataset=NAME, dataset.KEY=VALUE'}")


def _check(spec: DatasetSpec) -> None:
    from samp.robot import available_robots
    from samp.scene import available_generators

    def require(ok: bool, what: str) -> None:
        if not ok:
            raise ValueError(f"dataset spec {spec.name!r}: {what}")

    require(spec.name not in ("", "???") and "@" not in spec.name and _plain(spec.name),
            f"name must be a plain folder name (no '/', '@', '.' or '..', not starting with '.'), got {spec.name!r}")
    require(spec.robot in available_robots(), f"unknown robot {spec.robot!r}; available: {available_robots()}")
    require(spec.scene_namespace is None or spec.scene_namespace.strip() != "",
            f"scene_namespace must be a non-empty string or null (the spec's name), got {spec.scene_namespace!r}")
    counts = (spec.train_scenes, spec.val_scenes, spec.test_scenes)
    require(min(counts) >= 0 and spec.num_scenes >= 1,
            f"train_scenes, val_scenes and test_scenes must be >= 0 with at least one scene, got {counts}")
    demos = spec.train_scenes + spec.val_scenes > 0
    require(spec.trajectories_per_scene >= 1 or not demos,
            f"trajectories_per_scene must be >= 1 when the spec has train or val scenes, got "
            f"{spec.trajectories_per_scene}")
    require(spec.trajectories_per_scene >= 0, f"trajectories_per_scene must be >= 0, got {spec.trajectories_per_scene}")
    require(spec.eval_problems_per_scene >= (1 if spec.test_scenes else 0),
            f"eval_problems_per_scene must be >= 0, and >= 1 when the spec has test scenes (they hold nothing else), "
            f"got {spec.eval_problems_per_scene}")
    require(0.0 <= spec.detour_share <= 1.0, f"detour_share must be in [0, 1], got {spec.detour_share}")
    require(len(spec.generators) >= 1, "generators must list at least one scene generator")
    stray_splits = sorted(set(spec.scene_files) - set(SPLIT_ORDER))
    require(not stray_splits, f"scene_files has splits {stray_splits}; valid: {list(SPLIT_ORDER)}")
    hashes = []  # each file scene read once here
    try:
        refs = spec.file_refs()
    except (ValueError, FileNotFoundError) as err:
        require(False, f"scene_files: {err}")
    for split, expanded in refs.items():
        require(len(set(expanded)) == len(expanded), f"scene_files.{split} lists a file twice: {expanded}")
        for ref in expanded:
            try:
                hashes.append(spec.file_scene(ref).content_hash())
                given = spec.problems_from_files and split == "test" and _file_problem_count(ref)
            except (ValueError, FileNotFoundError) as err:
                require(False, f"scene_files.{split}: {err}")
            require(given or split != "test" or not spec.problems_from_files,
                    f"problems_from_files: scene_files.test: {ref} gives no problems of its own (only a problem set "
                    "has starts and goals); list it without problems_from_files, or in another spec")
    require(len(set(hashes)) == len(hashes), "scene_files names the same scene twice (two files with one geometry)")
    require(spec.trajectories_per_scene >= 1 or not any(refs.get(s) for s in ("train", "val")),
            f"trajectories_per_scene must be >= 1 when scene_files has train or val scenes, got "
            f"{spec.trajectories_per_scene}")
    require(not spec.problems_from_files or refs.get("test"),
            "problems_from_files takes the problems of the test split's scene files, but scene_files.test is empty")
    unknown = sorted(set(spec.generators) - set(available_generators()))
    require(not unknown, f"unknown scene generators {unknown}; available: {available_generators()}")
    stray = sorted(set(spec.generator_overrides) - set(spec.generators))
    require(not stray, f"generator_overrides for generators not in `generators`: {stray}")
    require(len(spec.resolutions) >= 1 and all(2 <= n <= N_E_MAX for n in spec.resolutions),
            f"resolutions must list anchor counts per axis in [2, {N_E_MAX}], got {spec.resolutions}")
    require(len(set(spec.resolutions)) == len(spec.resolutions), f"resolutions has duplicates: {spec.resolutions}")
    spec.expert_config()  # raises with the expert config's own message


def _file_problem_count(ref: str) -> int:
    from samp.scene.files import file_problems, resolve_scene_file

    return len(file_problems(resolve_scene_file(ref)))


def _problems_hash(ref: str) -> str:
    """sha256 of the starts and goals a scene file gives, as stored (float64 bytes)."""
    from samp.scene.files import file_problems, resolve_scene_file

    h = hashlib.sha256()
    for p in file_problems(resolve_scene_file(ref)):
        h.update(f"{p.where} {p.goals.shape}".encode())
        h.update(p.start.astype("<f8").tobytes() + p.goals.astype("<f8").tobytes())
    return h.hexdigest()


def _plain(name) -> bool:
    from samp.paths import check_name

    try:
        check_name(name, "dataset name")
    except ValueError:
        return False
    return True
