"""What a training needs before its system and DataModule exist: a robot SDF given by experiment name is
turned into the path of its run, a missing dataset or robot SDF is built when the config asks
(`build_missing.dataset`, `build_missing.robot_sdf`), DAgger rounds run (`dagger.rounds`, samp/train/dagger.py),
and a dataset the evaluation after training could not use is refused before training. Steps of the recipe,
never of a LightningModule.
"""

from __future__ import annotations

from pathlib import Path

from samp.cli import paste

__all__ = ["build_overrides", "prepare", "resolve_robot_sdf"]


def _experiment_model(name: str) -> str | None:
    """The `_target_` of the network the experiment `name` trains by default (None: no such experiment)."""
    from samp.paths import conf_dir

    if not (conf_dir() / "experiment" / f"{name}.yaml").is_file():
        return None
    from samp.train.config import compose_train_config

    model = compose_train_config([f"experiment={name}"]).get("model") or {}
    return model.get("_target_")


def _candidates(folder: Path) -> list[dict]:
    """The completed runs in `folder` that wrote a robot SDF artifact, newest first: path, id, network."""
    from samp.robot_sdf.artifact import ARTIFACT_FILE, artifact_id
    from samp.runs import RunFolder

    found = []
    for run in sorted(folder.glob("*/"), reverse=True):
        record = RunFolder(run).read() if (run / ARTIFACT_FILE).is_file() else {}
        if record.get("status") == "completed":
            model = ((record.get("config") or {}).get("model") or {}).get("_target_")
            found.append({"path": run, "id": record.get("robot_sdf_artifact_id") or artifact_id(run / ARTIFACT_FILE),
                          "model": model})
    return found


def _listing(found: list[dict]) -> str:
    return "; ".join(f"{c['path']} (id {c['id']}, {c['model'] or 'network not recorded'})" for c in found)


def resolve_robot_sdf(ref: str, runs_dir: str | Path | None = None, lock: bool = True) -> Path:
    """A robot SDF reference -> its artifact or run folder.

    REF is an existing path, an experiment name (`robot_sdf_panda`: its newest completed run that wrote
    `robot_sdf.pt` and trained the network the experiment trains by default, so an NN-SDF run made with
    `model=robot_sdf_nn` under the same name is never picked for it), or `NAME@ID` (the run of that name
    whose artifact's content id starts with ID, whatever its network). A name whose runs trained several
    kinds of network, with no experiment config to say which is meant, or an ID prefix matching several
    artifacts, is refused with the candidates. FileNotFoundError when nothing matches. A bare name that the
    lock file in effect pins (samp/data/lock.py) means its pinned NAME@ID, unless `lock=False`."""
    from samp.robot_sdf.artifact import ARTIFACT_FILE
    from samp.runs import runs_root

    path = Path(str(ref)).expanduser()
    if path.exists():
        return path
    pin = _pinned_robot_sdf(str(ref)) if lock and "@" not in str(ref) else None
    name, _, wanted_id = str(pin[0] if pin else ref).partition("@")
    folder = (Path(runs_dir) if runs_dir else runs_root()) / name
    found = _candidates(folder)
    if wanted_id:
        matches = [c for c in found if str(c["id"]).startswith(wanted_id)]
        if len(matches) > 1:
            raise ValueError(f"robot SDF {ref!r} is ambiguous: {len(matches)} artifacts' ids start with {wanted_id!r}: "
                             f"{_listing(matches)}. Give more digits of the id, or the run folder")
        if matches:
            return matches[0]["path"]
        pinned = f" ({ref!r} is pinned to {pin[0]} by the lock file {pin[1]})" if pin else ""
        raise FileNotFoundError(f"no completed {name!r} run under {folder} has a robot SDF whose id starts with "
                                f"{wanted_id!r}{pinned}; there are: {_listing(found) or 'none'}. Pull the run that "
                                "made it (`python -m samp.runs pull`), or train it")
    kind = _experiment_model(name)
    of_kind = [c for c in found if kind is None or c["model"] in (kind, None)]
    if kind is None and len({c["model"] for c in of_kind}) > 1:
        raise ValueError(f"robot SDF {ref!r} is ambiguous: its runs trained different networks and no "
                         f"conf/experiment/{name}.yaml says which is meant: {_listing(of_kind)}. Give the run folder, "
                         f"or {name}@ID with one of these ids")
    if of_kind:
        return of_kind[0]["path"]
    robot = name.removeprefix("robot_sdf_").split("_")[0] or "panda"
    other = f" (runs of other networks there, not taken by name: {_listing(found)})" if found else ""
    raise FileNotFoundError(f"no robot SDF {ref!r}: not a file or folder, and no completed run with {ARTIFACT_FILE} "
                            f"of the network {kind or 'it trains'} under {folder}{other}. Train one with "
                            f"`{paste('python -m samp.train', experiment=f'robot_sdf_{robot}')}`, pass build_missing.robot_sdf=true, or "
                            "set system.robot_sdf to a run folder, an artifact, or NAME@ID")


def _pinned_robot_sdf(ref: str):
    from samp.data.lock import locked

    return locked("robot_sdf", ref)


def build_overrides(ref: str, robot: str) -> list[str] | None:
    """The overrides that train the robot SDF `ref` of `robot`: its own experiment (robot_sdf_<robot>[_...]
    in conf/experiment/), else the robot-independent one it names with the robot taken out, for the
    robot (`robot_sdf_myarm_quick`: experiment=robot_sdf_quick robot=myarm); None when neither exists."""
    from samp.paths import conf_dir

    prefix = f"robot_sdf_{robot}"
    if not ref.startswith(prefix):
        return None
    if (conf_dir() / "experiment" / f"{ref}.yaml").is_file():
        return [f"experiment={ref}"]
    generic = "robot_sdf" + ref[len(prefix):]
    if generic != "robot_sdf" and (conf_dir() / "experiment" / f"{generic}.yaml").is_file():
        return [f"experiment={generic}", f"robot={robot}"]
    return None


def _robot_sdf(cfg) -> str:
    """The path of the system's robot SDF, trained first when missing and `build_missing.robot_sdf`."""
    from samp.train.recipe import train

    ref, runs_dir, build = str(cfg.system.robot_sdf), cfg.paths.runs_dir, cfg.build_missing
    try:
        path = resolve_robot_sdf(ref, runs_dir)
    except FileNotFoundError:
        recipe = build_overrides(ref, cfg.robot.name)
        if not (build.robot_sdf and recipe):
            raise
    else:
        print(f"robot SDF {ref!r}: {path}", flush=True)
        return str(path)
    overrides = [*recipe, *build.robot_sdf_overrides]
    print(f"robot SDF {ref!r} is not trained yet: running {' '.join(overrides)} (runs in {runs_dir}, datasets in "
          f"{cfg.paths.datasets_dir})", flush=True)
    return str(train(overrides, paths={"runs_dir": runs_dir, "datasets_dir": cfg.paths.datasets_dir}).path)


def _datasets_root(cfg) -> Path:
    """Where the DataModule looks for its dataset: its own `root`, else `paths.datasets_dir`."""
    return Path(cfg.datamodule.get("root") or cfg.paths.datasets_dir)


def _dataset(cfg) -> None:
    """Generate the DataModule's dataset from its spec (conf/dataset/) when none is built yet, or when the
    newest one of that name was generated from another version of the spec (its config hash differs)."""
    from samp.data import DatasetError, available_specs, generate, load_spec, open_dataset
    from samp.data.lock import is_pinned

    ref, root = str(cfg.datamodule.dataset), _datasets_root(cfg)
    spec = load_spec(ref) if ref in available_specs() else None
    try:
        found = open_dataset(ref, root)
    except DatasetError:
        if spec is None:
            raise
        print(f"dataset {ref!r} is not built yet: generating it from conf/dataset/{ref}.yaml", flush=True)
    else:
        if spec is None or found.manifest.get("config_hash") == spec.config_hash() or is_pinned(ref):
            return  # a dataset pinned by the lock file is used as it is, whatever the spec says now
        print(f"the newest {ref!r} dataset ({found.name}@{found.id}) was made from another version of "
              f"conf/dataset/{ref}.yaml: generating the current one (the older one stays as it is)", flush=True)
    generate(ref, workers=int(cfg.build_missing.workers), root=root)


def _manifest(cfg) -> dict:
    """The manifest of the DataModule's dataset (the manifest alone: no decoding)."""
    from samp.data import read_manifest, resolve_ref

    return read_manifest(resolve_ref(str(cfg.datamodule.dataset), _datasets_root(cfg)))


def _check_resolution(cfg, manifest: dict) -> None:
    """Fail before the run folder exists when the dataset stores no anchor grids at `datamodule.n_e` (the
    resolutions its spec or import asked for, in its manifest; older manifests say nothing: the DataModule
    checks the scene files)."""
    from samp.data import available_specs

    stored, n_e = (manifest.get("config") or {}).get("resolutions"), cfg.datamodule.get("n_e")
    if not stored or n_e is None or int(n_e) in stored:
        return
    name, wanted = manifest.get("name"), sorted({*stored, int(n_e)})
    if name in available_specs():
        make = paste("python -m samp.data generate", dataset=name) + f" dataset.resolutions=[{','.join(map(str, wanted))}]"
    else:
        make = f"import it again with resolutions={','.join(map(str, wanted))} (`python -m samp.data import ...`)"
    raise ValueError(f"dataset {name}@{manifest.get('id')} stores anchor grids at n_e in {list(stored)}, not {n_e}: "
                     f"set datamodule.n_e={stored[0]} (or another of them), or make a dataset that stores {n_e}: "
                     f"{make}")


def _check_evaluable(cfg, manifest: dict) -> None:
    """Fail before training, not after it, when the evaluation after training cannot run on the dataset."""
    if not (manifest.get("counts") or {}).get("eval_problems"):
        name = manifest.get("name")
        raise ValueError(f"dataset {name}@{manifest.get('id')} stores no evaluation problems (it predates them), so "
                         f"the run could not be evaluated after training: regenerate it "
                         f"(`{paste('python -m samp.data generate', dataset=name)}`, or build_missing.dataset=true), "
                         "or set evaluation.problems=0")


def prepare(cfg, overrides: list[str] | None = None) -> None:
    """Resolve and build what `cfg` (the composed training config, writable, composed from `overrides`)
    needs; rewrites `cfg.system.robot_sdf` to a path, and with `dagger.rounds` > 0 `cfg.datamodule.dataset`
    to the aggregated dataset (`samp.train.dagger`). Call on rank 0 before instantiating the system."""
    if cfg.datamodule.get("dataset") is not None:
        if cfg.build_missing.dataset:
            _dataset(cfg)
        manifest = _manifest(cfg)
        _check_resolution(cfg, manifest)
        if cfg.evaluation.problems:
            _check_evaluable(cfg, manifest)
    if cfg.system.get("robot_sdf"):
        cfg.system.robot_sdf = _robot_sdf(cfg)
    if cfg.datamodule.get("dataset") is not None and (cfg.get("dagger") or {}).get("rounds"):
        from samp.train.dagger import stage

        stage(cfg, list(overrides or []))  # imports the aggregated dataset, with its evaluation problems
