"""Value types of the PID gains, shared by the PLC, the supervisor and the configuration.

One frozen type per concept (decision 0030):

- `LoopGains`: one loop's velocity-form gains (Kp, Ki, Kd) as floats, the law
  ``u(k) = u(k-1) + Kp De_P + Ki Ts e + Kd (d(k) - d(k-1))`` of ``plc_emulator.pid``;
- `PidGains`: the gains of a group of loops as (n_u, n_loops) matrices (row i: actuator i,
  column j: loop j's error), the shape the MIMO PID block runs and the adaptation estimates;
- `GainBox`: the admissible gains, element-wise ``lower <= gain <= upper`` (infinite allowed);
- `LoopLimits`: a loop's output range [mv_min, mv_max] and rate limit du_max per scan.

Units: Kp in MV unit per error unit, Ki in MV unit per (error unit s), Kd in MV unit s per
error unit (the error unit is the loop's ``error_unit``: the rig's gains assume cm); MV limits in
the actuator's unit, du_max in MV unit per scan. The ISA form (Kc, Ti, Td) is a different concept
(the tuning rules' output, ``plc_emulator.tuning.PidParams``) and converts to `LoopGains`.

The configuration's pydantic models (``tanklab.config.PidGainsSpec``, ``GainBox``) are the file
format; they convert to these types in one place each, here (`LoopGains.of_spec`,
`GainBox.of_spec`): ``tanklab.config`` imports no numpy, so the operator commands that read a
config stay free of it (decision 0023), and the conversion cannot live there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["GainBox", "LoopGains", "LoopLimits", "PidGains"]

FloatArray = NDArray[np.float64]

_NAMES = ("kp", "ki", "kd")


class _GainsSpec(Protocol):
    """What `LoopGains.of_spec` reads (``tanklab.config.PidGainsSpec``)."""

    @property
    def kp(self) -> float: ...
    @property
    def ki(self) -> float: ...
    @property
    def kd(self) -> float: ...


class _BoxSpec(Protocol):
    """What `GainBox.of_spec` reads (``tanklab.config.GainBox``: a [min, max] per gain)."""

    @property
    def kp(self) -> tuple[float, float]: ...
    @property
    def ki(self) -> tuple[float, float]: ...
    @property
    def kd(self) -> tuple[float, float]: ...


def _real(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    return float(value)


@dataclass(frozen=True)
class LoopGains:
    """One loop's velocity-form gains, finite floats (negative allowed: the digest's Kd < 0).

    Attributes
    ----------
    kp : float
        Proportional gain [MV unit per error unit].
    ki : float
        Integral gain [MV unit per (error unit s)].
    kd : float
        Derivative gain [MV unit s per error unit].
    """

    kp: float
    ki: float
    kd: float = 0.0

    def __post_init__(self) -> None:
        for name in _NAMES:
            x = _real(name, getattr(self, name))
            if not math.isfinite(x):
                raise ValueError(f"{name} must be finite, got {x}")
            object.__setattr__(self, name, x)

    # The tuning tables and the PLC's tags spell the gains Kp, Ki, Kd; read-only aliases.
    @property
    def Kp(self) -> float:
        """Alias of `kp`."""
        return self.kp

    @property
    def Ki(self) -> float:
        """Alias of `ki`."""
        return self.ki

    @property
    def Kd(self) -> float:
        """Alias of `kd`."""
        return self.kd

    @classmethod
    def of_spec(cls, spec: _GainsSpec) -> LoopGains:
        """From the config's ``PidGainsSpec`` (the one conversion from the file format)."""
        return cls(spec.kp, spec.ki, spec.kd)

    def as_tuple(self) -> tuple[float, float, float]:
        """``(kp, ki, kd)``."""
        return (self.kp, self.ki, self.kd)


@dataclass(frozen=True, eq=False)
class PidGains:
    """Velocity-form gains of a group of loops, each an (n_u, n_loops) matrix.

    Entry (i, j) couples loop j's error into actuator i; a decentralised PID is diagonal.

    Attributes
    ----------
    kp : ndarray, shape (n_u, n_loops)
        Proportional gains [MV unit per error unit].
    ki : ndarray, shape (n_u, n_loops)
        Integral gains [MV unit per (error unit s)].
    kd : ndarray, shape (n_u, n_loops)
        Derivative gains [MV unit s per error unit].

    The arrays are read-only float64 copies. Only the shape is checked here: a candidate may be
    non-finite (the adaptation's guards say so); a PID block checks finiteness and squareness
    when it takes the gains.
    """

    kp: FloatArray
    ki: FloatArray
    kd: FloatArray

    def __post_init__(self) -> None:
        arrays = []
        for name in _NAMES:
            raw = np.asarray(getattr(self, name))
            if raw.dtype.kind not in "iuf":
                raise TypeError(f"{name} must be numeric, got dtype {raw.dtype}")
            arr = np.array(raw, dtype=np.float64)
            if arr.ndim != 2:
                raise ValueError(f"{name} must be a 2-D (n_u, n_loops) matrix, got shape {arr.shape}")
            arr.setflags(write=False)
            arrays.append(arr)
        if not (arrays[0].shape == arrays[1].shape == arrays[2].shape):
            raise ValueError("kp, ki and kd must have the same shape (n_u, n_loops)")
        for name, arr in zip(_NAMES, arrays, strict=True):
            object.__setattr__(self, name, arr)

    @classmethod
    def diagonal(cls, kp: ArrayLike, ki: ArrayLike, kd: ArrayLike) -> PidGains:
        """Decentralised gains (actuator i on loop i) from per-loop vectors of shape (n,)."""
        return cls(np.diag(np.atleast_1d(kp)), np.diag(np.atleast_1d(ki)), np.diag(np.atleast_1d(kd)))

    @classmethod
    def of_loops(cls, loops: Sequence[LoopGains]) -> PidGains:
        """Decentralised gains from one `LoopGains` per loop."""
        return cls.diagonal([g.kp for g in loops], [g.ki for g in loops], [g.kd for g in loops])

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_u, n_loops)``."""
        return (int(self.kp.shape[0]), int(self.kp.shape[1]))

    def loop(self, i: int, j: int | None = None) -> LoopGains:
        """Entry (i, j) as `LoopGains` (j defaults to i: loop i's own gains)."""
        k = i if j is None else j
        return LoopGains(float(self.kp[i, k]), float(self.ki[i, k]), float(self.kd[i, k]))

    def stacked(self) -> FloatArray:
        """Gains stacked as shape (3, n_u, n_loops): ``[kp, ki, kd]``."""
        return np.stack([self.kp, self.ki, self.kd])

    @classmethod
    def from_stacked(cls, g: ArrayLike) -> PidGains:
        """Inverse of :meth:`stacked`."""
        arr = np.asarray(g, dtype=np.float64)
        return cls(arr[0], arr[1], arr[2])

    def is_finite(self) -> bool:
        """True when every gain is finite."""
        return bool(np.isfinite(self.stacked()).all())

    def allclose(self, other: PidGains, *, rtol: float = 1e-12, atol: float = 0.0) -> bool:
        """Element-wise ``numpy.allclose`` of all three matrices."""
        return self.shape == other.shape and bool(
            np.allclose(self.stacked(), other.stacked(), rtol=rtol, atol=atol)
        )


@dataclass(frozen=True, eq=False)
class GainBox:
    """Admissible gains ``lower <= gain <= upper``, element-wise (bounds may be infinite).

    Attributes
    ----------
    lower, upper : PidGains
        Bounds of the same shape as the gains; ``lower <= upper`` everywhere, no NaN.
    """

    lower: PidGains
    upper: PidGains

    def __post_init__(self) -> None:
        if self.lower.shape != self.upper.shape:
            raise ValueError("GainBox lower and upper must have the same shape")
        lo, hi = self.lower.stacked(), self.upper.stacked()
        if np.isnan(lo).any() or np.isnan(hi).any():
            raise ValueError("GainBox bounds must not be NaN")
        if (lo > hi).any():
            raise ValueError("GainBox lower must be <= upper for every gain")

    @classmethod
    def of_loop(cls, kp: tuple[float, float], ki: tuple[float, float], kd: tuple[float, float]) -> GainBox:
        """A one-loop (1 x 1) box from the [min, max] of each gain."""
        return cls(
            PidGains(np.array([[kp[0]]]), np.array([[ki[0]]]), np.array([[kd[0]]])),
            PidGains(np.array([[kp[1]]]), np.array([[ki[1]]]), np.array([[kd[1]]])),
        )

    @classmethod
    def of_spec(cls, spec: _BoxSpec) -> GainBox:
        """From the config's ``GainBox`` (the one conversion from the file format)."""
        return cls.of_loop(spec.kp, spec.ki, spec.kd)

    def contains(self, gains: PidGains | LoopGains) -> bool:
        """True when every gain lies inside the box (bounds included); a `LoopGains` needs a
        one-loop box."""
        if isinstance(gains, LoopGains):
            if self.lower.shape != (1, 1):
                raise ValueError(f"a LoopGains needs a 1 x 1 box, this one is {self.lower.shape}")
            lo, hi = self.lower.loop(0).as_tuple(), self.upper.loop(0).as_tuple()
            return all(a <= v <= b for v, a, b in zip(gains.as_tuple(), lo, hi, strict=True))
        g = gains.stacked()
        return bool(((g >= self.lower.stacked()) & (g <= self.upper.stacked())).all())


@dataclass(frozen=True)
class LoopLimits:
    """A loop's output limits: range [mv_min, mv_max] and rate limit du_max per scan.

    Attributes
    ----------
    mv_min, mv_max : float
        Output range [MV unit], finite, mv_min < mv_max.
    du_max : float
        Largest output change per scan [MV unit], > 0; ``math.inf``: no rate limit.
    """

    mv_min: float
    mv_max: float
    du_max: float = math.inf

    def __post_init__(self) -> None:
        lo, hi = _real("mv_min", self.mv_min), _real("mv_max", self.mv_max)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError("mv_min and mv_max must be finite")
        if lo >= hi:
            raise ValueError(f"mv_min must be < mv_max, got [{lo}, {hi}]")
        du = _real("du_max", self.du_max)
        if math.isnan(du) or du <= 0.0:
            raise ValueError(f"du_max must be > 0 (per scan), got {du}")
        object.__setattr__(self, "mv_min", lo)
        object.__setattr__(self, "mv_max", hi)
        object.__setattr__(self, "du_max", du)

    def clamp(self, value: float) -> float:
        """``value`` clamped to [mv_min, mv_max]."""
        return min(max(value, self.mv_min), self.mv_max)
