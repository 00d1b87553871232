"""The PLC program's writable items: one handler per writable tag, for every transport.

Each writable variable of the PLC contract (``SP``, ``SPLow``, ``SPHigh``, ``Mode``,
``ManualMV``, ``RemoteMV``, ``RemoteSource`` of each loop, ``Supervisor.Heartbeat`` and
``External.Heartbeat``) gets its own handler,
attached to its path (:mod:`tanklab.paths`) in :func:`program_writes`: the program setter it
goes to, with the value converted to the setter's type. The OPC UA server
(:class:`plc_emulator.server.PlcServer`) wraps these handlers in its status codes; the
co-simulation's in-process PLC port (:class:`tankctl.cosim.ProgramPort`) applies a write through
:func:`apply_write`, the same table, so a value reaches the program the same way, with the same
checks, whichever way it travelled. The contract's own checks (type, finiteness, EURange,
enumeration) run before, in :class:`tanklab_io.ua.WriteGuard` for OPC UA; the program's checks run
in its setters (ValueError or KeyError: refused, nothing changed).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any
from weakref import WeakKeyDictionary

from plc_emulator.program import PlcProgram
from tanklab import paths
from tanklab.enums import LoopMode, RemoteSource
from tanklab.handlers import HandlerTable

ProgramWrite = Callable[[Any], None]
"""Apply a contract-checked value to the program; raises ValueError or KeyError on refusal."""


def program_writes(program: PlcProgram) -> HandlerTable[ProgramWrite]:
    """The handler of each writable PLC variable, by path."""
    table: HandlerTable[ProgramWrite] = HandlerTable()
    table.on(paths.plc.heartbeat, lambda value: program.heartbeat(int(value)))
    table.on(paths.plc.external_heartbeat, lambda value: program.external_heartbeat(int(value)))
    for lp in program.loops:
        _loop_writes(table, program, lp.spec.name)
    return table


def _loop_writes(table: HandlerTable[ProgramWrite], program: PlcProgram, name: str) -> None:
    loop = paths.plc.loop(name)
    table.on(loop.sp, lambda value: program.set_sp(name, float(value)))
    table.on(loop.sp_low, lambda value: program.set_sp_limits(name, low_m=float(value)))
    table.on(loop.sp_high, lambda value: program.set_sp_limits(name, high_m=float(value)))
    table.on(loop.mode, lambda value: program.set_mode(name, LoopMode(int(value))))
    table.on(loop.manual_mv, lambda value: program.set_manual_mv(name, float(value)))
    table.on(loop.remote_mv, lambda value: program.set_remote_mv(name, float(value)))
    table.on(loop.remote_source, lambda value: program.set_remote_source(name, RemoteSource(int(value))))


_TABLES: WeakKeyDictionary[PlcProgram, HandlerTable[ProgramWrite]] = WeakKeyDictionary()


def apply_write(program: PlcProgram, path: str, value: Any) -> bool:
    """Apply a write of ``value`` to the contract path ``path`` (through :func:`program_writes`,
    built once per program).

    Returns
    -------
    bool
        True when applied; False when ``path`` is not a writable item of the program.

    Raises
    ------
    ValueError, KeyError
        The program refused the value (out of range, unknown loop): nothing changed.
    """
    table = _TABLES.get(program)
    if table is None:
        table = _TABLES[program] = program_writes(program)
    handler = table.get(path)
    if handler is None:
        return False
    handler(value)
    return True
