"""Sweeps: Hydra multirun over the training recipe, one run folder per member, named by its overrides.

    python -m samp.train -m sweep=anchor_size                           # members one after another
    python -m samp.train -m sweep=anchor_size hydra/launcher=runs_joblib hydra.launcher.n_jobs=2
    python -m samp.train -m sweep=loss_ablation trainer=gpu hydra/launcher=runs_slurm hydra.launcher.partition=P
    python -m samp.train -m experiment=samp_n40,samp_n70 seed=0,1      # an ad-hoc sweep

(`+sweep=NAME` and `+experiment=...` are read as `sweep=NAME` and `experiment=...`: both groups are in
conf/train.yaml's defaults list.) `samp.train` composes with Hydra's compose API; `-m` (or `sweep=NAME`)
hands the arguments to `multirun` here, which runs Hydra's own `main` on conf/train.yaml so that sweepers
and launchers (basic, joblib, submitit/SLURM) work as Hydra documents them. A sweep config (conf/sweep/NAME.yaml) sets
`hydra.sweeper.params` and `hydra.sweep.dir` (runs/sweeps/NAME). Every member is exactly `samp.train.train(its
overrides, run_dir=<member folder>)` (the folder passed as data, never as an override string), so it is
checked, recorded and evaluated like a single run. Its folder is `<sweep dir>/<override_dirname>`, built from
the overrides that vary between members and the experiment, e.g.
`runs/sweeps/anchor_size/experiment=samp_n40/`; the other overrides are recorded in the member's run.json. A
member folder named before `experiment` joined the defaults list (`+experiment=samp_n40`) is still found and
used in place.

Running a sweep again: a member whose run.json says completed with the same overrides is skipped; one
completed with other overrides is an error (use another `hydra.sweep.dir`); an interrupted or failed
member with a checkpoint resumes from it; one without a checkpoint starts again, its old run.json and
metrics.csv kept as run.attempt-K.json and metrics.attempt-K.csv.

DDP inside a sweep works only through the SLURM launcher (one SLURM task per GPU; Lightning reads the
ranks from SLURM). Lightning's local DDP launcher re-runs the command line in each rank, which would
start the whole sweep again there, so that combination is refused.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from pathlib import Path

from samp.cli import canonical_overrides
from samp.runs.distributed import is_rank_zero
from samp.runs.folder import METRICS_CSV, RUN_JSON, RunFolder
from samp.runs.lineage import override_key

__all__ = ["keep_lock", "member_state", "multirun"]

# Overrides of the member itself that the folder name never needs (they do not vary in a sweep).
ALWAYS_NAMED = ("experiment",)
# Groups that member folders were once named with a `+` (`+experiment=samp_n40`), before conf/train.yaml's
# defaults list named them: such a folder is found again (skipped, resumed) rather than started anew.
LEGACY_ADDED = ("experiment",)


def _swept_keys(overrides: list[str]) -> tuple[set[str], str | None]:
    """(keys that take several values, from the command line and the sweep config; the sweep's name)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    from samp.paths import conf_dir

    parsed = OverridesParser.create().parse_overrides(overrides)
    swept = {o.key_or_group for o in parsed if o.is_sweep_override()}
    names = [o.value() for o in parsed if o.key_or_group == "sweep"]
    sweep = str(names[-1]) if names else None
    if sweep is not None:
        path = conf_dir() / "sweep" / f"{sweep}.yaml"
        if not path.is_file():
            known = ", ".join(sorted(p.stem for p in (conf_dir() / "sweep").glob("*.yaml")))
            raise ValueError(f"no sweep {sweep!r} (conf/sweep/{sweep}.yaml); sweeps: {known}")
        params = OmegaConf.select(OmegaConf.load(path), "hydra.sweeper.params") or {}
        added = [str(k) for k in params if canonical_overrides("train", [f"{k}=x"]) != [f"{k}=x"]]
        if added:  # Hydra would refuse each member ("Multiple values for experiment")
            raise ValueError(f"conf/sweep/{sweep}.yaml: write {', '.join(k[1:] for k in added)} without the `+` under "
                             "hydra.sweeper.params (conf/train.yaml's defaults list already names that group)")
        swept |= {override_key(str(k)) for k in params}
    return swept, sweep


def _hydra_settings(overrides: list[str]) -> list[str]:
    """Overrides of Hydra's own settings for a sweep of `samp.train` (the user's own settings win)."""
    swept, sweep = _swept_keys(overrides)
    keys = [override_key(o) for o in overrides]
    named = swept | set(ALWAYS_NAMED)
    if not named & set(keys) and not swept:
        raise ValueError("a sweep needs something to vary: sweep=NAME (conf/sweep/), or an override with several "
                         "values such as experiment=samp_n40,samp_n70 or seed=0,1")
    exclude = sorted({k for k in keys if not k.startswith("hydra") and k not in named} | {"sweep"})
    settings = {"hydra.job.config.override_dirname.exclude_keys": "[" + ",".join(f"'{k}'" for k in exclude) + "]",
                "hydra.sweep.subdir": "${hydra.job.override_dirname}",
                "hydra.output_subdir": "null",  # samp writes .hydra/ itself; Hydra's copy would overwrite it
                "hydra.job.name": "train", "hydra.job.chdir": "false",
                # Logging left as a single run has it (samp composes those with Hydra's API, which configures
                # none): Hydra's defaults would give Lightning's lines Hydra's format, bring back the tip that
                # quiet_lightning filters from Lightning's own handler, and write each line a second time into
                # the member's train.log (the job log's file has that name too). Hydra's own lines (the sweep
                # folder, the members launched) stay, plain, through its own loggers only (conf/hydra/hydra_logging).
                "hydra/job_logging": "none", "hydra/hydra_logging": "samp"}
    if sweep is None:
        settings["hydra.sweep.dir"] = "'${paths.runs_dir}/sweeps/${now:%Y-%m-%d_%H-%M-%S}'"
    return [f"{k}={v}" for k, v in settings.items() if k not in keys]


def _first_member(argv: list[str]) -> list[str]:
    """The overrides of the sweep's first member: every swept value (command line or sweep config) at its
    first choice, the sweep's name dropped."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    from samp.paths import conf_dir

    parser = OverridesParser.create()
    member, swept = [], {}
    for o in parser.parse_overrides(argv):
        if o.key_or_group == "sweep" or o.key_or_group.startswith("hydra"):
            continue
        if o.is_sweep_override():
            swept[o.key_or_group] = next(iter(o.sweep_string_iterator()))
        else:
            member.append(o.input_line)
    _, sweep = _swept_keys(argv)
    if sweep is not None:
        params = OmegaConf.select(OmegaConf.load(conf_dir() / "sweep" / f"{sweep}.yaml"), "hydra.sweeper.params") or {}
        for key, values in params.items():
            o = parser.parse_override(f"{key}={values}")
            swept.setdefault(override_key(str(key)), next(iter(o.sweep_string_iterator())) if o.is_sweep_override()
                             else str(values))
    return member + [f"{k}={v}" for k, v in swept.items()]


def _keys_of_swept_experiments(argv: list[str]) -> list[str]:
    """`argv` with every plain `a.b=value` whose node exists only once an experiment is chosen written
    `++a.b=value`, after checking the sweep's first member composes with the plain spelling.

    Hydra composes a sweep's primary config before it applies the swept values, so with the experiment
    swept (`-m sweep=anchor_size`, `experiment=A,B`) a key the experiment brings (`datamodule.dataset`)
    does not exist yet there, and Hydra would refuse it ("Key 'dataset' is not in struct"). Each member
    composes with its experiment, where `++a.b=value` means the same as `a.b=value`; the check on the
    first member keeps a typo an error, as in a single run."""
    from omegaconf import OmegaConf

    from samp.cli import compose
    from samp.train.config import compose_train_config

    plain = [o for o in argv if "=" in o and not o.startswith(("+", "~")) and "." in o.partition("=")[0]
             and not o.startswith("hydra")]
    if not plain:
        return argv
    base = compose("train", [o for o in argv if o not in plain and not o.startswith("hydra")
                             and not _is_sweep(o) and override_key(o) != "sweep"])
    late = [o for o in plain if OmegaConf.select(base, o.partition("=")[0], default=_ABSENT,
                                                 throw_on_missing=False) is _ABSENT]
    if not late:
        return argv
    compose_train_config(_first_member(argv))  # unknown keys are named here, as for a single run
    return [f"++{o}" if o in late else o for o in argv]


_ABSENT = object()


def _is_sweep(override: str) -> bool:
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return OverridesParser.create().parse_override(override).is_sweep_override()


def keep_lock() -> None:
    """Name the lock file in effect (`./samp.lock` of the folder the sweep starts in) in `$SAMP_LOCK`, so
    that the members, which run from the repository root or in processes of their own, honour it too."""
    from samp.data.lock import LOCK_ENV, active_lock

    lock = active_lock()
    if lock is not None:
        os.environ[LOCK_ENV] = str(lock.resolve())


def multirun(argv: list[str]) -> int:
    """Run a sweep (arguments as `python -m samp.train -m ...` takes them, without the `-m`).
    Relative paths are taken from the project folder (`samp.paths.project_dir`), as everywhere in samp."""
    import hydra
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from samp.paths import conf_dir, project_dir

    from samp.cli import check_override_syntax

    try:
        check_override_syntax("train", argv)  # a bad override named on one line, before Hydra's parser sees it
        argv = canonical_overrides("train", argv)  # +experiment=, +sweep= as experiment=, sweep=
        settings = _hydra_settings(argv)
        argv = _keys_of_swept_experiments(argv)
        keep_lock()
    except (ValueError, FileNotFoundError, HydraException, OmegaConfBaseException) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    os.chdir(project_dir())
    sys.argv = [sys.argv[0], "--multirun", *argv, *settings]
    hydra.main(config_path=str(conf_dir()), config_name="train", version_base="1.3")(_member)()
    return 0


def member_state(folder: Path, overrides: list[str]) -> str:
    """What a sweep member does with its folder: "new", "skip" (completed with the same overrides) or
    "resume" (stopped after a checkpoint). Raises ValueError for a folder completed with other overrides
    or still running here. A stopped member without a checkpoint is set aside and starts "new"."""
    path = folder / RUN_JSON
    if not path.is_file():
        return "new"
    run = RunFolder(folder)
    record = run.read()
    recorded = [o for o in record.get("overrides", []) if override_key(o) not in ("resume", "run_dir")]
    # `+experiment=X` (as recorded before the defaults list named the group) and `experiment=X` are one override
    recorded, overrides = _same_spelling(recorded), _same_spelling(overrides)
    if record.get("status") == "completed":
        if sorted(recorded) == sorted(overrides):
            return "skip"
        raise ValueError(f"sweep member {folder} was completed with overrides {sorted(set(recorded) - set(overrides))} "
                         f"where this sweep has {sorted(set(overrides) - set(recorded))}; run the sweep into another "
                         "folder (hydra.sweep.dir=DIR) or move that member away")
    if record.get("status") == "running" and record.get("host") == os.uname().nodename and _alive(record.get("pid")):
        raise ValueError(f"sweep member {folder} is still running (pid {record['pid']}); wait for it or stop it")
    if run.last_checkpoint.is_file():
        return "resume"
    k = 1
    while (folder / f"run.attempt-{k}.json").exists():
        k += 1
    path.rename(folder / f"run.attempt-{k}.json")
    if (folder / METRICS_CSV).is_file():
        (folder / METRICS_CSV).rename(folder / f"metrics.attempt-{k}.csv")
    print(f"{folder}: the earlier attempt stopped before its first checkpoint; kept as run.attempt-{k}.json, "
          "starting again", flush=True)
    return "new"


def _same_spelling(overrides: list[str]) -> list[str]:
    """`+experiment=X` (as recorded before the defaults list named the group) is `experiment=X`, and
    `++a.b=v` (how a sweep over experiments hands keys to Hydra) is `a.b=v`."""
    return [o[2:] if o.startswith("++") else o for o in canonical_overrides("train", overrides)]


def _alive(pid) -> bool:
    if not isinstance(pid, int) or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    return True


@contextmanager
def _outside_hydra():
    """Let `samp.train` compose its config (Hydra's compose API refuses while a Hydra app is running)."""
    from hydra.core.global_hydra import GlobalHydra

    running = GlobalHydra.instance().hydra
    GlobalHydra.instance().clear()
    try:
        yield
    finally:
        GlobalHydra.instance().hydra = running


def _legacy_folder(folder: Path, hc, tidy: bool) -> Path:
    """`folder`, or the folder an earlier version gave this member (`+experiment=NAME,...`, Hydra's naming
    with the `+`) when only that one holds a run.json. With `tidy`, the new folder, which Hydra has just
    made and which holds at most its empty log, is removed."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    if (folder / RUN_JSON).is_file():
        return folder
    naming = hc.job.config.override_dirname
    lines = sorted(f"+{o.input_line}" if o.key_or_group in LEGACY_ADDED and not o.input_line.startswith("+")
                   else o.input_line for o in OverridesParser.create().parse_overrides(list(hc.overrides.task))
                   if o.key_or_group not in naming.exclude_keys)
    legacy = folder.parent / naming.item_sep.join(lines).replace("=", naming.kv_sep)
    if legacy == folder or not (legacy / RUN_JSON).is_file():
        return folder
    if tidy and folder.is_dir():
        for path in folder.iterdir():
            if path.suffix == ".log" and path.stat().st_size == 0:
                path.unlink()
        if not any(folder.iterdir()):
            folder.rmdir()
        print(f"{legacy.name}: the folder an earlier run of this sweep gave this member, used in place", flush=True)
    return legacy


def _member(cfg) -> dict | None:
    """One sweep member (Hydra's task function): skip, resume or start it in its folder."""
    from hydra.core.hydra_config import HydraConfig

    from samp.train import train

    hc = HydraConfig.get()
    folder = Path(hc.runtime.output_dir)
    overrides = [o for o in hc.overrides.task if override_key(o) != "sweep"]
    strategy = str((cfg.get("trainer") or {}).get("strategy", ""))
    # Only SLURM starts the ranks for Lightning: submitit's local executor (runs_submitit_local) runs one process
    # per member, in which Lightning's local DDP launcher would start the ranks by re-running that job.
    if "ddp" in strategy and not str(hc.launcher.get("_target_", "")).endswith(".SlurmLauncher"):
        raise ValueError(f"trainer.strategy={strategy} in a sweep needs the SLURM launcher (hydra/launcher=runs_slurm): "
                         "Lightning's local DDP launcher would run the whole sweep again in every rank")
    named = folder
    folder = _legacy_folder(folder, hc, tidy=is_rank_zero())
    if is_rank_zero():
        state = member_state(folder, overrides)
    else:  # the other SLURM tasks of a DDP member follow rank 0 (samp.train attaches them to its folder)
        state = "skip" if RunFolder(folder).read().get("status") == "completed" else "new"
    if state == "skip":
        print(f"{folder.name}: completed earlier, skipped", flush=True)
        return RunFolder(folder).read().get("metrics")
    # The folder goes to the recipe as data: member names hold `=` and `,`, which an override string would parse.
    where = {"resume": folder} if state == "resume" else {"run_dir": folder}
    sweep = {"dir": str(Path(hc.sweep.dir).resolve()), "member": hc.job.override_dirname if folder == named
             else folder.name}
    with _outside_hydra():
        run = train(overrides, sweep=sweep, **where)
    return run.read().get("metrics")
