"""Datasets: specs, parallel sharded generation, MCAP scene files, the registry, and decoded access.

    from samp.data import open_dataset
    ds = open_dataset("quickstart")          # name (newest), name@id or a folder
    ds.trajectories, ds.traj_scene, ds.traj_split, ds.grid(0, 40)

Names are imported on first use, so the light commands (`python -m samp.data ls | show | verify`) do
not pay for torch and the planner.
"""

from importlib import import_module

_EXPORTS = {
    "Dataset": "dataset", "open_dataset": "dataset", "write_dataset": "dataset",
    "GenerationError": "generation", "generate": "generation", "merge": "generation",
    "DatasetError": "registry", "list_datasets": "registry", "read_manifest": "registry", "resolve_ref": "registry",
    "verify_dataset": "registry",
    "DatasetSpec": "spec", "available_specs": "spec", "load_spec": "spec",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'samp.data' has no attribute {name!r}")
    value = getattr(import_module(f"samp.data.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value
