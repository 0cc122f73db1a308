"""`python -m samp.eval run=RUN_DIR [benchmark=[unseen,hard]] [splits=[val,train]] [problems=N] [key=value ...]`
`python -m samp.eval planner=expert|expert_raw|ompl_sampling|straight dataset=REF [out=DIR] ...`

Evaluates a run's policy (or the expert, or the straight-line baseline) under the evaluation protocol
(`samp.eval.report`): the stored evaluation problems of the run's dataset, per split (validation and
training scenes, never trained on), the standing benchmark of unseen scenes and the hard benchmark (every
problem needs a detour), with the expert and the straight line beside it on the same problems. Writes into
`RUN_DIR/eval/` (without a run: `<runs folder>/eval/PLANNER_DATASET@ID/`; or `out=DIR`): metrics.json,
metrics.md, problems.jsonl and recording.rrd. An earlier evaluation there is kept and the new one goes beside
it (`eval-2/`, ...), unless `overwrite=true`. The evaluation is also logged to MLflow (`samp.tracking`): a
run's into its own MLflow run, as a section named after the folder (`eval-2/...`), unless
`SAMP_TRACKING_URI=off`. Settings: conf/eval.yaml (schema: samp/eval/config.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

from samp.cli import compose, output_path, run_command

USAGE = """usage: python -m samp.eval [run=]RUN_DIR [benchmark=[unseen,hard]|NAME|null] [splits=[val,train]]
                          [problems=N] [key=value ...]                    a run's policy
       python -m samp.eval planner=expert|expert_raw|ompl_sampling|straight dataset=REF [out=DIR] [key=value ...]
Sections: the dataset's stored evaluation problems per split (val, train, test scenes), the standing
benchmark of unseen scenes ("benchmark") and the hard one ("hard": every problem needs a detour), each
with the expert and the straight line beside the planner.
Writes RUN_DIR/eval/ (or out=DIR): metrics.json, metrics.md, problems.jsonl and recording.rrd; an earlier
evaluation in RUN_DIR/eval/ is kept and the new one goes to RUN_DIR/eval-2/ (overwrite=true replaces it)."""


def _config(overrides: list[str]):
    from hydra.errors import ConfigCompositionException
    from omegaconf import OmegaConf

    from samp.eval.config import EvalConfig, load_eval_config
    from samp.paths import conf_dir

    # `dataset=REF` names a config group to Hydra (conf/dataset/ holds dataset specs), so keys that are
    # also group names are set after composition instead of being passed to Hydra.
    valid = list(EvalConfig.__dataclass_fields__)
    overrides = [_old_split(_bare_run(o)) for o in overrides]
    for o in overrides:  # a typo is named with the valid keys (Hydra would suggest `+key=`, then refused)
        key = o.partition("=")[0].lstrip("+~").split(".")[0]
        if key not in valid and key != "hydra":
            raise ValueError(f"unknown eval setting {key!r} (in {o!r}); valid keys: {', '.join(valid)}")
    groups = {k for k in valid if (conf_dir() / k).is_dir()}
    late = [o for o in overrides if o.partition("=")[0] in groups | set(PATH_KEYS)]
    try:
        raw = compose("eval", [o for o in overrides if o not in late])
    except ConfigCompositionException as err:
        raise ValueError(f"{err}. Valid keys: {', '.join(valid)}") from None
    raw = OmegaConf.to_container(raw, resolve=True)
    for o in late:
        key, _, value = o.partition("=")
        raw[key] = None if value in ("", "null") else value
    return load_eval_config(raw)


# Keys whose value is a path, taken verbatim rather than through Hydra's grammar: a sweep member's folder
# (`runs/sweeps/S/experiment=samp_n40,seed=1`) holds `=` and `,`, which Hydra reads as syntax.
PATH_KEYS = ("run", "out", "root")


def _bare_run(arg: str) -> str:
    """A bare run folder (`runs/EXP/TIME`, or a sweep member's folder, `=` and all) as `run=FOLDER`: an
    argument without `=`, one whose part before the first `=` holds a `/`, or an existing folder."""
    key = arg.partition("=")[0]
    if "=" not in arg or "/" in key or (key not in PATH_KEYS and Path(arg).is_dir()):
        return f"run={arg}"
    return arg


OLD_SPLITS = {"heldout": "[val]", "val": "[val]", "train": "[train]", "test": "[test]", "both": "[val,train]"}


def _old_split(override: str) -> str:
    """`split=heldout|train|both` (before evaluation sections) as the `splits=[...]` it means now."""
    key, _, value = override.partition("=")
    if key != "split":
        return override
    if value not in OLD_SPLITS:
        raise ValueError(f"split={value!r}: give the sections as splits=[val,train] (any of train, val, test)")
    return f"splits={OLD_SPLITS[value]}"


def _open_dataset(cfg, run):
    """The dataset whose splits are evaluated and, for a run, whose scenes it trained on (None: neither)."""
    from samp.data import open_dataset

    ref = cfg.dataset or (run.dataset if run else None)
    if ref is None:
        if cfg.splits:
            where = f"{run.path / 'run.json'} names no dataset" if run else "no run was given"
            raise ValueError(f"say which dataset to take problems from: dataset=REF ({where}), or splits=[] with a "
                             "benchmark")
        return None
    return open_dataset(ref, Path(cfg.root) if cfg.root else None)


def _planner(cfg, run, manifest: dict):
    from samp.eval.loading import load_planner
    from samp.device import resolve_device
    from samp.robot import load_robot

    if run is not None:
        from samp.eval.loading import check_policy_robot

        options = {} if cfg.robot_sdf_tables is None else {"robot_sdf_tables": cfg.robot_sdf_tables}
        if cfg.robot_sdf_pairs is not None:
            options["robot_sdf_pairs"] = cfg.robot_sdf_pairs
        if cfg.compiled is not None:
            options["compiled"] = cfg.compiled
        if cfg.trust_checkpoint:
            options["trust_checkpoint"] = True
        if cfg.check is not None:
            options["check"] = cfg.check
        if cfg.stride is not None:
            options["stride"] = cfg.stride
        policy = load_planner(run.path, device=cfg.device, **options)
        check_policy_robot(policy, manifest)
        own = getattr(policy, "n_e", None)
        if cfg.n_e is not None and own is not None and cfg.n_e != own:
            raise ValueError(f"n_e={cfg.n_e} contradicts the policy of {run.path}: it was trained on grids at n_e = "
                             f"{own} and reads no other; leave n_e out (or give n_e={own}), or train a policy at "
                             f"n_e={cfg.n_e}")
        if cfg.n_e is not None and own is None:  # a policy without grids of its own (the engine's choice)
            policy.n_e = cfg.n_e
        return policy
    robot = load_robot(manifest["robot"]["name"])
    if cfg.planner == "straight":
        robot = robot.to(resolve_device(cfg.device))
        return load_planner("straight", robot=robot, max_step=cfg.straight_max_step, n_e=cfg.n_e)
    from samp.eval.planners import EXPERT_VARIANTS

    if cfg.planner in EXPERT_VARIANTS:  # the dataset's expert settings, planned afresh without post-processing
        from samp.expert import load_expert_config

        config = load_expert_config(manifest.get("config", {}).get("expert_config"), **EXPERT_VARIANTS[cfg.planner])
        return load_planner("expert", robot=robot, mode="plan", config=config, seed=cfg.seed, name=cfg.planner)
    return load_planner("expert", robot=robot, mode=cfg.expert_mode, seed=cfg.seed)


def _out_dir(cfg, run, label: str) -> Path:
    """Where the files go: `out` as given, else `RUN/eval/` or `<runs folder>/eval/PLANNER_LABEL/`. A default
    folder that already holds an evaluation is kept and this one goes beside it (`eval-2/`, `eval-3/`, ...)
    unless `overwrite=true`; an `out` that holds one is refused unless `overwrite=true`."""
    from samp.names import EVAL_DIR, METRICS_JSON
    from samp.paths import runs_root

    if cfg.out:
        out = output_path(Path(cfg.out) / METRICS_JSON).parent
        if (out / METRICS_JSON).exists() and not cfg.overwrite:
            raise ValueError(f"{out / METRICS_JSON} exists from an earlier evaluation; pass overwrite=true to replace "
                             "it, or leave out= away to write beside the run's evaluation")
    else:
        out = run.path / EVAL_DIR if run is not None else runs_root() / "eval" / f"{cfg.planner}_{label}"
        if (out / METRICS_JSON).exists() and not cfg.overwrite:
            first, k = out, 2
            while (out.with_name(f"{first.name}-{k}") / METRICS_JSON).exists():
                k += 1
            out = out.with_name(f"{first.name}-{k}")
            print(f"{first} holds an earlier evaluation, kept as it is; this one goes to {out} "
                  "(overwrite=true replaces the earlier one instead)", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _evaluate(overrides: list[str]) -> Path:
    """The recipe: config, run, dataset and benchmark, planner, sections, evaluation, files."""
    cfg = _config(overrides)
    # Heavy imports only once the config is known to be good.
    from samp.eval.benchmark import open_benchmarks
    from samp.eval.loading import check_robot, find_checkpoint, read_run
    from samp.eval.report import evaluate_sections, flat_report, protocol_sections
    from samp.tracking import track_evaluation

    if (cfg.run is None) == (cfg.planner is None):
        raise ValueError("say what to evaluate: run=RUN_DIR (a trained policy) or planner=expert|straight dataset=REF, "
                         "not both")
    run = read_run(cfg.run) if cfg.run else None
    if run is not None:
        find_checkpoint(run.path)  # a missing checkpoint fails before any dataset work
    ds = _open_dataset(cfg, run)
    benches = []
    if ds is None:  # the benchmarks alone: their manifests name the robot
        benches = open_benchmarks(cfg.benchmark, cfg.root)
        if not benches:
            raise ValueError("nothing to evaluate: splits=[] and benchmark=null")
    # (`ds or bench` would skip a dataset without demonstrations: an empty Dataset is falsy)
    manifest = (ds if ds is not None else benches[0].dataset).manifest
    if run is not None:
        check_robot(run, manifest)
    planner = _planner(cfg, run, manifest)  # a bad checkpoint fails before a benchmark is built
    provenance, trained = _provenance(cfg, run, planner, ds) if run is not None else (None, None)
    if ds is not None:
        benches = open_benchmarks(cfg.benchmark, cfg.root)
    sections = protocol_sections(cfg, ds if cfg.splits else None, benches, planner.robot if hasattr(planner, "robot")
                                 else None, trained=trained)
    label = f"{ds.name}@{ds.id}" if ds is not None else benches[0].ref
    out = _out_dir(cfg, run, label)
    report = evaluate_sections(planner, sections, cfg, out, run_path=run.path if run else None,
                               dataset=None if ds is None else f"{ds.name}@{ds.id}", provenance=provenance)
    # into the run's own MLflow run, as a section named after `out` (samp.tracking)
    from samp.data.registry import datasets_root
    from samp.paths import runs_root
    from samp.tracking import resolve_uri
    from samp.tracking_faults import TrackerDown, call, warn

    try:  # a store that fails (corrupt, locked past MLflow's wait) costs the tracking, never the evaluation's files
        call("logging the evaluation", str(resolve_uri(None, runs_root())), track_evaluation, out, report,
             flat_report(report, report["planner"]), run_path=run.path if run else None,
             datasets_root=Path(cfg.root) if cfg.root else datasets_root(), attempts=1)
    except TrackerDown as err:
        warn(err, out)
    return out


def _provenance(cfg, run, planner, ds):
    """(Provenance, the dataset the policy trained on or None) for a run's policy: its checkpoint's binding
    checked against `ds` (samp.eval.binding), and a checkpoint its run's record does not cover said loudly."""
    from samp.data import DatasetError, open_dataset
    from samp.eval.binding import Provenance, check_binding, policy_binding, unverified_reason
    from samp.eval.loading import find_checkpoint

    binding = policy_binding(planner)
    trained_on, other = check_binding(binding, ds, run.path, cfg.allow_other_dataset, cfg.splits if ds else [])
    checkpoint = find_checkpoint(run.path)
    reason = unverified_reason(checkpoint, binding)
    if binding is None and reason is None:
        reason = f"{checkpoint} holds no dataset binding this evaluation can read: which dataset it trained on is unknown"
    if reason:
        print(f"warning: {reason}; the results are marked unverified", file=sys.stderr, flush=True)
    trained = ds
    if (other or ds is None) and trained_on and ("test" in cfg.splits or cfg.benchmark):
        try:
            trained = open_dataset(trained_on, Path(cfg.root) if cfg.root else None)
        except DatasetError as err:
            raise ValueError(f"the policy trained on {trained_on}, which cannot be opened ({err}); without its scenes no "
                             "test or benchmark scene can be shown unseen. Restore that dataset, or evaluate "
                             "splits=[val] benchmark=null") from None
    elif other:
        trained = None  # validation scenes alone: no section claims to be unseen
    evaluated = None if ds is None else f"{ds.name}@{ds.id}"
    return Provenance(trained_on, evaluated, other, reason), trained


def main(argv: list[str] | None = None) -> int:
    from samp.cli import answer_help, settings_help, wants_help

    argv = sys.argv[1:] if argv is None else argv
    if wants_help(argv) or not argv:  # --help: stdout, 0; nothing to evaluate: stderr, 2
        return answer_help(argv, lambda: f"{USAGE}\n\nsettings (key=default; conf/eval.yaml, checked by "
                           f"samp/eval/config.py):\n{settings_help('eval')}")
    return run_command(["evaluate", *argv], USAGE, {"evaluate": _evaluate})


if __name__ == "__main__":
    sys.exit(main())
