"""The standing benchmark: named, versioned sets of unseen scenes with stored evaluation problems.

`benchmark=NAME` is the dataset spec `conf/dataset/bench_NAME.yaml`: test scenes only, from every scene
generator, in a scene namespace of its own (so no training spec draws the same scenes), with the
expert's solution and planning time stored for every problem. It is generated once, like any dataset,
and then found by name; its id (`bench_NAME@id`) goes into every report that uses it.

`benchmark=[unseen,hard]` (the default) evaluates several: the first is the section "benchmark" (the
headline, which the paper's tables report), each further one a section of its own name ("hard"). A
benchmark whose spec draws every problem to need a detour (`detour_share: 1`, `bench_hard`) holds only
the problems whose straight line was found blocked when they were drawn (`detour_only`).

Whether a scene is unseen is decided by content, not by seeds: `check_unseen` refuses to report a
test or benchmark problem whose scene (by its content hash) was among the training or validation scenes of
the dataset the run trained on.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["BENCHMARK_PREFIX", "Benchmark", "benchmark_names", "benchmark_spec", "check_unseen", "detour_only",
           "open_benchmark", "open_benchmarks", "trained_scene_hashes"]

BENCHMARK_PREFIX = "bench_"
HELD_OUT_SECTIONS = ("test",)  # sections that claim scenes the run never saw, besides every benchmark's
HEADLINE = "benchmark"  # the section of the first benchmark named


@dataclass
class Benchmark:
    """One benchmark an evaluation runs: the name of its section ("benchmark", "hard") and its dataset."""

    section: str
    dataset: object

    @property
    def ref(self) -> str:
        return f"{self.dataset.name}@{self.dataset.id}"


HELD_OUT = "final"  # bench_final: read only for a final table, never to choose (docs/evaluation.md)


def benchmark_names(value) -> list[str]:
    """`benchmark=` as a list of names: null -> [], "unseen" -> ["unseen"], [unseen, hard] -> as given."""
    if value is None:
        return []
    return [str(value)] if isinstance(value, str) else [str(v) for v in value]


def detour_only(ds) -> bool:
    """Whether a benchmark is drawn to need a detour on every problem (its spec's `detour_share` is 1)."""
    return float((ds.manifest.get("config") or {}).get("detour_share") or 0.0) >= 1.0


def open_benchmarks(value, root: str | Path | None = None, workers: int = 2) -> list[Benchmark]:
    """Every benchmark `value` names (`benchmark_names`), opened (generated once when missing): the first
    as the section "benchmark", the others under their own names."""
    names = benchmark_names(value)
    return [Benchmark(HEADLINE if i == 0 else name, open_benchmark(name, root, workers))
            for i, name in enumerate(names)]


def benchmark_spec(name: str) -> str:
    """`unseen` -> `bench_unseen`, checked to exist in conf/dataset/."""
    from samp.data import available_specs

    spec = f"{BENCHMARK_PREFIX}{name}"
    if spec not in available_specs():
        known = [s.removeprefix(BENCHMARK_PREFIX) for s in available_specs() if s.startswith(BENCHMARK_PREFIX)]
        raise ValueError(f"unknown benchmark {name!r}: no conf/dataset/{spec}.yaml; benchmarks: {', '.join(known)}")
    return spec


def open_benchmark(name: str, root: str | Path | None = None, workers: int = 2):
    """The benchmark's dataset as its spec defines it now, generated first (once) when it is not built yet
    or when the newest one of its name was made from another version of the spec (its config hash)."""
    from samp.data import DatasetError, generate, load_spec, open_dataset
    from samp.data.lock import is_pinned

    spec = benchmark_spec(name)
    root = Path(root) if root else None
    if name == HELD_OUT:
        print(f"benchmark {name!r} is held out for final tables: choosing a setting by its figures makes it one "
              "more selection set (conf/dataset/bench_final.yaml)", flush=True)
    try:
        found = open_dataset(spec, root)
    except DatasetError:
        print(f"benchmark {name!r} is not built yet: generating {spec} from conf/dataset/{spec}.yaml once "
              f"(expert solutions for every problem, {workers} workers)", flush=True)
    else:
        if found.manifest.get("config_hash") == load_spec(spec).config_hash() or is_pinned(spec):
            return found  # one pinned by the lock file is used as it is
        print(f"benchmark {name!r}: the newest {spec} ({found.name}@{found.id}) was made from another version of "
              f"conf/dataset/{spec}.yaml; generating the current one (the older one stays, by its id)", flush=True)
    return open_dataset(generate(spec, workers=workers, root=root))


def trained_scene_hashes(ds) -> set[str]:
    """Content hashes of the scenes a model trained on `ds` has seen: its training and validation scenes."""
    return {h for h, split in zip(ds.scene_hashes, ds.scene_split) if split in ("train", "val")}


def check_unseen(sections, seen: set[str], trained_on: str) -> None:
    """Refuse test and benchmark sections holding a scene the run trained or validated on (by content
    hash): reported as held out, such a problem would measure recall, not generalisation."""
    for section in sections:
        if section.name not in HELD_OUT_SECTIONS and not section.benchmark:
            continue
        clash = sorted({p.scene.name for p in section.problems if _scene_hash(p) in seen})
        if clash:
            raise ValueError(f"the {section.name} section holds {len(clash)} scene(s) that {trained_on} trained or "
                             f"validated on ({', '.join(clash[:5])}); they cannot be reported as unseen. Evaluate on "
                             "a benchmark whose scenes the run never saw (benchmark=unseen), or drop that section")


def _scene_hash(problem) -> str:
    return getattr(problem, "scene_hash", None) or problem.scene.content_hash()
