"""The PLC's control blocks: one block protocol and one loop shell around any block.

IEC 61131-3 function-block shape (decision 0029): a block is an instance with memory, called
once per scan with its inputs, giving its outputs; between scans it takes a few verbs. Every
control law of the PLC (the MIMO velocity-form PID, the nonlinear PI, MRAC) is a `Block`::

    step(w, pv, good, u_prev) -> raw      the law's output per actuator for this scan
    set_mode(loop, mode)                  the loop's mode changed (AUTO or not)
    track(loop, mv)                       the actuator is at mv, not at the law's output
    resume(loop, mv, w, pv)               continue from a running process (warm restart)

The `LoopShell` owns what is the same for every law, per loop j driving actuator j, in scan
order: the working setpoint (target clamped to [sp_min, sp_max], then ramped by at most sp_step
per scan), PV quality (a PV flagged bad or not finite; consecutive bad scans counted), the
block's step, the mode's selection (AUTO: the law; REMOTE: the held remote value; MANUAL: the
held manual value), the substitute output after ``pv_bad_scans`` bad scans (AUTO and REMOTE
only: ``hold`` keeps u(k-1), ``value`` goes to ``substitute_mv``), a NaN hold, and the output
limits::

    u_j(k) = sat_[mv_min, mv_max]( ratelimit_du_max( raw_j(k) ) )   relative to u_j(k-1)

u(k-1) is always the value actually applied, and the shell hands it to the block each scan, so
clamping is anti-windup for a velocity-form law by itself; a block with an internal state (the
NL-PI's integral, MRAC's parameters) is told by ``track`` whenever the applied output is not the
one its law asked for (limited, substituted, held in MANUAL or REMOTE, a bad PV, an interlock), and
re-initialises from it: every mode switch is bumpless, in every direction. Mode switches start
from the applied MV: entering MANUAL or REMOTE without a value holds it.

Units: the shell works in the block's units (for the PID the loop's error unit, e.g. cm: the
program scales SP and PV before the call); MV in the actuator's unit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from tanklab.enums import LoopMode
from tanklab.gains import LoopLimits

__all__ = ["Block", "LoopShell", "ShellConfig", "Substitute", "check_loop", "check_mode", "finite_scalar"]

FloatArray = NDArray[np.float64]
Substitute = Literal["hold", "value"]

_AUTO, _MANUAL, _REMOTE = LoopMode.AUTO, LoopMode.MANUAL, LoopMode.REMOTE  # bound once: hot path
_isfinite, _isnan = math.isfinite, math.isnan


def check_loop(loop: int, n: int) -> int:
    """A loop index in [0, n) as an int; TypeError or ValueError otherwise."""
    if isinstance(loop, bool) or not isinstance(loop, int | np.integer):
        raise TypeError(f"loop must be an int, got {type(loop).__name__}")
    if not 0 <= int(loop) < n:
        raise ValueError(f"loop must be in [0, {n - 1}], got {loop}")
    return int(loop)


def check_mode(mode: LoopMode) -> LoopMode:
    """A `LoopMode`; TypeError otherwise."""
    if not isinstance(mode, LoopMode):
        raise TypeError(f"mode must be a tanklab.enums.LoopMode, got {type(mode).__name__}")
    return mode


def finite_scalar(name: str, value: float) -> float:
    """A finite real number as a float; TypeError or ValueError otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


class Block(Protocol):
    """A control law in function-block shape, run by a `LoopShell` (see the module docstring).

    Loop j drives actuator j; ``n_loops`` of each.
    """

    @property
    def n_loops(self) -> int:
        """Number of loops (= actuators)."""
        ...

    def step(
        self, w: Sequence[float], pv: Sequence[float], good: Sequence[bool], u_prev: Sequence[float]
    ) -> list[float]:
        """One scan of the law: the output per actuator [MV unit] it asks for.

        ``w`` the working setpoints, ``pv`` the PVs (not finite where bad), ``good`` their quality,
        ``u_prev`` the outputs applied last scan. Runs in every mode (a law's memory may follow
        the process in MANUAL too); the shell applies the result in AUTO only.
        """
        ...

    def set_mode(self, loop: int, mode: LoopMode) -> None:
        """The loop's mode is now ``mode`` (from the next step on)."""
        ...

    def track(self, loop: int, mv: float) -> None:
        """The loop's actuator is at ``mv`` (inside the limits): continue from it."""
        ...

    def resume(self, loop: int, mv: float, w: float, pv: float) -> None:
        """Continue from a running process: the actuator at ``mv``, setpoint ``w``, reading ``pv``
        (not finite: unknown)."""
        ...


@dataclass(frozen=True)
class ShellConfig:
    """Per-loop constants of a `LoopShell` (index j: loop j and actuator j).

    Attributes
    ----------
    limits : tuple of LoopLimits
        Output range and rate limit per actuator.
    sp_min, sp_max : tuple of float
        Setpoint limits [block unit], sp_min <= sp_max (infinite allowed).
    sp_step : tuple of float
        Largest change of the working setpoint per scan [block unit], > 0; ``math.inf``: none.
    pv_bad_scans : int
        Consecutive bad-PV scans (>= 1) after which AUTO and REMOTE apply the substitute.
    substitute : tuple of {"hold", "value"}
        Substitute output per loop.
    substitute_mv : tuple of float
        Safe MV for ``value`` [MV unit], inside the limits.
    initial_mv : tuple of float
        u(-1) [MV unit], inside the limits.
    initial_mode : tuple of LoopMode
        Mode of each loop at construction.
    """

    limits: tuple[LoopLimits, ...]
    sp_min: tuple[float, ...]
    sp_max: tuple[float, ...]
    sp_step: tuple[float, ...]
    pv_bad_scans: int
    substitute: tuple[Substitute, ...]
    substitute_mv: tuple[float, ...]
    initial_mv: tuple[float, ...]
    initial_mode: tuple[LoopMode, ...]

    def __post_init__(self) -> None:
        n = len(self.limits)
        for name in (
            "sp_min",
            "sp_max",
            "sp_step",
            "substitute",
            "substitute_mv",
            "initial_mv",
            "initial_mode",
        ):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} must have one entry per loop ({n})")
        for j, lim in enumerate(self.limits):
            if not lim.mv_min <= self.initial_mv[j] <= lim.mv_max:
                raise ValueError("initial_mv must lie within [u_min, u_max] for every actuator")
            if not lim.mv_min <= self.substitute_mv[j] <= lim.mv_max:
                raise ValueError("substitute_mv must lie within [u_min, u_max] for every actuator")


class LoopShell:
    """Setpoint ramp, modes, PV-bad substitute, rate limit and clamp around a `Block`.

    Parameters
    ----------
    block : Block
        The control law (its ``n_loops`` must match the config).
    config : ShellConfig
        Per-loop constants.

    Notes
    -----
    Verbs: `scan` once per scan; `set_mode`, `set_manual_mv`, `set_remote_mv`, `track` and
    `force` between scans (they take effect at the next scan, bumplessly). After a scan the
    per-loop diagnostics of that scan are in `working_sp`, `substituted`, `rate_limited`,
    `clamped` and `good` (lists).
    """

    def __init__(self, block: Block, config: ShellConfig) -> None:
        n = len(config.limits)
        if block.n_loops != n:
            raise ValueError(f"the block has {block.n_loops} loops, the shell's config {n}")
        self.block = block
        self.shell_config = config
        self.n = n
        self._lo = [lim.mv_min for lim in config.limits]
        self._hi = [lim.mv_max for lim in config.limits]
        self._du = [lim.du_max for lim in config.limits]
        self._sp_lo, self._sp_hi, self._sp_step = (
            list(config.sp_min),
            list(config.sp_max),
            list(config.sp_step),
        )
        self._n_bad = config.pv_bad_scans
        self._subst_value = [s == "value" for s in config.substitute]
        self._subst_mv = list(config.substitute_mv)
        self._u: list[float] = list(config.initial_mv)  # u(k-1), the applied value
        self._manual: list[float] = list(config.initial_mv)
        self._remote: list[float] = list(config.initial_mv)
        self._modes: list[LoopMode] = list(config.initial_mode)
        self._bad_count: list[int] = [0] * n
        self._w: list[float] = [0.0] * n  # working setpoint (zeros before the first scan)
        self._started = False
        # The last scan's diagnostics.
        self.substituted: list[bool] = [False] * n
        self.rate_limited: list[bool] = [False] * n
        self.clamped: list[bool] = [False] * n
        self.good: list[bool] = [False] * n
        for j, mode in enumerate(self._modes):
            if mode is not _AUTO:
                block.set_mode(j, mode)

    # ------------------------------------------------------------------ state
    @property
    def n_loops(self) -> int:
        """Number of loops (= actuators)."""
        return self.n

    @property
    def mv(self) -> FloatArray:
        """Applied MV u(k-1) per actuator [MV unit] (copy)."""
        return np.array(self._u, dtype=np.float64)

    @property
    def modes(self) -> tuple[LoopMode, ...]:
        """Current mode per loop."""
        return tuple(self._modes)

    @property
    def manual_mv(self) -> FloatArray:
        """Held manual value per loop [MV unit] (copy)."""
        return np.array(self._manual, dtype=np.float64)

    @property
    def remote_mv(self) -> FloatArray:
        """Held remote value per loop [MV unit] (copy)."""
        return np.array(self._remote, dtype=np.float64)

    @property
    def working_sp(self) -> FloatArray:
        """Working setpoint per loop after the last scan [block unit] (copy; zeros before the first)."""
        return np.array(self._w, dtype=np.float64)

    @property
    def pv_bad_count(self) -> NDArray[np.int64]:
        """Consecutive bad-PV scans per loop (copy)."""
        return np.array(self._bad_count, dtype=np.int64)

    @property
    def started(self) -> bool:
        """Whether a scan has run (the working setpoint exists)."""
        return self._started

    def mv_of(self, loop: int) -> float:
        """Applied MV u(k-1) of one loop [MV unit]."""
        return self._u[loop]

    def held_mv(self, loop: int) -> tuple[float, float]:
        """(manual, remote) held values of one loop [MV unit]."""
        return self._manual[loop], self._remote[loop]

    # ------------------------------------------------------------------ verbs
    def set_mode(self, loop: int, mode: LoopMode, mv: float | None = None) -> None:
        """Switch one loop's mode, bumplessly.

        ``mv``: for MANUAL / REMOTE the held value to apply (clamped to the limits); omitted, the
        held value is initialised to the applied MV (tracking), so the switch does not move the MV.
        Must be omitted for AUTO (AUTO continues from the applied MV).
        """
        j = check_loop(loop, self.n)
        mode = check_mode(mode)
        if mode is _AUTO:
            if mv is not None:
                raise ValueError("mv applies only to MANUAL and REMOTE; AUTO continues from the applied MV")
        else:
            held = self._u[j] if mv is None else self._clamp(j, finite_scalar("mv", mv))
            if mode is _MANUAL and (self._modes[j] is not _MANUAL or mv is not None):
                self._manual[j] = held
            if mode is _REMOTE and (self._modes[j] is not _REMOTE or mv is not None):
                self._remote[j] = held
        if mode is not self._modes[j]:
            self.block.set_mode(j, mode)
        self._modes[j] = mode

    def set_manual_mv(self, loop: int, mv: float) -> None:
        """Set the held manual value of one loop [MV unit] (clamped; applied in MANUAL)."""
        j = check_loop(loop, self.n)
        self._manual[j] = self._clamp(j, finite_scalar("mv", mv))

    def set_remote_mv(self, loop: int, mv: float) -> None:
        """Set the held remote value of one loop [MV unit] (clamped; applied in REMOTE)."""
        j = check_loop(loop, self.n)
        self._remote[j] = self._clamp(j, finite_scalar("mv", mv))

    def track(self, loop: int, mv: float) -> None:
        """The actuator really is at ``mv`` (clamped): the next move and the rate limit count from
        it. The held manual / remote values are not changed."""
        j = check_loop(loop, self.n)
        self._u[j] = u = self._clamp(j, finite_scalar("mv", mv))
        self.block.track(j, u)

    def force(self, loop: int, mv: float) -> float:
        """An interlock forced the actuator to ``mv``: track it, and a loop in MANUAL or REMOTE
        holds it (no restart at an old held value after the reset). Returns the clamped value."""
        self.track(loop, mv)
        u = self._u[loop]
        if self._modes[loop] is _MANUAL:
            self._manual[loop] = u
        elif self._modes[loop] is _REMOTE:
            self._remote[loop] = u
        return u

    def resume(self, loop: int, mv: float, sp: float, pv: float) -> None:
        """Continue a loop from a running process (a warm restart): u(k-1) = ``mv`` (clamped), the
        block primed with the setpoint ``sp`` (clamped to its limits) and the reading ``pv``."""
        j = check_loop(loop, self.n)
        self._u[j] = u = self._clamp(j, finite_scalar("mv", mv))
        target = min(max(finite_scalar("sp", sp), self._sp_lo[j]), self._sp_hi[j])
        self.block.resume(j, u, target, float(pv))

    # ------------------------------------------------------------------ the scan
    def scan(self, sp: Sequence[float], pv: Sequence[float], pv_good: Sequence[bool]) -> list[float]:
        """Run one scan (validated inputs: finite setpoints, one entry per loop); returns the
        applied MV per actuator (the shell's own list: read, do not keep)."""
        n = self.n
        w_all, good_all, bad_count = self._w, self.good, self._bad_count
        sp_lo, sp_hi, sp_step = self._sp_lo, self._sp_hi, self._sp_step
        started = self._started
        for j in range(n):
            # Working setpoint: clamp the target, then ramp toward it. Every min(max(x, lo), hi)
            # here is written out as the builtins evaluate it (NaN and signed zeros alike).
            s = sp[j]
            lo, hi = sp_lo[j], sp_hi[j]
            target = lo if lo > s else s
            target = hi if hi < target else target
            if started:
                w_prev, step = w_all[j], sp_step[j]
                delta = target - w_prev
                delta = -step if -step > delta else delta
                w_all[j] = w_prev + (step if step < delta else delta)
            else:
                w_all[j] = target
            good = pv_good[j] and _isfinite(pv[j])
            good_all[j] = good
            bad_count[j] = 0 if good else bad_count[j] + 1
        self._started = True
        u_prev = self._u  # updated in place below: the law has read it, and each j once
        block = self.block
        raw_law = block.step(w_all, pv, good_all, u_prev)
        modes, n_bad, du_all, lo_all, hi_all = self._modes, self._n_bad, self._du, self._lo, self._hi
        substituted_all, rate_limited, clamped = self.substituted, self.rate_limited, self.clamped
        for j in range(n):
            up = u_prev[j]
            mode = modes[j]
            good = good_all[j]
            if mode is _AUTO:
                raw = raw_law[j]
            elif mode is _REMOTE:
                raw = self._remote[j]
            else:
                raw = self._manual[j]
            substituted = not good and bad_count[j] >= n_bad and mode is not _MANUAL
            if substituted:
                raw = self._subst_mv[j] if self._subst_value[j] else up
            if _isnan(raw):  # overflowing products (inf - inf): hold
                raw = up
            du = du_all[j]
            low, high = up - du, up + du
            limited = low if low > raw else raw
            limited = high if high < limited else limited
            lo, hi = lo_all[j], hi_all[j]
            u = lo if lo > limited else limited
            u = hi if hi < u else u
            u_prev[j] = u
            substituted_all[j] = substituted
            rate_limited[j] = limited != raw
            clamped[j] = u != limited
            if substituted or not good or mode is not _AUTO or u != raw_law[j]:
                block.track(j, u)
        return u_prev

    def _clamp(self, j: int, value: float) -> float:
        return float(min(max(value, self._lo[j]), self._hi[j]))
