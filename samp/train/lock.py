"""Writing the lock file: the exact inputs of a training config, as they resolve now
(`python -m samp.train experiment=NAME [KEY=VALUE ...] --lock[=FILE]`; the file is read by samp/data/lock.py)."""

from __future__ import annotations

import json
from pathlib import Path

from samp.data.lock import KINDS, LOCK_FORMAT, read_lock

__all__ = ["resolve_inputs", "write_lock"]


def _pin_dataset(ref: str, root: Path) -> tuple[str, str] | None:
    """(bare name, NAME@ID) for a bare dataset name (None for NAME@ID, a folder or a URL: already exact)."""
    from samp.data.registry import read_manifest, resolve_ref

    if "@" in ref or "://" in ref or Path(ref).is_dir():
        return None
    m = read_manifest(resolve_ref(ref, root, lock=False), check_sizes=False)
    return ref, f"{m['name']}@{m['id']}"


def resolve_inputs(overrides: list[str]) -> dict:
    """The exact inputs of the training config composed from `overrides`, as they resolve now:
    {"datasets": {name: NAME@ID}, "robot_sdf": {name: NAME@ARTIFACT_ID}}."""
    from samp.train.config import compose_train_config
    from samp.train.recipe import _repo_path

    cfg = compose_train_config(list(overrides))
    root = _repo_path(cfg.datamodule.get("root") or cfg.paths.datasets_dir)
    out: dict = {k: {} for k in KINDS}
    refs = [str(cfg.datamodule.dataset)] if cfg.datamodule.get("dataset") is not None else []
    if (cfg.get("evaluation") or {}).get("benchmark"):
        from omegaconf import OmegaConf

        from samp.eval.benchmark import benchmark_names, benchmark_spec

        value = cfg.evaluation.benchmark
        refs += [benchmark_spec(n) for n in benchmark_names(OmegaConf.to_object(value) if OmegaConf.is_config(value)
                                                             else value)]
    for ref in refs:
        pin = _pin_dataset(ref, root)
        if pin:
            out["datasets"][pin[0]] = pin[1]
    sdf = (cfg.get("system") or {}).get("robot_sdf")
    if sdf and "@" not in str(sdf) and not Path(str(sdf)).exists():
        from samp.robot_sdf.artifact import ARTIFACT_FILE, artifact_id
        from samp.train.prerequisites import resolve_robot_sdf

        path = resolve_robot_sdf(str(sdf), _repo_path(cfg.paths.runs_dir), lock=False)
        artifact = path / ARTIFACT_FILE if path.is_dir() else path
        out["robot_sdf"][str(sdf)] = f"{sdf}@{artifact_id(artifact)}"
    return out


def write_lock(overrides: list[str], out: Path) -> dict:
    """Resolve the inputs of the experiment `overrides` compose and write them to the lock file `out`
    (JSON; an existing lock's entries for other names are kept). Returns what was written."""
    previous = read_lock(out) if out.is_file() else {}
    inputs = resolve_inputs(overrides)
    data = {"format_version": LOCK_FORMAT, "overrides": list(overrides),
            **{k: {**previous.get(k, {}), **inputs[k]} for k in KINDS}}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    tmp.replace(out)
    return data
