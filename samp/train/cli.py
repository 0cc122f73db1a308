"""`python -m samp.train`'s command line: help built from conf/, Hydra's `--cfg`, sweeps, exit codes, and
the end of a run on the terminal. The recipe itself is `samp.train.recipe.train`."""

from __future__ import annotations

import sys
from pathlib import Path

from samp.train.config import compose_train_config
from samp.train.recipe import _resume_overrides, train

__all__ = ["USAGE", "hydra_quoted", "interrupted_hint", "main"]

USAGE = """usage: python -m samp.train experiment=NAME [key=value ...]        train a run (runs/<name>/<timestamp>/)
       python -m samp.train experiment=NAME [key=value ...] --cfg job|hydra|all [--resolve]
                                                                 print the composed config; nothing is trained
       python -m samp.train experiment=NAME [key=value ...] --lock[=FILE]
                    pin the NAME@ID of its dataset, benchmark and robot SDF in samp.lock (or FILE); nothing is trained
       python -m samp.train resume=RUN_DIR [key=value ...]         continue a run from its checkpoints/last.ckpt
       python -m samp.train -m sweep=NAME [hydra/launcher=runs_joblib|runs_slurm] [key=value ...]   a sweep
       python -m samp.train -m experiment=A,B [seed=0,1] [key=value ...]                             an ad-hoc sweep
key=value sets any config key (trainer.max_epochs=3), GROUP=OPTION picks a config of a group (trainer=gpu);
+experiment=NAME and +sweep=NAME mean the same as experiment=NAME and sweep=NAME. `--help` lists the options."""


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


def _lock_flag(argv: list[str]) -> tuple[Path | None, list[str]]:
    """`--lock` (samp.lock in the current folder) or `--lock=FILE`: (the lock file or None, the rest)."""
    from samp.data.lock import LOCK_FILE

    flags = [a for a in argv if a == "--lock" or a.startswith("--lock=")]
    if not flags:
        return None, argv
    return Path(flags[-1].partition("=")[2] or LOCK_FILE), [a for a in argv if a not in flags]


def _write_lock(overrides: list[str], out: Path) -> None:
    from samp.train.lock import write_lock

    if any(a in ("-m", "--multirun") or a.lstrip("+").startswith("sweep=") for a in overrides):
        raise ValueError("--lock pins the inputs of one config: give its experiment and overrides without -m or "
                         "sweep= (a sweep's members share them; lock them once)")
    data = write_lock(overrides, out)
    print(f"wrote {out}:")
    for kind in ("datasets", "robot_sdf"):
        for name, ref in sorted(data[kind].items()):
            print(f"  {name} -> {ref}")


def _print_config(overrides: list[str], show: str, resolve: bool | None) -> None:
    """`--cfg`: the config a run would get (checked as for a run; interpolations resolved where they can be),
    `hydra:` Hydra's own settings (as written), or both. For a sweep (`-m`, `sweep=NAME`): its first member's."""
    from omegaconf import OmegaConf

    from samp.cli import compose, config_yaml

    from samp.cli import canonical_overrides

    sweep = any(a in ("-m", "--multirun") for a in overrides) or any(a.lstrip("+").startswith("sweep=")
                                                                      for a in overrides)
    overrides = [a for a in overrides if a not in ("-m", "--multirun")]
    if sweep:  # a sweep: the config of its first member
        from samp.train.sweep import _first_member

        hydra_keys = [a for a in overrides if a.startswith("hydra")]
        overrides = _first_member(canonical_overrides("train", overrides)) + hydra_keys
    overrides = _resume_overrides(overrides)
    cfg = compose_train_config(overrides)
    if show in ("job", "all"):
        print(config_yaml(cfg, resolve), end="")
    if show in ("hydra", "all"):
        hydra = compose("train", overrides, return_hydra_config=True).hydra
        print(OmegaConf.to_yaml({"hydra": OmegaConf.to_container(hydra, resolve=False)}), end="")


def main(argv: list[str] | None = None) -> int:
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from samp.cli import answer_help, user_error, wants_help
    from samp.runs.folder import Terminated

    argv = sys.argv[1:] if argv is None else list(argv)
    if wants_help(argv) or not argv:
        return answer_help(argv, _help)
    bad_input = (HydraException, OmegaConfBaseException, ValueError, FileNotFoundError)
    try:
        show, resolve, argv = _cfg_flags(argv)
        if show is not None:
            _print_config(argv, show, resolve)
            return 0
        lock, argv = _lock_flag(argv)
        if lock is not None:
            _write_lock(argv, lock)
            return 0
    except bad_input as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if any(a in ("-m", "--multirun") for a in argv) or any(a.lstrip("+").startswith("sweep=") for a in argv):
        from samp.train.sweep import multirun

        return multirun([a for a in argv if a not in ("-m", "--multirun")])
    try:
        folder = train(argv)
    except (*bad_input, OSError) as err:
        if user_error(err) is None:
            raise
        print(f"error: {user_error(err)}", file=sys.stderr)
        return 2
    except FloatingPointError as err:  # a diverged run: run.json says failed, checkpoints/ keeps the last good state
        print(f"error: {err}", file=sys.stderr)
        return 1
    except (KeyboardInterrupt, Terminated) as err:  # run.json says interrupted
        print(interrupted_hint(err, getattr(err, "run_folder", None)), file=sys.stderr)
        return 143 if isinstance(err, Terminated) else 130
    _print_outputs(folder.path)
    return 0


def hydra_quoted(value) -> str:
    """`value` as the value of a Hydra override: as it is when plain, else double-quoted (a sweep member's
    folder holds `=` and `,`, which Hydra's grammar reads as syntax)."""
    import re

    text = str(value)
    if re.fullmatch(r"[\w/.\-~]+", text):
        return text
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def interrupted_hint(err: BaseException, folder) -> str:
    """What to do after an interrupted run: resume it when it has a checkpoint to resume from, else start
    it again (`resume=` would refuse a run that stopped before its first checkpoint)."""
    import shlex

    what = f"interrupted ({type(err).__name__})"
    if folder is None:
        return f"{what} before its run folder existed: nothing to resume; start it again"
    if folder.last_checkpoint.is_file():
        return f"{what}; continue with `python -m samp.train {shlex.quote('resume=' + hydra_quoted(folder.path))}`"
    return (f"{what} before its first checkpoint ({folder.last_checkpoint} does not exist), so it cannot be resumed; "
            f"start it again (run.json in {folder.path} keeps the record, marked interrupted)")


def _print_outputs(path: Path) -> None:
    """The end of a run on the terminal: where its files are (the evaluation printed its table already)."""
    from samp.eval.names import EVAL_DIR, METRICS_MD, RECORDING_RRD
    from samp.names import TRAIN_LOG

    print(f"done: {path}")
    for name, item in (("table", path / EVAL_DIR / METRICS_MD), ("log", path / TRAIN_LOG)):
        if item.is_file():
            print(f"  {name}: {item}")
    for name, found in (("recording", sorted({*path.glob(f"**/{RECORDING_RRD}"), *path.glob("*.rrd")})),
                        ("plots", sorted(path.glob("plots/*.png")))):
        for item in found:
            print(f"  {name}: {item}" + (f"   (open with: rerun {item})" if item.suffix == ".rrd" else ""))
