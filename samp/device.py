"""Where tensors run: `device=auto|cpu|cuda[:N]` as every command and loader reads it."""

from __future__ import annotations

import torch

__all__ = ["resolve_device"]


def resolve_device(device: str | torch.device | None = "auto") -> torch.device:
    """The torch device a `device` option names: auto (or None) is CUDA when torch sees a GPU, else the
    CPU; cpu, cuda and cuda:N are taken as given, and cuda is refused when torch sees no GPU."""
    if device is None or str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be auto, cpu or cuda[:N], got {device!r}") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device={device} was asked for, but torch sees no CUDA device here; use device=cpu or auto")
    if device.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be auto, cpu or cuda[:N], got {device!r}")
    return device
