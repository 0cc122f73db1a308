"""The dataset card: `CARD.md` beside `manifest.json`, written when a dataset is finalized, for a person
deciding whether and how to use or share it. It is made from the manifest alone and, like the manifest, is
not one of the hashed data files (so it does not enter the dataset id)."""

from __future__ import annotations

import json

from samp.cli import paste

__all__ = ["CARD", "dataset_card"]

CARD = "CARD.md"


def dataset_card(manifest: dict) -> str:
    """Markdown: what the dataset is, how it was generated, its splits, how to use and share it. Datasets
    that are not scenes with trajectories (robot SDF samples) get the general part only."""
    if not (isinstance(manifest.get("robot"), dict) and isinstance(manifest.get("splits"), dict)
            and isinstance(manifest.get("counts"), dict)):
        return _general_card(manifest)
    cfg, counts = manifest.get("config") or {}, manifest.get("counts") or {}
    ref = f"{manifest.get('name')}@{manifest.get('id')}"
    splits = manifest.get("splits") or {}
    code = manifest.get("code_version") or {}
    robot = manifest.get("robot") or {}
    lines = [
        f"# Dataset card: {ref}", "",
        f"Created {manifest.get('created', '?')} by samp {code.get('package', '?')} (git {code.get('git_commit', '?')}"
        f"{', with uncommitted changes' if code.get('git_dirty') else ''}); scene files of format "
        f"{manifest.get('scene_file_version', '?')}, manifest format {manifest.get('format_version', '?')}.", "",
        "## What it holds", "",
        f"- robot: `{robot.get('name', '?')}` (asset hash `{str(robot.get('asset_hash', '?'))[:16]}...`)",
        f"- scenes: {counts.get('scenes', '?')} ({counts.get('train_scenes', 0)} train, {counts.get('val_scenes', 0)} val, "
        f"{counts.get('test_scenes', 0)} test), generators {', '.join(cfg.get('generators') or []) or '?'}",
        f"- demonstrations: {counts.get('trajectories', '?')} expert trajectories of {counts.get('episodes', '?')} "
        f"problems ({counts.get('failures', 0)} unsolved)",
        f"- evaluation problems, stored apart from the training data: {counts.get('eval_problems', 0)} "
        f"({counts.get('eval_solved', 0)} with an expert solution)",
        f"- anchor grids (exact signed distance, metres) at n_e = {', '.join(map(str, cfg.get('resolutions') or []))}",
        "", "## How it was generated", "",
        f"Spec `{cfg.get('name', '?')}` (config hash `{str(manifest.get('config_hash', '?'))[:16]}`), seed "
        f"{manifest.get('seed', '?')}, expert `{cfg.get('expert', '?')}` (OMPL with the post-processing of its expert config, "
        "`expert_config` in manifest.json). The full resolved spec is `config` in "
        "manifest.json; the same spec and seed give the same files and the same id.", "",
        "## Splits", "",
        *[f"- {split}: {', '.join(names) if names else '(none)'}" for split, names in splits.items()],
        "", "Scenes are identified by their content hash (manifest `scenes`). Validation scenes drive model "
        "selection; test scenes are for the final evaluation only.", "",
        "## Use", "",
        "```python", "from samp.data import open_dataset", f'ds = open_dataset("{ref}")', "```", "",
        "Each `scene_*.mcap` opens in Foxglove Studio (scene, anchor grid, robot moving along every trajectory).",
        f"Check a copy with `{paste('python -m samp.data verify', dataset=ref)}`.", "",
        "## Sharing", "",
        "Share the whole folder (manifest.json, this card and every .mcap file): the id is the hash of the data "
        "files, so a recipient can verify it. The robot model comes from the URDF named by the robot config "
        f"(`conf/robot/{robot.get('name', '?')}.yaml`); its meshes are embedded in the scene files for display, "
        "so check the licence of those robot assets before you redistribute the dataset.",
        "", "## Parents", "",
        json.dumps(manifest.get("parents") or []), "",
    ]
    return "\n".join(lines)


def _general_card(manifest: dict) -> str:
    ref = f"{manifest.get('name')}@{manifest.get('id')}"
    code = manifest.get("code_version") or {}
    code = code if isinstance(code, dict) else {}
    return "\n".join([
        f"# Dataset card: {ref}", "",
        f"Created {manifest.get('created', '?')} by samp {code.get('package', '?')} (git {code.get('git_commit', '?')}).", "",
        f"{len(manifest.get('files') or {})} data files, listed with their sizes and sha256 in manifest.json, "
        "which also holds the configuration that made them; the id is the hash of the data files.", "",
        f"Check a copy with `{paste('python -m samp.data verify', dataset=ref)}`; share the whole folder.", "",
        "## Parents", "", json.dumps(manifest.get("parents") or []), "",
    ])
