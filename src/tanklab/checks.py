"""Scalar argument checks shared by the pure cores: one wording for one rule.

Each returns the value as a float or raises early: ``TypeError`` for a non-number (bool is not
a number here), ``ValueError`` naming the parameter and the rule for a bad value.
"""

from __future__ import annotations

import math

import numpy as np


def real(name: str, value: float) -> float:
    """A real number (int, float or numpy scalar; not bool)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    return float(value)


def finite(name: str, value: float) -> float:
    """A finite real number."""
    x = real(name, value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


def positive(name: str, value: float) -> float:
    """A finite real number > 0."""
    x = finite(name, value)
    if x <= 0.0:
        raise ValueError(f"{name} must be > 0, got {x}")
    return x


def non_negative(name: str, value: float) -> float:
    """A finite real number >= 0."""
    x = finite(name, value)
    if x < 0.0:
        raise ValueError(f"{name} must be >= 0, got {x}")
    return x
