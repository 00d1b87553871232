"""Argument checks shared by the adaptation's value types and pure functions (one-line errors)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["FloatArray", "finite", "matrix", "positive", "state_space"]

FloatArray = NDArray[np.float64]


def matrix(value: ArrayLike, name: str, shape: tuple[int, ...] | None = None) -> FloatArray:
    """``value`` as a float64 array of at least one dimension, of ``shape`` when given."""
    arr = np.array(value, dtype=np.float64, ndmin=1)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


def finite(arr: FloatArray, name: str) -> FloatArray:
    """``arr`` itself, after checking that every entry is finite."""
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite")
    return arr


def positive(value: float, name: str, *, allow_zero: bool = False) -> float:
    """``value`` as a float, after checking that it is a finite real > 0 (>= 0 with allow_zero)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0.0 or (v == 0.0 and not allow_zero):
        rule = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {rule}, got {v!r}")
    return v


def state_space(A: ArrayLike, B: ArrayLike, C: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``A`` (n_x, n_x), ``B`` (n_x, n_u) and ``C`` (n_loops, n_x) as finite arrays of those shapes."""
    Am = finite(matrix(A, "A"), "A")
    if Am.ndim != 2 or Am.shape[0] != Am.shape[1]:
        raise ValueError(f"A must be square (n_x, n_x), got shape {Am.shape}")
    n = Am.shape[0]
    Bm = finite(matrix(B, "B"), "B")
    if Bm.ndim != 2 or Bm.shape[0] != n:
        raise ValueError(f"B must have shape ({n}, n_u), got {Bm.shape}")
    Cm = finite(matrix(C, "C"), "C")
    if Cm.ndim != 2 or Cm.shape[1] != n:
        raise ValueError(f"C must have shape (n_loops, {n}), got {Cm.shape}")
    return Am, Bm, Cm
