"""A run's lineage: which data, which robot SDF, which code, which settings (docs/design.md section 6).

`run.json` holds it in full (written by `RunFolder.record` and `samp.train`); `lineage_tags` flattens the
parts that identify a run into string tags for trackers such as MLflow and W&B, and `flatten` turns a
nested config into dotted keys for tables and filters.
"""

from __future__ import annotations

from samp.tracking import flatten  # (defined there, where trackers flatten configs into params)

__all__ = ["LINEAGE_KEYS", "flatten", "lineage_tags", "merge_overrides", "override_key"]

# run.json fields that say where a result came from; each becomes a tracker tag (`samp.<key>`).
LINEAGE_KEYS = ("experiment", "seed", "dataset_id", "robot_sdf_artifact_id", "host", "run_dir")


def lineage_tags(record: dict) -> dict[str, str]:
    """String tags from a run.json record: the LINEAGE_KEYS, the git commit and dirty flag, the package
    version and the overrides (keys prefixed `samp.`; missing values are left out)."""
    code = record.get("code_version") or {}
    values = {**{k: record.get(k) for k in LINEAGE_KEYS}, "git_commit": code.get("git_commit"),
              "git_dirty": code.get("git_dirty"), "package_version": code.get("package"),
              "overrides": " ".join(record.get("overrides") or []) or None}
    return {f"samp.{k}": str(v) for k, v in values.items() if v is not None}


def override_key(override: str) -> str:
    """`+experiment=samp_n40` -> `experiment`; `~trainer.max_steps` -> `trainer.max_steps`."""
    return override.partition("=")[0].lstrip("+~")


def merge_overrides(earlier: list[str], later: list[str]) -> list[str]:
    """`earlier` with every override whose key `later` sets again dropped, then `later` (later wins)."""
    keys = {override_key(o) for o in later}
    return [o for o in earlier if override_key(o) not in keys] + list(later)
