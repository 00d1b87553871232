"""The soft PLC's program: one scan, in PLC order, as a pure function of its inputs.

A scan (period Ts of model time) does, in order:

1. **Watchdog**: the supervisor's heartbeat must change within ``timeout_s`` of model time
   (counted from the scan that saw the last change; the first timeout after start is a grace
   period counted from the first scan). On timeout ``Alive`` goes false; loops on SUPERVISOR
   gains go to FALLBACK gains (the fixed ones or the last accepted ones), loops in REMOTE shed
   to AUTO at their current setpoint, both bumpless (the velocity form continues from the
   applied MV; NL-PI and MRAC re-initialise from it), and the supervisor's gains staged since
   the last scan are dropped. ENGINEER gains, and an engineer's or operator's staged request
   (SetGains, ResetGains), are never touched by the watchdog. Supervisor gains are accepted
   again only after the heartbeat has been good for ``good_scans_to_accept`` scans. Only loops
   whose ``RemoteSource`` is SUPERVISOR shed on the supervisor's timeout; a loop handed to an
   external controller (``RemoteSource`` EXTERNAL, decision 0055) has a watchdog of its own on
   ``PLC.External.Heartbeat``, with the same timeout and rule, and on its timeout such a loop in
   REMOTE sheds to AUTO the same bumpless way.
2. **Boundary**: gains staged since the last scan (``SetGains``, ``ResetGains``) take effect
   now, all three at once, so no scan runs with half-applied gains, and the loop's
   ``GainSource`` changes with them.
3. **Read inputs**: the level transmitters' readings and their quality. A reading is bad when
   the field link failed (``io_healthy`` false), the link flagged it, it is not finite, outside
   the transmitter range, or frozen (``pv_frozen_scans`` identical readings in a row, when
   enabled).
4. **Execute blocks**: one ``plc_emulator.loop.LoopShell`` per group of loops, whatever its block
   (decision 0029): the PID loops as MIMO velocity-form blocks (one per group of loops coupled
   by ``cross_gains``), the NL-PI and MRAC loops as single-loop blocks. The shell owns the SP
   ramp, the modes and held values, the substitute output (``hold`` or ``value``, at the rate
   limit) after ``pv_bad_scans`` bad scans in AUTO and REMOTE, the rate limit and the clamp, so
   every block is bumpless in every direction.
5. **Interlocks**: a delivered, finite reading at or above high-high (over-range and frozen
   readings included: fail-safe) trips its tank's pumps to their lowest command in every mode,
   with any gains, supervisor alive or not. The trip latches until the level is below the reset
   level and an operator resets it. The blocks are told where the actuator really is
   (``track``), and a loop in MANUAL or REMOTE holds the forced value, so the loop resumes
   bumplessly after the reset and no pump restarts by itself at an old manual value.
6. **Write outputs**: one command per pump, in the pump's own unit, always inside the pump's
   command range.
7. **Alarms**: the alarm manager (``plc_emulator.alarms``, docs/alarms.md) takes the scan's
   state; its events are kept for the OPC UA projection, its booleans are ``PLC.Alarms.*``.
8. **Report**: the program's state as a value (``status()``: a
   :class:`plc_emulator.status.PlcStatus`), which the OPC UA side maps to the contract's nodes
   (:func:`plc_emulator.publish.status_values`); the program knows no node path.

Gain sources (``tanklab.enums.GainSource``, one per PID loop):

- FIXED: the configured gains (at start, after ``ResetGains``), or gains left in place by
  ``ReleaseGains`` until the supervisor pushes again.
- SUPERVISOR: the supervisor's last accepted ``SetGains``.
- FALLBACK: the supervisor was lost; the fixed or its last accepted gains (``watchdog.fallback``).
- ENGINEER: an engineer's own ``SetGains`` (whatever the supervisor's state). While a loop is
  ENGINEER the supervisor's ``SetGains`` on it is refused (INVALID_STATE) and the watchdog
  leaves it alone, until ``ReleaseGains`` (the gains stay, source FIXED) or ``ResetGains`` (the
  fixed gains at the next boundary, source FIXED) hands it back.

Errors are SP - PV in the loop's ``error_unit``: the rig's gains assume centimetres, so SP and PV
are scaled by 100 before the PID block sees them (the PID's setpoint limits and ramp scale with
them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from plc_emulator import retain
from plc_emulator.alarms import PlcAlarms
from plc_emulator.interlocks import Interlock, latch, reset_trips
from plc_emulator.loops import ERROR_SCALE, Group, Loop, build_groups, group_gains, make_loops
from plc_emulator.pid import Pid
from plc_emulator.status import InterlockStatus, LoopStatus, PlcStatus, TankStatus
from plc_emulator.watchdog import Watchdog
from tanklab.config import SiteConfig
from tanklab.enums import GainSource, LoopMode, RemoteSource
from tanklab.gains import LoopGains

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

__all__ = ["ERROR_SCALE", "GainStatus", "PlcProgram", "ScanInputs", "ScanOutputs"]


class GainStatus(Enum):
    """Outcome of staging a gain set (the OPC UA layer maps it to a status code)."""

    STAGED = "Good"
    OUT_OF_RANGE = "BadOutOfRange"
    INVALID_STATE = "BadInvalidState"


@dataclass(frozen=True)
class ScanInputs:
    """What a scan reads.

    Attributes
    ----------
    t_s : model time at the start of the scan [s].
    levels_m : (n_tanks,) transmitter readings [m] (NaN where unavailable).
    good : (n_tanks,) quality of each reading as delivered by the field link.
    io_healthy : whether the field link worked this scan (False makes every reading bad).
    """

    t_s: float
    levels_m: FloatArray
    good: BoolArray
    io_healthy: bool = True


@dataclass(frozen=True)
class ScanOutputs:
    """What a scan writes: pump commands (pump order, pump units) and, when it publishes, the
    program's state after it (:meth:`PlcProgram.status`; None for ``scan(publish=False)``)."""

    commands: FloatArray
    status: PlcStatus | None


@dataclass
class _Frozen:
    last: list[float]  # the previous scan's readings
    repeats: list[int]  # consecutive scans each reading has repeated the one before


class PlcProgram:
    """The PLC program of a site, scanned by :meth:`scan`.

    Operator and supervisor requests (``set_sp``, ``set_mode``, ``set_manual_mv``,
    ``set_remote_mv``, ``heartbeat``, ``stage_gains``, ``reset_gains``, ``release_gains``,
    ``reset_interlocks``) take effect at the next scan; the value checks of the contract (type,
    finiteness, EURange) are the OPC UA layer's job, the checks that need the program's state are
    made here (``ValueError`` on refusal; the gain requests answer a :class:`GainStatus`).

    Parameters
    ----------
    site : a site config with a ``plc`` section.
    watchdog_timeout_s : heartbeat timeout in model time; default: the config's (the runtime
        raises it to a wall-clock floor at high speed).
    alarm_event_prefix : the alarms' EventId prefix, unique per process (the runtime's).

    Raises
    ------
    ValueError
        No ``plc`` section; a loop's MV range does not overlap its pump's command range; PID loops
        coupled by cross gains disagree on ``pv_bad_scans`` or ``derivative_filter_s``.
    """

    def __init__(
        self, site: SiteConfig, *, watchdog_timeout_s: float | None = None, alarm_event_prefix: bytes = b""
    ) -> None:
        if site.plc is None:
            raise ValueError(f"site {site.name!r} has no plc section")
        self.site = site
        plc = site.plc
        self.ts_s = plc.scan_period_s
        tanks = site.tank_names
        pumps = site.pump_names
        self.n_tanks = len(tanks)
        self.n_pumps = len(pumps)
        self.scan_count = 0
        self.t_s = 0.0
        # Constants per pump and per tank, as arrays (read by other modules and tests) ...
        self.pump_min = np.array([p.command_min for p in site.plant.pumps], dtype=float)
        self.pump_max = np.array([p.command_max for p in site.plant.pumps], dtype=float)
        self.pump_tank = np.array([tanks.index(p.feeds) for p in site.plant.pumps], dtype=np.int64)
        self.tr_range = np.array([t.transmitter_range() for t in site.plant.tanks], dtype=float)
        sw = [t.switch_levels() for t in site.plant.tanks]
        self.high_m = np.array([s.high_m for s in sw])
        self.low_m = np.array([s.low_m for s in sw])
        # ... and as Python floats for the scan, which works per tank and per pump: with a handful
        # of each, numpy's per-call overhead on 3-element arrays costs more than the loops.
        self._pump_min: list[float] = self.pump_min.tolist()
        self._pump_max: list[float] = self.pump_max.tolist()
        self._pump_tank: list[int] = self.pump_tank.tolist()
        self._tr_range: list[tuple[float, float]] = [(lo, hi) for lo, hi in self.tr_range.tolist()]
        # Per-tank and per-pump state as lists (the array attributes are properties built from them)
        n = self.n_tanks
        self._shape = (n,)
        self._commands: list[float] = np.array(
            [p.initial_command for p in site.plant.pumps], dtype=float
        ).tolist()
        self._levels_m: list[float] = [math.nan] * n  # readings used this scan; NaN where bad
        self._good: list[bool] = [False] * n
        self._last_good_m: list[float] = [0.0] * n
        self._raw_m: list[float] = [math.nan] * n  # delivered, finite readings (for interlocks)
        self.io_healthy = False
        self.pv_frozen_scans = plc.pv_frozen_scans
        self._frozen = _Frozen(last=[math.nan] * n, repeats=[0] * n)
        self.watchdog = Watchdog(
            timeout_s=plc.watchdog.timeout_s if watchdog_timeout_s is None else watchdog_timeout_s,
            good_scans_needed=plc.watchdog.good_scans_to_accept,
        )
        self.external_watchdog = Watchdog(
            timeout_s=self.watchdog.timeout_s, good_scans_needed=plc.watchdog.good_scans_to_accept
        )
        """The external controller's heartbeat watchdog (same timeout and rule as the supervisor's)."""
        self.fallback = plc.watchdog.fallback
        self.interlocks = [
            Interlock(tanks.index(il.tank), il.tank, il.high_high_m, il.reset_below_m)
            for il in plc.interlocks
        ]
        self.hh_m = np.full(self.n_tanks, math.inf)
        for il in self.interlocks:
            self.hh_m[il.tank] = min(self.hh_m[il.tank], il.high_high_m)
        # status()'s constants per tank: name, high, low and high-high levels [m] as Python floats
        # (the same float64 values as the arrays)
        self._tank_consts: list[tuple[str, float, float, float]] = list(
            zip(tanks, self.high_m.tolist(), self.low_m.tolist(), self.hh_m.tolist(), strict=True)
        )
        self.loops = make_loops(site)
        self._pending_heartbeat: int | None = None
        self._pending_external_heartbeat: int | None = None
        self.pid_groups: list[Group]
        self.groups: list[Group]
        self.pid_groups, self.groups = build_groups(self.loops, self.ts_s)
        # status()'s constants per loop: the loop, its name, the config's setpoint range [m]
        self._loop_consts: list[tuple[Loop, str, float, float]] = [
            (lp, lp.spec.name, lp.spec.sp_min_m, lp.spec.sp_max_m) for lp in self.loops
        ]
        self.alarms = PlcAlarms(site, event_prefix=alarm_event_prefix)

    # ---- state after the last scan (arrays built on request) -----------------------------

    @property
    def levels_m(self) -> FloatArray:
        """(n_tanks,) readings the last scan used [m], NaN where bad (a new array)."""
        return np.array(self._levels_m, dtype=float)

    @property
    def good(self) -> BoolArray:
        """(n_tanks,) quality of each reading in the last scan (a new array)."""
        return np.array(self._good, dtype=bool)

    @property
    def last_good_m(self) -> FloatArray:
        """(n_tanks,) each transmitter's last good reading [m], 0 before the first (a new array)."""
        return np.array(self._last_good_m, dtype=float)

    @property
    def commands(self) -> FloatArray:
        """(n_pumps,) the last scan's pump commands, pump units (initial commands before the first
        scan; a new array)."""
        return np.array(self._commands, dtype=float)

    # ---- construction -------------------------------------------------------------------

    # ---- requests between scans ---------------------------------------------------------

    def loop(self, name: str) -> Loop:
        """The loop called ``name`` (LIC1, ...)."""
        for lp in self.loops:
            if lp.spec.name == name:
                return lp
        raise KeyError(f"unknown loop {name!r}")

    def set_sp(self, name: str, sp_m: float) -> None:
        """Operator setpoint [m]; must lie in the loop's program limits [SPLow, SPHigh]."""
        lp = self.loop(name)
        lo, hi = self.sp_limits(name)
        if not (math.isfinite(sp_m) and lo <= sp_m <= hi):
            raise ValueError(f"{name} SP {sp_m} outside [{lo}, {hi}]")
        lp.sp_m = float(sp_m)

    def sp_limits(self, name: str) -> tuple[float, float]:
        """The operator's setpoint range of a loop now [m]: the engineer's limits, which lie
        inside the config's [sp_min_m, sp_max_m] (the defaults)."""
        return _sp_limits(self.loop(name))

    def set_sp_limits(self, name: str, low_m: float | None = None, high_m: float | None = None) -> None:
        """Engineer: narrow (or restore) the operator's setpoint range of a loop [m].

        Both limits must be finite, inside the config's [sp_min_m, sp_max_m], low <= high, and
        the current setpoint must lie inside the new range (move it first); else ValueError and
        nothing changes.
        """
        lp = self.loop(name)
        lo_now, hi_now = self.sp_limits(name)
        lo = lo_now if low_m is None else float(low_m)
        hi = hi_now if high_m is None else float(high_m)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError(f"{name} setpoint limits must be finite")
        if not lp.spec.sp_min_m <= lo <= hi <= lp.spec.sp_max_m:
            raise ValueError(
                f"{name} setpoint limits [{lo}, {hi}] must lie in [{lp.spec.sp_min_m}, {lp.spec.sp_max_m}]"
            )
        if not lo <= lp.sp_m <= hi:
            raise ValueError(f"{name} SP {lp.sp_m} lies outside the new limits [{lo}, {hi}]")
        lp.sp_low_m, lp.sp_high_m = lo, hi

    def set_mode(self, name: str, mode: LoopMode) -> None:
        """Switch a loop's mode (bumpless in every direction: MANUAL and REMOTE start from the MV)."""
        lp = self.loop(name)
        mode = LoopMode(mode)
        if mode is lp.mode:
            return
        lp.mode_changed_scan = self.scan_count
        shell = lp.loop_shell
        shell.set_mode(lp.slot, mode)
        # Entering MANUAL or REMOTE holds the applied MV (until the operator or the supervisor
        # writes ManualMV or RemoteMV).
        if mode is LoopMode.REMOTE:
            lp.remote_mv = shell.held_mv(lp.slot)[1]
        elif mode is LoopMode.MANUAL:
            lp.manual_mv = shell.held_mv(lp.slot)[0]
        lp.mode = mode

    def set_manual_mv(self, name: str, mv: float) -> None:
        """Operator output for MANUAL [pump unit]; must lie in the MV range."""
        lp = self.loop(name)
        self._check_mv(lp, mv)
        lp.manual_mv = float(mv)
        lp.loop_shell.set_manual_mv(lp.slot, mv)

    def set_remote_mv(self, name: str, mv: float) -> None:
        """Supervisor output for REMOTE [pump unit]; must lie in the MV range."""
        lp = self.loop(name)
        self._check_mv(lp, mv)
        lp.remote_mv = float(mv)
        lp.loop_shell.set_remote_mv(lp.slot, mv)

    @staticmethod
    def _check_mv(lp: Loop, mv: float) -> None:
        if not (math.isfinite(mv) and lp.mv_min <= mv <= lp.mv_max):
            raise ValueError(f"{lp.spec.name} MV {mv} outside [{lp.mv_min}, {lp.mv_max}]")

    def heartbeat(self, value: int) -> None:
        """The supervisor wrote its heartbeat (any change counts as alive at the next scan)."""
        self._pending_heartbeat = int(value)

    def external_heartbeat(self, value: int) -> None:
        """The external controller wrote its heartbeat (any change counts as alive at the next scan)."""
        self._pending_external_heartbeat = int(value)

    def set_remote_source(self, name: str, source: RemoteSource) -> None:
        """Engineer: hand a loop's REMOTE to the supervisor or to an external controller.

        Refused (ValueError, nothing changed) while the loop is in REMOTE: the owner of a running
        REMOTE loop never changes under it; switch it to AUTO or MANUAL first.
        """
        lp = self.loop(name)
        source = RemoteSource(source)
        if source is lp.remote_source:
            return
        if lp.mode is LoopMode.REMOTE:
            raise ValueError(f"{name} is in REMOTE: RemoteSource changes only outside REMOTE")
        lp.remote_source = source

    @property
    def supervisor_trusted(self) -> bool:
        """Alive, and alive long enough for its gains to be accepted."""
        w = self.watchdog
        return w.alive and w.good_scans >= w.good_scans_needed

    def stage_gains(
        self, name: str, kp: float, ki: float, kd: float, source: GainSource = GainSource.SUPERVISOR
    ) -> GainStatus:
        """Validate (Kp, Ki, Kd) and stage them for the next scan boundary; all or nothing.

        Parameters
        ----------
        name : the loop (LIC1, ...).
        kp, ki, kd : the gains, in the loop's error unit.
        source : who asks: SUPERVISOR (the supervisor's identity) or ENGINEER (an engineer's own
            call); the applied gains carry it as their GainSource from the boundary on.

        Order of the checks: a block without PID gains answers INVALID_STATE; a non-finite value
        or one outside the loop's ``gain_box`` (when configured) OUT_OF_RANGE; then, for the
        supervisor only: a loop held by an engineer (GainSource ENGINEER, or an engineer's
        SetGains or a ResetGains staged) INVALID_STATE, a supervisor that is not trusted yet
        INVALID_STATE. An engineer's call works whatever the supervisor's state. A refused call
        changes nothing.

        Raises
        ------
        ValueError
            ``source`` is neither SUPERVISOR nor ENGINEER (a programming error).
        """
        if source not in (GainSource.SUPERVISOR, GainSource.ENGINEER):
            raise ValueError(f"SetGains is labelled SUPERVISOR or ENGINEER, not {source!r}")
        lp = self.loop(name)
        if lp.spec.block != "pid":
            return GainStatus.INVALID_STATE
        try:
            values = (float(kp), float(ki), float(kd))
        except (TypeError, ValueError):
            return GainStatus.OUT_OF_RANGE
        if not all(math.isfinite(v) for v in values):
            return GainStatus.OUT_OF_RANGE
        box = lp.gain_box
        if box is not None and not box.contains(LoopGains(*values)):
            return GainStatus.OUT_OF_RANGE
        if source is GainSource.SUPERVISOR and (self.engineer_holds(name) or not self.supervisor_trusted):
            return GainStatus.INVALID_STATE
        lp.staged = LoopGains(*values)
        lp.staged_source = source
        return GainStatus.STAGED

    def engineer_holds(self, name: str) -> bool:
        """Whether the supervisor is kept off a loop's gains: its GainSource is ENGINEER, or an
        engineer's SetGains or a ResetGains waits for the next boundary."""
        lp = self.loop(name)
        return lp.source is GainSource.ENGINEER or lp.staged_source in (GainSource.ENGINEER, GainSource.FIXED)

    def mode_change_pending(self, name: str) -> bool:
        """Whether a loop's mode changed since the last scan (the new mode has not run yet)."""
        return self.loop(name).mode_changed_scan == self.scan_count

    def reset_gains(self, name: str) -> GainStatus:
        """Return a PID loop to its configured (FIXED) gains at the next scan boundary.

        Staged like ``stage_gains`` (the velocity form makes the change bumpless: the scan after
        the boundary moves the MV by the fixed gains' increment only); the loop's GainSource
        becomes FIXED there, which also releases an engineer's hold. Until then the supervisor's
        SetGains on the loop is refused.

        Returns INVALID_STATE for a block without PID gains and while a mode change of the loop
        is pending (written since the last scan: the mode and the gains would change on the same
        scan; retry after it); else STAGED. A refused call changes nothing.
        """
        lp = self.loop(name)
        if lp.spec.block != "pid" or lp.fixed is None or self.mode_change_pending(name):
            return GainStatus.INVALID_STATE
        lp.staged = lp.fixed
        lp.staged_source = GainSource.FIXED
        return GainStatus.STAGED

    def release_gains(self, name: str) -> GainStatus:
        """Hand a loop held by an engineer back to adaptation, now.

        The applied gains stay; GainSource ENGINEER becomes FIXED (what it would be without the
        engineer: no tier changes these gains until the supervisor pushes again), and an
        engineer's SetGains still staged is dropped (the release is the later instruction). A
        loop not held is left as it is (STAGED: done). INVALID_STATE for a block without PID gains.
        """
        lp = self.loop(name)
        if lp.spec.block != "pid":
            return GainStatus.INVALID_STATE
        if lp.staged_source is GainSource.ENGINEER:
            lp.staged = None
            lp.staged_source = None
        if lp.source is GainSource.ENGINEER:
            lp.source = GainSource.FIXED
        return GainStatus.STAGED

    # ---- retentive memory (warm restart) -------------------------------------------------

    def retained(self) -> dict[str, Any]:
        """The retentive data of a warm restart (JSON-able).

        Per loop: SP, the engineer's SP limits, mode, manual MV, the applied gains and their source
        (ENGINEER included: an engineer's hold survives a restart) and the last MV (the fallback
        start value when the plant cannot be read at start). Latched interlocks (a trip survives
        a restart until an operator resets it), the scan counter (scans run so far), the model
        time at the start of the last scan [s] and the alarms' state (enabled, active, acked,
        confirmed, comment, shelving: ``AlarmManager.to_retain``).
        """
        return retain.retained(self)

    def restore_retained(self, data: Mapping[str, Any]) -> list[str]:
        """Warm restart from :meth:`retained` output; return what could not be restored.

        Every value is checked as if it were written now (setpoint range, gain box, MV range);
        an entry that fails keeps the cold-start value and is reported, never half-applied.
        The scan counter and the model time continue from the retained ones (the next scan is
        ``scan + 1`` at ``t_s + Ts``: :attr:`next_scan_t_s`); each loop's MV starts at its
        retained MV until :meth:`resume_from_plant` puts it at the pump's command.
        Gains from the supervisor come back as SUPERVISOR; the watchdog turns them into FALLBACK
        if the supervisor does not return within its timeout. An engineer's gains come back as
        ENGINEER, still held (the supervisor stays off them until a release or a reset).
        """
        return retain.restore_retained(self, data)

    @property
    def next_scan_t_s(self) -> float:
        """Model time of the next scan [s]: 0 before the first, else the last scan's + Ts."""
        return self.t_s + self.ts_s if self.scan_count > 0 else 0.0

    def resume_from_plant(self, commands: FloatArray, levels_m: FloatArray, good: BoolArray) -> None:
        """Warm restart: continue from the plant as it is now, before the first scan.

        Parameters
        ----------
        commands : (n_pumps,) the plant's pump commands now [pump units] (NaN: unknown; the
            loop keeps its retained MV).
        levels_m : (n_tanks,) the transmitter readings now [m].
        good : (n_tanks,) their quality.

        Each loop's MV becomes its pump's command (clamped to the loop's MV range), so the first
        scan does not move the output from where the pump is: a PID continues its velocity form
        from it, primed with the reading (``Pid.resume``: the first increment with the same SP
        and PV is ``Ki * Ts * e`` alone), NL-PI and MRAC track it, a loop in REMOTE holds it
        until the supervisor writes ``RemoteMV``; a loop in MANUAL applies its retained manual
        MV from the first scan on (the operator's value), rate-limited from the pump's command.
        The readings are shown on the PV nodes until the first scan replaces them.

        Raises
        ------
        ValueError
            An array does not have one entry per pump or tank (a programming error).
        """
        return retain.resume_from_plant(self, commands, levels_m, good)

    def _resume_mv(self, lp: Loop, mv: float, pv_m: float) -> None:
        """Put a loop's applied MV at ``mv`` (and a PID's memory at the reading ``pv_m``)."""
        lp.mv = mv
        self._commands[lp.pump] = mv
        shell = lp.loop_shell
        shell.resume(lp.slot, mv, lp.sp_m * lp.block_scale, pv_m * lp.block_scale)
        if lp.mode is LoopMode.REMOTE:
            lp.remote_mv = mv
            shell.set_remote_mv(lp.slot, mv)

    def reset_interlocks(self) -> list[str]:
        """Reset latched trips whose (good) level is below the reset level; return the tanks reset
        (their trip alarms reset at the next scan)."""
        reset = reset_trips(self.interlocks, self._levels_m, self._good)
        self.alarms.interlocks_reset(reset)
        return reset

    # ---- the scan -----------------------------------------------------------------------

    def scan(self, inputs: ScanInputs, *, publish: bool = True) -> ScanOutputs:
        """Run one scan at model time ``inputs.t_s``; see the module docstring for the order.

        ``publish=False`` leaves ``ScanOutputs.status`` None (a co-simulation without a
        supervisor reads no PLC node, and :meth:`status` with its mapping to the nodes is about
        a tenth of a scan's time).

        Raises
        ------
        ValueError
            ``levels_m`` or ``good`` does not have one entry per tank (a programming error).
        """
        levels = np.asarray(inputs.levels_m, dtype=float)
        delivered = np.asarray(inputs.good, dtype=bool)
        if levels.shape != self._shape or delivered.shape != self._shape:
            raise ValueError(  # checked before anything changes: a refused scan leaves no trace
                f"scan inputs need {self.n_tanks} levels and qualities, got shapes "
                f"{levels.shape} and {delivered.shape}"
            )
        self.t_s = float(inputs.t_s)
        if self._run_watchdog():
            self._fall_back()
        if self._run_external_watchdog():
            self._shed(RemoteSource.EXTERNAL)
        self._apply_staged_gains()
        self._read_inputs(levels.tolist(), delivered.tolist(), bool(inputs.io_healthy))
        self._execute_blocks()
        self._write_outputs(self._apply_interlocks())
        self.alarms.scan(self)
        self.scan_count += 1
        return ScanOutputs(
            commands=np.array(self._commands, dtype=float), status=self.status() if publish else None
        )

    def _set_pid_gains(self) -> None:
        for group in self.pid_groups:
            g = group_gains(group.loops)
            assert isinstance(group.shell, Pid)
            group.shell.set_gains(g.kp, g.ki, g.kd)

    def _apply_staged_gains(self) -> None:
        changed = False
        for lp in self.loops:
            if lp.staged is not None:
                source = GainSource.SUPERVISOR if lp.staged_source is None else lp.staged_source
                lp.applied = lp.staged
                if source is GainSource.SUPERVISOR:
                    lp.last_accepted = lp.staged
                lp.staged = None
                lp.staged_source = None
                lp.source = source
                changed = True
        if changed:
            self._set_pid_gains()

    def _run_watchdog(self) -> bool:
        """Update Alive from the heartbeat; return whether the timeout has expired."""
        value, self._pending_heartbeat = self._pending_heartbeat, None
        return self.watchdog.update(self.t_s, value, self.ts_s)

    def _run_external_watchdog(self) -> bool:
        """Update the external controller's Alive; return whether its timeout has expired."""
        value, self._pending_external_heartbeat = self._pending_external_heartbeat, None
        return self.external_watchdog.update(self.t_s, value, self.ts_s)

    def _shed(self, source: RemoteSource) -> None:
        """Loops in REMOTE driven by ``source`` -> AUTO at their current setpoint (bumpless)."""
        for lp in self.loops:
            if lp.mode is LoopMode.REMOTE and lp.remote_source is source:
                self.set_mode(lp.spec.name, LoopMode.AUTO)

    def _fall_back(self) -> None:
        """Supervisor lost: the supervisor's staged gains dropped, supervisor gains -> FALLBACK,
        REMOTE -> AUTO for the loops the supervisor drives (ENGINEER gains, an engineer's or a
        reset's staged set and the loops handed to an external controller stay).

        Runs every scan while the supervisor is away (the co-simulation without one: always), so
        each loop is only read unless it has something to undo.
        """
        changed = False
        for lp in self.loops:
            if lp.staged is not None and lp.staged_source is GainSource.SUPERVISOR:
                lp.staged = None
                lp.staged_source = None
            if lp.source is GainSource.SUPERVISOR:
                lp.applied = lp.fixed if self.fallback == "fixed" else lp.last_accepted
                lp.source = GainSource.FALLBACK
                changed = True
            if lp.mode is LoopMode.REMOTE and lp.remote_source is RemoteSource.SUPERVISOR:
                self.set_mode(lp.spec.name, LoopMode.AUTO)
        if changed:
            self._set_pid_gains()

    def _read_inputs(self, levels: list[float], delivered: list[bool], io_healthy: bool) -> None:
        # Per tank on Python floats, the state updated in place (see __init__).
        self.io_healthy = io_healthy
        frozen_n = self.pv_frozen_scans
        ranges, raw, good, used, last_good = (
            self._tr_range,
            self._raw_m,
            self._good,
            self._levels_m,
            self._last_good_m,
        )
        last, repeats = self._frozen.last, self._frozen.repeats
        for k, x in enumerate(levels):
            delivered_k = delivered[k] and io_healthy and math.isfinite(x)
            raw[k] = x if delivered_k else math.nan
            lo, hi = ranges[k]
            ok = delivered_k and lo <= x <= hi
            if frozen_n > 0:
                repeats[k] = repeats[k] + 1 if x == last[k] else 0
                ok = ok and repeats[k] < frozen_n
            good[k] = ok
            if ok:
                used[k] = last_good[k] = x
            else:
                used[k] = math.nan
        if frozen_n > 0:
            self._frozen.last = levels  # the scan's own list (tolist of the input)

    def _execute_blocks(self) -> None:
        good, levels = self._good, self._levels_m
        # One call per shell, whatever the block: SP ramp, modes, the law, substitute, limits.
        for group in self.groups:
            sp, pv, ok = group.sp, group.pv, group.ok  # the group's input buffers
            for k, lp in enumerate(group.loops):
                tank = lp.tank
                scale = lp.block_scale
                sp[k] = lp.sp_m * scale
                if good[tank]:
                    lp.pv_bad = False
                    lp.pv_m = lp.pv_last_good_m = levels[tank]
                    pv[k] = lp.pv_m * scale
                    ok[k] = True
                else:
                    lp.pv_bad = True
                    lp.pv_m = pv[k] = math.nan
                    ok[k] = False
            mv = group.shell.scan(sp, pv, ok)
            substituted = group.shell.substituted
            for k, lp in enumerate(group.loops):
                lp.mv = mv[k]
                lp.substituted = substituted[k]

    def _apply_interlocks(self) -> list[bool] | None:
        """Latch trips; return which pumps (pump order) are forced to their lowest command this
        scan (None: none)."""
        forced = latch(self.interlocks, self._raw_m, self._pump_tank)
        if forced is None:  # the usual scan: no pump forced, no block to tell
            return None
        for lp in self.loops:
            if not forced[lp.pump]:
                continue
            lp.mv = self._pump_min[lp.pump]
            held = lp.loop_shell.force(lp.slot, lp.mv)  # clamped to the loop's MV range
            if lp.mode is LoopMode.MANUAL:
                lp.manual_mv = held
            elif lp.mode is LoopMode.REMOTE:
                lp.remote_mv = held
        return forced

    def _write_outputs(self, forced: list[bool] | None) -> None:
        commands, lows, highs = self._commands, self._pump_min, self._pump_max
        for lp in self.loops:
            commands[lp.pump] = lp.mv
        for k, c in enumerate(commands):
            lo, hi = lows[k], highs[k]
            if forced is not None and forced[k]:
                commands[k] = lo
            else:  # min(max(c, lo), hi) as the builtins evaluate it, without their calls
                low = lo if lo > c else c
                commands[k] = hi if hi < low else low

    # ---- reporting ----------------------------------------------------------------------

    def status(self) -> PlcStatus:
        """The program's state now (after the last scan; before the first, the initial state).

        A bad PV is reported as its last good value (0 before the first one), with its quality
        (``LoopStatus.pv_bad``, ``TankStatus.good``). Values are plain Python floats, ints and
        bools, the enumerations their enum members.

        Built on every published scan, so built for speed: the named tuples through
        ``tuple.__new__`` (their generated ``__new__`` is one Python call more per object), the
        config's constants read from lists made once, the setpoint range inline (as
        :meth:`sp_limits` computes it: ``max`` and ``min`` of two floats).
        """
        w = self.watchdog
        new = tuple.__new__
        loops = [
            new(
                LoopStatus,
                (
                    name,
                    float(lp.sp_m),
                    spec_lo if spec_lo > lp.sp_low_m else lp.sp_low_m,  # max(sp_low_m, spec_lo)
                    spec_hi if spec_hi < lp.sp_high_m else lp.sp_high_m,  # min(sp_high_m, spec_hi)
                    float(lp.pv_last_good_m),
                    float(lp.mv),
                    lp.mode,
                    float(lp.manual_mv),
                    float(lp.remote_mv),
                    lp.applied,
                    lp.source,
                    bool(lp.pv_bad),
                    lp.remote_source,
                ),
            )
            for lp, name, spec_lo, spec_hi in self._loop_consts
        ]
        tanks = [
            new(TankStatus, (name, last_good, ok, ok and x >= high, ok and x <= low, raw >= hh))
            for (name, high, low, hh), last_good, ok, x, raw in zip(
                self._tank_consts, self._last_good_m, self._good, self._levels_m, self._raw_m, strict=True
            )
        ]
        trips = [new(InterlockStatus, (il.tank_name, bool(il.tripped))) for il in self.interlocks]
        return new(
            PlcStatus,
            (
                self.scan_count,
                float(self.t_s),
                bool(self.io_healthy),
                bool(w.alive),
                bool(w.ever_alive and not w.alive),
                tuple(loops),
                tuple(tanks),
                tuple(trips),
                self.alarms.flags(),
                bool(self.external_watchdog.alive),
            ),
        )


def _sp_limits(lp: Loop) -> tuple[float, float]:
    """A loop's operator setpoint range now [m] (see :meth:`PlcProgram.sp_limits`)."""
    return max(lp.sp_low_m, lp.spec.sp_min_m), min(lp.sp_high_m, lp.spec.sp_max_m)
