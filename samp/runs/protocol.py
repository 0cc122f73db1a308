"""The evaluation protocols a run's numbers come from, as the registry, tables, plots and paper tables
read them (docs/design.md section 4, "Splits and problems" and "Metrics").

Protocol 2 (`<run>/eval/metrics.json` says `"protocol": 2`): the planner, the expert and the straight
line per group of problems, `metrics.json` {"groups": {GROUP: {"source", "problems"}}, "metrics": {GROUP:
summary}, "expert": ..., "straight": ..., "benchmark": "name@id"}. The groups are "val" (stored
evaluation problems in the dataset's validation scenes), "train" (new problems in its training scenes),
"benchmark" (the standing benchmark of unseen scenes, which the paper's tables report), "hard" (the hard
benchmark, `bench_hard`: every problem drawn to need a detour), their hard subsets ("<group>_hard": the
straight joint-space line collides; "hard" has none, all of it is) and the benchmarks per generator
("benchmark_tabletop", "hard_shelf", ...); "benchmarks" maps each benchmark section to its `name@id`. Every
rate has its Wilson 95 % interval beside it (`<rate>_ci_low`, `<rate>_ci_high`), and the timings are one
problem at a time (B = 1) apart from the batched throughput.

Protocol 1 (no "protocol" key; runs evaluated before): problems drawn from the dataset's demonstration
trajectories, per scene split "train" / "heldout" (and "all" pooled), with the held-out scenes also
driving validation and the choice of checkpoint. Such runs still list and show, marked as legacy.

run.json holds the same numbers flat, `eval/<planner>/<group>/<metric>` (`eval_key`).
"""

from __future__ import annotations

from samp.eval.metrics import metric, metric_keys
from samp.eval.report import PROTOCOL as EVALUATION_PROTOCOL
from samp.names import EVAL_PREFIX

__all__ = ["BENCHMARK", "BENCHMARK_REF", "BLOCKS", "CURRENT", "GROUPS", "HARD_BENCHMARK", "PROTOCOL", "SOLUTION_TIME_B1",
           "STEP_TIME_B1", "THROUGHPUT", "eval_key", "hard", "interval_keys", "is_rate", "label",
           "protocol_of"]

CURRENT = EVALUATION_PROTOCOL  # what `samp.eval.report` writes now
PROTOCOL = "protocol"  # eval/metrics.json's field, and the run key it becomes (`ls protocol=2`)
# What each protocol's numbers mean: (its cell in `ls`; the line `show` adds).
LABELS = {
    2: ("2", "new problems in the dataset's validation and training scenes, and the standing benchmark of "
             "unseen scenes; rates with Wilson 95 % intervals"),
    1: ("1 (legacy)", "problems from the demonstration trajectories of the training / held-out scenes, which "
                      "also drove validation"),
}
# The groups of problems a run's summary shows, in order (the hard and per-generator subsets come beside them).
GROUPS = {2: ("val", "train", "benchmark", "hard"), 1: ("train", "heldout")}
BENCHMARK = "benchmark"
HARD_BENCHMARK = "hard"  # the hard benchmark's group (`bench_hard`), beside the standing one's
BENCHMARK_REF = "benchmark"  # eval/metrics.json: the benchmark's `name@id` (null when a run was not evaluated on it)
_LEGACY_ONLY = ("heldout", "all")  # groups only protocol 1 has
# The blocks of eval/metrics.json besides the planner's own ("metrics"), by the planner name run.json uses.
BLOCKS = {"expert": "expert", "straight": "straight"}
# Protocol 2's timings (`samp.eval.metrics.METRICS`): seconds per problem and per policy step one problem at a
# time (B = 1), and problems per second in batched rollouts.
SOLUTION_TIME_B1, STEP_TIME_B1, THROUGHPUT = (metric(name).key for name in ("solution_time_b1", "step_time_b1",
                                                                              "throughput"))


def hard(group: str) -> str:
    """The group's hard subset: "benchmark" -> "benchmark_hard"."""
    return f"{group}_hard"


def eval_key(key: str) -> tuple[str, str, str] | None:
    """`eval/<planner>/<group>/<metric>` -> (planner, group, metric); None for any other key."""
    parts = key.split("/")
    if len(parts) != 4 or parts[0] + "/" != EVAL_PREFIX:
        return None
    return parts[1], parts[2], parts[3]


def is_rate(key: str) -> bool:
    """Whether `key` (`eval/<planner>/<group>/<metric>`) is a rate of `samp.eval.metrics.METRICS` (bare or at a
    tolerance)."""
    parts = eval_key(key)
    return parts is not None and parts[2].partition("@")[0] in metric_keys(rate=True)


def interval_keys(key: str) -> tuple[str, str]:
    """The keys of a rate's Wilson interval, beside it: `eval/samp/benchmark/success_rate` ->
    `.../success_rate_ci_low`, `.../success_rate_ci_high` (`success_rate@1cm` -> `success_rate_ci_low@1cm`)."""
    head, tail = key.rsplit("/", 1) if "/" in key else ("", key)
    name, at, tol = tail.partition("@")
    prefix = f"{head}/" if head else ""
    return f"{prefix}{name}_ci_low{at}{tol}", f"{prefix}{name}_ci_high{at}{tol}"


def protocol_of(evaluation: dict | None, metrics: dict) -> int | None:
    """The protocol of a run's evaluation: eval/metrics.json's "protocol" (1 when it has none); without
    that file, what its run.json metrics name (groups "heldout", "all": 1, others: 2); None: not evaluated."""
    if evaluation is not None:
        return int(evaluation.get(PROTOCOL, 1))
    groups = {parts[1] for parts in map(eval_key, metrics) if parts}
    if not groups:
        return None
    return 1 if groups & set(_LEGACY_ONLY) else CURRENT


def label(protocol: int | None, short: bool = False) -> str:
    """`ls`'s cell ("2", "1 (legacy)") or `show`'s line ("1 (legacy): problems from ...") for a protocol;
    None: not evaluated."""
    if protocol is None:
        return "not evaluated"
    if protocol not in LABELS:
        return str(protocol) if short else f"{protocol}: unknown to this version of samp (it knows {sorted(LABELS)})"
    brief, line = LABELS[protocol]
    return brief if short else f"{brief}: {line}"
