"""The PLC's state after a scan, as values: what the program shows, not where it is shown.

:meth:`plc_emulator.program.PlcProgram.status` returns a :class:`PlcStatus`; the OPC UA side
maps it to the contract's nodes (:func:`plc_emulator.publish.status_values`), the only place
that knows which node shows what (decision 0033). The supervisor's core does the same with
``supervisor.cycle.SupervisorStatus`` (decision 0033).

The types are named tuples: frozen, slotted (``__slots__ = ()``), typed fields with defaults
after the required ones. One status is built per published scan, so the cost of building it is
part of every scan: a frozen dataclass sets each field through ``object.__setattr__`` and costs
about four times as much to build as a named tuple of the same fields (2.7 against 0.6 µs for
14 fields, measured with ``time.process_time`` over 100,000 builds). To extend a type (the
alarm conditions, say), add a field at the end with a default, fill it in
``PlcProgram.status`` and map it in ``status_values``; the contract test lists every node the
mapping must publish.

Units: levels and setpoints in metres, MVs in the pump's own unit (flow m^3/s or speed rpm),
model time in seconds, gains in the loop's error unit (``plc_emulator.loops.ERROR_SCALE``).
"""

from __future__ import annotations

from typing import NamedTuple

from tanklab.enums import GainSource, LoopMode, RemoteSource
from tanklab.gains import LoopGains

__all__ = ["InterlockStatus", "LoopStatus", "PlcStatus", "TankStatus"]


class LoopStatus(NamedTuple):
    """One control loop after a scan.

    Attributes
    ----------
    name : the loop's tag (``LIC1``).
    sp_m : setpoint [m] (the operator's; the block sees it ramped and in the error unit).
    sp_low_m, sp_high_m : the operator's setpoint range now [m] (:meth:`PlcProgram.sp_limits`).
    pv_m : the last good process value [m] (0 before the first): a bad PV shows its last good
        value, ``pv_bad`` says it is bad.
    mv : the output applied this scan [pump unit].
    mode : MANUAL, AUTO or REMOTE.
    manual_mv, remote_mv : the operator's and the supervisor's held outputs [pump unit].
    gains : the applied (Kp, Ki, Kd); None for a block without PID gains (MRAC, NL-PI).
    gain_source : where the applied gains came from.
    pv_bad : this scan's PV was bad (the loop ran on its substitute).
    remote_source : who drives the loop in REMOTE (SUPERVISOR or EXTERNAL).
    """

    name: str
    sp_m: float
    sp_low_m: float
    sp_high_m: float
    pv_m: float
    mv: float
    mode: LoopMode
    manual_mv: float
    remote_mv: float
    gains: LoopGains | None
    gain_source: GainSource
    pv_bad: bool
    remote_source: RemoteSource = RemoteSource.SUPERVISOR


class TankStatus(NamedTuple):
    """One tank's level as the PLC read it in a scan, and its level alarms.

    Attributes
    ----------
    name : the tank's tag (``T1``; its transmitter is ``LT1``).
    pv_m : the transmitter's last good reading [m] (0 before the first).
    good : this scan's reading was good (delivered, finite, in range, not frozen).
    high, low : a good reading at or above the high switch level, at or below the low one.
    high_high : the delivered, finite reading at or above the interlock's trip level (over-range
        and frozen readings included, as the interlock sees them); False without an interlock.
    """

    name: str
    pv_m: float
    good: bool
    high: bool
    low: bool
    high_high: bool


class InterlockStatus(NamedTuple):
    """One high-high interlock: ``tripped`` while its latch holds (until an operator resets it)."""

    tank: str
    tripped: bool


class AlarmFlags(NamedTuple):
    """The ``PLC.Alarms.*`` booleans as the alarm manager has them (each follows its alarm's
    ActiveState after deadband, delays and latching: docs/alarms.md), not the raw comparisons of
    :class:`TankStatus` and :class:`LoopStatus`.

    Attributes
    ----------
    levels : per tank, in plant order, its (high, low, high_high) level-alarm flags.
    pv_bad : per loop, in config order, its PvBad alarm.
    io_fault, supervisor_lost : the PLC's IoFault and SupervisorLost alarms.
    """

    levels: tuple[tuple[bool, bool, bool], ...]
    pv_bad: tuple[bool, ...]
    io_fault: bool
    supervisor_lost: bool


class PlcStatus(NamedTuple):
    """The PLC program's state after a scan (or before the first: the initial state).

    Attributes
    ----------
    scan : scans run so far.
    t_s : model time at the start of the last scan [s] (0 before the first).
    io_healthy : the field link worked in the last scan.
    supervisor_alive : the watchdog sees the supervisor's heartbeat.
    supervisor_lost : the supervisor was alive once and is not now.
    loops : per loop, in config order.
    tanks : per tank, in plant order.
    interlocks : per configured interlock, in config order.
    alarms : the alarm booleans (the alarm manager's).
    external_alive : the external heartbeat's watchdog sees it changing (decision 0055).
    """

    scan: int
    t_s: float
    io_healthy: bool
    supervisor_alive: bool
    supervisor_lost: bool
    loops: tuple[LoopStatus, ...]
    tanks: tuple[TankStatus, ...]
    interlocks: tuple[InterlockStatus, ...]
    alarms: AlarmFlags
    external_alive: bool = False
