"""`init_from=RUN_DIR`: a new run that starts from the network weights of a trained policy run.

Fine-tuning (`python -m samp.train.adapt` uses it) keeps the from-run's network: after composition the run's
`model` node is replaced by the one the from-run recorded in its run.json (resolved, so an experiment that
set the network's sizes in its own file is matched too); the system is built as usual, then its weights are
those of the from-run's policy checkpoint (`checkpoints/best.ckpt`, else `last.ckpt`: the policy the
from-run's own evaluation loads). The checkpoint is loaded as `samp.policy.registry.read_checkpoint` loads
any policy: its recorded hash compared, no code run from it unless `trust_checkpoint`. Networks that differ
(another `datamodule.n_e`, a `model.*` override) are refused in one line. run.json records the lineage under
`init_from`: the run, the checkpoint file and its sha256, and `weights_sha256`, a hash of the weights the
new run started from (`weights_hash`), which a reader can compare with the from-run's.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["check_policy_run", "load_initial_weights", "recorded_model", "weights_hash"]


def check_policy_run(path: str | Path) -> dict:
    """The run.json record of `path` when it is a completed policy training run with a checkpoint;
    ValueError in one line otherwise (not a run folder, not finished, a robot SDF run, no checkpoint)."""
    from samp.paths import find_checkpoint
    from samp.runs import RUN_JSON, RunFolder

    path = Path(path)
    if not (path / RUN_JSON).is_file():
        raise ValueError(f"{path} is not a run folder (no {RUN_JSON} there); give the folder of a trained policy run, "
                         "e.g. runs/quickstart/<timestamp>")
    record = RunFolder(path).read()
    config = record.get("config") or {}
    if "dataset" not in (config.get("datamodule") or {}) or not config.get("model"):
        raise ValueError(f"{path} is not a policy run (its config trains no policy on a trajectory dataset: "
                         f"experiment {record.get('experiment')!r}); give the folder of a trained policy run")
    if record.get("status") != "completed":
        raise ValueError(f"{path} is not a trained policy run: its status is {record.get('status')!r}, not "
                         "'completed'; finish it (`python -m samp.train resume=RUN_DIR`) or give another run")
    try:
        find_checkpoint(path)
    except FileNotFoundError as err:
        raise ValueError(str(err).split(". ")[0]) from None
    return record


def recorded_model(path: str | Path) -> dict:
    """The resolved `model` node the run at `path` trained (from its run.json)."""
    return check_policy_run(path)["config"]["model"]


def weights_hash(state_dict: dict) -> str:
    """sha256 over a state dict's names, dtypes, shapes and values, in name order (float32 on the CPU, so a
    checkpoint and a live module hash alike)."""
    import torch

    h = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name]
        if not isinstance(t, torch.Tensor):
            continue
        value = t.detach().to("cpu").contiguous()
        h.update(f"{name}\0{value.dtype}\0{tuple(value.shape)}\n".encode())
        h.update(value.numpy().tobytes() if value.dtype != torch.bfloat16 else value.float().numpy().tobytes())
    return h.hexdigest()


def load_initial_weights(system, run: str | Path, trust: bool | None = None) -> dict:
    """Load the policy weights of the run at `run` into `system` (strictly) -> the lineage for run.json.
    ValueError in one line when the networks differ."""
    from samp.names import CHECKPOINT_RECORD
    from samp.paths import file_sha256, find_checkpoint
    from samp.policy.registry import read_checkpoint

    check_policy_run(run)
    path = find_checkpoint(run)
    ckpt = read_checkpoint(path, trust_checkpoint=trust)
    kind = (ckpt.get(CHECKPOINT_RECORD) or {}).get("kind")
    if kind is None:
        raise ValueError(f"init_from={run}: {path} is not a policy checkpoint (it records no policy kind)")
    theirs, ours = ckpt["state_dict"], system.state_dict()
    missing, extra = sorted(set(ours) - set(theirs)), sorted(set(theirs) - set(ours))
    shapes = [(k, tuple(theirs[k].shape), tuple(ours[k].shape)) for k in sorted(set(ours) & set(theirs))
              if tuple(theirs[k].shape) != tuple(ours[k].shape)]
    if missing or extra or shapes:
        what = (f"{shapes[0][0]} is {shapes[0][1]} there, {shapes[0][2]} here" if shapes else
                f"{(missing or extra)[0]} is only {'here' if missing else 'there'}")
        raise ValueError(f"init_from={run}: its network does not fit this run's ({len(shapes)} shape(s) differ, "
                         f"{len(missing)} key(s) only here, {len(extra)} only there; {what}): train with the "
                         "from-run's model and datamodule.n_e")
    system.load_state_dict(theirs, strict=True)
    return {"run": str(Path(run)), "checkpoint": str(path), "checkpoint_sha256": file_sha256(path),
            "kind": kind, "weights_sha256": weights_hash(system.state_dict())}
