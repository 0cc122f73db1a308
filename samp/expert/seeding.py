"""Seed streams of the expert and of dataset specs, kept free of heavy imports (a spec's scene seeds need no
torch or OMPL)."""

from __future__ import annotations

import numpy as np

__all__ = ["derive_seed"]


def derive_seed(seed: int, *keys: int) -> int:
    """A 32-bit seed determined by `seed` and `keys` (attempt, problem index), well mixed."""
    return int(np.random.SeedSequence([int(seed) % 2**63, *map(int, keys)]).generate_state(1)[0])
