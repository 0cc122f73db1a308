"""`python -m samp.train experiment=NAME [key=value ...]`: compose, prepare, seed, instantiate, fit,
evaluate, record.

The experiment decides what is trained (`system`, `datamodule`, `model`, each a `_target_`); this file only
runs the recipe. Before fitting, `prerequisites.prepare` resolves the system's robot SDF by name, builds what
is missing when `build_missing` says so, and runs the DAgger rounds `dagger.rounds` asks for
(`samp.train.dagger`: a teacher run, then the dataset the run trains on); after fitting, `after_fit.after_fit`
evaluates the model just trained, in memory (`evaluation.problems` per split for a policy; export and Table
III for a robot SDF). Each run gets `runs/<name>/<timestamp>/` (`SAMP_RUNS_DIR` or `paths.runs_dir` moves the
root) with `.hydra/`, `run.json`, `metrics.csv`, `checkpoints/` and what the evaluation writes; it is also a
run of the MLflow tracking store (`samp.runs.tracking`; `tracking.uri`).
`resume=RUN_DIR` continues a run in its own folder from its last checkpoint, with the overrides it was
started with (new ones win) and its loggers continuing; `run_dir=DIR` puts a new run in a folder of your
choice; `init_from=RUN_DIR` starts a new run from the network weights of a trained policy run
(`samp.train.init_from`). `-m` / `sweep=NAME` hand the arguments to the Hydra multirun entry point (`samp.train.sweep`),
which calls `train` once per sweep member.
"""

from __future__ import annotations

import warnings
from contextlib import nullcontext
from pathlib import Path

from samp.integrity import trusted
from samp.train.config import compose_train_config

__all__ = ["train"]

def _repo_path(path: str) -> Path:
    from samp.paths import project_dir

    p = Path(path).expanduser()
    return p if p.is_absolute() else project_dir() / p


def _resume_overrides(overrides: list[str], resume: str | Path | None = None) -> list[str]:
    """`resume=RUN_DIR [key=value ...]` (or `resume` given as data): the run's recorded overrides, then the
    new ones (which win)."""
    from samp.runs import RunFolder
    from samp.runs.lineage import merge_overrides, override_key

    path = resume
    if path is None:
        given = [o for o in overrides if override_key(o) == "resume"]
        if not given:
            return overrides
        from hydra.core.override_parser.overrides_parser import OverridesParser

        path = OverridesParser.create().parse_override(given[-1]).value()  # unquoted, as Hydra reads it
    if path in (None, ""):
        return overrides
    folder = RunFolder(_repo_path(str(path)))
    # trust_checkpoint is never carried over: trusting a file is a decision for each load
    recorded = [o for o in folder.read().get("overrides", [])
                if override_key(o) not in ("resume", "run_dir", "trust_checkpoint")]
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
        from samp.integrity import check_recorded_hash

        check_recorded_hash(folder.last_checkpoint)  # before the run is marked running again
        return folder, folder.last_checkpoint
    if cfg.run_dir:  # a sweep member's folder, or one the user names
        folder = RunFolder.create_at(_repo_path(cfg.run_dir))
    else:
        folder = RunFolder.create(_repo_path(cfg.paths.runs_dir), cfg.name)
    os.environ[RUN_DIR_ENV] = str(folder.path)
    return folder, None


def train(overrides: list[str], *, run_dir: str | Path | None = None, resume: str | Path | None = None,
          paths: dict | None = None, **info):
    """Run the recipe; returns the `RunFolder`. `info` goes into run.json (a sweep names itself there).
    What it prints is also kept in the run folder's `train.log`.

    Folders a caller already holds are passed as data, never spliced into override strings (a folder
    name may hold `=`, `,`, quotes or spaces, which Hydra's override grammar would read): `run_dir` (a
    new run in that folder), `resume` (continue that run) and `paths` (`{"runs_dir": ..., "datasets_dir":
    ...}`, set after composition) act as the overrides of the same names."""
    from samp.names import TRAIN_LOG
    from samp.runs.console import RunLog

    with RunLog(TRAIN_LOG) as log:
        return _train(overrides, log, run_dir=run_dir, resume=resume, paths=paths, **info)


def _train(overrides: list[str], log, *, run_dir, resume, paths, **info):
    import time

    import pytorch_lightning as pl
    from hydra.utils import instantiate
    from omegaconf import OmegaConf, open_dict

    from samp.data.lock import lock_record
    from samp.runs.console import quiet_lightning, trainer_console
    from samp.runs.distributed import is_rank_zero
    from samp.runs.folder import Terminated
    from samp.runs.loggers import LogEveryEpoch, finish_loggers
    from samp.runs.tracker_guard import start_tracking
    from samp.train.after_fit import after_fit
    from samp.train.prerequisites import prepare

    overrides = _resume_overrides(list(overrides), resume)
    cfg = compose_train_config(overrides)
    with open_dict(cfg):
        for key, value in (paths or {}).items():
            if key not in cfg.paths:
                raise ValueError(f"paths has no key {key!r}; keys: {', '.join(cfg.paths)}")
            cfg.paths[key] = str(value)
        if run_dir is not None:
            cfg.run_dir = str(run_dir)
        if resume is not None:
            cfg.resume = str(resume)
        cfg.paths.runs_dir = str(_repo_path(cfg.paths.runs_dir))
        cfg.paths.datasets_dir = str(_repo_path(cfg.paths.datasets_dir))
        if cfg.get("init_from"):  # the from-run's network, so that its weights fit (samp.train.init_from)
            from samp.train.init_from import recorded_model

            cfg.init_from = str(_repo_path(cfg.init_from))
            cfg.model = recorded_model(cfg.init_from)
        prepare(cfg, overrides)  # before this run's folder exists: a robot SDF or DAgger teacher is a run of its own
    folder, ckpt = _open_folder(cfg)
    with open_dict(cfg):
        cfg.run_dir = str(folder.path)
    rank_zero = is_rank_zero()
    if rank_zero:
        log.attach(folder.path)
        folder.write_config(OmegaConf.to_yaml(cfg, resolve=True), overrides)
        if ckpt is not None:
            _trim_metrics(folder, ckpt, _trust(cfg))
        print(f"run folder: {folder.path}" + (f" (resuming from {ckpt.name})" if ckpt else ""), flush=True)
    else:
        log.discard()

    # The CSV logger writes into the run folder, which already holds .hydra/ and run.json by design.
    warnings.filterwarnings("ignore", message="Experiment logs directory .* exists and is not empty")
    config = OmegaConf.to_container(cfg, resolve=True)
    try:
        with folder.record(experiment=cfg.name, seed=int(cfg.seed), overrides=overrides, run_dir=str(folder.path),
                           config=config, lock=lock_record(), **info) if rank_zero else nullcontext(folder):
            pl.seed_everything(int(cfg.seed), workers=True, verbose=False)
            datamodule = instantiate(cfg.datamodule)
            system = instantiate(cfg.system)
            if cfg.get("init_from") and ckpt is None:  # a resumed run's weights come from its own checkpoint
                from samp.train.init_from import load_initial_weights

                lineage = load_initial_weights(system, cfg.init_from, _trust(cfg))
                if rank_zero:
                    folder.update(init_from=lineage)
                    print(f"init_from: the network starts from {lineage['checkpoint']}", flush=True)
            callbacks = [instantiate(c) for c in (cfg.callbacks or {}).values()]
            loggers = [instantiate(c) for c in (cfg.logger or {}).values()]
            tracker = start_tracking(cfg, folder) if rank_zero else None  # MLflow, unless tracking is off (or fails)
            loggers += [tracker] if tracker is not None else []
            console, progress = trainer_console(cfg.trainer)  # a progress bar on a terminal, else lines
            quiet_lightning()  # before the Trainer, which logs its tip when it is made
            trainer = instantiate(cfg.trainer, callbacks=callbacks + progress + [LogEveryEpoch()],
                                  logger=loggers or False, default_root_dir=folder.path, **console)
            start = time.perf_counter()
            with _safe_resume(ckpt, cfg):
                trainer.fit(system, datamodule=datamodule, ckpt_path=str(ckpt) if ckpt else None,
                            weights_only=None if ckpt is None else not trusted(_trust(cfg)))
            fit_s = time.perf_counter() - start + ((folder.read().get("fit_time_s") or 0.0) if ckpt else 0.0)
            trainer.save_checkpoint(folder.last_checkpoint, weights_only=False)  # the full state, to resume from
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
            finish_loggers(loggers, record, evaluated, step=int(trainer.global_step), final=metrics)
    except (KeyboardInterrupt, Terminated) as err:
        err.run_folder = folder  # the command line says whether it can be resumed
        raise
    return folder


def _trust(cfg) -> bool | None:
    """`trust_checkpoint=true` on the command line (a key of the training config), else the environment."""
    return True if cfg.trust_checkpoint else None


def _safe_resume(ckpt: Path | None, cfg):
    """Resuming: Lightning unpickles the checkpoint with `weights_only=True` and samp's allow-list
    (`samp.integrity`), so it cannot run code (its hash was checked when the folder was opened)."""
    import torch

    from samp.integrity import safe_globals

    if ckpt is None or trusted(_trust(cfg)):
        return nullcontext()
    return torch.serialization.safe_globals(safe_globals())


def _trim_metrics(folder, ckpt: Path, trust: bool | None = None) -> None:
    """Rows of metrics.csv logged after the checkpoint a resumed run starts from are set aside."""
    from samp.integrity import load_torch_file

    step = int(load_torch_file(ckpt, "checkpoint to resume from", trust=trust, mmap=True)["global_step"])
    moved = folder.trim_metrics(step)
    if moved:
        print(f"metrics.csv: {moved} row(s) logged after step {step} (past the checkpoint) moved to "
              "metrics.superseded.csv", flush=True)


