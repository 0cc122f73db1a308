"""The model card of a policy run: `MODEL_CARD.md` in the run folder, from its run.json, its config and its
evaluation (eval/metrics.md), for a person deciding whether and how to use or share the trained policy."""

from __future__ import annotations

from pathlib import Path

from samp.console import plural
from samp.names import EVAL_DIR, METRICS_MD, PLOTS_DIR, RUN_JSON

__all__ = ["MODEL_CARD", "model_card", "write_model_card"]

MODEL_CARD = "MODEL_CARD.md"


def model_card(run_dir: Path) -> str:
    """Markdown: the model, its training data and config, its benchmark results, how to load it."""
    from samp.runs.registry import load_run

    run = load_run(run_dir)
    record, cfg = run.record, run.record.get("config") or {}
    system, data = cfg.get("system") or {}, cfg.get("datamodule") or {}
    model = {k: v for k, v in (system.get("model") or cfg.get("model") or {}).items() if not k.startswith("_")}
    code = record.get("code_version") or {}
    table = Path(run_dir) / EVAL_DIR / METRICS_MD
    results = table.read_text().strip() if table.is_file() else "(this run was not evaluated)"
    fit = record.get("fit_time_s")
    lines = [
        f"# Model card: {record.get('experiment')} / {Path(run_dir).name}", "",
        f"A motion policy for the `{(cfg.get('robot') or {}).get('name', '?')}` arm trained by samp "
        f"{code.get('package', '?')} (git {code.get('git_commit', '?')}"
        f"{', with uncommitted changes' if code.get('git_dirty') else ''}); status: {record.get('status', '?')}.", "",
        "## Data", "",
        f"- dataset: `{record.get('dataset_id')}` (its CARD.md describes it), anchor grids at n_e = {data.get('n_e', '?')}",
        f"- robot SDF: artifact `{record.get('robot_sdf_artifact_id')}`", "",
        "## Config", "",
        f"- system: `{system.get('_target_', '?')}`; network settings: `{model}`",
        f"- seed {record.get('seed')}, {plural(record.get('steps'), 'step')}, {plural(record.get('epochs'), 'epoch')}"
        + (f", {fit:.0f} s of fitting" if isinstance(fit, (int, float)) else ""),
        f"- overrides: `{' '.join(record.get('overrides') or []) or '(none)'}`",
        "- the full resolved config is `.hydra/config.yaml` (and `config` in run.json)", "",
        "## Results", "", results, "",
        f"Plots: `{PLOTS_DIR}/`; rollouts: `{EVAL_DIR}/recording.rrd` (`rerun` opens it).", "",
        "## Use", "",
        "```python", "from samp.policy import load_policy",
        f'policy = load_policy("{run_dir}")', "result = policy.plan(scene, q_start, q_goal)  # .trajectory (T, n) radians, .reached, times", "```", "",
        "## Sharing", "",
        f"The run folder alone rebuilds the policy: share it with `{RUN_JSON}` (which holds the checkpoints' "
        "sha256, checked on load) and `checkpoints/`. Checkpoints are read with `weights_only=True`; a "
        "recipient needs the dataset only to train further or to evaluate on its stored problems.", "",
        "Limits: trained on the scenes of one dataset; the results above say how it does on scenes it did not see "
        "(the benchmark rows). It has not been run on a real robot by samp.", "",
    ]
    return "\n".join(lines)


def write_model_card(run_dir: Path) -> Path:
    path = Path(run_dir) / MODEL_CARD
    path.write_text(model_card(run_dir))
    return path
