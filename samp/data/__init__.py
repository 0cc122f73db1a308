"""Datasets: specs, parallel sharded generation, MCAP scene files, the registry, and decoded access.

    from samp.data import open_dataset
    ds = open_dataset("quickstart")          # name (newest), name@id or a folder
    ds.trajectories, ds.traj_scene, ds.traj_split, ds.grid(0, 40)

Names are imported on first use, so the light commands (`python -m samp.data ls | show | verify`) do
not pay for torch and the planner.
"""

from samp import lazy_exports

_MODULES = {
    "Dataset": "dataset", "open_dataset": "dataset", "write_dataset": "dataset",
    "GenerationError": "generation", "generate": "generation", "merge": "generation",
    "DatasetError": "registry", "list_datasets": "registry", "read_manifest": "registry", "resolve_ref": "registry",
    "verify_dataset": "registry",
    "pull_dataset": "sharing", "push_dataset": "sharing",
    "DatasetSpec": "spec", "available_specs": "spec", "load_spec": "spec",
}
__getattr__, __all__ = lazy_exports(__name__, {name: f"samp.data.{module}" for name, module in _MODULES.items()})
