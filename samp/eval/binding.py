"""What ties a run's evaluation to what produced it: the checkpoint's own dataset binding and the run's
recorded file hashes, compared before anything is evaluated (docs/integrity.md, "Which dataset a run is
evaluated on").

* **Binding.** A trained policy's checkpoint records the dataset it was fitted to (`DatasetBinding`: robot,
  `name@id`, n_e, bounds). Evaluation compares that id with the dataset it is given (`dataset=`, or the
  one run.json names) and refuses another one, naming both, unless `allow_other_dataset=true`; then the
  results say so (`other_dataset`, `trained_on`), the "train" section is refused (those scenes are not the
  ones the policy trained on) and test and benchmark scenes are checked against the dataset the policy did
  train on. run.json is an editable file: it proposes a dataset, the checkpoint's binding decides.
* **Hashes.** A finished run records the sha256 of its checkpoints in run.json (`files_sha256`); a
  checkpoint that is not covered by that record (a run without it, a running run, a checkpoint the record
  does not list) cannot be tied to the run. It is evaluated, but said loudly once and marked in the results
  (`unverified`, with the reason), so no table reads it as the run's own.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Provenance", "check_binding", "policy_binding", "unverified_reason"]


@dataclass
class Provenance:
    """How an evaluated checkpoint relates to its run and to the dataset it is evaluated on (metrics.json)."""

    trained_on: str | None  # the checkpoint's own dataset binding, name@id (None: it records none)
    evaluated_on: str | None  # the dataset whose splits are evaluated, name@id
    other_dataset: bool = False  # evaluated on another dataset than it trained on (allow_other_dataset=true)
    unverified: str | None = None  # why the checkpoint cannot be tied to the run (None: its recorded hash matched)

    def record(self) -> dict:
        return {"trained_on": self.trained_on, "evaluated_on": self.evaluated_on, "other_dataset": self.other_dataset,
                "unverified": self.unverified}

    def heading(self) -> str:
        """The lines under a report's title that say what the numbers are not (empty when they are whole)."""
        lines = []
        if self.other_dataset:
            lines.append(f"**On another dataset:** the policy trained on {self.trained_on} and is evaluated on "
                         f"{self.evaluated_on} (allow_other_dataset=true).")
        if self.unverified:
            lines.append(f"**Unverified:** {self.unverified}.")
        return "\n".join(lines)


def policy_binding(planner):
    """The `DatasetBinding` of a loaded policy (a step policy's system, or samp+check's policy's), or None."""
    for holder in (planner, getattr(planner, "policy", None)):
        system = getattr(holder, "system", None)
        if system is not None and getattr(system, "binding", None) is not None:
            return system.binding
    return None


def check_binding(binding, ds, run_path: Path, allow_other: bool, splits: list[str]) -> tuple[str | None, bool]:
    """(the dataset the policy trained on, name@id or None; whether `ds` is another one). Refuses `ds` when the
    checkpoint's binding names another dataset, unless `allow_other`; refuses the "train" split of another
    dataset even then. A binding without a dataset id (a checkpoint older than the record) is returned as
    None: `unverified_reason` says so."""
    trained = getattr(binding, "dataset_id", None)
    given = None if ds is None else f"{ds.name}@{ds.id}"
    if trained is None or given is None or trained == given:
        return trained, False
    if not allow_other:
        raise ValueError(f"the checkpoint of {run_path} was trained on dataset {trained}, not {given} (the dataset "
                         f"given, or named by its run.json); evaluate it on its own (dataset={trained}), or pass "
                         "allow_other_dataset=true to evaluate it on another dataset, which the results then record")
    if "train" in splits:
        raise ValueError(f"splits include train, but the policy of {run_path} never trained on the training scenes of "
                         f"{given} (it trained on {trained}); give splits=[val] or splits=[val,test] with "
                         "allow_other_dataset=true")
    return trained, True


def unverified_reason(checkpoint: Path, binding) -> str | None:
    """Why `checkpoint` cannot be tied to its run by the run's record, or None when it can: its run.json
    lists its sha256 (checked on loading, `samp.integrity.check_recorded_hash`) and its binding names a dataset."""
    from samp.integrity import FILES_SHA256, run_of
    from samp.names import RUN_JSON

    checkpoint = Path(checkpoint)
    run = run_of(checkpoint)
    if binding is not None and getattr(binding, "dataset_id", None) is None:
        return f"{checkpoint} records no dataset binding (a checkpoint older than the record): its dataset is unknown"
    if run is None:
        return f"{checkpoint} is not inside a run folder with a {RUN_JSON}: nothing records which run wrote it"
    try:
        record = json.loads((run / RUN_JSON).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, OSError) as err:
        return f"{run / RUN_JSON} cannot be read ({type(err).__name__}): no recorded hash to compare"
    record = record if isinstance(record, dict) else {}
    if record.get("status") == "running":  # its checkpoints still change: nothing compares them with a record
        return f"{run / RUN_JSON} says the run is still running: its checkpoints are not compared with recorded hashes"
    hashes = record.get(FILES_SHA256)
    if not isinstance(hashes, dict) or not hashes:
        return (f"{run / RUN_JSON} records no {FILES_SHA256} (an older run, or an edited record): the checkpoint "
                "cannot be verified as the one this run trained")
    rel = checkpoint.resolve().relative_to(run.resolve()).as_posix()
    if rel not in hashes:
        return f"{rel} is not among the files {run / RUN_JSON} records ({FILES_SHA256}): it was added after the run ended"
    return None
