"""The PLC's nodes of a :class:`plc_emulator.status.PlcStatus`: the one place that knows which
node shows which part of the program's state.

:func:`status_values` maps a status to the contract's paths (:mod:`tanklab.paths` builders
only). The PLC server publishes it every scan (:meth:`plc_emulator.server.PlcServer.publish_status`),
and the co-simulation's in-process port reads the supervisor's snapshot from it
(``tankctl.cosim.ProgramPort``), as the supervisor's one Read sees the server's nodes. It lives
beside the server rather than in it because the co-simulation must not import asyncua
(decision 0023).
"""

from __future__ import annotations

from functools import cache
from typing import Any

from plc_emulator.status import PlcStatus
from tanklab import paths

__all__ = ["RUNTIME_OWNED_TAGS", "status_values"]

RUNTIME_OWNED_TAGS = (
    paths.plc.scan_period,
    paths.plc.last_scan_duration,
    paths.plc.overruns,
    paths.plc.heartbeat,
    paths.plc.supervisor_timeout,
    paths.plc.external_heartbeat,
    paths.plc.external_timeout,
    *paths.link_status_paths(paths.plc.plant_link).values(),
    *paths.alarm_summary_paths("plc").values(),
)
"""PLC variables the runtime publishes, not :func:`status_values` (plus ``PLC.LIC*.Block`` and
``PLC.Identity.*``, constant): its scan timing, the supervisor's and the external controller's
heartbeats and timeouts, its field link's status, and the alarm summary (published after
condition events and when the rate window moves on:
:class:`tanklab_io.conditions.summary.SummaryPublisher`)."""


def status_values(status: PlcStatus) -> dict[str, Any]:
    """The PLC's node values of ``status``, keyed by tag path, as plain Python types.

    Every variable of :func:`tanklab.tags.plc_tags` except :data:`RUNTIME_OWNED_TAGS`,
    ``PLC.LIC*.Block`` and ``PLC.Identity.*``, each once. Enumerations are published as their
    ints, a block without PID gains as Kp = Ki = Kd = 0.

    The ``PLC.Alarms.*`` booleans are the alarm manager's (``status.alarms``): each follows its
    alarm's ActiveState, after deadband and delays (docs/alarms.md).
    """
    v: dict[str, Any] = {}
    alarms = status.alarms
    for lp, alarm_pv_bad in zip(status.loops, alarms.pv_bad, strict=True):
        sp, sp_low, sp_high, pv, mv, mode, manual, remote, kp, ki, kd, source, pv_bad, owner = _loop_paths(
            lp.name
        )
        v[sp] = lp.sp_m
        v[sp_low] = lp.sp_low_m
        v[sp_high] = lp.sp_high_m
        v[pv] = lp.pv_m
        v[mv] = lp.mv
        v[mode] = int(lp.mode)
        v[manual] = lp.manual_mv
        v[remote] = lp.remote_mv
        g = lp.gains
        if g is None:
            v[kp] = v[ki] = v[kd] = 0.0
        else:
            v[kp], v[ki], v[kd] = g.kp, g.ki, g.kd
        v[source] = int(lp.gain_source)
        v[pv_bad] = alarm_pv_bad
        v[owner] = int(lp.remote_source)
    plc = paths.plc
    v[plc.scan] = status.scan
    v[plc.io_healthy] = status.io_healthy
    v[plc.model_time] = status.t_s
    v[plc.supervisor_alive] = status.supervisor_alive
    v[plc.external_alive] = status.external_alive
    v[plc.io_fault] = alarms.io_fault
    v[plc.supervisor_lost] = alarms.supervisor_lost
    for tank, (a_high, a_low, a_high_high) in zip(status.tanks, alarms.levels, strict=True):
        pv, good, high, low, high_high = _tank_paths(tank.name)
        v[pv] = tank.pv_m
        v[good] = tank.good
        v[high] = a_high
        v[low] = a_low
        v[high_high] = a_high_high
    for il in status.interlocks:
        v[plc.interlock(il.tank)] = il.tripped
    return v


@cache
def _loop_paths(loop: str) -> tuple[str, ...]:
    """A loop's published paths in :func:`status_values` order."""
    lp = paths.plc.loop(loop)
    return (
        lp.sp,
        lp.sp_low,
        lp.sp_high,
        lp.pv,
        lp.mv,
        lp.mode,
        lp.manual_mv,
        lp.remote_mv,
        lp.kp,
        lp.ki,
        lp.kd,
        lp.gain_source,
        paths.plc.pv_bad_alarm(loop),
        lp.remote_source,
    )


@cache
def _tank_paths(tank: str) -> tuple[str, ...]:
    """A tank's published paths in :func:`status_values` order: IO PV and Good, alarms H, L, HH."""
    io = paths.plc.io(tank)
    return (
        io.pv,
        io.good,
        paths.plc.alarm(tank, "H"),
        paths.plc.alarm(tank, "L"),
        paths.plc.alarm(tank, "HH"),
    )
