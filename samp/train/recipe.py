"""`python -m samp.train experiment=NAME [key=value ...]`: compose, prepare, seed, instantiate, fit,
evaluate, record.

The experiment decides what is trained (`system`, `datamodule`, `model`, each a `_target_`); this file
only runs the recipe. Before fitting, `prerequisites.prepare` resolves the system's robot SDF by name and
builds what is missing when `build_missing` says so; after fitting, `after_fit.after_fit` evaluates the
model just trained, in memory (`evaluation.problems` per split for a policy; export and Table III for a
robot SDF). Each run gets `runs/<name>/<timestamp>/` (`SAMP_RUNS_DIR` or `paths.runs_dir` moves the root)
with `.hydra/`, `run.json`, `metrics.csv`, `checkpoints/` and what the evaluation writes.
`resume=RUN_DIR` continues a run in its own folder from its last checkpoint, with the overrides it was
started with (new ones win) and its loggers continuing; `run_dir=DIR` puts a new run in a folder of your
choice. `-m` / `sweep=NAME` hand the arguments to the Hydra multirun entry point (`samp.train.sweep`),
which calls `train` once per sweep member.
"""

from __future__ import annotations

import inspect
import re
import sys
import warnings
from contextlib import nullcontext
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

__all__ = ["compose_train_config", "main", "train"]

USAGE = """usage: python -m samp.train experiment=NAME [key=value ...]        train a run (runs/<name>/<timestamp>/)
       python -m samp.train experiment=NAME [key=value ...] --cfg job|hydra|all [--resolve]
                                                                 print the composed config; nothing is trained
       python -m samp.train resume=RUN_DIR [key=value ...]         continue a run from its checkpoints/last.ckpt
       python -m samp.train -m sweep=NAME [hydra/launcher=runs_joblib|runs_slurm] [key=value ...]   a sweep
       python -m samp.train -m experiment=A,B [seed=0,1] [key=value ...]                             an ad-hoc sweep
key=value sets any config key (trainer.max_epochs=3), GROUP=OPTION picks a config of a group (trainer=gpu);
+experiment=NAME and +sweep=NAME mean the same as experiment=NAME and sweep=NAME. `--help` lists the options."""
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
            raise ValueError(f"the config sets no `{key}`; pick an experiment: {USAGE}")
    plain = OmegaConf.to_container(cfg, resolve=False)
    try:  # types of the top-level values (seed must be an int, ...)
        OmegaConf.merge(OmegaConf.structured(TrainSchema), {k: v for k, v in plain.items() if k in schema_keys})
    except (ConfigKeyError, ValidationError) as err:
        raise ValueError(f"invalid top-level config value: {str(err).splitlines()[0]}") from None
    _check_targets(plain)
    return cfg


def _repo_path(path: str) -> Path:
    from samp.paths import REPO_ROOT

    p = Path(path).expanduser()
    return p if p.is_absolute() else REPO_ROOT / p


def _resume_overrides(overrides: list[str]) -> list[str]:
    """`resume=RUN_DIR [key=value ...]`: the run's recorded overrides, then the new ones (which win)."""
    from samp.runs import RunFolder
    from samp.runs.lineage import merge_overrides, override_key

    resume = [o for o in overrides if override_key(o) == "resume"]
    if not resume:
        return overrides
    from hydra.core.override_parser.overrides_parser import OverridesParser

    path = OverridesParser.create().parse_override(resume[-1]).value()  # unquoted, as Hydra reads it
    if path in (None, ""):
        return overrides
    folder = RunFolder(_repo_path(str(path)))
    recorded = [o for o in folder.read().get("overrides", []) if override_key(o) not in ("resume", "run_dir")]
    return merge_overrides(recorded, overrides)


def _open_folder(cfg):
    """(the run folder, the checkpoint to resume from or None), by `resume`, `run_dir` or a new folder."""
    import os

    from samp.runs import RunFolder
    from samp.runs.distributed import RUN_DIR_ENV, is_rank_zero

    if not is_rank_zero():  # another DDP rank: rank 0's folder (Lightning's launcher passes it in the environment)
        path = os.environ.get(RUN_DIR_ENV) or cfg.resume or cfg.run_dir
        if not path:
            raise ValueError("DDP ranks started apart (srun, torchrun) must share one run folder: pass run_dir=DIR, "
                             "e.g. run_dir=runs/NAME/$SLURM_JOB_ID")
        _repo_path(path).mkdir(parents=True, exist_ok=True)
        folder = RunFolder(_repo_path(path))
        return folder, folder.last_checkpoint if folder.last_checkpoint.is_file() else None
    if cfg.resume:
        folder = RunFolder(_repo_path(cfg.resume))
        if not folder.last_checkpoint.is_file():
            raise FileNotFoundError(f"cannot resume {folder.path}: it has no {folder.last_checkpoint.name} in "
                                    f"checkpoints/ (the run stopped before its first checkpoint); start it again")
        return folder, folder.last_checkpoint
    if cfg.run_dir:  # a sweep member's folder, or one the user names
        folder = RunFolder.create_at(_repo_path(cfg.run_dir))
    else:
        folder = RunFolder.create(_repo_path(cfg.paths.runs_dir), cfg.name)
    os.environ[RUN_DIR_ENV] = str(folder.path)
    return folder, None


def train(overrides: list[str], **info):
    """Run the recipe; returns the `RunFolder`. `info` goes into run.json (a sweep names itself there)."""
    import time

    import pytorch_lightning as pl
    from hydra.utils import instantiate
    from omegaconf import OmegaConf, open_dict

    from samp.runs.distributed import is_rank_zero
    from samp.runs.loggers import finish_loggers
    from samp.train.after_fit import after_fit
    from samp.train.prerequisites import prepare

    overrides = _resume_overrides(list(overrides))
    cfg = compose_train_config(overrides)
    with open_dict(cfg):
        cfg.paths.runs_dir = str(_repo_path(cfg.paths.runs_dir))
        cfg.paths.datasets_dir = str(_repo_path(cfg.paths.datasets_dir))
        prepare(cfg)  # before this run's folder exists: a robot SDF built here is a run of its own
    folder, ckpt = _open_folder(cfg)
    with open_dict(cfg):
        cfg.run_dir = str(folder.path)
    rank_zero = is_rank_zero()
    if rank_zero:
        folder.write_config(OmegaConf.to_yaml(cfg, resolve=True), overrides)
        if ckpt is not None:
            _trim_metrics(folder, ckpt)
        print(f"run folder: {folder.path}" + (f" (resuming from {ckpt.name})" if ckpt else ""), flush=True)

    # The CSV logger writes into the run folder, which already holds .hydra/ and run.json by design.
    warnings.filterwarnings("ignore", message="Experiment logs directory .* exists and is not empty")
    config = OmegaConf.to_container(cfg, resolve=True)
    with folder.record(experiment=cfg.name, seed=int(cfg.seed), overrides=overrides, run_dir=str(folder.path),
                       config=config, **info) if rank_zero else nullcontext(folder):
        pl.seed_everything(int(cfg.seed), workers=True, verbose=False)
        datamodule = instantiate(cfg.datamodule)
        system = instantiate(cfg.system)
        callbacks = [instantiate(c) for c in (cfg.callbacks or {}).values()]
        loggers = [instantiate(c) for c in (cfg.logger or {}).values()]
        trainer = instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False, default_root_dir=folder.path)
        start = time.perf_counter()
        trainer.fit(system, datamodule=datamodule, ckpt_path=str(ckpt) if ckpt else None)
        fit_s = time.perf_counter() - start + ((folder.read().get("fit_time_s") or 0.0) if ckpt else 0.0)
        trainer.save_checkpoint(folder.last_checkpoint)
        if not rank_zero:
            return folder
        metrics = {k: float(v) for k, v in trainer.callback_metrics.items()}
        folder.update(dataset_id=getattr(datamodule, "dataset_id", None), steps=int(trainer.global_step),
                      epochs=int(trainer.current_epoch), fit_time_s=fit_s, metrics=metrics,
                      robot_sdf_artifact_id=getattr(system, "robot_sdf_artifact_id", None))
        evaluated = after_fit(cfg, system, datamodule, folder.path)
        metrics.update(evaluated)
        record = folder.update(metrics=metrics, robot_sdf_artifact_id=metrics.get("robot_sdf_artifact_id")
                               or folder.read().get("robot_sdf_artifact_id"))
        finish_loggers(loggers, record, evaluated, step=int(trainer.global_step))
    return folder


def _trim_metrics(folder, ckpt: Path) -> None:
    """Rows of metrics.csv logged after the checkpoint a resumed run starts from are set aside."""
    import torch

    step = int(torch.load(ckpt, map_location="cpu", weights_only=False, mmap=True)["global_step"])
    moved = folder.trim_metrics(step)
    if moved:
        print(f"metrics.csv: {moved} row(s) logged after step {step} (past the checkpoint) moved to "
              "metrics.superseded.csv", flush=True)


def _help() -> str:
    """USAGE, then what conf/ offers: experiments, sweeps, and the options of each config group."""
    from omegaconf import OmegaConf

    from samp.cli import config_names, default_groups, describe, wrap
    from samp.paths import conf_dir

    defaults = {g: o for g, o in default_groups("train").items() if g not in ("experiment", "sweep")}
    added = set()  # groups an experiment adds to the defaults list (`- /robot_sdf_samples: default`)
    for name in config_names("experiment"):
        raw = OmegaConf.to_container(OmegaConf.load(conf_dir() / "experiment" / f"{name}.yaml"))
        for entry in raw.get("defaults") or []:
            added |= {k.lstrip("/") for k in (entry if isinstance(entry, dict) else {}) if k.startswith("/")}
    lines = [USAGE, "", "experiments (experiment=NAME; conf/experiment/NAME.yaml):"]
    lines += [f"  {n:<24}{describe('experiment', n)}" for n in config_names("experiment")]
    lines += ["", "sweeps (-m sweep=NAME; conf/sweep/NAME.yaml):"]
    lines += [f"  {n:<24}{describe('sweep', n)}" for n in config_names("sweep")]
    lines += ["", "config groups (GROUP=OPTION; conf/GROUP/OPTION.yaml; * marks the default):"]
    for group in sorted(set(defaults) | added):
        note = ("(added by the experiments that use it)" if group not in defaults
                else "(the experiment picks one)" if defaults[group] is None else "")
        options = [o + ("*" if o == defaults.get(group) else "") for o in config_names(group)]
        lines.append(wrap([f"{group:<20}", *options, note], "  ", 100).replace("\n  ", "\n" + " " * 24))
    return "\n".join(lines)


def _cfg_flags(argv: list[str]) -> tuple[str | None, bool | None, list[str]]:
    """Hydra's `--cfg job|hydra|all` (`-c`) and `--resolve`: (what to print or None, resolve, the rest)."""
    show, resolve, rest = None, None, []
    args = iter(argv)
    for a in args:
        if a in ("--cfg", "-c") or a.startswith("--cfg="):
            show = a.partition("=")[2] if "=" in a else next(args, "")
            if show not in ("job", "hydra", "all"):
                raise ValueError(f"--cfg takes job, hydra or all, got {show!r}")
        elif a == "--resolve":
            resolve = True
        else:
            rest.append(a)
    if resolve and show is None:
        raise ValueError("--resolve goes with --cfg job|hydra|all (print the config resolved, and train nothing)")
    return show, resolve, rest


def _print_config(overrides: list[str], show: str, resolve: bool | None) -> None:
    """`--cfg`: the config a run would get (checked as for a run; interpolations resolved where they can be),
    `hydra:` Hydra's own settings (as written), or both."""
    from omegaconf import OmegaConf

    from samp.cli import compose, config_yaml

    overrides = _resume_overrides([a for a in overrides if a not in ("-m", "--multirun")])
    cfg = compose_train_config(overrides)
    if show in ("job", "all"):
        print(config_yaml(cfg, resolve), end="")
    if show in ("hydra", "all"):
        hydra = compose("train", overrides, return_hydra_config=True).hydra
        print(OmegaConf.to_yaml({"hydra": OmegaConf.to_container(hydra, resolve=False)}), end="")


def main(argv: list[str] | None = None) -> int:
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from samp.cli import wants_help
    from samp.runs.folder import Terminated

    argv = sys.argv[1:] if argv is None else list(argv)
    if wants_help(argv) or not argv:
        print(_help(), file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    bad_input = (HydraException, OmegaConfBaseException, ValueError, FileNotFoundError)
    try:
        show, resolve, argv = _cfg_flags(argv)
        if show is not None:
            _print_config(argv, show, resolve)
            return 0
    except bad_input as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if any(a in ("-m", "--multirun") for a in argv) or any(a.lstrip("+").startswith("sweep=") for a in argv):
        from samp.train.sweep import multirun

        return multirun([a for a in argv if a not in ("-m", "--multirun")])
    try:
        folder = train(argv)
    except bad_input as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except FloatingPointError as err:  # a diverged run: run.json says failed, checkpoints/ keeps the last good state
        print(f"error: {err}", file=sys.stderr)
        return 1
    except (KeyboardInterrupt, Terminated) as err:  # run.json says interrupted
        print(f"interrupted ({type(err).__name__}); continue with `python -m samp.train resume=RUN_DIR`",
              file=sys.stderr)
        return 143 if isinstance(err, Terminated) else 130
    _print_outputs(folder.path)
    return 0


def _print_outputs(path: Path) -> None:
    """The end of a run on the terminal: its evaluation table and where its files are."""
    from samp.eval.names import EVAL_DIR, METRICS_MD, RECORDING_RRD

    table = path / EVAL_DIR / METRICS_MD
    if table.is_file():
        print("\n" + table.read_text().strip() + "\n")
    print(f"done: {path}")
    for name, found in (("recording", sorted({*path.glob(f"**/{RECORDING_RRD}"), *path.glob("*.rrd")})),
                        ("plots", sorted(path.glob("plots/*.png")))):
        for item in found:
            print(f"  {name}: {item}" + (f"   (open with: rerun {item})" if item.suffix == ".rrd" else ""))

