"""Seeded draws shared by the fuzz and flood generators (pure: the generator is the only state)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def pick(rng: np.random.Generator, items: Sequence[Any]) -> Any:
    """One of ``items``, uniformly."""
    return items[int(rng.integers(len(items)))]


def random_bytes(rng: np.random.Generator, n: int) -> bytes:
    """``n`` uniformly random bytes."""
    return rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()
