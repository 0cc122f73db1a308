"""Evaluation settings as data: the rollout's definitions (`RolloutConfig`) and the CLI's (`EvalConfig`,
the schema of `conf/eval.yaml`). Radians, metres, seconds; orientation tolerance in degrees."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, ValidationError

from samp.names import N_E_MAX

__all__ = ["PLANNERS", "EvalConfig", "RolloutConfig", "load_eval_config", "rollout_config", "tolerance_label"]

# planner=NAME without a run: the expert's stored trajectories, the straight-line baseline, the expert
# planned afresh without simplification and smoothing (expert_raw), and RRTConnect alone (ompl_sampling);
# the last two are samp.eval.planners.EXPERT_VARIANTS.
PLANNERS = ("expert", "straight", "expert_raw", "ompl_sampling")


@dataclass
class RolloutConfig:
    """How a rollout runs and what counts as reaching the goal (docs/design.md section 4)."""

    max_steps: int = 150  # policy steps at most
    position_tolerance: float = 0.02  # reached: end-effector position error below this (m) ...
    orientation_tolerance: float = 15.0  # ... and orientation error below this (degrees); the rollout stops there
    report_tolerances: list[float] = field(default_factory=lambda: [0.01])  # also judged on the final state (m)
    substep_resolution: float = 0.02  # collision sub-steps: joint-space Euclidean spacing (rad), as the expert's
    stall_threshold: float = 1e-3  # a step moving less than this (rad, Euclidean) counts as still ...
    stall_steps: int = 10  # ... and this many still steps in a row end the rollout as stalled
    batch_size: int | None = 100  # problems rolled out together for the outcomes (None: a whole split at once)
    timed_problems: int = 20  # of these, rolled out again one at a time (B = 1) for the per-problem times

    def tolerances(self) -> list[float]:
        """Every position tolerance reported, the stopping one first, without repeats."""
        return list(dict.fromkeys([self.position_tolerance, *self.report_tolerances]))


@dataclass
class EvalConfig:
    """`python -m samp.eval`: which planner on which problems, where the results go, and the rollout."""

    run: str | None = None  # a run folder: evaluate its policy checkpoint (best.ckpt, else last.ckpt)
    planner: str | None = None  # without a run: one of PLANNERS
    dataset: str | None = None  # dataset reference (name, name@id, folder); default: the run's dataset
    root: str | None = None  # datasets folder (default: datasets/ or $SAMP_DATASETS_DIR)
    splits: list[str] = field(default_factory=lambda: ["val", "train"])  # the dataset's sections: train|val|test
    problems: int | None = 100  # per split, of its stored evaluation problems, fixed by seed (null: all)
    # benchmarks (conf/dataset/bench_NAME.yaml): the first is the section "benchmark", the others sections of their
    # own name ("hard"); a single name, or null for none
    benchmark: Any = field(default_factory=lambda: ["unseen", "hard"])
    benchmark_problems: int | None = None  # of the benchmark's problems (null: all of them)
    seed: int = 0
    out: str | None = None  # output folder; default RUN/eval, or runs/eval/PLANNER_DATASET without a run
    overwrite: bool = False  # replace the files of an earlier evaluation in `out`
    n_e: int | None = None  # grid resolution: a run's policy is refused at another n_e than its own (null: its own)
    trust_checkpoint: bool = False  # unpickle the run's checkpoint fully (it can run code): only files you trust
    allow_other_dataset: bool = False  # evaluate a run's policy on another dataset than its checkpoint's own
    device: str = "auto"  # where the policy runs: auto (CUDA when there is a GPU) | cpu | cuda[:N]
    robot_sdf_tables: int | None = None  # samp policies: robot SDF tables (0: exact; null: the policy's own)
    robot_sdf_pairs: str | None = None  # samp policies: all | near (robot SDF pairs of a step; null: the policy's own)
    compiled: bool | None = None  # samp policies: a step's inputs in one compiled call on a CPU (null: where allowed)
    # samp policies: samp+check with this many candidate rollouts per problem, or {candidates: 8, noisy: 4, ...}
    # (samp.policy.checked.CheckConfig; noisy: the policy's own rollouts with noise on its steps); null: plain
    check: Any = None
    stride: float | None = None  # samp policies: each step moves up to this many times the predicted step (null: 1, as trained)
    grid_source: str = "exact"  # exact (the dataset's grids) | reconstructed (from simulated depth cameras)
    camera: str = "default"  # grid_source=reconstructed: camera set, conf/camera/NAME.yaml or a YAML path
    unknown: str = "free"  # grid_source=reconstructed: what space no camera saw becomes: free | occupied
    compare_expert: bool = True  # also evaluate the expert's stored trajectories on the same problems
    expert_mode: str = "replay"  # replay (stored trajectories and times) | plan (plan afresh with OMPL)
    straight_max_step: float = 0.05  # the straight-line baseline's step (rad)
    record: bool = True  # write recording.rrd
    record_rollouts: int = 10  # rollouts drawn with robot meshes and points (the others as paths only)
    record_points: int = 256  # robot points drawn per step, coloured by their environment distance
    max_steps: int = 150
    position_tolerance: float = 0.02
    orientation_tolerance: float = 15.0
    report_tolerances: list[float] = field(default_factory=lambda: [0.01])
    substep_resolution: float = 0.02
    stall_threshold: float = 1e-3
    stall_steps: int = 10
    batch_size: int | None = 100
    timed_problems: int = 20

    def rollout(self) -> RolloutConfig:
        names = {f.name for f in fields(RolloutConfig)}
        return rollout_config({k: v for k, v in asdict(self).items() if k in names})


def tolerance_label(tolerance: float) -> str:
    """0.02 -> "2cm", 0.005 -> "0.5cm": metric-name suffixes."""
    return f"{tolerance * 100:g}cm"


def _require(ok: bool, key: str, expected: str, got) -> None:
    if not ok:
        raise ValueError(f"eval config: {key} must be {expected}, got {got!r}")


def _check_rollout(c: RolloutConfig) -> None:
    _require(isinstance(c.max_steps, int) and c.max_steps >= 1, "max_steps", "an integer >= 1", c.max_steps)
    for key in ("position_tolerance", "substep_resolution", "stall_threshold"):
        v = getattr(c, key)
        _require(isinstance(v, (int, float)) and math.isfinite(v) and v > 0, key, "a positive number", v)
    _require(0 < c.orientation_tolerance <= 180, "orientation_tolerance", "in (0, 180] degrees", c.orientation_tolerance)
    _require(all(t > 0 for t in c.report_tolerances), "report_tolerances", "positive metres", c.report_tolerances)
    _require(c.stall_steps >= 1, "stall_steps", ">= 1", c.stall_steps)
    _require(c.batch_size is None or c.batch_size >= 1, "batch_size", "null or >= 1", c.batch_size)
    _require(isinstance(c.timed_problems, int) and c.timed_problems >= 0, "timed_problems", "an integer >= 0",
             c.timed_problems)


def _check_setting(check) -> bool:
    """Whether `check=` is a number of candidates >= 1 or a valid set of `CheckConfig` fields."""
    if isinstance(check, bool):
        return False
    if isinstance(check, int):
        return check >= 1
    if not isinstance(check, dict):
        return False
    from samp.policy.checked import CheckConfig

    try:
        CheckConfig(**check)
    except (TypeError, ValueError) as err:
        raise ValueError(f"eval config: check={check}: {err}") from None
    return True


def _merge(schema, raw, what: str):
    try:
        merged = OmegaConf.merge(OmegaConf.structured(schema), raw)
    except (ConfigKeyError, ValidationError) as err:
        first = str(getattr(err, "msg", err)).splitlines()[0]
        valid = ", ".join(f.name for f in fields(schema))
        raise ValueError(f"invalid {what}: {first} (key {err.full_key!r}). Valid keys: {valid}") from None
    return OmegaConf.to_object(merged)


def rollout_config(source: RolloutConfig | dict | DictConfig | None = None) -> RolloutConfig:
    """A validated `RolloutConfig` from itself, a mapping of some of its keys, or None (defaults)."""
    if isinstance(source, RolloutConfig):
        cfg = source
    else:
        cfg = _merge(RolloutConfig, OmegaConf.create({} if source is None else source), "rollout config")
    _check_rollout(cfg)
    return cfg


def load_eval_config(raw: DictConfig | dict[str, Any]) -> EvalConfig:
    """Re-merge a composed config strictly against `EvalConfig`: a key added with `+key=...` that the
    schema does not know is refused with the valid keys (Hydra alone would accept it)."""
    raw = OmegaConf.create(raw) if isinstance(raw, dict) else raw
    cfg: EvalConfig = _merge(EvalConfig, raw, "eval config")
    cfg.splits = ["val" if s == "heldout" else s for s in cfg.splits]  # the validation scenes' old name
    _require(set(cfg.splits) <= {"train", "val", "test"} and len(set(cfg.splits)) == len(cfg.splits), "splits",
             "a list of distinct train | val | test", cfg.splits)
    _require(cfg.problems is None or cfg.problems >= 1, "problems", "null or >= 1", cfg.problems)
    _require(cfg.benchmark_problems is None or cfg.benchmark_problems >= 1, "benchmark_problems", "null or >= 1",
             cfg.benchmark_problems)
    names = cfg.benchmark if isinstance(cfg.benchmark, (list, tuple)) else [cfg.benchmark]
    _require(cfg.benchmark is None or (all(isinstance(n, str) and n and "/" not in n for n in names)
                                       and len(set(names)) == len(names)
                                       and not set(names[1:]) & {"train", "val", "test", "benchmark"}), "benchmark",
             "a benchmark name (conf/dataset/bench_NAME.yaml), a list of distinct names ([unseen,hard]) or null",
             cfg.benchmark)
    if isinstance(cfg.benchmark, (list, tuple)):
        cfg.benchmark = list(cfg.benchmark) or None
    _require(cfg.expert_mode in ("replay", "plan"), "expert_mode", "replay | plan", cfg.expert_mode)
    _require(cfg.planner in (None, *PLANNERS), "planner", f"{' | '.join(PLANNERS)} (or give run=RUN_DIR)",
             cfg.planner)
    _require(cfg.record_rollouts >= 0 and cfg.record_points >= 1, "record_rollouts / record_points", ">= 0 / >= 1",
             (cfg.record_rollouts, cfg.record_points))
    _require(cfg.n_e is None or 2 <= cfg.n_e <= N_E_MAX, "n_e", f"null or an integer in [2, {N_E_MAX}]", cfg.n_e)
    _require(cfg.device == "auto" or cfg.device == "cpu" or cfg.device.split(":")[0] == "cuda", "device",
             "auto | cpu | cuda[:N]", cfg.device)
    _require(cfg.robot_sdf_tables is None or cfg.robot_sdf_tables == 0 or cfg.robot_sdf_tables >= 2,
             "robot_sdf_tables", "null, 0 (exact) or an integer >= 2", cfg.robot_sdf_tables)
    _require(cfg.robot_sdf_pairs in (None, "all", "near"), "robot_sdf_pairs", "null, all or near", cfg.robot_sdf_pairs)
    _require(cfg.compiled in (None, True, False), "compiled", "null, true or false", cfg.compiled)
    _require(cfg.check is None or _check_setting(cfg.check), "check",
             "null, a number of candidates >= 1, or {candidates: K, noisy: N, ...} (samp.policy.checked.CheckConfig)",
             cfg.check)
    _require(cfg.stride is None or 0 < cfg.stride <= 4, "stride", "null or a number in (0, 4]", cfg.stride)
    _require(cfg.grid_source in ("exact", "reconstructed"), "grid_source", "exact | reconstructed", cfg.grid_source)
    _require(cfg.unknown in ("occupied", "free"), "unknown", "occupied | free", cfg.unknown)
    cfg.rollout()  # validates the rollout keys
    return cfg
