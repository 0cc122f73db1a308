"""What the `python -m samp.X COMMAND key=value ...` entry points share: Hydra composition, output
paths, and turning bad input into a one-line error with exit code 2 instead of a traceback."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable

__all__ = ["compose", "output_path", "run_command"]


def compose(config_name: str, overrides: list[str]):
    """Compose `conf/<config_name>.yaml` with command-line overrides (`key=value`)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    from samp.paths import conf_dir

    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=overrides)


def output_path(out: str | Path) -> Path:
    """An output file path; relative paths are taken from the repository root. Its folder is created."""
    from samp.paths import REPO_ROOT

    path = Path(out)
    path = path if path.is_absolute() else REPO_ROOT / path
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def run_command(argv: list[str] | None, usage: str, commands: dict[str, Callable[[list[str]], object]]) -> int:
    """Dispatch `argv[0]` to `commands`, passing the remaining overrides; bad input exits with 2."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in commands:
        print(usage, file=sys.stderr)
        return 2
    try:
        commands[argv[0]](argv[1:])
    except (HydraException, OmegaConfBaseException, ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0
