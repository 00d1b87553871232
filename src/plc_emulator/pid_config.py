"""Configuration of the velocity-form PID block (``plc_emulator.pid.Pid``), validated.

`PidConfig` is what a caller writes (scalars broadcast to every loop); `resolve` checks it once
and gives the per-loop constants the law and its shell use (`Resolved`): output limits and rate
limit [u, u per scan], the derivative filter's alpha = Tf / (Tf + Ts) (backward Euler), setpoint
weights b and c, setpoint limits and the ramp step sp_rate Ts [PV unit per scan], the action's
sign (+1 reverse, -1 direct), substitutes and initial modes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from plc_emulator.loop import Substitute, finite_scalar
from plc_emulator.loop import check_mode as _check_mode
from tanklab.enums import LoopMode

__all__ = ["InitMemory", "PidConfig", "Resolved", "float_array"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
InitMemory = Literal["zero", "first_error"]

_SUBSTITUTES = ("hold", "value")
_INIT_MEMORIES = ("zero", "first_error")


def float_array(name: str, value: ArrayLike) -> FloatArray:
    """Convert to a float64 array; TypeError for non-numeric (or boolean) input."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be numeric, got dtype {arr.dtype}")
    return arr.astype(np.float64)


def _per_loop(name: str, value: float | Sequence[float], n: int) -> FloatArray:
    """Broadcast a scalar or a length-n sequence to a float64 array of shape (n,)."""
    arr = float_array(name, value)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got shape {arr.shape}")
    return arr.copy()


def _weights(name: str, value: float | Sequence[float], n: int) -> FloatArray:
    """Setpoint weights per loop: finite, in [0, 1]."""
    arr = _per_loop(name, value, n)
    if np.any(~np.isfinite(arr)) or np.any(arr < 0.0) or np.any(arr > 1.0):
        raise ValueError(f"{name} must lie in [0, 1] for every loop")
    return arr


@dataclass(frozen=True)
class PidConfig:
    """Static configuration of a `Pid` block. Scalars broadcast to every loop.

    Attributes
    ----------
    n_loops : int
        Number of loops n (= actuators), >= 1.
    ts_s : float
        Scan period Ts [s], > 0.
    u_min, u_max : float or sequence of n floats
        Output limits per actuator [u], finite, u_min < u_max.
    du_max : float or sequence, optional
        Output rate limit |u(k) - u(k-1)| <= du_max per scan [u], > 0; None: no rate limit.
    d_filter_tf_s : float
        Derivative filter time constant Tf [s], >= 0 (0: unfiltered D). Tf = Td / N in the ISA
        notation (Td = Kd / Kp).
    setpoint_weight_p : float or sequence of n floats
        Setpoint weight b of the proportional term, in [0, 1] (default 1: P on the error; 0: P on
        the measurement only, no proportional kick on a setpoint step).
    setpoint_weight_d : float or sequence of n floats
        Setpoint weight c of the derivative term, in [0, 1] (default 1: D on the error, the
        digest's form; 0: D on the measurement, no derivative kick on a setpoint step).
    sp_min, sp_max : float or sequence
        Setpoint limits [PV unit], sp_min <= sp_max (infinite allowed). Targets outside are clamped.
    sp_rate : float or sequence, optional
        Setpoint ramp rate [PV unit per s], > 0: the working setpoint moves toward the target by at
        most sp_rate Ts per scan. None: the working setpoint jumps to the target.
    direct_acting : bool or sequence of bool
        True for a loop whose actuator lowers its PV (e = y - w); False (default): e = w - y.
    initial_mv : float or sequence
        u(-1) [u], within the limits (default 0).
    init_memory : {"zero", "first_error"}
        "zero": e(-1) = e(-2) = 0 (the digest's reference behaviour); "first_error": e(-1) =
        e(-2) = e(0), so the first scan makes an integral-only move.
    pv_bad_scans : int
        Consecutive bad-PV scans N (>= 1) after which a loop in AUTO/REMOTE applies its substitute.
    substitute : {"hold", "value"} or sequence
        Substitute output per loop: keep the applied MV, or drive to ``substitute_mv``.
    substitute_mv : float or sequence
        Safe MV for ``substitute == "value"`` [u], within the limits.
    initial_mode : LoopMode or sequence of LoopMode
        Mode of each loop at construction (default AUTO).
    """

    n_loops: int
    ts_s: float
    u_min: float | Sequence[float]
    u_max: float | Sequence[float]
    du_max: float | Sequence[float] | None = None
    d_filter_tf_s: float = 0.0
    setpoint_weight_p: float | Sequence[float] = 1.0
    setpoint_weight_d: float | Sequence[float] = 1.0
    sp_min: float | Sequence[float] = -np.inf
    sp_max: float | Sequence[float] = np.inf
    sp_rate: float | Sequence[float] | None = None
    direct_acting: bool | Sequence[bool] = False
    initial_mv: float | Sequence[float] = 0.0
    init_memory: InitMemory = "zero"
    pv_bad_scans: int = 3
    substitute: Substitute | Sequence[Substitute] = "hold"
    substitute_mv: float | Sequence[float] = 0.0
    initial_mode: LoopMode | Sequence[LoopMode] = LoopMode.AUTO
    _resolved: Resolved = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_resolved", resolve(self))


@dataclass(frozen=True, eq=False)
class Resolved:
    """Per-loop arrays derived from a `PidConfig` (validated)."""

    n: int
    ts: float
    lo: FloatArray
    hi: FloatArray
    du_max: FloatArray  # inf where no rate limit
    alpha: float
    b: FloatArray
    c: FloatArray
    sp_lo: FloatArray
    sp_hi: FloatArray
    sp_step: FloatArray  # sp_rate * Ts, inf where no ramp
    sign: FloatArray
    initial_mv: FloatArray
    first_error: bool
    pv_bad_scans: int
    subst_value: BoolArray
    substitute_mv: FloatArray
    modes: tuple[LoopMode, ...]


def resolve(c: PidConfig) -> Resolved:
    if isinstance(c.n_loops, bool) or not isinstance(c.n_loops, int):
        raise TypeError(f"n_loops must be an int, got {type(c.n_loops).__name__}")
    n = c.n_loops
    if n < 1:
        raise ValueError(f"n_loops must be >= 1, got {n}")
    ts = finite_scalar("ts_s", c.ts_s)
    if ts <= 0.0:
        raise ValueError(f"ts_s must be > 0, got {ts}")

    lo = _per_loop("u_min", c.u_min, n)
    hi = _per_loop("u_max", c.u_max, n)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("u_min and u_max must be finite")
    if np.any(lo >= hi):
        raise ValueError("u_min must be < u_max for every actuator")

    if c.du_max is None:
        du = np.full(n, np.inf)
    else:
        du = _per_loop("du_max", c.du_max, n)
        if np.any(np.isnan(du)) or np.any(du <= 0.0):
            raise ValueError("du_max must be > 0 (per scan) for every actuator")

    tf = finite_scalar("d_filter_tf_s", c.d_filter_tf_s)
    if tf < 0.0:
        raise ValueError(f"d_filter_tf_s must be >= 0, got {tf}")

    b = _weights("setpoint_weight_p", c.setpoint_weight_p, n)
    cw = _weights("setpoint_weight_d", c.setpoint_weight_d, n)

    sp_lo = _per_loop("sp_min", c.sp_min, n)
    sp_hi = _per_loop("sp_max", c.sp_max, n)
    if np.any(np.isnan(sp_lo)) or np.any(np.isnan(sp_hi)) or np.any(sp_lo > sp_hi):
        raise ValueError("sp_min must be <= sp_max for every loop")

    if c.sp_rate is None:
        sp_step = np.full(n, np.inf)
    else:
        rate = _per_loop("sp_rate", c.sp_rate, n)
        if np.any(np.isnan(rate)) or np.any(rate <= 0.0):
            raise ValueError("sp_rate must be > 0 [PV unit/s] for every loop")
        sp_step = rate * ts

    direct = np.asarray(c.direct_acting)
    if direct.dtype.kind != "b":
        raise TypeError("direct_acting must be a bool or a sequence of bools")
    if direct.ndim == 0:
        direct = np.full(n, bool(direct))
    if direct.shape != (n,):
        raise ValueError(f"direct_acting must be a bool or have shape ({n},), got {direct.shape}")
    sign = np.where(direct, -1.0, 1.0)

    u0 = _per_loop("initial_mv", c.initial_mv, n)
    if np.any(~np.isfinite(u0)) or np.any(u0 < lo) or np.any(u0 > hi):
        raise ValueError("initial_mv must lie within [u_min, u_max] for every actuator")

    if c.init_memory not in _INIT_MEMORIES:
        raise ValueError(f"init_memory must be one of {_INIT_MEMORIES}, got {c.init_memory!r}")

    if isinstance(c.pv_bad_scans, bool) or not isinstance(c.pv_bad_scans, int):
        raise TypeError(f"pv_bad_scans must be an int, got {type(c.pv_bad_scans).__name__}")
    if c.pv_bad_scans < 1:
        raise ValueError(f"pv_bad_scans must be >= 1, got {c.pv_bad_scans}")

    subst_in: object = c.substitute
    subst: list[object]
    if isinstance(subst_in, str):
        subst = [subst_in] * n
    elif isinstance(subst_in, Sequence):
        subst = list(subst_in)
    else:
        raise TypeError(
            f"substitute must be a string or a sequence of strings, got {type(c.substitute).__name__}"
        )
    if len(subst) != n:
        raise ValueError(f"substitute must be a string or have {n} entries, got {len(subst)}")
    for s in subst:
        if s not in _SUBSTITUTES:
            raise ValueError(f"substitute must be one of {_SUBSTITUTES}, got {s!r}")
    smv = _per_loop("substitute_mv", c.substitute_mv, n)
    if np.any(~np.isfinite(smv)) or np.any(smv < lo) or np.any(smv > hi):
        raise ValueError("substitute_mv must lie within [u_min, u_max] for every actuator")

    if isinstance(c.initial_mode, LoopMode):
        modes_in = [c.initial_mode] * n
    elif isinstance(c.initial_mode, Sequence) and not isinstance(c.initial_mode, str):
        modes_in = list(c.initial_mode)
    else:
        raise TypeError(
            f"initial_mode must be a LoopMode or a sequence of them, got {type(c.initial_mode).__name__}"
        )
    if len(modes_in) != n:
        raise ValueError(f"initial_mode must be a LoopMode or have {n} entries, got {len(modes_in)}")
    modes = tuple(_check_mode(m) for m in modes_in)

    return Resolved(
        n=n,
        ts=ts,
        lo=lo,
        hi=hi,
        du_max=du,
        alpha=tf / (tf + ts),
        b=b,
        c=cw,
        sp_lo=sp_lo,
        sp_hi=sp_hi,
        sp_step=sp_step,
        sign=sign,
        initial_mv=u0,
        first_error=c.init_memory == "first_error",
        pv_bad_scans=c.pv_bad_scans,
        subst_value=np.array([s == "value" for s in subst], dtype=bool),
        substitute_mv=smv,
        modes=modes,
    )
