"""The PLC program's alarms: its :class:`~tanklab.alarms.AlarmManager`, fed once per scan.

After the outputs are written (step 7 of the scan, docs/plc.md), each alarm gets its input from
the scan's state: a tank's level alarm the delivered reading (NaN where none) and the PLC's
quality, a loop's PvBad its bad-PV flag, IoFault the field link's failure, SupervisorLost the
watchdog's (alive once, not alive now), a trip its interlock's latch. The ``PLC.Alarms.*``
booleans are the manager's (docs/alarms.md); the events of the last scan are kept in
:attr:`PlcAlarms.events` for the OPC UA projection, which also calls the manager directly.

An interlock reset (``PlcProgram.reset_interlocks``) resets the tank's latched trip alarm at the
next scan, when its input (the interlock's latch) has gone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from plc_emulator.status import AlarmFlags
from tanklab import paths
from tanklab.alarms import AlarmManager, ConditionEvent, names
from tanklab.alarms.definitions import plc_manager
from tanklab.config import SiteConfig
from tanklab.enums import LoopMode

if TYPE_CHECKING:
    from plc_emulator.program import PlcProgram

__all__ = ["PlcAlarms"]


class PlcAlarms:
    """The PLC's alarm manager and how a scan feeds it.

    Parameters
    ----------
    site : the site (its ``plc`` section).
    event_prefix : the EventId prefix, unique per process (the runtime's; tests leave it empty).
    """

    def __init__(self, site: SiteConfig, *, event_prefix: bytes = b"") -> None:
        self.manager: AlarmManager = plc_manager(site, event_prefix=event_prefix)
        self.events: list[ConditionEvent] = []
        """The events of the last scan."""
        index = {name: i for i, name in enumerate(self.manager.names)}
        # Where each input goes in the manager's definition order (filled in place every scan).
        self._level = [index[names.level(t)] for t in site.tank_names]
        self._pv_bad = [index[names.pv_bad(lp.name)] for lp in site.plc.loops] if site.plc else []
        self._io_fault = index[names.IO_FAULT]
        self._supervisor_lost = index[names.SUPERVISOR_LOST]
        self._trip = {n: index[n] for n in self.manager.names if n.endswith("Trip")}
        self._il_trip = [index[names.trip(il.tank)] for il in site.plc.interlocks] if site.plc else []
        self._values: list[float | bool | None] = [None] * len(index)
        self._good = [True] * len(index)
        self._resets: list[str] = []
        self._suppression = any(d.suppress_when_manual is not None for d in self.manager.definitions)
        # Before the first scan the PLC has read nothing: IoFault shows as it always has (the
        # condition stays normal; the first scan's input replaces it without an event).
        self.manager.prime(names.IO_FAULT, True)
        # The booleans' paths in AlarmFlags order (the manager keys its booleans by path).
        self._level_paths = [tuple(paths.plc.alarm(t, k) for k in ("H", "L", "HH")) for t in site.tank_names]
        self._pv_bad_paths = [paths.plc.pv_bad_alarm(lp.name) for lp in site.plc.loops] if site.plc else []

    def scan(self, program: PlcProgram) -> list[ConditionEvent]:
        """Feed the scan's state at model time ``program.t_s``; return (and keep) its events."""
        t_s = program.t_s
        values, good = self._values, self._good
        raw, ok = program._raw_m, program._good
        for k, i in enumerate(self._level):
            values[i], good[i] = raw[k], ok[k]
        for lp, i in zip(program.loops, self._pv_bad, strict=True):
            values[i] = lp.pv_bad
        values[self._io_fault] = not program.io_healthy
        wd = program.watchdog
        values[self._supervisor_lost] = wd.ever_alive and not wd.alive
        for i in self._trip.values():
            values[i] = False
        for il, i in zip(program.interlocks, self._il_trip, strict=True):
            if il.tripped:  # a tank with two interlocks: either one
                values[i] = True
        manual: set[str] | tuple[()] = ()
        if self._suppression:
            manual = {lp.spec.name for lp in program.loops if lp.mode is LoopMode.MANUAL}
        events = self.manager.scan_values(values, good, t_s, manual=manual)
        for name in self._resets:
            events += self.manager.reset(name, t_s)
        self._resets.clear()
        self.events = events
        return events

    def interlocks_reset(self, tanks: list[str]) -> None:
        """Tanks whose interlock an operator reset: their trip alarms reset at the next scan."""
        self._resets += [n for n in map(names.trip, tanks) if n in self._trip]

    def booleans(self) -> dict[str, bool]:
        """The ``PLC.Alarms.*`` values."""
        return self.manager.booleans()

    def flags(self) -> AlarmFlags:
        """The booleans as a value for :class:`plc_emulator.status.PlcStatus`."""
        b = self.manager.booleans()
        levels = tuple(
            (b.get(h, False), b.get(lo, False), b.get(hh, False)) for h, lo, hh in self._level_paths
        )
        return AlarmFlags(
            levels,
            tuple(b[p] for p in self._pv_bad_paths),
            b[paths.plc.io_fault],
            b[paths.plc.supervisor_lost],
        )
