"""What a training needs before its system and DataModule exist: a robot SDF given by experiment name is
turned into the path of its run, a missing dataset or robot SDF is built when the config asks
(`build_missing.dataset`, `build_missing.robot_sdf`), and a dataset the evaluation after training could
not use is refused before training. Steps of the recipe, never of a LightningModule.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["prepare", "resolve_robot_sdf"]


def resolve_robot_sdf(ref: str, runs_dir: str | Path | None = None) -> Path:
    """A robot SDF reference -> its artifact or run folder: an existing path, or an experiment name under
    the runs folder (its newest completed run that wrote `robot_sdf.pt`). FileNotFoundError otherwise."""
    from samp.robot_sdf.artifact import ARTIFACT_FILE
    from samp.runs import RunFolder, runs_root

    path = Path(str(ref)).expanduser()
    if path.exists():
        return path
    folder = Path(runs_dir) if runs_dir else runs_root()
    for run in sorted((folder / str(ref)).glob("*/"), reverse=True):
        if (run / ARTIFACT_FILE).is_file() and RunFolder(run).read().get("status") == "completed":
            return run
    robot = str(ref).removeprefix("robot_sdf_").split("_")[0] or "panda"
    raise FileNotFoundError(f"no robot SDF {ref!r}: not a file or folder, and no completed run with {ARTIFACT_FILE} "
                            f"under {folder / str(ref)}. Train one with `python -m samp.train "
                            f"experiment=robot_sdf_{robot}`, pass build_missing.robot_sdf=true, or set "
                            "system.robot_sdf to a run folder or artifact")


def _buildable(ref: str, robot: str) -> bool:
    """Whether `ref` names a robot SDF experiment of `robot` in conf/experiment/ (robot_sdf_<robot>[_...])."""
    from samp.paths import conf_dir

    return ref.startswith(f"robot_sdf_{robot}") and (conf_dir() / "experiment" / f"{ref}.yaml").is_file()


def _robot_sdf(cfg) -> str:
    """The path of the system's robot SDF, trained first when missing and `build_missing.robot_sdf`."""
    from samp.train.recipe import train

    ref, runs_dir, build = str(cfg.system.robot_sdf), cfg.paths.runs_dir, cfg.build_missing
    try:
        return str(resolve_robot_sdf(ref, runs_dir))
    except FileNotFoundError:
        if not (build.robot_sdf and _buildable(ref, cfg.robot.name)):
            raise
    overrides = [f"experiment={ref}", f"paths.runs_dir={runs_dir}", f"paths.datasets_dir={cfg.paths.datasets_dir}",
                 *build.robot_sdf_overrides]
    print(f"robot SDF {ref!r} is not trained yet: running {' '.join(overrides)}", flush=True)
    return str(train(overrides).path)


def _datasets_root(cfg) -> Path:
    """Where the DataModule looks for its dataset: its own `root`, else `paths.datasets_dir`."""
    return Path(cfg.datamodule.get("root") or cfg.paths.datasets_dir)


def _dataset(cfg) -> None:
    """Generate the DataModule's dataset from its spec (conf/dataset/) when none is built yet, or when the
    newest one of that name was generated from another version of the spec (its config hash differs)."""
    from samp.data import DatasetError, available_specs, generate, load_spec, open_dataset

    ref, root = str(cfg.datamodule.dataset), _datasets_root(cfg)
    spec = load_spec(ref) if ref in available_specs() else None
    try:
        found = open_dataset(ref, root)
    except DatasetError:
        if spec is None:
            raise
        print(f"dataset {ref!r} is not built yet: generating it from conf/dataset/{ref}.yaml", flush=True)
    else:
        if spec is None or found.manifest.get("config_hash") == spec.config_hash():
            return
        print(f"the newest {ref!r} dataset ({found.name}@{found.id}) was made from another version of "
              f"conf/dataset/{ref}.yaml: generating the current one (the older one stays as it is)", flush=True)
    generate(ref, workers=int(cfg.build_missing.workers), root=root)


def _check_evaluable(cfg) -> None:
    """Fail before training, not after it, when the evaluation after training cannot run on the dataset."""
    from samp.data import read_manifest, resolve_ref

    manifest = read_manifest(resolve_ref(str(cfg.datamodule.dataset), _datasets_root(cfg)))  # the manifest alone: no decoding
    if not (manifest.get("counts") or {}).get("eval_problems"):
        name = manifest.get("name")
        raise ValueError(f"dataset {name}@{manifest.get('id')} stores no evaluation problems (it predates them), so "
                         f"the run could not be evaluated after training: regenerate it (`python -m samp.data "
                         f"generate dataset={name}`, or build_missing.dataset=true), or set evaluation.problems=0")


def prepare(cfg) -> None:
    """Resolve and build what `cfg` (the composed training config, writable) needs; rewrites
    `cfg.system.robot_sdf` to a path. Call on rank 0 before instantiating the system."""
    if cfg.datamodule.get("dataset") is not None:
        if cfg.build_missing.dataset:
            _dataset(cfg)
        if cfg.evaluation.problems:
            _check_evaluable(cfg)
    if cfg.system.get("robot_sdf"):
        cfg.system.robot_sdf = _robot_sdf(cfg)
