"""samp: spatial-anchor motion policies for robot arms."""

import sys
from importlib import import_module

__version__ = "0.1.0"
__all__ = ["__version__"]


def lazy_exports(package: str, exports: dict[str, str]):
    """For a subpackage's `__init__`: its module `__getattr__` and `__all__`, where `exports` maps each public
    name to the module that defines it. A name's module is imported on first use, so importing one light
    module of the package (a config reader, a spec) does not pay for torch, pybullet or OMPL; a dataset
    generation's main process, for one, starts its workers seconds sooner."""

    def __getattr__(name: str):
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(exports[name]), name)
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__, sorted(exports)
